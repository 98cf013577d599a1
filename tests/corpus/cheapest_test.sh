#!/usr/bin/env bash
# The cheapest files of the real third-party corpus (bench/corpus/real) as `make corpus` runs
# them: `meshflow init` (its preflight included) then `meshflow run`, no hand edits; each must end
# with exit 0 and a final mesh that is valid to us (meshflow contract), and none flagged by Gmsh's
# or VTK's own Jacobian checks. wigley_hull is one face heal closes (its deck and centreplane
# capped along their crossing); wing_surfaces_5m an IGES file in metres.
#
#   tests/corpus/cheapest_test.sh PROJECT_ROOT BUILD
set -euo pipefail
root="$1"
build="$2"
files=(cylinder_in_channel.iges ring.brep bl3d_5.brep wigley_hull.step wing_surfaces_5m.iges)
results="$(mktemp -d /tmp/meshflow-cheapest.XXXXXX)"
trap 'rm -rf "$results"' EXIT
args=()
for f in "${files[@]}"; do args+=("$root/bench/corpus/real/$f"); done
PICTURES=0 TIMEOUT=300 "$root/scripts/corpus.sh" "$build" "$results/corpus.md" "${args[@]}"
cat "$results/corpus.md"
fail=0
grep -q "^${#files[@]} of ${#files[@]} end with exit 0 and a valid mesh" "$results/corpus.md" || { echo "FAIL: not every file ended valid"; fail=1; }
# every row: Gmsh and VTK flag no element
if grep -E '^\| real/' "$results/corpus.md" | grep -vE '\| 0 of [0-9]+ flagged \| 0 of [0-9]+ flagged \|'; then
  echo "FAIL: Gmsh or VTK flagged elements (rows above)"
  fail=1
fi
exit $fail
