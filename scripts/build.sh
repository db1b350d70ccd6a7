#!/usr/bin/env bash
# Configures and builds sonoslice in ./build (Release). The CLI lands at build/bin/sonoslice.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
# The CUDA toolkit's usual home, for machines where nvcc is installed but not on PATH.
if ! command -v nvcc >/dev/null && [[ -x /usr/local/cuda/bin/nvcc ]]; then
  export PATH="/usr/local/cuda/bin:$PATH"
fi
cmake -S . -B build -DCMAKE_BUILD_TYPE=Release "$@"
cmake --build build -j "$(nproc)"
