#!/usr/bin/env bash
# A one-node Slurm cluster on this machine, without systemd: Debian's munge, slurmctld and slurmd, all state
# under DIR. What tests/cluster.rs runs the daemon against, and what a developer can try the cluster path on.
#
#   scripts/slurm-cluster.sh install          # the Debian packages (munge slurmctld slurmd slurm-client)
#   scripts/slurm-cluster.sh start DIR        # writes DIR/slurm.conf, starts munged, slurmctld, slurmd
#   scripts/slurm-cluster.sh stop DIR         # stops them
#   scripts/slurm-cluster.sh kill-node DIR    # kill -9 slurmd and every job step on the node (a node failure)
#   scripts/slurm-cluster.sh start-node DIR   # slurmd again (the node returns to service)
#
# Then `export SLURM_CONF=DIR/slurm.conf` for sbatch, squeue, scancel, scontrol and sacct. Job completion
# records go to DIR/jobcomp.log (`sacct --completion` reads them; no slurmdbd). The node is this host, with
# its cores and memory; partition `scan`. Needs root (slurmd runs jobs as their submitter).
set -euo pipefail

cmd=${1:-}
dir=${2:-}

install() {
  local missing=()
  for tool in munged:munge slurmctld:slurmctld slurmd:slurmd sbatch:slurm-client; do
    command -v "${tool%%:*}" >/dev/null 2>&1 || missing+=("${tool#*:}")
  done
  if [ ${#missing[@]} -eq 0 ]; then
    echo "slurm: all present ($(sbatch --version))"
    return
  fi
  local sudo=""
  [ "$(id -u)" -eq 0 ] || sudo="sudo"
  echo "installing: ${missing[*]}"
  $sudo apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}"
}

need_dir() {
  if [ -z "$dir" ]; then
    echo "usage: $0 $cmd DIR" >&2
    exit 2
  fi
  mkdir -p "$dir"
  dir=$(cd "$dir" && pwd)
}

wait_for() { # what, seconds, command...
  local what=$1 limit=$2
  shift 2
  for _ in $(seq 1 $((limit * 10))); do
    if "$@" >/dev/null 2>&1; then return 0; fi
    sleep 0.1
  done
  echo "slurm-cluster: $what did not come up within ${limit}s; logs in $dir" >&2
  tail -n 20 "$dir"/*.log >&2 || true
  return 1
}

start_slurmd() {
  slurmd -f "$dir/slurm.conf" -L "$dir/slurmd.log"
  wait_for "the node" 20 bash -c "sinfo -h -N -o %t | grep -qE '^(idle|mix|alloc)'"
}

start() {
  need_dir
  for tool in munged slurmctld slurmd sbatch; do
    command -v "$tool" >/dev/null || { echo "slurm-cluster: $tool is missing: run $0 install (Debian: munge slurmctld slurmd slurm-client)" >&2; exit 1; }
  done
  stop >/dev/null 2>&1 || true
  mkdir -p "$dir/munge" "$dir/state" "$dir/spool"
  chmod 700 "$dir/munge"
  # 1. munge, its key and socket under DIR.
  [ -f "$dir/munge/munge.key" ] || dd if=/dev/urandom of="$dir/munge/munge.key" bs=1024 count=1 status=none
  chmod 400 "$dir/munge/munge.key"
  munged --force --key-file="$dir/munge/munge.key" --socket="$dir/munge/munge.socket" \
    --pid-file="$dir/munge/munged.pid" --log-file="$dir/munge.log" --seed-file="$dir/munge/munge.seed"
  wait_for munged 10 test -S "$dir/munge/munge.socket"
  # 2. slurm.conf: this host as the one node, every path under DIR, ports free for this cluster.
  local host cpus mem port
  host=$(hostname -s)
  cpus=$(nproc)
  mem=$(awk '/MemTotal/ { printf "%d", $2 / 1024 * 0.9 }' /proc/meminfo)
  port=$((20000 + RANDOM % 20000))
  cat >"$dir/slurm.conf" <<EOF
# A one-node cluster for scanstation's tests (scripts/slurm-cluster.sh).
ClusterName=scanstation
SlurmctldHost=$host
SlurmctldPort=$port
SlurmdPort=$((port + 1))
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
AuthInfo=socket=$dir/munge/munge.socket
CredType=cred/munge
StateSaveLocation=$dir/state
SlurmdSpoolDir=$dir/spool
SlurmctldPidFile=$dir/slurmctld.pid
SlurmdPidFile=$dir/slurmd.pid
SlurmctldLogFile=$dir/slurmctld.log
SlurmdLogFile=$dir/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
MpiDefault=none
SwitchType=switch/none
JobCompType=jobcomp/filetxt
JobCompLoc=$dir/jobcomp.log
AccountingStorageType=accounting_storage/none
JobAcctGatherType=jobacct_gather/linux
JobAcctGatherFrequency=1
ReturnToService=2
SlurmdTimeout=5
SlurmctldTimeout=10
MessageTimeout=5
InactiveLimit=0
MinJobAge=600
KillWait=2
SchedulerType=sched/backfill
SchedulerParameters=sched_interval=1
JobRequeue=0
NodeName=$host CPUs=$cpus RealMemory=$mem State=UNKNOWN
PartitionName=scan Nodes=$host Default=YES MaxTime=INFINITE State=UP
EOF
  export SLURM_CONF="$dir/slurm.conf"
  # 3. The controller, then the node.
  slurmctld -f "$dir/slurm.conf" -L "$dir/slurmctld.log" -i
  wait_for slurmctld 20 scontrol ping
  start_slurmd
  echo "slurm-cluster: up: export SLURM_CONF=$dir/slurm.conf (node $host, $cpus CPUs, $mem MB; partition scan)"
}

kill_pid() { # pidfile
  if [ -f "$1" ]; then
    kill -9 "$(cat "$1")" 2>/dev/null || true
    rm -f "$1"
  fi
}

stop() {
  need_dir
  pkill -9 -f "slurmstepd.*" 2>/dev/null || true
  kill_pid "$dir/slurmd.pid"
  kill_pid "$dir/slurmctld.pid"
  kill_pid "$dir/munge/munged.pid"
  pkill -9 -f "slurmd -f $dir/slurm.conf" 2>/dev/null || true
  pkill -9 -f "slurmctld -f $dir/slurm.conf" 2>/dev/null || true
  pkill -9 -f "munged .*--key-file=$dir/munge/munge.key" 2>/dev/null || true
  echo "slurm-cluster: stopped"
}

case "$cmd" in
  install) install ;;
  start) start ;;
  stop) stop ;;
  kill-node)
    need_dir
    kill_pid "$dir/slurmd.pid"
    pkill -9 -f "slurmd -f $dir/slurm.conf" 2>/dev/null || true
    # The job steps and what they run die with the node.
    pkill -9 slurmstepd 2>/dev/null || true
    pkill -9 -f "scanstation cluster-run" 2>/dev/null || true
    ;;
  start-node)
    need_dir
    export SLURM_CONF="$dir/slurm.conf"
    start_slurmd
    ;;
  *)
    echo "usage: $0 install | start DIR | stop DIR | kill-node DIR | start-node DIR" >&2
    exit 2
    ;;
esac
