# Sourced by the remote-cache tests (needs $src, the source folder): their shared helpers and the
# small variant of the demo they all run.
#   fail MSG          prints FAIL: MSG and exits 1
#   json FILE EXPR    prints a Python expression of the JSON in FILE (as r)
#   wf, small, stages the demo workflow, the --set arguments that make it small, its stage count
fail() { echo "FAIL: $*"; exit 1; }
json() { /usr/bin/python3 -c "import json,sys; r=json.load(open(sys.argv[1])); print($2)" "$1"; }

wf=$src/workflows/naca_wingtip.yaml
small=(--set geometry.farfield_chords=3 --set balance.min_size=0.015 --set balance.max_size=0.15
       --set curve.order=2 --set split.layers=3 -j 2 --threads 2)
stages=10
