#!/usr/bin/env bash
# The study on a workflow engine gives the report of one process: runs `hilo study --profile
# quick` in one process, then the same study as a Snakemake workflow (--cores 2), killed with
# kill -9 part-way and rerun; compares the two report.json files apart from timing fields and
# says how many stages the rerun redid.
#
# Usage: scripts/workflow-check.sh [HILO] [PROFILE]   (defaults: target/release/hilo, quick)
# Needs python3 with venv; installs Snakemake into .venv-snakemake (or $SNAKEMAKE_VENV).
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/study-check-lib.sh
check_setup quick "$@"

one_process_report "$HILO" "$PROFILE" "$WORK/one"

echo "+ hilo study --profile $PROFILE --workflow snakemake; snakemake --cores 2, killed after the first training"
"$HILO" study --profile "$PROFILE" --workflow snakemake --out "$WORK/wf"
cd "$WORK/wf"
setsid "$SMK" --cores 2 > first.log 2>&1 &
pid=$!
# Wait for the first finished training (its metadata file), then kill the whole process group.
for _ in $(seq 1 1200); do
  if ls results/*/*.meta.json > /dev/null 2>&1; then break; fi
  if ! kill -0 "$pid" 2> /dev/null; then echo "snakemake ended before any training finished" >&2; tail -20 first.log; exit 1; fi
  sleep 0.5
done
kill -9 -- -"$pid"
wait "$pid" 2> /dev/null || true
done_before=$(ls results/*/*.meta.json | wc -l)
echo "  killed (kill -9) with $done_before training(s) finished"
"$SMK" --unlock > /dev/null 2>&1
start=$(date +%s)
"$SMK" --cores 2 --rerun-incomplete > second.log 2>&1 || { tail -30 second.log; exit 1; }
redone=$(grep -c "^Finished jobid" second.log || true)
total=$(grep -c "^rule \|^localrule " Snakefile || true)
echo "  rerun: $redone of $total jobs run (the rest were done), $(( $(date +%s) - start )) s"
cd - > /dev/null
python3 scripts/compare-reports.py "$WORK/one/report.json" "$WORK/wf/report.json"
