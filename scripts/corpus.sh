#!/usr/bin/env bash
# The corpus as a new user meets it: for each CAD file `meshflow init` writes the workflow and
# `meshflow run` runs it as it is, from an empty cache. Per file: what init decided, the exit
# code, time, peak memory, how far it got, the final mesh's elements and min scaled Jacobian,
# and three verdicts on the final mesh: ours (`meshflow contract`, the clauses that need no
# CAD), Gmsh's (Plugin AnalyseMeshQuality, Jacobian determinant) and VTK's (Lagrange cells);
# plus a cut picture of the final mesh.
#
#   scripts/corpus.sh BUILD [RESULTS.md] [CAD_FILE|WORKFLOW.yaml ...]
#
# Defaults: every file of both corpora, the simple one (data/corpus) and the real
# third-party CAD (bench/corpus/real; sources of both in SOURCES.md), into
# bench/results/corpus.md, the pictures beside it in bench/results/corpus/. Each failure gets a
# class (scripts/corpus-class.py) and the table ends with the failures counted by class. A .yaml argument is run as it is (no init).
# MESHFLOW_BIN runs another meshflow (an older build, to compare: its init writes the workflow,
# its preflight on the run's cache, and its run runs it) while BUILD's meshflow judges the meshes; TIMEOUT (seconds, default 900) bounds each run;
# PICTURES=0 skips the pictures; KEEP=DIR keeps each run's logs, workflow and report.json there.
set -uo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
build="$(cd "${1:?usage: scripts/corpus.sh BUILD [RESULTS.md] [CAD_FILE|WORKFLOW.yaml ...]}" && pwd)"
results="${2:-$root/bench/results/corpus.md}"
shift $(( $# >= 2 ? 2 : $# ))
inputs=("$@")
if [ ${#inputs[@]} -eq 0 ]; then
  shopt -s nullglob nocaseglob
  inputs=("$root"/data/corpus/*.{step,stp}
          "$root"/bench/corpus/real/*.{step,stp,iges,igs,brep,brp})
  shopt -u nullglob nocaseglob
fi
judge="$build/meshflow"
bin="${MESHFLOW_BIN:-$judge}"
timeout_s="${TIMEOUT:-900}"
pictures="${PICTURES:-1}"
picdir="$(dirname "$results")/corpus"
py=/usr/bin/python3
scratch="$(mktemp -d /tmp/meshflow-corpus.XXXXXX)"
trap 'rm -rf "$scratch"' EXIT
[ "$pictures" = 1 ] && mkdir -p "$picdir"

{
  echo "| file | init | exit | seconds | peak MB | reached | final mesh elements | min scaled J | ours (contract) | Gmsh | VTK | class |"
  echo "|---|---|---|---|---|---|---|---|---|---|---|---|"
} > "$scratch/table"
valid=0
for input in "${inputs[@]}"; do
  name="$(basename "${input%.*}")"
  [[ "$input" == */bench/corpus/real/* ]] && name="real/$name"
  # two files of one name in different formats (a blade as .igs and .stp): the second keeps its extension
  [ -e "$scratch/$name" ] && name="${name}.${input##*.}"
  dir="$scratch/$name"
  mkdir -p "$dir"
  decided="given"
  wf="$input"
  start=$(date +%s.%N)
  if [[ "$input" != *.yaml ]]; then
    wf="$dir/$(basename "$name").yaml"
    timeout "$timeout_s" "$bin" init "$input" -o "$wf" --cache "$dir/cache" > "$dir/init.log" 2>&1
    init_code=$?
    if grep -q "unknown option --cache" "$dir/init.log"; then  # a meshflow from before init's preflight
      "$bin" init "$input" -o "$wf" > "$dir/init.log" 2>&1
      init_code=$?
    fi
    if [ "$init_code" != 0 ]; then
      cls=$($py "$root/scripts/corpus-class.py" init "$dir")
      [ "$init_code" = 124 ] && cls="timeout (init's preflight)"
      printf '| %s | refused: %s | - | - | - | - | - | - | - | - | - | %s |\n' "$name" "$(tail -1 "$dir/init.log" | tr '|' '/')" "$cls" >> "$scratch/table"
      echo "$cls" >> "$scratch/classes"
      echo "$name: init refused ($cls)" >&2
      continue
    fi
    decided=$(grep -q 'symmetry_plane: [xyz][+-]}' "$wf" && echo "half model" || { grep -q 'fluid: box' "$wf" && echo "body in box" || echo "domain"; })
  fi
  timeout "$timeout_s" "$bin" run "$wf" --cache "$dir/cache" --out "$dir/out" > "$dir/log" 2>&1
  code=$?
  secs=$(echo "$(date +%s.%N) - $start" | bc)
  [ $code -eq 124 ] && code="timeout"
  facts="- | - | - | -"
  if [ -f "$dir/out/report.json" ]; then
    facts=$($py - "$dir/out/report.json" <<'EOF'
import json, sys
r = json.load(open(sys.argv[1]))
peak = max([s.get("peak_rss_mb") or 0 for s in r["stages"]] + [0])
bad = [s["name"] + " " + s["status"] for s in r["stages"] if s["status"] in ("failed", "invalid")]
done = [s["name"] for s in r["stages"] if s["status"] in ("ran", "cached")]
reached = ", ".join(bad) if bad else (done[-1] if done else "-")
last = next((s for s in reversed(r["stages"]) if (s.get("stats") or {}).get("mesh")), None)
elems, sj = "-", "-"
if last:
    m = last["stats"]["mesh"]
    elems = " ".join("%d %s" % (n, t) for t, n in m["elements"].items() if n) + " (" + last["name"] + ")"
    sj = "%.3g" % m["min_scaled_jacobian"]
print("%s | %s | %s | %s" % (round(peak) if peak else "-", reached, elems, sj))
EOF
)
  fi
  ours="no final mesh"; gmsh="-"; vtk="-"
  if [ -f "$dir/out/mesh.msh" ]; then
    "$judge" contract "$dir/out/mesh.msh" --json > "$dir/contract.json" 2>&1
    ours=$($py -c '
import json, sys
r = json.load(open(sys.argv[1]))
print("valid" if r["ok"] else "INVALID: " + "; ".join("%s %d" % (p["clause"], p["count"]) for p in r["problems"]))
' "$dir/contract.json" 2>/dev/null || echo "unreadable")
    gmsh=$(timeout 600 $py "$root/tests/workflows/gmsh_jacobian_check.py" "$dir/out/mesh.msh" 2>/dev/null |
           awk '{n+=$2; b+=$3} END {if (NR) printf "%d of %d", b, n; else print "failed"}')
    gmsh="${gmsh} flagged"
  fi
  if [ -f "$dir/out/mesh.vtu" ]; then
    vtk=$(timeout 600 $py "$root/tests/workflows/vtk_lagrange_check.py" "$dir/out/mesh.vtu" 2>/dev/null |
          awk '{n+=$2; b+=$3} END {if (NR) printf "%d of %d flagged", b, n; else print "failed"}')
    if [ "$pictures" = 1 ]; then
      mkdir -p "$(dirname "$picdir/$name.png")"
      $py "$root/scripts/render-cut.py" "$dir/out/mesh.vtu" "$picdir/$name.png" --relative \
          --point 0.5 0.5 0.5 --normal 0 0 1 --up 0 1 0 > "$dir/picture.log" 2>&1 && ours="$ours ([cut](corpus/$name.png))"
    fi
  fi
  cls="-"
  if [[ "$ours" == valid* ]] && [ "$code" = 0 ]; then
    valid=$((valid + 1))
  else
    cls=$($py "$root/scripts/corpus-class.py" "$code" "$dir")
    [ "$code" = 0 ] && cls="exit 0 with an invalid mesh"
    echo "$cls" >> "$scratch/classes"
  fi
  printf '| %s | %s | %s | %.1f | %s | %s | %s | %s | %s |\n' "$name" "$decided" "$code" "$secs" "$facts" "$ours" "$gmsh" "$vtk" "$cls" >> "$scratch/table"
  echo "$name: $decided, exit $code, $(printf '%.1f' "$secs") s, $ours, $cls" >&2
  if [ -n "${KEEP:-}" ]; then
    mkdir -p "$KEEP/$name"
    cp "$dir"/*.log "$dir"/log "$dir"/*.yaml "$dir"/out/report.json "$KEEP/$name/" 2>/dev/null
  fi
  rm -rf "$dir/cache" "$dir/out"
done
mkdir -p "$(dirname "$results")"
{
  echo "# Corpus: CAD nobody tuned for, through \`meshflow init\` and \`meshflow run\`"
  echo
  echo "\`MESHFLOW_BIN=$bin TIMEOUT=$timeout_s scripts/corpus.sh $build\` on $(date -u +%F), $(nproc) cores, $(git -C "$root" rev-parse --short HEAD 2>/dev/null)."
  echo "Each file: \`meshflow init FILE\` writes the workflow, run as it is from an empty cache (no hand edits)."
  echo "\"reached\": the stage that failed or was invalid, else the last stage. Verdicts on the final mesh:"
  echo "ours (\`meshflow contract\`: det J > 0 over each whole element, degenerate, conformity, tags, closure),"
  echo "Gmsh's AnalyseMeshQuality (elements with min J <= 0) and VTK's Lagrange cells (non-positive volume samples)."
  echo
  cat "$scratch/table"
  echo
  echo "$valid of ${#inputs[@]} end with exit 0 and a valid mesh."
  if [ -s "$scratch/classes" ]; then
    echo
    echo "Failures by class:"
    echo
    sort "$scratch/classes" | uniq -c | sort -rn | while read -r n c; do echo "- $c: $n"; done
  fi
} > "$results"
echo "$valid of ${#inputs[@]} end with exit 0 and a valid mesh; table in $results" >&2
