#!/usr/bin/env bash
# A single-node SLURM (slurmctld + slurmd + munge) on this Debian/Ubuntu machine, for the `slurm`
# tests (tests/test_slurm.py) and for trying `wavebrdf submit` scripts. Needs root (or sudo).
#
#   sudo bash tools/slurm-local.sh          # install (apt), configure for this node, start
#   sudo bash tools/slurm-local.sh stop     # stop the daemons
#   .venv/bin/python -m pytest -m slurm tests/test_slurm.py
#
# The node is this machine: its hostname, its cores, 90 % of its memory; one partition "debug";
# cons_tres, so --mem and --cpus-per-task are honoured; requeue allowed; no cgroups
# (proctrack/linuxproc), so it runs in containers too. Idempotent: a running SLURM of this
# configuration is left as it is.
set -euo pipefail
SUDO=""
[ "$(id -u)" = 0 ] || SUDO=sudo
CONF=/etc/slurm/slurm.conf

stop() {
    $SUDO pkill -x slurmd 2>/dev/null || true
    $SUDO pkill -x slurmctld 2>/dev/null || true
}
if [ "${1:-}" = stop ]; then stop; exit 0; fi

if ! command -v slurmctld >/dev/null || ! command -v munged >/dev/null; then
    echo "[slurm-local] installing slurm-wlm and munge (apt)"
    $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -q slurm-wlm munge >/dev/null
fi

node=$(hostname -s)
cpus=$(nproc)
memory_mib=$(awk '/MemTotal/ {printf "%d", $2 / 1024 * 0.9}' /proc/meminfo)
wanted=$(cat <<EOF
# Written by tools/slurm-local.sh: one node, this machine.
ClusterName=wavebrdf-local
SlurmctldHost=$node
SlurmUser=slurm
AuthType=auth/munge
CredType=cred/munge
StateSaveLocation=/var/lib/slurm/slurmctld
SlurmdSpoolDir=/var/lib/slurm/slurmd
SlurmctldPidFile=/run/slurmctld.pid
SlurmdPidFile=/run/slurmd.pid
SlurmctldLogFile=/var/log/slurm/slurmctld.log
SlurmdLogFile=/var/log/slurm/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
SchedulerType=sched/backfill
MpiDefault=none
ReturnToService=2
JobRequeue=1
KillWait=30
MinJobAge=600
InactiveLimit=0
NodeName=$node CPUs=$cpus RealMemory=$memory_mib State=UNKNOWN
PartitionName=debug Nodes=$node Default=YES MaxTime=INFINITE State=UP
EOF
)
if [ ! -f "$CONF" ] || [ "$(cat "$CONF")" != "$wanted" ]; then
    echo "[slurm-local] writing $CONF ($node: $cpus CPUs, $memory_mib MiB)"
    stop
    $SUDO mkdir -p /etc/slurm
    printf '%s\n' "$wanted" | $SUDO tee "$CONF" >/dev/null
fi
id slurm >/dev/null 2>&1 || $SUDO useradd --system --no-create-home slurm
$SUDO mkdir -p /var/lib/slurm/slurmctld /var/lib/slurm/slurmd /var/log/slurm /run/munge
$SUDO chown slurm: /var/lib/slurm/slurmctld /var/log/slurm
$SUDO chown munge: /run/munge 2>/dev/null || true

if [ ! -s /etc/munge/munge.key ]; then
    echo "[slurm-local] creating /etc/munge/munge.key"
    $SUDO mkdir -p /etc/munge
    $SUDO dd if=/dev/urandom of=/etc/munge/munge.key bs=1024 count=1 status=none
    $SUDO chown munge: /etc/munge/munge.key
    $SUDO chmod 400 /etc/munge/munge.key
fi
pgrep -x munged >/dev/null || $SUDO -u munge munged 2>/dev/null || $SUDO runuser -u munge -- munged
pgrep -x slurmctld >/dev/null || $SUDO slurmctld
pgrep -x slurmd >/dev/null || $SUDO slurmd

for _ in $(seq 60); do
    state=$(sinfo -h -N -o %t 2>/dev/null | head -1 || true)
    case "$state" in
        idle|mix|alloc) echo "[slurm-local] node $node is $state"; exit 0 ;;
        down*|drain*) $SUDO scontrol update nodename="$node" state=resume 2>/dev/null || true ;;
    esac
    sleep 1
done
echo "[slurm-local] the node did not come up; see /var/log/slurm/slurmctld.log and slurmd.log" >&2
exit 1
