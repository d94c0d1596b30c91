#!/usr/bin/env bash
# A sweep on a workflow engine gives the comparison of one process: the default study over two
# sensor catalogs (the default one, and one whose 16-beam LiDAR costs $6,000 instead of $4,000),
# run by `hilo study` in one process and as one Snakemake workflow; compares comparison.json and
# every study's report.json apart from timing fields.
#
# Usage: scripts/sweep-check.sh [HILO] [PROFILE]   (defaults: target/release/hilo, tiny)
# Needs python3 with venv; installs Snakemake into .venv-snakemake (or $SNAKEMAKE_VENV).
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/study-check-lib.sh
check_setup tiny "$@"
cp fixtures/sensors.toml "$WORK/list.toml"
sed 's/^price_usd = 4000.0$/price_usd = 6000.0/' fixtures/sensors.toml > "$WORK/dear.toml"
if cmp -s "$WORK/list.toml" "$WORK/dear.toml"; then
  echo "fixtures/sensors.toml has no 'price_usd = 4000.0' line to change" >&2
  exit 1
fi
{ echo 'catalogs = ["list.toml", "dear.toml"]'; cat fixtures/paper-sensors-study.toml; } > "$WORK/sweep.toml"

echo "+ hilo study sweep.toml --profile $PROFILE (one process)"
start=$(date +%s)
"$HILO" study "$WORK/sweep.toml" --profile "$PROFILE" --out "$WORK/one" 2> "$WORK/one.log" || { tail -20 "$WORK/one.log"; exit 1; }
echo "  $(( $(date +%s) - start )) s"

echo "+ hilo study sweep.toml --profile $PROFILE --workflow snakemake; snakemake --cores 2"
"$HILO" study "$WORK/sweep.toml" --profile "$PROFILE" --workflow snakemake --out "$WORK/wf"
start=$(date +%s)
(cd "$WORK/wf" && "$SMK" --cores 2 > run.log 2>&1) || { tail -30 "$WORK/wf/run.log"; exit 1; }
jobs=$(grep -c "^Finished jobid" "$WORK/wf/run.log" || true)
echo "  $jobs jobs, $(( $(date +%s) - start )) s"
for f in comparison.json list/report.json dear/report.json; do
  echo "  $f:"
  python3 scripts/compare-reports.py "$WORK/one/$f" "$WORK/wf/$f"
done
grep -q '^| 2x lidar-16 + radar | \$10,000' "$WORK/wf/comparison.md" || { echo "comparison.md lacks the list price row" >&2; exit 1; }
echo "sweep check: comparison.md and every study's report equal apart from timing fields"
