#!/usr/bin/env bash
# A one-node Slurm cluster on localhost, for `make test-slurm`:
#   cluster.sh up STATE     install slurm-wlm and munge if missing, start munged,
#                           slurmctld and slurmd with everything under STATE
#                           (keys, sockets, spool, logs, pid files), print
#                           `export SLURM_CONF=...` for the client commands
#   cluster.sh down STATE   stop exactly the daemons `up` started (by the pids
#                           it recorded), never by name
# Needs root. No systemd and no cgroups: proctrack/linuxproc, task/none.
# Its own ports (6917, 6918) and munge socket, so a real cluster on the same
# machine is left alone.
set -euo pipefail

cmd=${1:?usage: cluster.sh up|down STATE}
state=$(realpath -m "${2:?usage: cluster.sh up|down STATE}")
daemons=(slurmd slurmctld munged)

stop() {
    for d in "${daemons[@]}"; do
        pidfile="$state/$d.pid"
        [[ -f $pidfile ]] || continue
        pid=$(cat "$pidfile")
        # Only a process that is still the daemon we started (its command line).
        if [[ -n $pid ]] && grep -qa "$d" "/proc/$pid/cmdline" 2>/dev/null; then
            kill "$pid" 2>/dev/null || true
            for _ in $(seq 50); do kill -0 "$pid" 2>/dev/null || break; sleep 0.1; done
            kill -9 "$pid" 2>/dev/null || true
        fi
        rm -f "$pidfile"
    done
}

case $cmd in
down)
    stop
    exit 0
    ;;
up) ;;
*)
    echo "cluster.sh: unknown command '$cmd' (up, down)" >&2
    exit 2
    ;;
esac

if [[ $(id -u) != 0 ]]; then
    echo "cluster.sh: a local Slurm cluster needs root (munged and slurmd run as root here)" >&2
    exit 1
fi
if ! command -v slurmctld >/dev/null || ! command -v munged >/dev/null; then
    echo "cluster.sh: installing slurm-wlm and munge (Debian packages)" >&2
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq slurm-wlm munge >/dev/null
fi

stop # leftovers of an earlier `up` in the same STATE
mkdir -p "$state/ctld" "$state/spool"
chmod 700 "$state"
# The init scripts do not start daemons here; munge 0.5 makes keys with mungekey.
[[ -f $state/munge.key ]] || mungekey --create --keyfile="$state/munge.key"
chmod 600 "$state/munge.key"
munged --force --key-file="$state/munge.key" --socket="$state/munge.socket" \
    --pid-file="$state/munged.pid" --log-file="$state/munged.log" \
    --seed-file="$state/munge.seed"

host=$(hostname -s)
cpus=$(nproc)
cat >"$state/slurm.conf" <<CONF
ClusterName=terrabake
SlurmctldHost=$host(127.0.0.1)
SlurmUser=root
SlurmdUser=root
SlurmctldPort=6917
SlurmdPort=6918
AuthType=auth/munge
AuthInfo=socket=$state/munge.socket
CredType=cred/munge
StateSaveLocation=$state/ctld
SlurmdSpoolDir=$state/spool
SlurmctldPidFile=$state/slurmctld.pid
SlurmdPidFile=$state/slurmd.pid
SlurmctldLogFile=$state/slurmctld.log
SlurmdLogFile=$state/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
SchedulerType=sched/builtin
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
# sbatch --wait polls slowly unless finished jobs leave the queue quickly.
MinJobAge=5
ReturnToService=2
NodeName=$host NodeAddr=127.0.0.1 CPUs=$cpus State=UNKNOWN
PartitionName=main Nodes=$host Default=YES MaxTime=INFINITE State=UP OverSubscribe=YES
CONF
export SLURM_CONF="$state/slurm.conf"
slurmctld -f "$SLURM_CONF"
slurmd -f "$SLURM_CONF"
for _ in $(seq 100); do
    if sinfo -h -o %T 2>/dev/null | grep -qE '^(idle|mixed|allocated)'; then
        echo "export SLURM_CONF=$SLURM_CONF"
        exit 0
    fi
    sleep 0.2
done
echo "cluster.sh: the node did not come up; logs in $state" >&2
sinfo >&2 || true
stop
exit 1
