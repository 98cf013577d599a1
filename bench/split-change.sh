#!/usr/bin/env bash
# Issue 24 item 3: the cost of a split-only change next to a cold run of the same workflow.
# Usage: bench/split-change.sh [WORKFLOW] [BUILD]   (default workflows/naca_wingtip.yaml, build)
#   1. cold: `meshflow run WORKFLOW` on a fresh cache and a fresh out/ (every stage, every output);
#   2. split-only: `meshflow run WORKFLOW --set split.layers=12` on that cache and out/ (split
#      re-runs, the outputs taken from it are rewritten, nothing else).
# Prints wall and CPU (user + sys of the whole process tree: the forked stages are waited for)
# of each and the ratios split-only / cold, with the load before and after. On this shared
# 2-core machine wall time follows the load; CPU time is the steadier figure.
set -eu
wf=${1:-workflows/naca_wingtip.yaml} build=${2:-build}
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
run() {  # label, extra args...
  local label=$1; shift
  /usr/bin/time -f "%e %U %S" -o "$tmp/$label.time" "$build/meshflow" run "$wf" --cache "$tmp/cache" --out "$tmp/out" "$@" \
    > "$tmp/$label.log" 2>&1 || { echo "$label run failed:"; tail -20 "$tmp/$label.log"; exit 1; }
  read -r wall user sys < "$tmp/$label.time"
  echo "$label $wall $(echo "$user + $sys" | bc)"
}
load0=$(uptime | sed 's/.*load average: //')
cold=$(run cold)
change=$(run split_only --set split.layers=12)
load1=$(uptime | sed 's/.*load average: //')
read -r _ cw cc <<< "$cold"
read -r _ sw sc <<< "$change"
echo "# $(date -u +%F) binary $build/meshflow, load before $load0, after $load1"
echo "| run | wall s | CPU s (user+sys) |"
echo "|---|---|---|"
echo "| cold: \`meshflow run $wf\` | $cw | $cc |"
echo "| split-only: \`meshflow run $wf --set split.layers=12\` | $sw | $sc |"
echo "| ratio split-only / cold | $(echo "scale=1; 100 * $sw / $cw" | bc) % | $(echo "scale=1; 100 * $sc / $cc" | bc) % |"
grep -E '^split ' "$tmp/split_only.log" | sed 's/^/stage table: /' || true
