#!/usr/bin/env bash
# Profiles one cold run of a workflow with perf and writes one summary per stage (issue 24).
# Usage: bench/profile-stages.sh WORKFLOW NAME [BUILD]
#        PERF_DATA=F RUN_LOG=L [LOAD0=.. LOAD1=..] bench/profile-stages.sh ...: summarise an earlier recording
#   -> bench/results/profile/NAME.<stage>.txt: the stage's top functions by self time, then the
#      top ones with their callees (children), each file headed by the commands that made it.
# Each stage runs in a forked process named "mf:<stage>" (engine/runner.cpp), so one perf record
# of the whole run (children inherit it) is split by command name. This machine's perf has no
# hardware counters (a VM), so it samples the cpu-clock software event; DWARF call graphs,
# because the Release build omits frame pointers. The run uses a fresh cache (cold).
set -eu
wf=$1 name=$2 build=${3:-build}
out=bench/results/profile
mkdir -p "$out"
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
load0=$(uptime)
rec=(perf record -e cpu-clock -F 97 --call-graph dwarf,8192 -o "$tmp/perf.data" --
     "$build/meshflow" run "$wf" --cache "$tmp/cache" --out "$tmp/out" -v)
if [ -n "${PERF_DATA:-}" ]; then  # summarise a recording made earlier by this command (with its run log)
  cp "$PERF_DATA" "$tmp/perf.data"; cp "$RUN_LOG" "$tmp/run.log"
  load0=${LOAD0:-unknown}
else
  "${rec[@]}" > "$tmp/run.log" 2>&1 || true
fi
load1=${LOAD1:-$(uptime)}
stages=$(perf report -i "$tmp/perf.data" --stdio --sort comm 2>/dev/null | grep -o 'mf:[A-Za-z0-9_:-]*' | sort -u)
for comm in $stages; do
  stage=${comm#mf:}
  f="$out/$name.$stage.txt"
  {
    echo "# $name, stage $stage: perf profile of a cold run (cpu-clock samples at 97 Hz, percentages of this stage's samples)"
    echo "# recorded: ${rec[*]}" | sed "s|$tmp|\$TMP|g"
    echo "# load: before ${load0##*load}; after ${load1##*load}"
    grep -E "^$stage +" "$tmp/run.log" | sed 's/^/# stage table: /' || true
    echo "# self:     perf report --comm $comm --percentage relative --stdio --no-children --sort symbol -g none"
    echo
    perf report -i "$tmp/perf.data" --comm "$comm" --percentage relative --stdio --no-children --sort symbol -g none 2>/dev/null |
      grep -v '^#' | grep '%' | head -30 | cut -c1-220
    echo
    echo "# children: perf report --comm $comm --percentage relative --stdio --children --sort symbol -g none"
    echo
    perf report -i "$tmp/perf.data" --comm "$comm" --percentage relative --stdio --children --sort symbol -g none 2>/dev/null |
      grep -v '^#' | grep '%' | head -30 | cut -c1-220
  } > "$f"
  echo "wrote $f"
done
grep -A14 '^stage ' "$tmp/run.log" > "$out/$name.stages.txt" || true
