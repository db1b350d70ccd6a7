#!/usr/bin/env bash
# Configures and builds sonoslice in ./build (Release). The CLI lands at build/bin/sonoslice.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
# The CUDA toolkit's usual home, for machines where nvcc is installed but not on PATH.
if ! command -v nvcc >/dev/null && [[ -x /usr/local/cuda/bin/nvcc ]]; then
  export PATH="/usr/local/cuda/bin:$PATH"
fi
# Ninja when there is one (and build/ is new: a configured build keeps its generator), so that
# scripts/install-python.sh can build the Python module inside this same tree.
generator=()
[[ ! -f build/CMakeCache.txt ]] && command -v ninja >/dev/null && generator=(-G Ninja)
cmake -S . -B build "${generator[@]}" -DCMAKE_BUILD_TYPE=Release "$@"
cmake --build build -j "$(nproc)"
