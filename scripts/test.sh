#!/usr/bin/env bash
# The test command (README): the C++ suites under CTest, then the Python package's pytest suite.
# Expects scripts/build.sh and scripts/install-python.sh to have run (.ci/run does both).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
ctest --test-dir build --output-on-failure -j "$(nproc)"
# pytest on up to four processes when pytest-xdist is installed (scripts/install-deps.sh): the
# suite is mostly single-threaded (168 s alone, 116 s on two processes on two cores). The tests
# marked `alone` measure a rate or a latency (the live view's updates a second): they run
# afterwards, by themselves, since beside another process on two cores they fell short.
export SONOSLICE_CLI="$PWD/build/bin/sonoslice"
pytest=(build/venv/bin/python -m pytest -q -rs)
if build/venv/bin/python -c "import xdist" 2>/dev/null; then
  n=$(nproc)
  "${pytest[@]}" -n "$((n < 4 ? n : 4))" -m "not alone" python/tests
  "${pytest[@]}" -m alone python/tests
else
  "${pytest[@]}" python/tests
fi
