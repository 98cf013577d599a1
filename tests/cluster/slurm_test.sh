#!/usr/bin/env bash
# End to end on Slurm: starts a single-node Slurm on 127.0.0.1 (munged, slurmctld, slurmd from
# Debian, each with its own key, config, state and logs under a temp folder, all stopped on exit),
# exports a two-variant matrix of a small demo workflow with `meshflow export snakemake`, runs it
# with `snakemake --slurm` (Snakemake 7), and checks that every rule ran as a Slurm job and that
# the outputs are byte-identical to `meshflow run`'s.
# usage: slurm_test.sh MESHFLOW_EXE SOURCE_DIR
# Exit 0 pass, 1 fail, 77 skipped (Slurm cannot start here: not root, a daemon missing or refusing).
set -uo pipefail
exe=$1
src=$2
SKIP=77
skip() { echo "SKIP: $*"; exit $SKIP; }
fail() { echo "FAIL: $*"; exit 1; }

for p in munged munge slurmctld slurmd sbatch sinfo scontrol snakemake; do
  command -v "$p" >/dev/null || [ -x "/usr/sbin/$p" ] || skip "$p is not installed (scripts/install-deps installs slurm-wlm, slurm-client, munge, snakemake)"
done
[ "$(id -u)" -eq 0 ] || skip "slurmd runs jobs only as root: run this test as root"
export PATH=$PATH:/usr/sbin:/sbin

