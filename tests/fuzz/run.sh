#!/usr/bin/env bash
# Runs every fuzz target built in BUILD/tests/fuzz for SECONDS each, starting from the seed
# corpus tests/fuzz/corpus/<name>/, and writes executions and coverage to tests/fuzz/RESULTS.md.
# A crash stops with the reproducer in BUILD/fuzz-crashes/: fix it, then add the file to
# tests/fuzz/corpus/<name>/ so `make test` replays it forever.
set -uo pipefail
cd "$(dirname "$0")/../.."
build=${1:-build-fuzz}
secs=${2:-60}
mkdir -p "$build/fuzz-crashes"
rows=""
status=0
for t in "$build"/tests/fuzz/*_fuzz; do
  [ -x "$t" ] || continue
  name=$(basename "$t" _fuzz)
  work="$build/fuzz-corpus/$name"
  mkdir -p "$work" "tests/fuzz/corpus/$name"
  log="$build/fuzz-$name.log"
  echo "== $name: ${secs}s"
  "$t" -max_total_time="$secs" -timeout=10 -rss_limit_mb=4096 -print_final_stats=1 \
       -artifact_prefix="$build/fuzz-crashes/$name-" "$work" "tests/fuzz/corpus/$name" >"$log" 2>&1
  rc=$?
  execs=$(grep -m1 'stat::number_of_executed_units' "$log" | awk '{print $2}')
  cov=$(grep -E '^#[0-9]+.*(DONE|cov:)' "$log" | tail -1 | sed -E 's/.*cov: ([0-9]+).*/\1/')
  ft=$(grep -E '^#[0-9]+.*ft:' "$log" | tail -1 | sed -E 's/.*ft: ([0-9]+).*/\1/')
  result=$([ $rc -eq 0 ] && echo "no crash" || echo "CRASH (see $log)")
  [ $rc -eq 0 ] || status=1
  rows="$rows| $name | ${secs} s | ${execs:-?} | ${cov:-?} | ${ft:-?} | $result |\n"
done
{
  echo "# Fuzzing results"
  echo
  echo "\`make fuzz FUZZ_SECONDS=$secs\` on $(date -u +%Y-%m-%d), commit $(git rev-parse --short HEAD 2>/dev/null)."
  echo
  echo "| target | time | executions | coverage (edges) | features | result |"
  echo "|---|---|---|---|---|---|"
  printf "$rows"
} > tests/fuzz/RESULTS.md
cat tests/fuzz/RESULTS.md
exit $status
