#!/usr/bin/env bash
# Builds the libFuzzer harnesses (fuzz/, Debian's clang) in ./build-fuzz and, for each parser:
#   1. replays every input of fuzz/regressions/<parser>/ once, without mutation: each must run
#      clean (these are the crashes found so far; a fixed bug stays fixed);
#   2. fuzzes for a bounded time, from the seeds in fuzz/corpus/<parser>/ plus the regression
#      inputs (the corpus grown so far lives in build-fuzz/corpus/<parser>/, outside git).
# A crash (sanitizer report, deadly signal, foreign exception, leak, out-of-memory, timeout) is
# copied into fuzz/regressions/<parser>/ and the script fails. Commit the new input with the fix.
#   scripts/fuzz.sh [seconds-per-target] [parser...]     default: 20 s, every parser
#   JOBS=N            build jobs, and parsers fuzzed at once (default: nproc)
#   FUZZ_FORK=N       run N fuzzing processes per parser that carry on after a crash (long runs
#                     that collect several crashes); default 0: stop at the first crash
#   FUZZ_FOREIGN=log  an exception that is not a sonoslice::Error is saved (one input per kind)
#                     and the run carries on, instead of stopping there (long runs)
#   FUZZ_SEED=N       libFuzzer's random seed (default: a new one each run); CI fixes it, so
#                     that its runs follow the same mutations (how far each gets still varies)
#   FUZZ_REPLAY_ONLY=1  only step 1 (replay the regression inputs, no fuzzing)
#   FUZZ_BUILD_DIR=dir  use the harnesses of an existing build instead of configuring build-fuzz:
#                     scripts/sanitize.sh's build-asan holds them when it was built with clang
#                     (.ci/run: one instrumented build of the library for both stages)
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
root=$PWD
build=$root/build-fuzz
if [[ -n ${FUZZ_BUILD_DIR:-} ]]; then
  build=$(realpath "$FUZZ_BUILD_DIR")
  [[ -f $build/fuzz-targets.txt ]] || {
    echo "fuzz: $FUZZ_BUILD_DIR has no libFuzzer harnesses (configure it with clang and" \
      "-DSONOSLICE_BUILD_FUZZERS=ON, as scripts/sanitize.sh does)" >&2
    exit 2
  }
fi
seconds=${1:-20}
shift || true
jobs=${JOBS:-$(nproc)}
fork=${FUZZ_FORK:-0}
start=$(date +%s)

command -v clang++ >/dev/null || {
  echo "fuzz: clang++ not found (Debian: apt-get install clang libclang-rt-14-dev)" >&2
  exit 1
}
launcher=()
command -v ccache >/dev/null && launcher=(-DCMAKE_CXX_COMPILER_LAUNCHER=ccache)
if [[ -z ${FUZZ_BUILD_DIR:-} ]]; then
  cmake -S . -B "$build" -G Ninja -DCMAKE_C_COMPILER=clang -DCMAKE_CXX_COMPILER=clang++ \
    -DCMAKE_BUILD_TYPE=RelWithDebInfo -DCMAKE_CXX_FLAGS_RELWITHDEBINFO="-O1" "${launcher[@]}" \
    -DSONOSLICE_BUILD_FUZZERS=ON -DSONOSLICE_WITH_CUDA=OFF -DSONOSLICE_BUILD_TESTS=OFF \
    -DSONOSLICE_BUILD_APPS=OFF -DSONOSLICE_BUILD_BENCHMARKS=OFF -DSONOSLICE_BUILD_PYTHON=OFF >/dev/null
fi
read -r -a all <<<"$(tr ';' ' ' <"$build/fuzz-targets.txt")"
cmake --build "$build" -j "$jobs" --target "${all[@]/#/fuzz_}"

