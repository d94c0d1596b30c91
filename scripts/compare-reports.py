#!/usr/bin/env python3
"""Compares two report.json files apart from what measures time.

Usage: compare-reports.py A/report.json B/report.json
Prints the timing fields that differ (they differ between any two runs) and exits 1 when
anything else differs. The placement trade-off's time-limit rows (tradeoffs.limits[]) are
results of a solver stopped by the wall clock: under another load the same limit can stop at
another incumbent, so their results are listed apart and do not fail the comparison.
"""
import json
import sys


def timing(key):
    return key == "seconds" or key.endswith("_s") or key.endswith("_seconds") or key == "ms_per_frame"


def time_limited(path):
    return path.startswith("tradeoffs.limits[") and not path.endswith(".time_limit_s")


def walk(a, b, path, out):
    if time_limited(path) and not isinstance(a, (dict, list)) and a != b:
        out["limited"].append(f"{path}: {a!r} against {b!r}")
    elif isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b)):
            p = f"{path}.{k}" if path else k
            if k not in a or k not in b:
                out["other"].append(p + " (present in one only)")
            elif timing(k):
                if a[k] != b[k]:
                    out["timing"].add(generic(p))
            else:
                walk(a[k], b[k], p, out)
    elif isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            out["other"].append(f"{path} (length {len(a)} against {len(b)})")
        for i, (x, y) in enumerate(zip(a, b)):
            walk(x, y, f"{path}[{i}]", out)
    elif a != b:
        out["other"].append(f"{path}: {a!r} against {b!r}")


def generic(path):
    """entries[3].train_s -> entries[].train_s"""
    out, skip = [], False
    for ch in path:
        if ch == "[":
            skip = True
            out.append("[]")
        elif ch == "]":
            skip = False
        elif not skip:
            out.append(ch)
    return "".join(out)


def main():
    a, b = (json.load(open(p)) for p in sys.argv[1:3])
    out = {"timing": set(), "other": [], "limited": []}
    walk(a, b, "", out)
    print("timing fields that differ:", ", ".join(sorted(out["timing"])) or "none")
    if out["limited"]:
        print("results under a solver time limit that differ (the wall clock stopped the solver elsewhere):")
        for line in out["limited"]:
            print("  " + line)
    if out["other"]:
        print("other differences:")
        for line in out["other"][:50]:
            print("  " + line)
        sys.exit(1)
    print("equal apart from timing fields")


if __name__ == "__main__":
    main()