work=$(mktemp -d "${TMPDIR:-/tmp}/meshflow-slurm.XXXXXX")
chmod 700 "$work"
pids=()
stop_all() {
  for ((i = ${#pids[@]} - 1; i >= 0; i--)); do kill "${pids[i]}" 2>/dev/null; done
  for p in "${pids[@]}"; do
    for _ in $(seq 50); do kill -0 "$p" 2>/dev/null || break; sleep 0.1; done
    kill -9 "$p" 2>/dev/null
  done
  # jobs still running (a failed test): their processes are children of slurmstepd, ended above
  [ -n "${MESHFLOW_KEEP_TEST_DIRS:-}" ] || rm -rf "$work"
}
trap stop_all EXIT
# dump LOG...: the daemons' logs, for a failure
dump() { for f in "$@"; do echo "--- $f"; tail -n 30 "$f" 2>/dev/null; done; }
free_port() {
  /usr/bin/python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'
}
t_start=$(date +%s%N)
ms() { echo $((($(date +%s%N) - $1) / 1000000)); }

# --- munge: its own key and socket
mkdir -p "$work/munge"
chmod 700 "$work/munge"
dd if=/dev/urandom of="$work/munge/munge.key" bs=1024 count=1 status=none
chmod 400 "$work/munge/munge.key"
sock=$work/munge/munge.socket
munged --foreground --force --socket="$sock" --key-file="$work/munge/munge.key" --pid-file="$work/munge/munged.pid" \
  --log-file="$work/munge/munged.log" --seed-file="$work/munge/munged.seed" >"$work/munge/stdout" 2>&1 &
pids+=($!)
for _ in $(seq 100); do [ -S "$sock" ] && break; sleep 0.1; done
munge -n -S "$sock" 2>/dev/null | unmunge -S "$sock" >/dev/null 2>&1 ||
  { dump "$work/munge/stdout" "$work/munge/munged.log"; skip "munged does not start or does not answer (log above)"; }

# --- Slurm: one node with this machine's cores and half its memory, no accounting, no cgroups
mkdir -p "$work/slurm/state" "$work/slurm/spool" "$work/slurm/log"
cpus=$(nproc)
mem=$(($(free -m | awk '/Mem:/{print $2}') / 2))
export SLURM_CONF=$work/slurm/slurm.conf
cat > "$SLURM_CONF" <<CONF
ClusterName=meshflowtest
SlurmctldHost=localhost(127.0.0.1)
SlurmctldPort=$(free_port)
SlurmdPort=$(free_port)
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket=$sock
StateSaveLocation=$work/slurm/state
SlurmdSpoolDir=$work/slurm/spool
SlurmctldPidFile=$work/slurm/slurmctld.pid
SlurmdPidFile=$work/slurm/slurmd.pid
SlurmctldLogFile=$work/slurm/log/slurmctld.log
SlurmdLogFile=$work/slurm/log/slurmd.log
SlurmctldDebug=info
SlurmdDebug=info
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/none
SwitchType=switch/none
MpiDefault=none
ReturnToService=2
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
MinJobAge=600
NodeName=mfnode NodeHostname=$(hostname -s) NodeAddr=127.0.0.1 CPUs=$cpus RealMemory=$mem State=UNKNOWN
PartitionName=test Nodes=mfnode Default=YES MaxTime=INFINITE State=UP
CONF
slurmctld -D -i -f "$SLURM_CONF" >"$work/slurm/log/slurmctld.out" 2>&1 &
pids+=($!)
slurmd -D -f "$SLURM_CONF" -N mfnode >"$work/slurm/log/slurmd.out" 2>&1 &
pids+=($!)
state=""
for _ in $(seq 300); do
  state=$(sinfo -h -n mfnode -o %T 2>/dev/null)
  [ "$state" = idle ] && break
  sleep 0.1
done
[ "$state" = idle ] || {
  dump "$work"/slurm/log/*
  skip "Slurm did not start here: node state '${state:-none}' after 30 s (logs above)"
}
echo "slurm: munged, slurmctld and slurmd up, node idle after $(ms "$t_start") ms"

# --- the study: the demo wing, small, two values of split.layers
mkdir -p "$work/study"
wf=$work/study/study.yaml
sed -e '/^golden:/d' -e 's/^name: naca-wingtip/name: slurm-study/' "$src/workflows/naca_wingtip.yaml" > "$wf"
cat >> "$wf" <<'YAML'
matrix:
  split.layers: [2, 3]
YAML
small=(--set geometry.farfield_chords=3 --set balance.min_size=0.015 --set balance.max_size=0.15 --set curve.order=2
       --set medial.passes=1 --set medial.spacing=0.04 --set shell.spacing=0.02)
variants=(layers-2 layers-3)

# reference: meshflow run, the whole matrix in one process
t0=$(date +%s%N)
"$exe" run "$wf" "${small[@]}" -j 2 --threads 2 --cache "$work/ref-cache" --out "$work/ref" >"$work/ref.log" 2>&1 ||
  { cat "$work/ref.log"; fail "meshflow run of the study failed"; }
echo "meshflow run: $(ms "$t0") ms"
for v in "${variants[@]}"; do [ -d "$work/ref/$v" ] || fail "meshflow run wrote no $work/ref/$v (variants: $(ls "$work/ref"))"; done

# the export, into a folder that does not exist yet
smk=$work/smk
"$exe" export snakemake "$wf" "${small[@]}" --threads 1 --cache "$work/smk-cache" --out "$work/smk-out" -o "$smk/Snakefile" \
  >"$work/export.log" 2>&1 || { cat "$work/export.log"; fail "meshflow export snakemake failed"; }
rules=$(grep -c '^rule ' "$smk/Snakefile")
rules=$((rules - 1))  # rule all runs no job
echo "export: $rules rules"

# snakemake --slurm: every rule an sbatch job, its status read back through scontrol (no accounting;
# Snakemake 7 turns a status rate above 1/s into one check per 33 s, hence 1)
t0=$(date +%s%N)
(cd "$smk" && USER=${USER:-$(id -un)} timeout 900 snakemake -s Snakefile --slurm --jobs 4 \
  --default-resources runtime=30 --max-status-checks-per-second 1 --latency-wait 10 >"$work/snakemake.log" 2>&1)
code=$?
if [ $code -ne 0 ]; then
  cat "$work/snakemake.log"
  for f in "$smk"/.snakemake/slurm_logs/*/*.log; do dump "$f"; done
  dump "$work"/slurm/log/*
  fail "snakemake --slurm exited $code"
fi
echo "snakemake --slurm: $(ms "$t0") ms"

jobs=$(ls "$smk"/.snakemake/slurm_logs/*/*.log 2>/dev/null | wc -l)
[ "$jobs" -eq "$rules" ] || fail "$jobs Slurm job logs for $rules rules"
completed=$(grep -c "_job_complete: JobId=[0-9]* WEXITSTATUS 0$" "$work/slurm/log/slurmctld.log")
[ "$completed" -eq "$rules" ] || { dump "$work/slurm/log/slurmctld.log"; fail "slurmctld saw $completed jobs end with status 0, not $rules"; }
echo "slurm: $jobs jobs, each ended with status 0"

# the outputs: byte-identical to meshflow run's (report.json and report.html aside: they hold
# timings and each stage's status, ran or cached)
n=0
for v in "${variants[@]}"; do
  for f in "$work/ref/$v"/*; do
    case "$(basename "$f")" in report.json | report.html) continue ;; esac
    cmp -s "$f" "$work/smk-out/$v/$(basename "$f")" || fail "$v/$(basename "$f") differs from meshflow run's"
    n=$((n + 1))
  done
done
[ "$n" -ge 16 ] || fail "only $n output files compared"
echo "outputs: $n files of ${#variants[@]} variants byte-identical to meshflow run's"
echo "PASS in $(ms "$t_start") ms"
