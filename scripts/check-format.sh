#!/usr/bin/env bash
# Checks (never rewrites) that every C++/CUDA source follows .clang-format, with Debian's
# clang-format (bookworm: version 14; another version may format a few constructs differently).
# Fix with: git ls-files '*.cpp' '*.h' '*.cu' '*.cuh' ':!third_party' | xargs clang-format -i
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
command -v clang-format >/dev/null || { echo "check-format: clang-format not found (scripts/install-deps.sh installs it)" >&2; exit 1; }
mapfile -t files < <(git ls-files '*.cpp' '*.h' '*.cu' '*.cuh' ':!third_party')
if ! clang-format --dry-run --Werror "${files[@]}" 2>/tmp/check-format.$$; then
  grep -oE '^[^ :]+:[0-9]+:[0-9]+: (error|warning)' /tmp/check-format.$$ | cut -d: -f1 | sort -u |
    sed 's/^/check-format: not formatted: /' >&2
  rm -f /tmp/check-format.$$
  exit 1
fi
rm -f /tmp/check-format.$$
echo "check-format: ${#files[@]} files follow .clang-format ($(clang-format --version))"
