#!/usr/bin/env python3
"""The realism ablation's table: what each effect does to the headline and to the radar.
    python3 scripts/realism-table.py ablation [more sweep folders...] > table.md

Reads every shard's report.json under the sweep folders (`hilo study OUT --out ablation` of
the files scripts/realism-ablation.py writes) and prints one markdown row per shard:
- headline: `lirafusion-like` on 2 x lidar-16 + radar - `centerpoint` on 1 x lidar-64 (the
  claim vs_lidar_alone), mAP and pedestrian AP;
- viewpoints: `centerpoint` on 2 x lidar-16 + radar - `centerpoint` on 1 x lidar-64 (the two
  16-beam LiDARs' second viewpoint against the 64-beam sensor; the radar unused), mAP;
- radar: `lirafusion-like` - `centerpoint` on 2 x lidar-16 + radar (the claim
  fusion_vs_lidar_only: the radar fused, at identical LiDAR poses), mAP, and car AVE (m/s);
each an estimate with its 95% interval and the verdict where it is a claim; then the three
detectors' mAP. A shard without a row reads "-".
"""
import json
import os
import sys


def interval(t, digits=3):
    if not t or not t.get("estimable", True):
        return "-"
    return f"{t['estimate']:+.{digits}f} [{t['lo']:+.{digits}f}, {t['hi']:+.{digits}f}]"


def claim_row(report, claim, metric):
    for c in report["claims"]:
        if c["id"] == claim:
            for row in c["rows"]:
                if row["metric"] == metric:
                    return row
    return None


def comparison(report, metric, a, b):
    for c in report["comparisons"]:
        if c["metric"] == metric and c["a"] == a and c["b"] == b:
            return c["test"]
    return None


def mean_map(report, configuration, preset):
    v = [e["mean_ap"] for e in report["entries"] if e["configuration"] == configuration and e["preset"] == preset]
    return f"{sum(v) / len(v):.3f}" if v else "-"


def cell(row, digits=3):
    if row is None:
        return "-"
    return f"{interval(row['test'], digits)} {row['verdict']}"


def main():
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    cheap, big = "2x lidar-16 + radar", "1x lidar-64"
    print(
        "| study | headline mAP | headline pedestrian AP | viewpoints mAP (LiDAR only) | radar fused, mAP | "
        "radar fused, car AVE (m/s) | mAP: centerpoint cheap / 64-beam, lirafusion-like cheap |"
    )
    print("|---|---|---|---|---|---|---|")
    for sweep in sys.argv[1:]:
        for name in sorted(os.listdir(sweep)):
            path = os.path.join(sweep, name, "report.json")
            if not os.path.isfile(path):
                continue
            with open(path) as f:
                r = json.load(f)
            view = comparison(r, "mAP", f"centerpoint on {big}", f"centerpoint on {cheap}")
            print(
                f"| {name} | {cell(claim_row(r, 'vs_lidar_alone', 'mAP'))} "
                f"| {cell(claim_row(r, 'vs_lidar_alone', 'pedestrian AP'))} "
                f"| {interval(view)} "
                f"| {cell(claim_row(r, 'fusion_vs_lidar_only', 'mAP'))} "
                f"| {cell(claim_row(r, 'fusion_lowers_velocity_error', 'car AVE'), 2)} "
                f"| {mean_map(r, cheap, 'centerpoint')} / {mean_map(r, big, 'centerpoint')}, "
                f"{mean_map(r, cheap, 'lirafusion-like')} |"
            )


if __name__ == "__main__":
    main()
