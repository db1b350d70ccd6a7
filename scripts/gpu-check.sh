#!/usr/bin/env bash
# For a machine with an NVIDIA GPU and none of Debian's packages (the lent H200 machine): builds
# the core and the CLI without ITK (volumes and outputs in .npy), runs every test (the CUDA ones
# included: slicing and compounding) and the GPU benchmarks. Needs GoogleTest's sources: GTEST_SRC, default
# .carry/googletest (copy /usr/src/googletest there and carry it). bench/peers_cuda.py needs the
# fan-slicer configs: FANSLICER_CONFIGS, default .carry/fanslicer.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
gtest="${GTEST_SRC:-.carry/googletest}"
configs="${FANSLICER_CONFIGS:-.carry/fanslicer}"
out="${OUT:-build-gpu/results}"
mkdir -p "$out"
generator=()
command -v ninja >/dev/null && generator=(-G Ninja)
cmake -S . -B build-gpu "${generator[@]}" -DCMAKE_BUILD_TYPE=Release -DSONOSLICE_WITH_ITK=OFF \
  -DSONOSLICE_WITH_CUDA=ON -DCMAKE_CUDA_ARCHITECTURES="${CUDA_ARCHS:-90}" \
  -DSONOSLICE_GTEST_SOURCE_DIR="$(realpath "$gtest")"
cmake --build build-gpu -j "$(nproc)"
build-gpu/bin/sonoslice info --devices | tee "$out/devices.txt"
ctest --test-dir build-gpu --output-on-failure -j 4 2>&1 | tee "$out/ctest.txt"
build-gpu/bin/test_core --gtest_filter='Cuda*:*cuda*' 2>&1 | grep -E "cuda vs cpu|accuracy|OK|FAILED" | tee "$out/cuda_equivalence.txt"
build-gpu/bin/sonoslice bench --device cuda --repeat 5 | tee "$out/bench_cuda.txt"
# Compounding: Jauer's workload (target: under 0.2 s on one H200) and the 2D sweep.
build-gpu/bin/sonoslice bench --compound --device cuda --repeat 3 | tee "$out/bench_compound_cuda.txt"
python3 bench/peers_cuda.py --sonoslice build-gpu/bin/sonoslice --shared "$configs" --json "$out/peers_cuda.json" \
  | tee "$out/peers_cuda.txt"
