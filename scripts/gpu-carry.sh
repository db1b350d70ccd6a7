#!/usr/bin/env bash
# Fills .carry/ (git-ignored) with what scripts/gpu-check.sh needs on a GPU machine that has no
# Debian packages and no network: GoogleTest's sources (Debian's googletest package) and the
# wheels of pytest and its dependencies (pure Python, any Python 3 there). Run it here, then carry
# .carry/ with the tree (the device tool's carry: [".carry"]).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
src=${GTEST_SOURCE:-/usr/src/googletest}
[[ -f $src/CMakeLists.txt ]] || { echo "gpu-carry: no GoogleTest sources at $src (apt-get install googletest)" >&2; exit 1; }
rm -rf .carry/googletest .carry/wheels
mkdir -p .carry
cp -r "$src" .carry/googletest
python3 -m pip download -q --only-binary=:all: --python-version 3.10 -d .carry/wheels pytest
echo "gpu-carry: $(du -sh .carry | cut -f1) in .carry/ (googletest, $(ls .carry/wheels | wc -l) wheels)"