targets=("$@")
[[ ${#targets[@]} -eq 0 ]] && targets=("${all[@]}")

# Leaks count (only the prebuilt libraries' own allocations are suppressed: scripts/lsan.supp).
export ASAN_OPTIONS="detect_leaks=1:halt_on_error=1:strict_string_checks=1"
export LSAN_OPTIONS="suppressions=$root/scripts/lsan.supp:print_suppressions=0"
export UBSAN_OPTIONS="print_stacktrace=1:halt_on_error=1"
# One input may take this long / this much memory before it counts as a finding. The memory
# limit is what a header may make sonoslice allocate when the file does not hold the data.
limits=(-timeout=30 -rss_limit_mb=3072 -malloc_limit_mb=2048)

# One parser: replay its regression inputs, then fuzz it. Its summary line goes to
# logs/<parser>.summary; the status says whether it failed.
fuzz_one() {
  local t=$1
  exe=$build/bin/fuzz_$t
  seeds=$root/fuzz/corpus/$t
  regressions=$root/fuzz/regressions/$t
  corpus=$build/corpus/$t
  artifacts=$build/artifacts/$t
  export TMPDIR=$build/tmp/$t  # each parser's own: parsers run side by side
  rm -rf "$TMPDIR" "$artifacts"
  unset SONOSLICE_FUZZ_FOREIGN_DIR  # replays stop at a foreign exception
  mkdir -p "$TMPDIR" "$corpus" "$artifacts" "$regressions"
  log=$build/logs/$t.log
  : >"$log"
  local failed=0

  # 1. The regression corpus, every input once.
  bad=0
  total=0
  shopt -s nullglob
  for input in "$regressions"/*; do
    total=$((total + 1))
    if ! "$exe" "${limits[@]}" "$input" >>"$log" 2>&1; then
      bad=$((bad + 1))
      echo "fuzz: $t: regression input still fails: ${input#"$root"/}" >&2
    fi
  done
  shopt -u nullglob
  if [[ $bad -gt 0 ]]; then
    failed=1
    echo "$t: $bad of $total regression inputs FAIL" >"$build/logs/$t.summary"
    grep -E '^(==[0-9]+==ERROR|SUMMARY|FOREIGN EXCEPTION|    #[0-9] )' "$log" | head -40 >&2 || true
  fi
  if [[ ${FUZZ_REPLAY_ONLY:-0} == 1 ]]; then
    [[ $failed -eq 1 ]] || echo "$t: $total regression inputs replayed" >"$build/logs/$t.summary"
    return $failed
  fi

  # 2. Fuzz for a bounded time.
  extra=()
  [[ -f $root/fuzz/dict/$t.dict ]] && extra+=(-dict="$root/fuzz/dict/$t.dict")
  [[ $fork -gt 0 ]] && extra+=(-fork="$fork" -ignore_crashes=1 -ignore_ooms=1 -ignore_timeouts=1)
  [[ -n ${FUZZ_SEED:-} ]] && extra+=(-seed="$FUZZ_SEED")
  dirs=("$corpus")
  [[ -d $seeds ]] && dirs+=("$seeds")
  # Regression inputs that still fail would only be found again: left out until fixed.
  [[ $bad -eq 0 ]] && dirs+=("$regressions")
  foreign=$build/foreign/$t
  rm -rf "$foreign"
  if [[ ${FUZZ_FOREIGN:-} == log ]]; then
    mkdir -p "$foreign"
    export SONOSLICE_FUZZ_FOREIGN_DIR=$foreign
  fi
  local t0 rc=0
  t0=$(date +%s)
  "$exe" "${limits[@]}" "${extra[@]}" -max_total_time="$seconds" -print_final_stats=1 \
    -artifact_prefix="$artifacts/" "${dirs[@]}" >>"$log" 2>&1 || rc=$?
  runs=$(grep -oE 'stat::number_of_executed_units: *[0-9]+' "$log" | tail -1 | grep -oE '[0-9]+$' || echo "?")
  found=()
  shopt -s nullglob
  for f in "$foreign"/foreign-*; do
    [[ $f == *.txt ]] && continue
    cp "$f" "$artifacts/foreign-$(sha1sum "$f" | cut -c1-40)"
  done
  for a in "$artifacts"/{crash,leak,oom,timeout,foreign}-*; do
    name=fuzz/regressions/$t/$(basename "$a")
    if [[ -e $root/$name ]]; then
      found+=("$name (known)")
    else
      cp "$a" "$root/$name"
      found+=("$name")
    fi
  done
  shopt -u nullglob
  line="$t: $(($(date +%s) - t0)) s, $runs runs, corpus $(find "$corpus" -type f | wc -l) inputs"
  if [[ $rc -ne 0 || ${#found[@]} -gt 0 ]]; then
    failed=1
    line+=", FINDINGS: ${found[*]:-exit $rc, no input saved}"
    grep -E '^(==[0-9]+==ERROR|SUMMARY|FOREIGN EXCEPTION|    #[0-9] )' "$log" | head -40 >&2 || true
  fi
  [[ $bad -gt 0 ]] && line="$(cat "$build/logs/$t.summary"); $line"
  echo "$line" >"$build/logs/$t.summary"
  echo "fuzz: $line (log: ${log#"$root"/})"
  rm -rf "$TMPDIR"
  return $failed
}

for t in "${targets[@]}"; do
  [[ -x $build/bin/fuzz_$t ]] || { echo "fuzz: no harness '$t' (have: ${all[*]})" >&2; exit 2; }
done
mkdir -p "$build/logs"
# The parsers are fuzzed side by side, one per core (a libFuzzer process uses one): the same time
# per parser in a fraction of the wall time. With FUZZ_FORK each parser has its own processes.
parallel=$jobs
[[ $fork -gt 0 ]] && parallel=1
for t in "${targets[@]}"; do
  while [[ $(jobs -rp | wc -l) -ge $parallel ]]; do wait -n || true; done
  rm -f "$build/logs/$t.summary" "$build/logs/$t.status"
  (
    rc=0
    fuzz_one "$t" || rc=$?
    echo "$rc" >"$build/logs/$t.status"
  ) &
done
wait
failed=()
summary=()
for t in "${targets[@]}"; do
  [[ $(cat "$build/logs/$t.status" 2>/dev/null) == 0 ]] || failed+=("$t")
  summary+=("$(cat "$build/logs/$t.summary" 2>/dev/null || echo "$t: no result")")
done

echo "fuzz: summary after $(($(date +%s) - start)) s:"
printf '  %s\n' "${summary[@]}"
if [[ ${#failed[@]} -gt 0 ]]; then
  echo "fuzz: FAILED: ${failed[*]} (logs in ${build#"$root"/}/logs/; new inputs in fuzz/regressions/)" >&2
  exit 1
fi
echo "fuzz: clean"
