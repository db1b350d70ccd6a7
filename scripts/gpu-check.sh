#!/usr/bin/env bash
# The CUDA path on a machine with an NVIDIA GPU: the lent H100/H200 machine has the CUDA
# toolkit, CMake, ninja and a Python with torch, numpy and nanobind, but none of Debian's packages
# and no network. What the build needs beyond that travels in .carry/ (scripts/gpu-carry.sh fills
# it on a Debian machine): GoogleTest's sources and the wheels of pytest and its dependencies.
#
#   scripts/gpu-check.sh test       build (CLI, the C++ tests, the Python extension), check that a
#                                   GPU is used, every CUDA test (C++ and pytest) with
#                                   SONOSLICE_REQUIRE_CUDA=1 (a CUDA skip is a failure),
#                                   compute-sanitizer memcheck, initcheck and racecheck on the C++
#                                   CUDA tests
#   scripts/gpu-check.sh measure    the benchmarks (slicing, compounding, simulation; torch
#                                   grid_sample and the PCIe bandwidth on the same GPU),
#                                   compute-sanitizer on a short benchmark run, an ncu
#                                   Speed-of-Light pass on the slicing kernel
#   scripts/gpu-check.sh all        both (default); each step alone fits a 10-minute command
#   DRY_RUN=1 scripts/gpu-check.sh  print the commands instead of running them (any machine)
#
# Everything goes to $OUT (default build-gpu/results) in a few files, since the device tool brings
# back only a handful: summary.txt (each step's exit status and time), logs.txt (every step's
# output, one after another), peers_cuda.json and the ncu report. The script stops when the build
# fails or no GPU is seen; other failing steps are recorded in the summary and the rest go on
# (exit status 1 at the end).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
root=$PWD
step=${1:-all}
case $step in test | measure | all) ;; *)
  echo "gpu-check: unknown step '$step' (test, measure or all)" >&2
  exit 2
  ;;
