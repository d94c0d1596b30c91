#!/usr/bin/env python3
"""Checks hilo's nuScenes detection metrics against the official nuscenes-devkit (1.2).

Optional for users (hilo never needs Python):
    pip install nuscenes-devkit==1.2.0
    cargo build --release
    python3 scripts/devkit_compare.py --hilo target/release/hilo [--seed 0] [--samples 300]

It writes random but adversarial ground truth and predictions (score ties, boxes at the class
range limit, yaw near +-pi, empty ground-truth boxes, a class without ground truth, missing
attributes, duplicate detections), runs `hilo eval` on them, computes the same metrics with the
devkit's own accumulate / calc_ap / calc_tp / DetectionMetrics, and compares every number.
The devkit's hard-coded class list is replaced by hilo's six classes for the run; its range and
empty-box filter is applied exactly as `filter_eval_boxes` does (without the bike-rack rule).
"""
import argparse
import json
import math
import os
import random
import subprocess
import sys
import tempfile

import numpy as np
from nuscenes.eval.detection import constants
from nuscenes.eval.common.data_classes import EvalBoxes
from nuscenes.eval.detection.algo import accumulate, calc_ap, calc_tp
from nuscenes.eval.detection.constants import TP_METRICS
from nuscenes.eval.detection.data_classes import DetectionBox, DetectionConfig, DetectionMetricDataList, DetectionMetrics
from nuscenes.eval.common.utils import center_distance

CLASSES = ["car", "truck", "bus", "motorcycle", "pedestrian", "golf_cart"]
RANGES = {"car": 50, "truck": 50, "bus": 50, "motorcycle": 40, "pedestrian": 40, "golf_cart": 40}
SIZES = {"car": (1.9, 4.6, 1.6), "truck": (2.5, 8.5, 3.4), "bus": (2.6, 12.0, 3.2), "motorcycle": (0.8, 2.2, 1.4),
         "pedestrian": (0.6, 0.6, 1.75), "golf_cart": (1.3, 2.5, 1.8)}
ATTRS = {"car": ["vehicle.moving", "vehicle.stopped", "vehicle.parked"], "truck": ["vehicle.moving", "vehicle.parked"],
         "bus": ["vehicle.moving", "vehicle.stopped"], "motorcycle": ["cycle.with_rider", "cycle.without_rider"],
         "pedestrian": ["pedestrian.moving", "pedestrian.standing"], "golf_cart": [""]}


def quat(yaw):
    return [math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]


def make_fixture(seed, n_samples):
    rng = random.Random(seed)
    samples, gt, results = {}, {}, {}
    for s in range(n_samples):
        token = f"s{s:05d}"
        origin = [rng.uniform(-5, 5), rng.uniform(-5, 5), 0.0]
        samples[token] = {"scene": f"scene{s // 40}", "ego_translation": origin}
        boxes, preds = [], []
        for k in range(rng.randint(0, 14)):
            c = rng.choice(CLASSES[:-1] if s % 7 else CLASSES)  # golf carts only in some samples
            if c == "truck":
                continue  # no truck ground truth at all: a class without GT
            r = RANGES[c] * (1.0 if rng.random() < 0.05 else rng.uniform(0.05, 1.1))  # some exactly at the limit
            a = rng.uniform(-math.pi, math.pi)
            t = [origin[0] + r * math.cos(a), origin[1] + r * math.sin(a), 0.9]
            yaw = rng.choice([math.pi - 1e-9, -math.pi + 1e-9, rng.uniform(-math.pi, math.pi)])
            w, l, h = SIZES[c]
            v = [rng.uniform(-10, 10), rng.uniform(-10, 10)]
            attr = "" if rng.random() < 0.1 else rng.choice(ATTRS[c])
            g = {"sample_token": token, "translation": t, "size": [w, l, h], "rotation": quat(yaw), "velocity": v,
                 "detection_name": c, "detection_score": -1.0, "attribute_name": attr,
                 "num_pts": 0 if rng.random() < 0.1 else rng.randint(1, 200)}
            boxes.append(g)
            for _ in range(rng.choice([0, 1, 1, 1, 2])):  # missed, detected, duplicated
                noise = rng.uniform(0, 3.0)
                b = math.radians(rng.uniform(0, 360))
                p = {"sample_token": token,
                     "translation": [t[0] + noise * math.cos(b), t[1] + noise * math.sin(b), 0.9],
                     "size": [w * rng.uniform(0.8, 1.2), l * rng.uniform(0.8, 1.2), h * rng.uniform(0.8, 1.2)],
                     "rotation": quat(yaw + rng.gauss(0, 0.4)), "velocity": [v[0] + rng.gauss(0, 1), v[1] + rng.gauss(0, 1)],
                     "detection_name": c if rng.random() < 0.9 else rng.choice(CLASSES),
                     "detection_score": round(rng.random(), 2),  # two decimals: many ties
                     "attribute_name": rng.choice(ATTRS[c])}
                preds.append(p)
        for _ in range(rng.randint(0, 4)):  # false positives, some of a class without GT
            c = rng.choice(CLASSES)
            w, l, h = SIZES[c]
            preds.append({"sample_token": token, "translation": [origin[0] + rng.uniform(-45, 45), origin[1] + rng.uniform(-45, 45), 0.9],
                          "size": [w, l, h], "rotation": quat(rng.uniform(-3, 3)), "velocity": [0.0, 0.0],
                          "detection_name": c, "detection_score": round(rng.random(), 2), "attribute_name": ""})
        gt[token] = boxes
        results[token] = preds
    return {"samples": samples, "boxes": gt}, {"meta": {"use_lidar": True}, "results": results}


