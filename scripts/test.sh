#!/usr/bin/env bash
# The test command (README): the C++ suites under CTest, then the Python package's pytest suite.
# Expects scripts/build.sh and scripts/install-python.sh to have run (.ci/run does both).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
ctest --test-dir build --output-on-failure -j "$(nproc)"
# pytest on up to four processes when pytest-xdist is installed (scripts/install-deps.sh): the
# suite is mostly single-threaded (168 s alone, 116 s on two processes on two cores).
workers=()
if build/venv/bin/python -c "import xdist" 2>/dev/null; then
  n=$(nproc)
  workers=(-n "$((n < 4 ? n : 4))")
fi
SONOSLICE_CLI="$PWD/build/bin/sonoslice" build/venv/bin/python -m pytest -q -rs "${workers[@]}" python/tests
