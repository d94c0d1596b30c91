#!/usr/bin/env bash
# The study on Slurm, on this one machine: installs slurm-wlm and munge (apt), starts a
# single-node cluster (slurmctld and slurmd on localhost, no accounting database), runs the quick
# profile's workflow with Snakemake's Slurm executor, compares its report.json with the one of
# `hilo study --profile quick` in one process (apart from timing fields), and shuts Slurm down.
#
# Usage: scripts/slurm-local.sh [HILO] [PROFILE]   (defaults: target/release/hilo, quick)
# Needs root (or sudo) for apt and the daemons. Leaves the packages installed; removes its
# configuration and state on exit.
set -euo pipefail
cd "$(dirname "$0")/.."
HILO=$(realpath "${1:-target/release/hilo}")
PROFILE=${2:-quick}
VENV=${SNAKEMAKE_VENV:-.venv-snakemake}
SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO=sudo; fi

echo "+ apt-get install slurm-wlm munge"
$SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -q slurm-wlm munge > /dev/null

source scripts/study-check-lib.sh
snakemake_venv "$VENV" "snakemake==9.27.1" "snakemake-executor-plugin-slurm==2.8.0"

WORK=$(mktemp -d)
chmod 755 "$WORK"
STATE="$WORK/slurm"
mkdir -p "$STATE/ctld" "$STATE/d" "$STATE/log"
node=$(hostname -s)
cpus=$(nproc)
mem_mb=$(( $(awk '/MemTotal/ {print $2}' /proc/meminfo) / 1024 - 1024 ))
conf_dir=/etc/slurm
$SUDO mkdir -p "$conf_dir"
for f in slurm.conf cgroup.conf; do
  if [ -e "$conf_dir/$f" ]; then $SUDO mv "$conf_dir/$f" "$conf_dir/$f.before-hilo"; fi
done

cleanup() {
  set +e
  echo "+ shutting Slurm down"
  $SUDO scontrol shutdown > /dev/null 2>&1
  sleep 2
  $SUDO pkill -x slurmd; $SUDO pkill -x slurmctld; $SUDO pkill -x munged
  for f in slurm.conf cgroup.conf; do
    $SUDO rm -f "$conf_dir/$f"
    if [ -e "$conf_dir/$f.before-hilo" ]; then $SUDO mv "$conf_dir/$f.before-hilo" "$conf_dir/$f"; fi
  done
  rm -rf "$WORK"
}
trap cleanup EXIT

# No cgroups (containers often lack them) and no accounting database: job status comes from
# squeue, so finished jobs must stay visible to it for a while (MinJobAge).
$SUDO tee "$conf_dir/slurm.conf" > /dev/null << EOF
ClusterName=hilo-local
SlurmctldHost=$node
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
StateSaveLocation=$STATE/ctld
SlurmdSpoolDir=$STATE/d
SlurmctldPidFile=$STATE/slurmctld.pid
SlurmdPidFile=$STATE/slurmd.pid
SlurmctldLogFile=$STATE/log/slurmctld.log
SlurmdLogFile=$STATE/log/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
MpiDefault=none
ReturnToService=2
MinJobAge=86400
NodeName=$node CPUs=$cpus RealMemory=$mem_mb State=UNKNOWN
PartitionName=local Nodes=$node Default=YES MaxTime=INFINITE State=UP
EOF
$SUDO tee "$conf_dir/cgroup.conf" > /dev/null << EOF
CgroupPlugin=autodetect
IgnoreSystemd=yes
EOF

echo "+ munged, slurmctld, slurmd on $node ($cpus CPUs, $mem_mb MB)"
if [ ! -s /etc/munge/munge.key ]; then
  $SUDO dd if=/dev/urandom of=/etc/munge/munge.key bs=1024 count=1 status=none
  $SUDO chown munge:munge /etc/munge/munge.key
  $SUDO chmod 400 /etc/munge/munge.key
fi
$SUDO mkdir -p /run/munge && $SUDO chown munge:munge /run/munge
$SUDO -u munge /usr/sbin/munged --force 2> /dev/null || $SUDO runuser -u munge -- /usr/sbin/munged --force
$SUDO slurmctld
$SUDO slurmd
for _ in $(seq 1 60); do
  if sinfo -h -o %T 2> /dev/null | grep -q idle; then break; fi
  sleep 1
done
sinfo

one_process_report "$HILO" "$PROFILE" "$WORK/one"

echo "+ hilo study --profile $PROFILE --workflow snakemake; snakemake --executor slurm"
"$HILO" study --profile "$PROFILE" --workflow snakemake --out "$WORK/wf"
start=$(date +%s)
(
  cd "$WORK/wf"
  "$SMK" --executor slurm --jobs 4 --slurm-status-command squeue --slurm-no-account \
    --slurm-init-seconds-before-status-checks 5 --default-resources slurm_partition=local \
    > slurm-run.log 2>&1 || { tail -40 slurm-run.log; cat "$STATE/log/slurmctld.log" | tail -20; exit 1; }
)
jobs=$(grep -c "^Finished jobid" "$WORK/wf/slurm-run.log" || true)
echo "  $jobs Slurm jobs, $(( $(date +%s) - start )) s"
python3 scripts/compare-reports.py "$WORK/one/report.json" "$WORK/wf/report.json"
