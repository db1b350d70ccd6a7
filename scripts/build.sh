#!/usr/bin/env bash
# Configures and builds sonoslice in ./build (Release). The CLI lands at build/bin/sonoslice.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
cmake -S . -B build -DCMAKE_BUILD_TYPE=Release "$@"
cmake --build build -j "$(nproc)"
