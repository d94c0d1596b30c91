#!/usr/bin/env python3
"""Where a detector's car velocity error comes from, in a study folder's results.

    python3 scripts/car-velocity-errors.py DATASET RESULTS.json [--min-score 0.3]

DATASET is a study's dataset folder (`study/data/<configuration>-<hash>`), RESULTS.json one of
its detectors' result files (`study/results/<configuration>/<preset>-seed<k>-<hash>.json`).
Each car detection above the score is matched greedily (highest score first) to the nearest
unmatched ground-truth car within 2 m on the ground, as the nuScenes metric matches at its
2 m threshold; the ground truth's velocity is the devkit's (centred difference over the
annotation's neighbours). The matched cars are split by whether a radar detection of the key
frame hit them (`num_radar_pts`) and whether they move (> 0.5 m/s), and for the moving ones
with radar points the large errors (> 2 m/s) are split by cause: the box's heading off by more
than 10 degrees (the radar's Doppler, read along the heading, inherits it), a predicted speed
below 30% of the truth (the box not read), a direction off by more than 20 degrees. The
moving cars no radar detection hit are split by whether their centre lies inside any radar's
horizontal field (its boresight, the sensor's x axis, from `calibrated_sensor.json`; the field's
width and range given on the command line, the catalog `radar-4d`'s by default).

This is not the devkit's AVE (that averages over true positives at recall steps of the
precision-recall curve); it says which cars the error sits on. Standard library only.
"""
import argparse
import json
import math
import os


def table(ds, name):
    with open(os.path.join(ds, "v1.0-trainval", name + ".json")) as f:
        return json.load(f)


def yaw(q):
    w, x, y, z = q
    return math.atan2(2 * (x * y + w * z), 1 - 2 * (y * y + z * z))


def fold(deg):
    """An angle's distance from 0 or 180 degrees (a heading is read either way)."""
    deg %= 180.0
    return min(deg, 180.0 - deg)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dataset")
    ap.add_argument("results")
    ap.add_argument("--min-score", type=float, default=0.3)
    ap.add_argument("--radar-hfov-deg", type=float, default=120.0)
    ap.add_argument("--radar-range-m", type=float, default=90.0)
    args = ap.parse_args()
    radar_sensors = {s["token"] for s in table(args.dataset, "sensor") if s["modality"] == "radar"}
    radars = []
    for c in table(args.dataset, "calibrated_sensor"):
        if c["sensor_token"] in radar_sensors:
            w, x, y, z = c["rotation"]
            # The sensor's x axis in the world, on the ground.
            radars.append((c["translation"], math.atan2(2 * (x * y + w * z), 1 - 2 * (y * y + z * z))))

    def in_a_field(p):
        for at, boresight in radars:
            dx, dy = p[0] - at[0], p[1] - at[1]
            off = math.degrees(math.atan2(dy, dx) - boresight)
            off = (off + 180.0) % 360.0 - 180.0
            if abs(off) <= args.radar_hfov_deg / 2 and math.hypot(dx, dy) <= args.radar_range_m:
                return True
        return False

    category = {c["token"]: c["name"] for c in table(args.dataset, "category")}
    is_car = {i["token"]: category[i["category_token"]].startswith("vehicle.car") for i in table(args.dataset, "instance")}
    anns = table(args.dataset, "sample_annotation")
    by_token = {a["token"]: a for a in anns}
    stamp = {s["token"]: s["timestamp"] for s in table(args.dataset, "sample")}

    def velocity(a):
        first = by_token.get(a["next"]) or a
        last = by_token.get(a["prev"]) or a
        dt = (stamp[first["sample_token"]] - stamp[last["sample_token"]]) / 1e6
        if first is last or dt <= 0:
            return None
        return ((first["translation"][0] - last["translation"][0]) / dt, (first["translation"][1] - last["translation"][1]) / dt)

    cars = {}
    for a in anns:
        if is_car[a["instance_token"]]:
            cars.setdefault(a["sample_token"], []).append(a)
    with open(args.results) as f:
        results = json.load(f)["results"]
    unhit = {"inside a radar's field": 0, "outside every field": 0}
    groups, causes = {}, {"matched": 0, "heading > 10 deg": 0, "speed < 30%": 0, "direction > 20 deg": 0}
    for sample, dets in results.items():
        gts, used = cars.get(sample, []), set()
        dets = [d for d in dets if d["detection_name"] == "car" and d["detection_score"] > args.min_score]
        for d in sorted(dets, key=lambda d: -d["detection_score"]):
            best = None
            for i, a in enumerate(gts):
                dist = math.hypot(a["translation"][0] - d["translation"][0], a["translation"][1] - d["translation"][1])
                if i not in used and dist < 2.0 and (best is None or dist < best[0]):
                    best = (dist, i)
            if best is None:
                continue
            used.add(best[1])
            a = gts[best[1]]
            v = velocity(a)
            if v is None:
                continue
            p = d["velocity"]
            err, speed, pspeed = math.hypot(v[0] - p[0], v[1] - p[1]), math.hypot(*v), math.hypot(*p)
            radar, moving = a["num_radar_pts"] > 0, speed > 0.5
            groups.setdefault((radar, moving), []).append(err)
            if moving and not radar:
                unhit["inside a radar's field" if in_a_field(a["translation"]) else "outside every field"] += 1
            if radar and moving and err > 2.0:
                causes["matched"] += 1
                causes["heading > 10 deg"] += fold(math.degrees(yaw(a["rotation"]) - yaw(d["rotation"]))) > 10
                causes["speed < 30%"] += pspeed < 0.3 * speed
                if pspeed > 1e-6:
                    cos = (v[0] * p[0] + v[1] * p[1]) / (speed * pspeed)
                    causes["direction > 20 deg"] += math.degrees(math.acos(max(-1.0, min(1.0, cos)))) > 20
    print("| radar points | moving | cars | mean error (m/s) | median | 90th percentile |")
    print("|---|---|---:|---:|---:|---:|")
    for (radar, moving), errs in sorted(groups.items(), reverse=True):
        errs.sort()
        n = len(errs)
        print(f"| {'yes' if radar else 'no'} | {'yes' if moving else 'no'} | {n} | {sum(errs) / n:.2f} | {errs[n // 2]:.2f} | {errs[int(0.9 * n)]:.2f} |")
    every = [e for errs in groups.values() for e in errs]
    print(f"\nall matched cars: {len(every)}, mean error {sum(every) / max(len(every), 1):.2f} m/s")
    print("moving cars with radar points and an error above 2 m/s: " + ", ".join(f"{k} {v}" for k, v in causes.items()))
    print("moving cars no radar detection hit: " + ", ".join(f"{k} {v}" for k, v in unhit.items()))


if __name__ == "__main__":
    main()
