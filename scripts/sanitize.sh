#!/usr/bin/env bash
# The C++ test suites under AddressSanitizer + UndefinedBehaviorSanitizer (CI stage).
# Configures ./build-asan (CPU only, no benchmarks, no Python; SONOSLICE_SANITIZE=ON instruments
# sonoslice's own targets, not the prebuilt ITK/VTK), builds it and runs ctest with leak
# detection on. Any sanitizer report stops the process with exit status 23, which fails its test
# (the CLI tests compare exit statuses exactly, so a report in a CLI run that was expected to
# refuse its input with 1 fails too). AddressSanitizer and LeakSanitizer reports are also written
# to build-asan/sanitizer-logs/; UBSan's (GCC's runtime ignores log_path for them) are looked for
# in every test's output (build-asan/Testing/Temporary/LastTest.log). The script prints every
# report and fails when there is any, or when a test fails.
# The compiler: Debian's clang when installed (scripts/install-deps.sh installs it), and then the
# same build also holds the libFuzzer harnesses, so that scripts/fuzz.sh can fuzz without a second
# build of the library (FUZZ_BUILD_DIR=build-asan; .ci/run does this). Without clang: GCC, tests
# only. SANITIZE_CXX=g++ picks GCC (in a fresh build-asan/).
#   scripts/sanitize.sh [extra cmake -D options]
#   JOBS=N       parallel build and test jobs (default: nproc)
#   CTEST_ARGS   extra ctest arguments, e.g. CTEST_ARGS="-R Cli" for a quick look
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
root=$PWD
build=build-asan
jobs=${JOBS:-$(nproc)}
launcher=()
command -v ccache >/dev/null && launcher=(-DCMAKE_CXX_COMPILER_LAUNCHER=ccache)
start=$(date +%s)
mkdir -p "$build"
cxx=${SANITIZE_CXX:-$(command -v clang++ || command -v g++)}
compiler=(-DCMAKE_CXX_COMPILER="$cxx")
if [[ $(basename "$cxx") == clang* ]]; then
  compiler+=(-DCMAKE_C_COMPILER="${cxx%++}" -DSONOSLICE_BUILD_FUZZERS=ON)
  # LLVM's linker when installed: the 27 sanitized programs link in 14 s instead of 40 s with ld
  # (two cores).
  if command -v ld.lld >/dev/null; then
    for kind in EXE SHARED MODULE; do compiler+=(-DCMAKE_${kind}_LINKER_FLAGS=-fuse-ld=lld); done
  fi
else
  compiler+=(-DSONOSLICE_BUILD_FUZZERS=OFF)
fi

# -O1 (and line tables, CMakeLists.txt): readable stacks at a bearable speed; assertions stay on
# (no NDEBUG). A unity build (each target's files compiled a few at a time, files with their own
# options apart): 470 s instead of 567 s on two cores, since every file parses the same ITK, VTK
# and gtest headers. So two files of one target cannot both define a helper of the same name, even
# in an anonymous namespace. The release build stays one file at a time, so CI still compiles
# every file on its own (an include missing from a file would be hidden in a unity build).
cmake -S . -B "$build" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo \
  -DCMAKE_CXX_FLAGS_RELWITHDEBINFO="-O1" -DCMAKE_UNITY_BUILD=ON "${compiler[@]}" "${launcher[@]}" \
  -DSONOSLICE_SANITIZE=ON -DSONOSLICE_WITH_CUDA=OFF -DSONOSLICE_BUILD_BENCHMARKS=OFF \
  -DSONOSLICE_BUILD_PYTHON=OFF -DSONOSLICE_BUILD_TESTS=ON "$@" >"$build/configure.log" \
  || { cat "$build/configure.log"; exit 1; }
grep -E "^-- sonoslice:" "$build/configure.log" || true
cmake --build "$build" -j "$jobs"

logs=$root/$build/sanitizer-logs
rm -rf "$logs"
mkdir -p "$logs"
# Leaks are reported; only the prebuilt libraries' own allocations are suppressed (the list and
# why: scripts/lsan.supp). exitcode 23 tells a sanitizer stop from a sonoslice error (exit 1).
# No test needs 4 GiB in one allocation: one that large comes from a header claiming sizes its
# small file does not hold (the fuzz regressions replayed by ctest, FuzzRegressions.*).
export ASAN_OPTIONS="detect_leaks=1:halt_on_error=1:exitcode=23:strict_string_checks=1:\
detect_stack_use_after_return=1:check_initialization_order=1:strict_init_order=1:\
max_allocation_size_mb=4096:log_path=$logs/asan"
export LSAN_OPTIONS="suppressions=$root/scripts/lsan.supp:print_suppressions=0"
export UBSAN_OPTIONS="print_stacktrace=1:halt_on_error=1:exitcode=23:log_path=$logs/ubsan"

status=0
# shellcheck disable=SC2086
ctest --test-dir "$build" --output-on-failure -j "$jobs" ${CTEST_ARGS:-} || status=1

shopt -s nullglob
reports=("$logs"/*)
if [[ ${#reports[@]} -gt 0 ]]; then
  for r in "${reports[@]}"; do
    echo "==== sanitizer report: ${r#"$root"/}"
    cat "$r"
  done
  echo "sanitize: ${#reports[@]} AddressSanitizer/LeakSanitizer report(s) above" >&2
  status=1
fi
ub=$(grep -c -E 'runtime error:|ERROR: (Address|Leak)Sanitizer' \
  "$build/Testing/Temporary/LastTest.log" || true)
if [[ $ub -gt 0 ]]; then
  grep -E -A12 'runtime error:|ERROR: (Address|Leak)Sanitizer' "$build/Testing/Temporary/LastTest.log"
  echo "sanitize: $ub sanitizer report(s) in the test log (above)" >&2
  status=1
fi
echo "sanitize: $([[ $status -eq 0 ]] && echo clean || echo FAILED) in $(($(date +%s) - start)) s"
exit $status
