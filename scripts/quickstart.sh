#!/usr/bin/env bash
# The README's first command: install, build, and run the demo on the built-in phantom.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
scripts/install-deps.sh
scripts/build.sh
build/bin/sonoslice demo demo_out
echo "Open demo_out/contact_sheet.png (axial CT with the probe positions, fan images, simulated ultrasound, linear images)."