esac
out=${OUT:-$root/build-gpu/results}
build=$root/build-gpu
gtest=${GTEST_SRC:-$root/.carry/googletest}
wheels=${WHEELS:-$root/.carry/wheels}
python=${PYTHON:-$(command -v python3 || true)}
dry=${DRY_RUN:-0}
mkdir -p "$out"
summary=$out/summary.txt
logs=$build/gpu-logs  # one file per step; gathered into $out/logs.txt on exit
mkdir -p "$logs"
[[ $step == measure ]] || { : >"$summary" && rm -f "$logs"/*.txt; }
gather() {
  local f
  for f in "$logs"/*.txt; do
    [[ -f $f ]] && printf '\n===== %s\n' "$(basename "$f" .txt)" && cat "$f"
  done >"$out/logs.txt"
}
trap gather EXIT
note() { echo "gpu-check: $*" | tee -a "$summary"; }
# run <log name> <command...>: the command's output to the terminal and $logs/<log name>.txt.
run() {
  local name=$1
  shift
  if [[ $dry == 1 ]]; then
    printf 'would run (%s):' "$name"
    printf ' %q' "$@"
    printf '\n'
    return 0
  fi
  local t0=$SECONDS rc=0
  "$@" 2>&1 | tee "$logs/$name.txt" || rc=${PIPESTATUS[0]}
  note "$name: exit $rc, $((SECONDS - t0)) s"
  return "$rc"
}

# nvcc on PATH: the toolkit's usual homes.
if ! command -v nvcc >/dev/null; then
  for d in /usr/local/cuda/bin /usr/local/cuda-*/bin /opt/cuda/bin; do
    [[ -x $d/nvcc ]] && export PATH="$d:$PATH" && break
  done
fi
if [[ $dry != 1 ]]; then
  command -v nvcc >/dev/null || { note "FAILED: no nvcc (CUDA toolkit) found"; exit 1; }
  [[ -f $gtest/CMakeLists.txt ]] || {
    note "FAILED: no GoogleTest sources at $gtest: run scripts/gpu-carry.sh on a Debian machine" \
      "and carry .carry/ (GTEST_SRC names another copy)"
    exit 1
  }
  [[ -n $python ]] || { note "FAILED: no python3"; exit 1; }
fi
export SONOSLICE_REQUIRE_CUDA=1
pkg=$build/python-package  # the package as it would be installed: the .py files and the module
export PYTHONPATH=$pkg:$build/python-deps${PYTHONPATH:+:$PYTHONPATH}
sanitizer=${COMPUTE_SANITIZER:-$(command -v compute-sanitizer || echo "$(dirname "$(command -v nvcc || echo /usr/local/cuda/bin/nvcc)")/compute-sanitizer")}
ncu=${NCU:-$(command -v ncu || echo "$(dirname "$(command -v nvcc || echo /usr/local/cuda/bin/nvcc)")/ncu")}

# A step that fails is recorded and the rest go on (GPU time is short: one call should show
# everything); the script's exit status is then 1.
failed=0
check() { run "$@" || failed=1; }
# The CUDA tests of the C++ suite (every CUDA test is in test_core; the CPU suite runs in CI).
cuda_tests='Cuda*:*Cuda*:*cuda*'

if [[ $step == test || $step == all ]]; then
  note "$(date -u +%FT%TZ) test on $(hostname)"
  generator=()
  command -v ninja >/dev/null && generator=(-G Ninja)
  # The extension needs the Python's headers; without them the C++ checks still run.
  with_python=ON targets=(sonoslice test_core _sonoslice)
  if [[ $dry != 1 ]] && ! "$python" -c 'import os, sysconfig, sys
sys.exit(not os.path.exists(os.path.join(sysconfig.get_paths()["include"], "Python.h")))'; then
    note "FAILED: no Python.h for $python: the Python extension and pytest are left out"
    failed=1 with_python=OFF targets=(sonoslice test_core)
  fi
  run configure cmake -S . -B "$build" "${generator[@]}" -DCMAKE_BUILD_TYPE=Release \
    -DSONOSLICE_WITH_ITK=OFF -DSONOSLICE_WITH_VTK=OFF -DSONOSLICE_WITH_CUDA=ON \
    -DCMAKE_CUDA_ARCHITECTURES="${CUDA_ARCHS:-90}" -DSONOSLICE_GTEST_SOURCE_DIR="$gtest" \
    -DSONOSLICE_BUILD_PYTHON=$with_python -DPython_EXECUTABLE="$python"
  # What the GPU checks use: the CLI, the C++ test binary with the CUDA tests, the extension.
  run build cmake --build "$build" -j "$(nproc)" --target "${targets[@]}"
  # The Python package from the build tree: python/sonoslice/*.py plus the extension module.
  [[ $with_python == ON ]] && run python-package bash -c "rm -rf '$pkg' && mkdir -p '$pkg' && cp -r python/sonoslice '$pkg/' &&
    cp '$build'/python/_sonoslice*.so '$pkg/sonoslice/'"
  if [[ $with_python == ON && $dry != 1 ]] && ! "$python" -c "import pytest" 2>/dev/null; then
    run python-deps "$python" -m pip install --no-index --find-links "$wheels" \
      --target "$build/python-deps" pytest
  fi
  # A GPU must actually be there and used: the CUDA line of `info --devices` names it.
  run devices "$build/bin/sonoslice" info --devices
  if [[ $dry != 1 ]] && ! grep -q '^cuda:0: ' "$logs/devices.txt"; then
    note "FAILED: no GPU seen (sonoslice info --devices above)"
    exit 1
  fi
  check gtest-cuda "$build/bin/test_core" --gtest_filter="$cuda_tests"
  [[ $with_python == ON ]] && check pytest-cuda env SONOSLICE_CLI="$build/bin/sonoslice" "$python" -m pytest -q -rs \
    -p no:cacheprovider python/tests -k "cuda or gpu"
  # The CUDA tests under compute-sanitizer: out-of-bounds and misaligned accesses, reads of
  # uninitialised device memory, shared-memory races.
  for tool in memcheck initcheck racecheck; do
    check "sanitizer-$tool" timeout 150 "$sanitizer" --tool "$tool" --error-exitcode 1 \
      "$build/bin/test_core" --gtest_filter="$cuda_tests"
  done
fi

if [[ $step == measure || $step == all ]]; then
  note "$(date -u +%FT%TZ) measure on $(hostname)"
  [[ $dry == 1 || -x $build/bin/sonoslice ]] || { note "FAILED: run the test step first"; exit 1; }
  run gpu nvidia-smi --query-gpu=name,memory.total,clocks.max.sm,pcie.link.gen.max,pcie.link.width.max \
    --format=csv || true
  # Slicing: W1 and W2, float32 and int16, into GPU memory and to host memory. 10,000 poses, so
  # that one batch runs well past launch overhead (W1 float32: 3.6 GB of images).
  check bench-slice timeout 120 "$build/bin/sonoslice" bench --device cuda --count 10000 --repeat 5
  # The row kernels' tile (rows per warp; slicing's default 2, compounding's 1): other shapes, so
  # that the defaults stay the fastest on the card at hand.
  for tile in 1 4; do
    check "bench-slice-tile$tile" env SONOSLICE_CUDA_ROW_TILE=$tile timeout 120 \
      "$build/bin/sonoslice" bench --device cuda --count 10000 --repeat 3
  done
  # Compounding: Jauer's workload end to end (target: under 0.2 s) and the 1000-frame 2D sweep.
  check bench-compound timeout 120 "$build/bin/sonoslice" bench --compound --device cuda --repeat 3
  check bench-compound-tile2 env SONOSLICE_CUDA_ROW_TILE=2 timeout 120 "$build/bin/sonoslice" \
    bench --compound --device cuda --repeat 3
  # Simulation: W1 B-mode images from the phantom CT, on the GPU and on the machine's CPU cores.
  check bench-simulate timeout 120 "$build/bin/sonoslice" bench --simulate --device cuda \
    --count 4096 --repeat 3
  check bench-simulate-cpu timeout 120 "$build/bin/sonoslice" bench --simulate --count 256 --repeat 1
  # torch grid_sample on the same GPU, the same poses; the PCIe bandwidth of this machine.
  check peers-cuda timeout 240 "$python" bench/peers_cuda.py --sonoslice "$build/bin/sonoslice" \
    --count 10000 --repeat 5 --json "$out/peers_cuda.json"
  # The Python API into pageable and into pinned host memory (a torch tensor, pin_memory=True).
  check peers-cuda-python timeout 120 "$python" -X faulthandler bench/peers_cuda.py \
    --sonoslice "$build/bin/sonoslice" --count 10000 --repeat 5 --python-to-host
  check sanitizer-bench timeout 60 "$sanitizer" --tool memcheck --error-exitcode 1 \
    "$build/bin/sonoslice" bench --device cuda --count 50 --repeat 1
  # Speed of Light of the slicing kernel (rows_kernel: SliceImpl.h through parallel_for_rows),
  # W1 float32, one launch after warm-up; the report file opens in Nsight Compute.
  run ncu-slice timeout 120 "$ncu" --clock-control none --section SpeedOfLight \
    --section MemoryWorkloadAnalysis --section Occupancy --section LaunchStats --kernel-name regex:rows_kernel \
    --launch-skip 2 --launch-count 1 --export "$out/slice-kernel" --force-overwrite \
    "$build/bin/sonoslice" bench --device cuda --count 1000 --repeat 1 &&
    run ncu-slice-details "$ncu" --import "$out/slice-kernel.ncu-rep" --page details ||
    note "ncu failed (no permission for GPU performance counters?): see ncu-slice.txt"
fi
if [[ $failed == 1 ]]; then
  note "done, with failures (above)"
  exit 1
fi
note "done"
