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
build/venv/bin/python -m pip install -q .
build/venv/bin/python -c "import sonoslice; print('sonoslice', sonoslice.__version__, 'installed in build/venv')"
