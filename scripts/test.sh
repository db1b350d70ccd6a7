#!/usr/bin/env bash
# The test command (README): the C++ suites under CTest, then the Python package's pytest suite.
# Expects scripts/build.sh and scripts/install-python.sh to have run (.ci/run does both).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
ctest --test-dir build --output-on-failure -j "$(nproc)"
SONOSLICE_CLI="$PWD/build/bin/sonoslice" build/venv/bin/python -m pytest -q -rs python/tests
