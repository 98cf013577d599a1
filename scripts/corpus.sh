#!/usr/bin/env bash
# Runs workflows end to end, from an empty cache each, and says which end with a valid mesh:
# the exit code of `meshflow run`, its time, how far it got, and the verdict of
# `meshflow contract` (the clauses that need no CAD) on the final mesh (output `mesh`).
#
#   scripts/corpus.sh BUILD [RESULTS.md] [WORKFLOW.yaml ...]
#
# Defaults: the corpus (bench/corpus/*.yaml and workflows/cylinder_in_box.yaml) into
# bench/results/corpus.md. MESHFLOW_BIN runs another meshflow (e.g. an older build, to compare)
# while BUILD's meshflow judges the meshes; TIMEOUT (seconds, default 900) bounds each run.
set -uo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
build="$(cd "${1:?usage: scripts/corpus.sh BUILD [RESULTS.md] [WORKFLOW.yaml ...]}" && pwd)"
results="${2:-$root/bench/results/corpus.md}"
shift $(( $# >= 2 ? 2 : $# ))
workflows=("$@")
if [ ${#workflows[@]} -eq 0 ]; then workflows=("$root"/bench/corpus/*.yaml "$root/workflows/cylinder_in_box.yaml"); fi
judge="$build/meshflow"
bin="${MESHFLOW_BIN:-$judge}"
timeout_s="${TIMEOUT:-900}"
scratch="$(mktemp -d /tmp/meshflow-corpus.XXXXXX)"
trap 'rm -rf "$scratch"' EXIT

{
  echo "| workflow | exit | seconds | stages ran / failed / invalid / skipped | final mesh: contract (no CAD) |"
  echo "|---|---|---|---|---|"
} > "$scratch/table"
valid=0
for wf in "${workflows[@]}"; do
  name="$(basename "$wf" .yaml)"
  dir="$scratch/$name"
  mkdir -p "$dir"
  start=$(date +%s.%N)
  timeout "$timeout_s" "$bin" run "$wf" --cache "$dir/cache" --out "$dir/out" > "$dir/log" 2>&1
  code=$?
  secs=$(echo "$(date +%s.%N) - $start" | bc)
  [ $code -eq 124 ] && code="timeout"
  counts="-"
  if [ -f "$dir/out/report.json" ]; then
    counts=$(/usr/bin/python3 -c '
import json, sys
r = json.load(open(sys.argv[1]))
c = {k: 0 for k in ("ran", "failed", "invalid", "skipped")}
for s in r["stages"]:
    st = s["status"]
    st = "ran" if st == "cached" else st
    c[st] = c.get(st, 0) + 1
bad = [s["name"] for s in r["stages"] if s["status"] in ("failed", "invalid")]
print("%d / %d / %d / %d%s" % (c["ran"], c["failed"], c["invalid"], c["skipped"], (" (" + ", ".join(bad) + ")") if bad else ""))
' "$dir/out/report.json")
  fi
  verdict="no final mesh"
  if [ -f "$dir/out/mesh.msh" ]; then
    "$judge" contract "$dir/out/mesh.msh" --json > "$dir/contract.json" 2>&1
    verdict=$(/usr/bin/python3 -c '
import json, sys
r = json.load(open(sys.argv[1]))
if r["ok"]:
    print("valid")
else:
    print("INVALID: " + "; ".join("%s %d" % (p["clause"], p["count"]) for p in r["problems"]))
' "$dir/contract.json" 2>/dev/null || echo "unreadable")
  fi
  [ "$verdict" = "valid" ] && valid=$((valid + 1))
  printf '| %s | %s | %.1f | %s | %s |\n' "$name" "$code" "$secs" "$counts" "$verdict" >> "$scratch/table"
  echo "$name: exit $code, $(printf '%.1f' "$secs") s, $verdict" >&2
done
mkdir -p "$(dirname "$results")"
{
  echo "# Corpus: which workflows end with a valid mesh"
  echo
  echo "\`MESHFLOW_BIN=$bin TIMEOUT=$timeout_s scripts/corpus.sh $build\` on $(date -u +%F), $(nproc) cores, $(git -C "$root" rev-parse --short HEAD 2>/dev/null)."
  echo "Each workflow from an empty cache. \"valid\": its final mesh keeps the contract's clauses that need no CAD (\`meshflow contract\`)."
  echo
  cat "$scratch/table"
  echo
  echo "$valid of ${#workflows[@]} end with a valid mesh."
} > "$results"
echo "$valid of ${#workflows[@]} end with a valid mesh; table in $results" >&2
