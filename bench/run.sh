#!/usr/bin/env bash
# Runs every benchmark built in BUILD/bench and bench/speed.sh (issue 24's table), and assembles bench/RESULTS.md from the
# fragments they write to bench/results/ (each fragment names the command that produced it).
# Usage: bench/run.sh [BUILD]      run all, then assemble
#        bench/run.sh --assemble   only assemble the fragments already there
set -euo pipefail
cd "$(dirname "$0")/.."
if [ "${1:-}" = "--assemble" ]; then
  how="Assembled by \`bench/run.sh --assemble\` on $(date -u +%Y-%m-%d) from the fragments in bench/results/, each measured by the command it names"
else
  build=${1:-build}
  for b in "$build"/bench/*_bench; do
    [ -x "$b" ] || continue
    echo "== $b"
    "$b"
  done
  echo "== bench/speed.sh"
  bench/speed.sh "$build"
  how="Produced by \`make bench\` on $(date -u +%Y-%m-%d)"
fi
{
  echo "# meshflow benchmark results"
  echo
  echo "$how; $(nproc) cores, $(free -g | awk '/Mem:/{print $2}') GiB,"
  echo "$(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | sed 's/^ //'), commit $(git rev-parse --short HEAD 2>/dev/null || echo '?')."
  echo "The machine was shared with other builds while most fragments were measured: timings are noisy."
  echo
  for f in bench/results/*.md; do
    [ -f "$f" ] || continue
    # fragments link their plots beside them (bench/results/X.png); RESULTS.md is one folder up
    sed -E 's#\]\(([^/)]+\.png)\)#](results/\1)#g' "$f"
    echo
  done
} > bench/RESULTS.md
echo "wrote bench/RESULTS.md"
