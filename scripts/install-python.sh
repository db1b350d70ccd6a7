#!/usr/bin/env bash
# Builds and installs the Python package into build/venv, a virtual environment of Debian's
# /usr/bin/python3 that also sees Debian's python3-numpy, python3-torch (CPU), python3-pytest and
# python3-tqdm (scripts/install-deps.sh). The build requirements (scikit-build-core, nanobind)
# come from PyPI. Any other Python >= 3.9 works the same way: `pip install .`.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
if ! command -v nvcc >/dev/null && [[ -x /usr/local/cuda/bin/nvcc ]]; then
  export PATH="/usr/local/cuda/bin:$PATH"
fi
[[ -x build/venv/bin/python ]] || /usr/bin/python3 -m venv --system-site-packages build/venv
build/venv/bin/python -m pip install -q --upgrade pip
# After scripts/build.sh, pip builds the module inside build/ (the libraries are already there, so
# only the bindings compile; the options pyproject.toml turns off for a wheel keep build/'s values,
# so its tests, CLI and benchmarks stay). Without build/, pip builds in its own folder.
# The build requirements go into the venv itself (no isolated build environment): build/ then
# keeps a nanobind that stays, and a later `cmake --build build` can reconfigure.
options=()
if [[ -f build/CMakeCache.txt ]]; then
  build/venv/bin/python -m pip install -q "scikit-build-core>=0.10" "nanobind>=2.4"
  options+=(--no-build-isolation -Cbuild-dir=build)
  for o in SONOSLICE_BUILD_TESTS SONOSLICE_BUILD_APPS SONOSLICE_BUILD_BENCHMARKS; do
    v=$(sed -n "s/^$o:BOOL=//p" build/CMakeCache.txt)
    [[ -n $v ]] && options+=("-Ccmake.define.$o=$v")
  done
fi
build/venv/bin/python -m pip install -q "${options[@]}" .
# sonoslice dataset: Dask's distributed (--scheduler) and webdataset (its docs' reader, tests)
# come from PyPI.
build/venv/bin/python -m pip install -q "distributed>=2023.1" "webdataset>=0.2"
# sonoslice live: pyigtl, an independent OpenIGTLink implementation (tests and the example sender).
# --no-deps: its numpy and crcmod are Debian's (a PyPI numpy would hide the one torch is built for).
build/venv/bin/python -m pip install -q --no-deps "pyigtl>=0.3"
# sonoslice view: selenium drives Debian's chromium + chromium-driver in the browser tests.
build/venv/bin/python -m pip install -q "selenium>=4.10"
build/venv/bin/python -c "import sonoslice; print('sonoslice', sonoslice.__version__, 'installed in build/venv')"
