#!/usr/bin/env bash
# Velocity from LiDAR sweeps and the radar's Doppler: the default study's cheap rig on the
# paper's sensors (2x lidar-16 + radar) recorded with LiDAR sweeps between its key frames,
# `centerpoint` and `lirafusion-like` at their default schedules, each as its preset (single-frame LiDAR) and with
# fixtures/patches/ten-sweeps.json (ten LiDAR sweeps, 0.9 s, velocity loss weighted 2.0, 20
# points per pillar); prints mAP, NDS, mAVE, and car and pedestrian velocity error per run and seed.
#
# Usage: scripts/velocity.sh [HILO] [OUT] [SEEDS] [SAMPLES]
#   (defaults: target/release/hilo, velocity, 1, each preset's default schedule)
# Reruns resume: finished runs, detections and evaluations are kept.
set -euo pipefail
cd "$(dirname "$0")/.."
HILO=${1:-target/release/hilo}
OUT=${2:-velocity}
SEEDS=${3:-1}
samples=()
[ -n "${4:-}" ] && samples=(--samples "$4")
mkdir -p "$OUT/runs"
sed 's/^sweep_rate_hz = 10.0 .*$/sweep_rate_hz = 10.0\nlidar_sweeps = true/' fixtures/paper-sensors-study.toml > "$OUT/study.toml"
grep -q '^lidar_sweeps = true$' "$OUT/study.toml" || { echo "fixtures/paper-sensors-study.toml has no sweep_rate_hz line to extend" >&2; exit 1; }
"$HILO" place "$OUT/study.toml" --out "$OUT/placements" > "$OUT/place.log" 2>&1
"$HILO" simulate "$OUT/study.toml" --placement "$OUT/placements/2x_lidar_16_radar.json" --out "$OUT/data" > "$OUT/simulate.log" 2>&1
for seed in $(seq 0 $((SEEDS - 1))); do
  for preset in centerpoint lirafusion-like; do
    for variant in preset ten-sweeps; do
      run="$OUT/runs/$preset-$variant-$seed"
      [ -f "$run/eval/metrics_summary.json" ] && continue
      patch=()
      [ "$variant" = ten-sweeps ] && patch=(--detector-patch fixtures/patches/ten-sweeps.json)
      echo "+ $preset $variant seed $seed"
      "$HILO" train --data "$OUT/data" --detector "$preset" "${patch[@]}" "${samples[@]}" --seed "$seed" --out "$run" > "$run.log" 2>&1
      "$HILO" detect --data "$OUT/data" --run "$run" --out "$run/detections.json" >> "$run.log" 2>&1
      "$HILO" eval --data "$OUT/data" --results "$run/detections.json" --out "$run/eval" --bootstrap 0 >> "$run.log" 2>&1
    done
  done
done
python3 - "$OUT" <<'PY'
import json, pathlib, sys
runs = sorted(pathlib.Path(sys.argv[1], "runs").glob("*/eval/metrics_summary.json"))
print("| run | mAP | NDS | mAVE (m/s) | car AVE (m/s) | pedestrian AVE (m/s) |")
print("|---|---:|---:|---:|---:|---:|")
for p in runs:
    m = json.loads(p.read_text())
    e = m["label_tp_errors"]
    print(f"| {p.parent.parent.name} | {m['mean_ap']:.3f} | {m['nd_score']:.3f} | {m['tp_errors']['vel_err']:.2f} | {e['car']['vel_err']:.2f} | {e['pedestrian']['vel_err']:.2f} |")
PY
