#!/usr/bin/env python3
"""The claims of a study's report.json read again under the verdict's earlier rule, for comparison.

Usage: python3 scripts/verdict-rule-before.py report.json

Reports written since the seed component is taken net of the scene noise carry, per metric, the
pooled seed variance (sigma^2_full), the part the scene bootstrap already holds (sigma^2_within)
and its degrees of freedom (`calibration.seed_variance`), and per row the scene bootstrap's
standard error. The earlier rule added the whole pooled variance to the scene part and referred
t to the seed variance's degrees of freedom. This prints, for every claim row of a plain
comparison (one detector group a side) on a metric whose seed variance the report holds, the
standard error, degrees of freedom, interval half-width, minimum detectable effect (80% power,
alpha 0.05) and unadjusted p under both rules. Standard library only.
"""

import json
import math
import sys


def betacf(a, b, x):
    """Continued fraction of the regularised incomplete beta function (modified Lentz)."""
    tiny = 1e-300
    qab, qap, qam = a + b, a + 1.0, a - 1.0
    c, d = 1.0, 1.0 - qab * x / qap
    d = 1.0 / (d if abs(d) > tiny else tiny)
    h = d
    for m in range(1, 400):
        m2 = 2 * m
        aa = m * (b - m) * x / ((qam + m2) * (a + m2))
        d = 1.0 + aa * d
        d = 1.0 / (d if abs(d) > tiny else tiny)
        c = 1.0 + aa / c
        c = c if abs(c) > tiny else tiny
        h *= d * c
        aa = -(a + m) * (qab + m) * x / ((a + m2) * (qap + m2))
        d = 1.0 + aa * d
        d = 1.0 / (d if abs(d) > tiny else tiny)
        c = 1.0 + aa / c
        c = c if abs(c) > tiny else tiny
        delta = d * c
        h *= delta
        if abs(delta - 1.0) < 1e-15:
            break
    return h


def betai(a, b, x):
    if x <= 0.0:
        return 0.0
    if x >= 1.0:
        return 1.0
    lbeta = math.lgamma(a + b) - math.lgamma(a) - math.lgamma(b) + a * math.log(x) + b * math.log(1.0 - x)
    if x < (a + 1.0) / (a + b + 2.0):
        return math.exp(lbeta) * betacf(a, b, x) / a
    return 1.0 - math.exp(lbeta) * betacf(b, a, 1.0 - x) / b


def t_cdf(t, df):
    tail = 0.5 * betai(0.5 * df, 0.5, df / (df + t * t))
    return 1.0 - tail if t >= 0 else tail


def t_quantile(p, df):
    lo, hi = -1e3, 1e3
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if t_cdf(mid, df) < p:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def rule(est, var_scenes, var_seed, df):
    se = math.sqrt(var_scenes + var_seed)
    q = t_quantile(0.975, df)
    mde = (q + t_quantile(0.8, df)) * se
    p = 2.0 * (1.0 - t_cdf(abs(est) / se, df)) if se > 0 else float("nan")
    return se, q * se, mde, p


def main():
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    r = json.load(open(sys.argv[1]))
    sv = r["calibration"]["seed_variance"]
    scenes = r["validation_scenes"]
    print("claim | metric | B - A | rule | SE | df | +-95% | MDE | p")
    for c in r["claims"]:
        for row in c["rows"]:
            v = sv.get(row["metric"])
            t = row["test"]
            if v is None or "within" not in v or len(row["a"]) != 1 or len(row["b"]) != 1 or not t["estimable"]:
                continue
            term = 1.0 / t["seeds_a"] + 1.0 / t["seeds_b"]
            var_scenes = t["se_scenes"] ** 2
            now = rule(t["estimate"], var_scenes, max(v["variance"] - v["within"], 0.0) * term, t["df"])
            before = rule(t["estimate"], var_scenes, v["variance"] * term, v["df"])
            for name, (se, half, mde, p), df in (("now", now, t["df"]), ("before", before, v["df"])):
                print(
                    f"{c['id']} | {row['metric']} | {t['estimate']:+.3f} | {name} | {se:.4f} | {df:.0f} | "
                    f"{half:.3f} | {mde:.3f} | {p:.4f}"
                )


if __name__ == "__main__":
    main()
