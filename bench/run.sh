#!/usr/bin/env bash
# Runs every benchmark built in BUILD/bench and assembles bench/RESULTS.md from the
# fragments they write to bench/results/. Usage: bench/run.sh [BUILD]
set -euo pipefail
cd "$(dirname "$0")/.."
build=${1:-build}
for b in "$build"/bench/*_bench; do
  [ -x "$b" ] || continue
  echo "== $b"
  "$b"
done
{
  echo "# meshflow benchmark results"
  echo
  echo "Produced by \`make bench\` on $(date -u +%Y-%m-%d), $(nproc) cores, $(free -g | awk '/Mem:/{print $2}') GiB,"
  echo "$(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | sed 's/^ //'), commit $(git rev-parse --short HEAD 2>/dev/null || echo '?')."
  echo
  for f in bench/results/*.md; do
    [ -f "$f" ] || continue
    cat "$f"
    echo
  done
} > bench/RESULTS.md
echo "wrote bench/RESULTS.md"
