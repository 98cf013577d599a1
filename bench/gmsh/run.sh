#!/usr/bin/env bash
# Side-by-side benchmark (issue 8): Gmsh's closest equivalent and meshflow's workflow on the same
# CAD, alternating in one run (Gmsh variant, then meshflow from a cold cache, and so on). Each run
# is a separate process under /usr/bin/time -v and timeout; each mesh is then judged, outside the
# timing, by Gmsh's Plugin(AnalyseMeshQuality) (bench/gmsh/analyse.py) and by
# `meshflow quality --json`. Raw logs go to $OUT (not committed); bench/gmsh/report.py turns them
# into bench/results/gmsh.md.
# Usage: bench/gmsh/run.sh [MESHFLOW_BINARY] [OUT_DIR]
set -uo pipefail
cd "$(dirname "$0")/../.."
MF=${1:-build/meshflow}
OUT=${2:-/tmp/meshflow-gmshbench}
TMO=${TMO:-300}
mkdir -p "$OUT"
WING="data/wingtip/3d_bl_wing.stp --heal 1 --scale 1e-3 --walls auto --wall-size 0.05 --curv 12 --far-size 0.5 --first-height 4.4e-4"
DLR="data/dlr_f6/dlr_f6.brep --heal 0 --scale 1e-3 --walls 1-123 --wall-size 0.03 --curv 8 --far-size 0.2 --first-height 5e-5"
run() {  # name cadargs hoopt
  local name=$1 args=$2 ho=$3
  echo "== $name (HighOrderOptimize $ho)"
  /usr/bin/time -v -o "$OUT/$name.time" timeout "$TMO" /usr/bin/python3 bench/gmsh/wing_bl.py \
      ${args%% *} "$OUT/$name.msh" ${args#* } --layers 10 --ratio 1.5 --order 4 --hoopt "$ho" > "$OUT/$name.log" 2>&1
  echo "rc=$?" >> "$OUT/$name.time"
  if [ -s "$OUT/$name.msh" ]; then
    judge "$OUT/$name.msh" "$name"
    rm -f "$OUT/$name.msh"   # P4 meshes are large; nothing is kept
  fi
}
judge() {  # mesh file, name: Gmsh's and meshflow's checks
  timeout "$TMO" /usr/bin/python3 bench/gmsh/analyse.py "$1" > "$OUT/$2.analyse" 2>&1
  timeout "$TMO" "$MF" quality "$1" --json > "$OUT/$2.quality.json" 2> "$OUT/$2.quality.err"
}
mf() {  # name workflow: meshflow as a user runs it, from an empty cache
  local name=$1 wf=$2
  echo "== $name (meshflow run $wf)"
  rm -rf "$OUT/$name.cache" "$OUT/$name.out"
  /usr/bin/time -v -o "$OUT/$name.time" timeout "$TMO" "$MF" run "$wf" --cache "$OUT/$name.cache" --out "$OUT/$name.out" \
      > "$OUT/$name.log" 2>&1
  echo "rc=$?" >> "$OUT/$name.time"
  [ -s "$OUT/$name.out/mesh.msh" ] && judge "$OUT/$name.out/mesh.msh" "$name"
  rm -rf "$OUT/$name.cache" "$OUT/$name.out"/*.msh "$OUT/$name.out"/*.vtu "$OUT/$name.out"/*.xml
}
k=0
for ho in 0 4 2; do
  k=$((k + 1))
  run wing_ho$ho "$WING" $ho
  mf wing_meshflow$k workflows/wingtip_step.yaml
  run dlrf6_ho$ho "$DLR" $ho
done
mf dlrf6_meshflow1 workflows/wing_body.yaml
/usr/bin/python3 bench/gmsh/report.py "$OUT" > bench/results/gmsh.md
echo "wrote bench/results/gmsh.md"
