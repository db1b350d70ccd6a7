#!/usr/bin/env bash
# Installs the Debian (bookworm) packages sonoslice builds and tests with. Idempotent: packages
# already present are not fetched again. Needs root (or sudo).
#   scripts/install-deps.sh          build + test dependencies
#   scripts/install-deps.sh --bench  also the peers of bench/peers.py (Debian's python3-vtk9,
#                                    python3-scipy, python3-nibabel for /usr/bin/python3)
set -euo pipefail

packages=(
  build-essential cmake pkg-config ninja-build
  clang-format                           # scripts/check-format.sh (CI checks, never rewrites)
  clang libclang-rt-14-dev llvm          # scripts/fuzz.sh (libFuzzer, sanitizer runtimes) and
                                         # llvm-symbolizer for readable sanitizer stacks
  lld                                    # scripts/sanitize.sh links with it (faster than ld)
  libinsighttoolkit5-dev libgdcm-tools   # ITK 5.2 (NIfTI, MetaImage, NRRD, DICOM, PNG); gdcm tools
                                         # only so GDCM's CMake config finds the files it lists
  zlib1g-dev
  libpng-dev                             # PNG outputs, written with libpng so errors are seen
  libvtk9-dev                            # VTK 9.1: surface meshes (.vtk, .vtp, .stl, .obj, .ply)
  nlohmann-json3-dev libcli11-dev
  libpugixml-dev                         # PLUS configuration XML
  libnlopt-cxx-dev                       # registration's BOBYQA and Nelder-Mead
  googletest libgtest-dev libbenchmark-dev
  python3-venv python3-numpy python3-pytest python3-tqdm python3-torch python3-yaml  # the Python package's tests
  python3-pytest-xdist                   # ... run on every core (scripts/test.sh)
  libopenigtlink-dev python3-crcmod      # sonoslice live's tests: an OpenIGTLink peer on Debian's
                                         # library; pyigtl's CRC (with its C extension)
  libcpp-httplib-dev                     # sonoslice view's HTTP server
  chromium chromium-driver               # sonoslice view's browser tests (headless, selenium)
)
if [[ "${1:-}" == "--bench" ]]; then
  packages+=(python3-vtk9 python3-scipy python3-nibabel)
fi

missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [[ ${#missing[@]} -eq 0 ]]; then
  echo "install-deps: all ${#packages[@]} packages present"
  exit 0
fi

sudo=""
if [[ $(id -u) -ne 0 ]]; then
  command -v sudo >/dev/null || { echo "install-deps: need root or sudo to install: ${missing[*]}" >&2; exit 1; }
  sudo="sudo"
fi
echo "install-deps: installing ${missing[*]}"
export DEBIAN_FRONTEND=noninteractive
$sudo apt-get update -q
$sudo apt-get install -y -q --no-install-recommends "${missing[@]}"
