#!/usr/bin/env bash
# Issue 24's table, measured in one run: every figure beside its goal, in bench/results/speed.md.
#   wing        Gmsh 4.8 (bench/gmsh/wing_bl.py, order 4, 10 layers r 1.5, fast curving:
#               HighOrderOptimize 4) and `meshflow run workflows/wingtip_step.yaml` from an empty
#               cache, alternating Gmsh, meshflow, Gmsh, meshflow; best of 2 each; the ratio.
#   DLR-F6      `meshflow run workflows/wing_body.yaml`, empty cache: wall, and untangling.
#   Rotor 67    `meshflow run workflows/rotor67.yaml`, empty cache: wall, untangling, split's peak.
#   split-only  bench/split-change.sh on the demo: `--set split.layers=12` after a cold run.
#   cylinder    `meshflow run workflows/cylinder_in_box.yaml`, empty cache: untangling.
# Wall times of whole runs under /usr/bin/time; stage figures from each run's report.json
# (seconds, peak_rss_mb, stats.optimise.untangle). The load before each run is recorded: on a
# shared machine wall time follows it.
# Usage: bench/speed.sh [BUILD] [OUT_DIR]    (~25 min on 2 cores; Rotor 67 is most of it)
#        SPEED_ONLY="wing split" bench/speed.sh   runs only those rows (the others: "not run")
set -uo pipefail
cd "$(dirname "$0")/.."
build=${1:-build}
OUT=${2:-/tmp/meshflow-speed}
MF=$build/meshflow
ONLY=${SPEED_ONLY:-wing dlr rotor split cylinder}
mkdir -p "$OUT"
rm -f "$OUT"/*.row
want() { [[ " $ONLY " == *" $1 "* ]]; }
load() { cut -d' ' -f1 /proc/loadavg; }

# meshflow from an empty cache: NAME WORKFLOW -> $OUT/NAME.{time,log,report.json}
mf() {
  local name=$1 wf=$2
  rm -rf "$OUT/$name.cache" "$OUT/$name.out"
  echo "load $(load)" > "$OUT/$name.load"
  /usr/bin/time -f "%e %M" -o "$OUT/$name.time" "$MF" run "$wf" --cache "$OUT/$name.cache" --out "$OUT/$name.out" \
    > "$OUT/$name.log" 2>&1
  echo "rc=$?" >> "$OUT/$name.time"
  cp "$OUT/$name.out/report.json" "$OUT/$name.report.json" 2>/dev/null
  rm -rf "$OUT/$name.cache" "$OUT/$name.out"
}
gmsh_wing() {
  local name=$1
  echo "load $(load)" > "$OUT/$name.load"
  /usr/bin/time -f "%e %M" -o "$OUT/$name.time" /usr/bin/python3 bench/gmsh/wing_bl.py \
    data/wingtip/3d_bl_wing.stp "$OUT/$name.msh" --heal 1 --scale 1e-3 --walls auto --wall-size 0.05 \
    --curv 12 --far-size 0.5 --first-height 4.4e-4 --layers 10 --ratio 1.5 --order 4 --hoopt 4 > "$OUT/$name.log" 2>&1
  echo "rc=$?" >> "$OUT/$name.time"
  rm -f "$OUT/$name.msh"
}

if want wing; then
  echo "== wing: Gmsh and meshflow, alternating"
  for k in 1 2; do gmsh_wing gmsh_wing$k; mf mf_wing$k workflows/wingtip_step.yaml; done
fi
if want dlr; then echo "== DLR-F6"; mf dlr workflows/wing_body.yaml; fi
if want rotor; then echo "== Rotor 67"; mf rotor67 workflows/rotor67.yaml; fi
if want split; then
  echo "== split-only change"
  echo "load $(load)" > "$OUT/split.load"
  bench/split-change.sh workflows/naca_wingtip.yaml "$build" > "$OUT/split.log" 2>&1
fi
if want cylinder; then echo "== cylinder in a box"; mf cylinder workflows/cylinder_in_box.yaml; fi

/usr/bin/python3 bench/speed_report.py "$OUT" "$ONLY" "$(git rev-parse --short HEAD 2>/dev/null || echo '?')" \
  > bench/results/speed.md && echo "wrote bench/results/speed.md"
