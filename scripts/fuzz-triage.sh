#!/usr/bin/env bash
# Sorts the inputs of fuzz/regressions/<parser>/ by what they trigger: replays each once through
# build-fuzz/bin/fuzz_<parser> (scripts/fuzz.sh builds it) and prints one line per input:
#   <signature>  <bytes>  <file>
# where the signature is the sanitizer's SUMMARY (or the foreign exception, or the out-of-memory)
# and the first three frames of the stack outside the sanitizer, libc and libFuzzer. "clean" means
# the input no longer fails (its bug is fixed).
#   scripts/fuzz-triage.sh <parser>...           every parser when none is given
#   FUZZ_DEDUP=1 scripts/fuzz-triage.sh <parser> keep only the smallest failing input per
#                                                signature (clean ones are kept: they guard a fix)
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
build=build-fuzz
parsers=("$@")
if [[ ${#parsers[@]} -eq 0 ]]; then
  for d in fuzz/regressions/*/; do parsers+=("$(basename "$d")"); done
fi
export ASAN_OPTIONS="detect_leaks=1:halt_on_error=1:strict_string_checks=1"
export LSAN_OPTIONS="suppressions=$PWD/scripts/lsan.supp:print_suppressions=0"
export UBSAN_OPTIONS="print_stacktrace=1:halt_on_error=1"
export TMPDIR=$PWD/$build/tmp-triage
mkdir -p "$TMPDIR"
unset SONOSLICE_FUZZ_FOREIGN_DIR

signature() {  # the report on stdin -> one line
  awk '
    /FOREIGN EXCEPTION/ { sub(/.*FOREIGN EXCEPTION /, ""); sub(/[0-9.eE+-]+'"'"'?$/, ""); what = "foreign exception " $0 }
    /ERROR: libFuzzer: out-of-memory/ { what = "out-of-memory" }
    /ERROR: libFuzzer: timeout/ { what = "timeout" }
    /^SUMMARY: / && what == "" { s = $0; sub(/^SUMMARY: /, "", s); gsub(/\(BuildId: [0-9a-f]+\)/, "", s);
                                gsub(/0x[0-9a-f]+/, "", s); gsub(/\/[^ ]*\//, "", s); what = s }
    /^    #[0-9]+ / && n < 3 {
      line = $0
      if (line ~ /__sanitizer|__asan|__interceptor|libc\.so|fuzzer::|libFuzzer|LLVMFuzzerTestOneInput|expect_sonoslice_errors_only|operator\(\)|malloc|calloc|realloc|operator new|__cxa|abort|raise|pthread_kill|_start|__libc/) next
      if (match(line, / in [^(]+/)) { f = substr(line, RSTART + 4, RLENGTH - 4); frames = frames (n ? " < " : "") f; n++ }
    }
    END { if (what == "") what = "clean"; print what (frames != "" ? " @ " frames : "") }'
}

for p in "${parsers[@]}"; do
  exe=$build/bin/fuzz_$p
  [[ -x $exe ]] || { echo "fuzz-triage: no $exe (run scripts/fuzz.sh first)" >&2; exit 2; }
  declare -A best=()
  shopt -s nullglob
  for input in fuzz/regressions/"$p"/*; do
    sig=$( ("$exe" -timeout=30 -rss_limit_mb=3072 -malloc_limit_mb=2048 "$input" 2>&1 || true) | signature)
    bytes=$(stat -c %s "$input")
    printf '%s\t%s\t%s\n' "$sig" "$bytes" "$input"
    if [[ ${FUZZ_DEDUP:-0} == 1 ]]; then
      if [[ $sig == clean ]]; then
        :
      elif [[ -z ${best[$sig]:-} ]]; then
        best[$sig]=$input
      elif [[ $bytes -lt $(stat -c %s "${best[$sig]}") ]]; then
        rm "${best[$sig]}"
        best[$sig]=$input
      else
        rm "$input"
      fi
    fi
  done
  shopt -u nullglob
  unset best
done
rm -rf "$TMPDIR"
