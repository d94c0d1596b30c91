#!/usr/bin/env bash
# The validation on a workflow engine gives the validation of one process: runs the coarse
# validation fixture at the tiny profile in one process, then as a Snakemake workflow
# (--cores 2, one job per placement's dataset and per training), and compares the two
# validation.json files apart from timing fields.
#
# Usage: scripts/validation-workflow-check.sh [HILO]   (default: target/release/hilo)
# Needs python3 with venv; installs Snakemake into .venv-snakemake (or $SNAKEMAKE_VENV).
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/study-check-lib.sh
check_setup tiny "$@"
study=$(realpath fixtures/validation-coarse.toml)
args=(--profile tiny --seeds 1 --samples 4)

echo "+ hilo validate fixtures/validation-coarse.toml ${args[*]} (one process)"
start=$(date +%s)
"$HILO" validate "$study" "${args[@]}" --out "$WORK/one" 2> "$WORK/one.log" || { tail -20 "$WORK/one.log"; exit 1; }
echo "  $(( $(date +%s) - start )) s"

echo "+ hilo validate ... --workflow snakemake; snakemake --cores 2"
"$HILO" validate "$study" "${args[@]}" --workflow snakemake --out "$WORK/wf" 2> "$WORK/wf.log" || { tail -20 "$WORK/wf.log"; exit 1; }
start=$(date +%s)
(cd "$WORK/wf" && "$SMK" --cores 2 > run.log 2>&1) || { tail -30 "$WORK/wf/run.log"; exit 1; }
jobs=$(grep -c "^Finished jobid" "$WORK/wf/run.log" || true)
echo "  $jobs jobs, $(( $(date +%s) - start )) s"
python3 scripts/compare-reports.py "$WORK/one/validation.json" "$WORK/wf/validation.json"
