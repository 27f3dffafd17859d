#!/usr/bin/env bash
# s2r batch --slurm on a real Slurm (CTest: tests_batch_slurm, label slurm).
# Starts a single-node cluster on this machine from Debian's packages
# (slurm-wlm, munge): its own munge key and socket, slurmctld and slurmd on
# free loopback ports with a generated slurm.conf (proctrack/linuxproc,
# task/none, no cgroups, no accounting), submits a batch of three small
# captures (one broken on purpose) as a job array with a summary job after it,
# checks the results and the summary page, and stops every daemon by its PID.
# Exit 77 (skipped, with the reason) only where the daemons cannot start.
set -euo pipefail
s2r=${1:?usage: batch_slurm_test.sh BUILD/app/s2r}
skip() { echo "SKIP: $*"; exit 77; }
fail() { echo "FAIL: $*"; for f in "$tmp"/log/*.log; do echo "== $f"; tail -20 "$f"; done; exit 1; }
for p in munged mungekey slurmctld slurmd sbatch sinfo; do
  command -v $p >/dev/null || [ -x /usr/sbin/$p ] || skip "$p not installed (scripts/setup installs slurm-wlm and munge)"
done
export PATH=$PATH:/usr/sbin
s2r=$(readlink -f "$s2r")
tmp=$(mktemp -d /tmp/s2r_slurm.XXXXXX)
chmod 755 "$tmp"
mkdir -p "$tmp"/{munge,state,spool,log}
chmod 700 "$tmp/munge"
stop() {
  for f in "$tmp/slurmd.pid" "$tmp/slurmctld.pid" "$tmp/munge/munged.pid"; do
    [ -f "$f" ] && kill "$(cat "$f")" 2>/dev/null || true
  done
  for f in "$tmp/slurmd.pid" "$tmp/slurmctld.pid" "$tmp/munge/munged.pid"; do
    [ -f "$f" ] || continue
    pid=$(cat "$f")
    for _ in $(seq 50); do kill -0 "$pid" 2>/dev/null || break; sleep 0.1; done
    kill -9 "$pid" 2>/dev/null || true
  done
}
trap 'stop; rm -rf "$tmp"' EXIT
start=$SECONDS

mungekey --create --keyfile="$tmp/munge/munge.key" >/dev/null 2>&1 || skip "mungekey failed"
chmod 600 "$tmp/munge/munge.key"
munged --force --socket="$tmp/munge/sock" --key-file="$tmp/munge/munge.key" --log-file="$tmp/log/munged.log" \
  --pid-file="$tmp/munge/munged.pid" --seed-file="$tmp/munge/seed" || skip "munged did not start: $(tail -3 "$tmp/log/munged.log")"

ports=($(python3 -c 'import socket
s=[socket.socket() for _ in range(2)]
[x.bind(("127.0.0.1",0)) for x in s]
print(*[x.getsockname()[1] for x in s])'))
user=$(id -un)
node=$(hostname -s)
cpus=$(nproc)
mem_mb=$(awk '/MemTotal/{print int($2/1024*0.8)}' /proc/meminfo)
cat >"$tmp/slurm.conf" <<EOF
ClusterName=s2rtest
SlurmctldHost=$node(127.0.0.1)
SlurmctldPort=${ports[0]}
SlurmdPort=${ports[1]}
SlurmUser=$user
SlurmdUser=$user
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket=$tmp/munge/sock
StateSaveLocation=$tmp/state
SlurmdSpoolDir=$tmp/spool
SlurmctldPidFile=$tmp/slurmctld.pid
SlurmdPidFile=$tmp/slurmd.pid
SlurmctldLogFile=$tmp/log/slurmctld.log
SlurmdLogFile=$tmp/log/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
ReturnToService=2
MpiDefault=none
NodeName=$node NodeAddr=127.0.0.1 CPUs=$cpus RealMemory=$mem_mb State=UNKNOWN
PartitionName=s2r Nodes=ALL Default=YES MaxTime=INFINITE State=UP
EOF
export SLURM_CONF=$tmp/slurm.conf
slurmctld -f "$SLURM_CONF" || skip "slurmctld did not start: $(tail -5 "$tmp/log/slurmctld.log" 2>/dev/null)"
slurmd -f "$SLURM_CONF" || skip "slurmd did not start: $(tail -5 "$tmp/log/slurmd.log" 2>/dev/null)"
for _ in $(seq 150); do
  sinfo -h -o %t 2>/dev/null | grep -q idle && break
  sleep 0.2
done
sinfo -h -o %t 2>/dev/null | grep -q idle || skip "the node never came up idle: $(tail -5 "$tmp/log/slurmctld.log")"
echo "slurm: cluster up in $((SECONDS - start)) s"

for scene in blob bunny; do
  "$s2r" synth --scene $scene --views 8 --width 160 --height 120 --out "$tmp/caps/$scene" >/dev/null 2>&1
done
mkdir -p "$tmp/caps/broken"
printf '{"format": "s2r.session", "version": 1, ' >"$tmp/caps/broken/session.json"
echo '{"reconstruct": ["--voxel", "auto"]}' >"$tmp/options.json"

"$s2r" batch "$tmp/caps" --out "$tmp/res" --options "$tmp/options.json" --slurm --cpus-per-task 1 --partition s2r \
  --sbatch-arg=--comment=s2r-test >"$tmp/log/submit.log" 2>&1 || fail "submit: $(cat "$tmp/log/submit.log")"
cat "$tmp/log/submit.log"
grep -q "submitted job array" "$tmp/log/submit.log" || fail "no job array submitted"
[ -f "$tmp/res/slurm/jobs.json" ] || fail "no jobs.json"
for _ in $(seq 600); do
  [ -f "$tmp/res/index.html" ] && ! squeue -h 2>/dev/null | grep -q . && break
  sleep 0.2
done
[ -f "$tmp/res/index.html" ] || fail "the summary job wrote no index.html: $(squeue 2>&1)"
for cap in blob bunny; do
  grep -q '"state": "done"' "$tmp/res/$cap/status.json" || fail "$cap not done: $(cat "$tmp/res/$cap/status.json")"
  [ -f "$tmp/res/$cap/eval/eval.csv" ] || fail "$cap has no eval"
  grep -q -- '--voxel' "$tmp/res/$cap/steps/reconstruct.json" || fail "$cap: the options file's arguments were not used"
done
grep -q '"state": "failed"' "$tmp/res/broken/status.json" || fail "broken not failed"
grep -q 'class="failed"' "$tmp/res/index.html" || fail "no failed row on the page"
# Each capture ran in an array task; the summary ran after them.
ls "$tmp/res/slurm"/task_*.log >/dev/null || fail "no array task logs"
grep -q "summary" "$tmp/res/slurm/summary.log" || fail "summary job log: $(cat "$tmp/res/slurm/summary.log")"
code=0
"$s2r" batch --status "$tmp/res" >"$tmp/log/status.log" 2>&1 || code=$?
[ $code -eq 1 ] || fail "status exit $code with a failed capture (expected 1): $(cat "$tmp/log/status.log")"
grep -q "2 done, 1 failed" "$tmp/log/status.log" || fail "status: $(cat "$tmp/log/status.log")"
echo "slurm: batch of 3 through the job array and summary in $((SECONDS - start)) s"