def devkit_metrics(gt_doc, res_doc):
    constants.DETECTION_NAMES[:] = CLASSES  # the devkit's list object, shared by its modules
    cfg = DetectionConfig(class_range=RANGES, dist_fcn="center_distance", dist_ths=[0.5, 1.0, 2.0, 4.0], dist_th_tp=2.0,
                          min_recall=0.1, min_precision=0.1, max_boxes_per_sample=500, mean_ap_weight=5)

    def load(doc, is_gt):
        boxes = EvalBoxes()
        for token, lst in doc.items():
            origin = gt_doc["samples"][token]["ego_translation"]
            out = []
            for b in lst:
                box = DetectionBox(sample_token=token, translation=b["translation"], size=b["size"], rotation=b["rotation"],
                                   velocity=b["velocity"], detection_name=b["detection_name"],
                                   detection_score=float(b["detection_score"]) if not is_gt else -1.0,
                                   attribute_name=b["attribute_name"], num_pts=b.get("num_pts", -1),
                                   ego_translation=(b["translation"][0] - origin[0], b["translation"][1] - origin[1], b["translation"][2] - origin[2]))
                out.append(box)
            # filter_eval_boxes, as in the devkit (no bike racks here):
            out = [x for x in out if x.ego_dist < cfg.class_range[x.detection_name]]
            out = [x for x in out if not x.num_pts == 0]
            boxes.add_boxes(token, out)
        return boxes

    gt_boxes = load(gt_doc["boxes"], True)
    for token in gt_doc["samples"]:
        if token not in gt_boxes.boxes:
            gt_boxes.add_boxes(token, [])
    pred_boxes = load(res_doc["results"], False)
    mdl = DetectionMetricDataList()
    for c in cfg.class_names:
        for th in cfg.dist_ths:
            mdl.set(c, th, accumulate(gt_boxes, pred_boxes, c, center_distance, th))
    metrics = DetectionMetrics(cfg)
    for c in cfg.class_names:
        for th in cfg.dist_ths:
            metrics.add_label_ap(c, th, calc_ap(mdl[(c, th)], cfg.min_recall, cfg.min_precision))
        for m in TP_METRICS:
            metrics.add_label_tp(c, m, calc_tp(mdl[(c, cfg.dist_th_tp)], cfg.min_recall, m))
    metrics.add_runtime(0.0)
    return metrics.serialize()


def compare(a, b, path, diffs):
    if isinstance(a, dict):
        for k in a:
            if k in ("eval_time", "cfg"):
                continue
            kb = str(k)  # the devkit keys distance thresholds by float; JSON by their str()
            compare(a[k], b[kb], f"{path}.{kb}", diffs)
    else:
        x, y = float(a), float(b) if b is not None else float("nan")
        if math.isnan(x) and math.isnan(y):
            return
        diffs.append((abs(x - y), path, x, y))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--hilo", default="target/release/hilo")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--samples", type=int, default=300)
    ap.add_argument("--tol", type=float, default=1e-6)
    args = ap.parse_args()
    gt_doc, res_doc = make_fixture(args.seed, args.samples)
    with tempfile.TemporaryDirectory() as d:
        gt_p, res_p = os.path.join(d, "gt.json"), os.path.join(d, "results.json")
        json.dump(gt_doc, open(gt_p, "w"))
        json.dump(res_doc, open(res_p, "w"))
        subprocess.run([args.hilo, "eval", "--gt", gt_p, "--results", res_p, "--out", d, "--bootstrap", "0"], check=True, stdout=subprocess.DEVNULL)
        ours = json.load(open(os.path.join(d, "metrics_summary.json")))
    ref = devkit_metrics(gt_doc, res_doc)
    diffs = []
    compare(ref, ours, "", diffs)
    worst = max(diffs)
    print(f"compared {len(diffs)} numbers; largest difference {worst[0]:.3g} at {worst[1]} (devkit {worst[2]}, hilo {worst[3]})")
    print(f"devkit mAP {ref['mean_ap']:.6f} NDS {ref['nd_score']:.6f}; hilo mAP {ours['mean_ap']:.6f} NDS {ours['nd_score']:.6f}")
    bad = [d for d in diffs if not d[0] <= args.tol]
    for d in bad[:10]:
        print("MISMATCH", d)
    sys.exit(1 if bad else 0)


if __name__ == "__main__":
    main()
