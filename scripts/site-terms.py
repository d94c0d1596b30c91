#!/usr/bin/env python3
"""Leave-one-site-out rank of a plain least-squares fit over chosen placement terms.

    python3 scripts/site-terms.py docs/validation-sites [--terms lidar_dense,radar ...] [--worst SITE]
        [--classes car,pedestrian]

Reads `<dir>/<site>/validation.json` for every site folder of a `hilo validate --sites` run.
For each set of terms (comma-separated; several --terms give several rows) it fits mAP =
intercept + weights · terms by least squares over the members of all sites but one, predicts
the held-out site's members and prints Spearman's rho between prediction and measured mean
mAP, per site and on average. Terms are the calibrated objective's, read from each member's
predictors: lidar / radar (coverage, saturated), lidar_two_views / radar_two_views, lidar_dense /
radar_dense (coverage at twice the threshold); a radar term is 0 for a rig without radar.

It is not hilo's fit: that one also chooses its terms and weighs its sites (with the single term
lidar_dense both give nearly the same line). It answers one question quickly: does a term help
the held-out ranking? `--worst SITE` lists that site's members by how far the first term set's
prediction misranks them. `--classes` measures each member by the mean AP of those classes
(from its `class_ap`, the mean over its trainings) in place of its mAP, fit and rank alike.
Standard library only.
"""
import argparse
import json
import os

TERMS = {
    "lidar": "LiDAR coverage (saturated)",
    "radar": "radar coverage (saturated)",
    "lidar_two_views": "LiDAR coverage by two views",
    "radar_two_views": "radar coverage by two views",
    "lidar_dense": "LiDAR coverage at twice the threshold",
    "radar_dense": "radar coverage at twice the threshold",
}


def load(folder, site, classes):
    with open(os.path.join(folder, site, "validation.json")) as f:
        v = json.load(f)
    rows = []
    for member, result in v["members"]:
        p = member["predictors"]
        if classes:
            missing = [c for c in classes if c not in result["class_ap"]]
            if missing:
                raise SystemExit(f"{site}/{member['slug']}: no class_ap for {missing}; it has {sorted(result['class_ap'])}")
            measured = sum(result["class_ap"][c] for c in classes) / len(classes)
        else:
            measured = result["map_mean"]
        rows.append((member["slug"], {k: p.get(name) or 0.0 for k, name in TERMS.items()}, measured))
    return rows


def least_squares(a, b):
    """Solves the normal equations by Gauss-Jordan elimination with partial pivoting."""
    n = len(a[0])
    m = [[sum(r[i] * r[j] for r in a) for j in range(n)] + [sum(r[i] * y for r, y in zip(a, b))] for i in range(n)]
    for i in range(n):
        p = max(range(i, n), key=lambda r: abs(m[r][i]))
        m[i], m[p] = m[p], m[i]
        if abs(m[i][i]) < 1e-12:
            raise SystemExit("the terms are collinear over the fitted sites")
        for r in range(n):
            if r != i:
                f = m[r][i] / m[i][i]
                m[r] = [x - f * y for x, y in zip(m[r], m[i])]
    return [m[i][n] / m[i][i] for i in range(n)]


def ranks(xs):
    order = sorted(range(len(xs)), key=lambda i: xs[i])
    r, i = [0.0] * len(xs), 0
    while i < len(order):
        j = i
        while j + 1 < len(order) and xs[order[j + 1]] == xs[order[i]]:
            j += 1
        for k in range(i, j + 1):
            r[order[k]] = (i + j) / 2
        i = j + 1
    return r


def spearman(a, b):
    ra, rb = ranks(a), ranks(b)
    ma, mb = sum(ra) / len(ra), sum(rb) / len(rb)
    num = sum((x - ma) * (y - mb) for x, y in zip(ra, rb))
    den = (sum((x - ma) ** 2 for x in ra) * sum((y - mb) ** 2 for y in rb)) ** 0.5
    return num / den if den else float("nan")


def held_out(data, terms, held):
    a = [[1.0] + [x[t] for t in terms] for s, rows in data.items() if s != held for _, x, _ in rows]
    b = [y for s, rows in data.items() if s != held for _, _, y in rows]
    w = least_squares(a, b)
    pred = [w[0] + sum(wi * x[t] for wi, t in zip(w[1:], terms)) for _, x, _ in data[held]]
    return pred, w


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder")
    ap.add_argument("--terms", action="append", help="comma-separated terms (default: lidar_dense; lidar_dense,radar)")
    ap.add_argument("--worst", help="list this site's members by misrank under the first term set")
    ap.add_argument("--classes", help="measure by the mean AP of these classes (comma-separated), not mAP")
    args = ap.parse_args()
    sets = [t.split(",") for t in (args.terms or ["lidar_dense", "lidar_dense,radar"])]
    for terms in sets:
        unknown = [t for t in terms if t not in TERMS]
        if unknown:
            raise SystemExit(f"unknown term(s) {unknown}; known: {', '.join(TERMS)}")
    sites = sorted(d for d in os.listdir(args.folder) if os.path.isfile(os.path.join(args.folder, d, "validation.json")))
    if len(sites) < 3:
        raise SystemExit(f"{args.folder}: needs at least three site folders with a validation.json, found {sites}")
    classes = args.classes.split(",") if args.classes else []
    data = {s: load(args.folder, s, classes) for s in sites}
    print("| terms | " + " | ".join(sites) + " | mean |")
    print("|---|" + "---:|" * (len(sites) + 1))
    for terms in sets:
        rho = [spearman(held_out(data, terms, s)[0], [y for _, _, y in data[s]]) for s in sites]
        print(f"| {' + '.join(terms)} | " + " | ".join(f"{r:+.2f}" for r in rho) + f" | {sum(rho) / len(rho):+.2f} |")
    if args.worst:
        if args.worst not in data:
            raise SystemExit(f"--worst {args.worst!r}: not one of {sites}")
        pred, w = held_out(data, sets[0], args.worst)
        measured = [y for _, _, y in data[args.worst]]
        rp, rm = ranks(pred), ranks(measured)
        print(f"\n{args.worst}, fitted on the others: intercept {w[0]:+.3f}, weights {[round(x, 3) for x in w[1:]]}")
        rows = sorted(zip(data[args.worst], pred, rp, rm), key=lambda t: -abs(t[2] - t[3]))
        for (slug, _, y), p, a, b in rows:
            print(f"{slug:48s} predicted {p:.3f} (rank {a:4.1f})  measured {y:.3f} (rank {b:4.1f})")


if __name__ == "__main__":
    main()
