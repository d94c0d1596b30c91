#!/usr/bin/env python3
"""What each kind of stage of a study needed, from a Snakemake run of its workflow.

Usage: stage-resources.py STUDY_DIR

Reads the benchmark files Snakemake wrote for every job (STUDY_DIR/benchmarks/**.tsv: wall
seconds and CPU seconds; the Snakefile `hilo study --workflow snakemake` writes asks for them),
each job's peak memory from its log (STUDY_DIR/logs/**.log: every `hilo study <stage>` ends
with `peak memory: N MB`, the kernel's high-water mark; Snakemake's own max_rss samples every
30 s after the first 15 and can miss a peak) and the disk each stage's outputs take in
STUDY_DIR, and prints one Markdown table row per kind of stage (place, simulate, train, report,
compare).
"""
import csv
import os
import statistics
import sys


def du(path):
    """Bytes under path (files only, not following links)."""
    if os.path.isfile(path):
        return os.path.getsize(path)
    total = 0
    for root, _, files in os.walk(path):
        for f in files:
            p = os.path.join(root, f)
            if not os.path.islink(p):
                total += os.path.getsize(p)
    return total


def peak(log):
    """The `peak memory: N MB` line a stage's log ends with, or None."""
    try:
        with open(log) as fh:
            lines = [l for l in fh if l.startswith("peak memory: ")]
    except OSError:
        return None
    return float(lines[-1].split()[2]) if lines else None


def kind(name):
    for k in ("place", "simulate", "train", "report", "compare"):
        if name == k or name.startswith(k + "-"):
            return k
    return None


def disk(study):
    """Per kind of stage, the bytes each job's outputs take (one study folder)."""
    out = {"place": [], "simulate": [], "train": [], "report": []}
    d = os.path.join(study, "placements")
    if os.path.isdir(d):
        out["place"] = [du(os.path.join(d, h)) for h in sorted(os.listdir(d))]
    d = os.path.join(study, "data")
    if os.path.isdir(d):
        out["simulate"] = [du(os.path.join(d, x)) for x in sorted(os.listdir(d))]
    runs, results = os.path.join(study, "runs"), os.path.join(study, "results")
    if os.path.isdir(runs):
        for conf in sorted(os.listdir(runs)):
            for run in sorted(os.listdir(os.path.join(runs, conf))):
                res = os.path.join(results, conf)
                extra = sum(
                    du(os.path.join(res, f)) for f in (os.listdir(res) if os.path.isdir(res) else []) if f.startswith(run)
                )
                out["train"].append(du(os.path.join(runs, conf, run)) + extra)
    rep = [os.path.join(study, f) for f in ("report.json", "report.md", "figures")]
    if all(os.path.exists(p) for p in rep):
        out["report"] = [sum(du(p) for p in rep)]
    return out


def main():
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    top = sys.argv[1]
    bench = os.path.join(top, "benchmarks")
    if not os.path.isdir(bench):
        sys.exit(f"{bench}: no benchmark files (run the study's Snakefile first)")
    rows = {}
    for root, _, files in os.walk(bench):
        for f in files:
            if not f.endswith(".tsv"):
                continue
            k = kind(f[: -len(".tsv")])
            if k is None:
                continue
            log = os.path.join(top, "logs", os.path.relpath(os.path.join(root, f), bench)[: -len(".tsv")] + ".log")
            with open(os.path.join(root, f)) as fh:
                for r in csv.DictReader(fh, delimiter="\t"):
                    r["peak_mb"] = peak(log)
                    rows.setdefault(k, []).append(r)
    # A sweep's studies each have a folder with study.json; a single study is the folder itself.
    studies = [top] if os.path.exists(os.path.join(top, "study.json")) else [
        os.path.join(top, d) for d in sorted(os.listdir(top)) if os.path.exists(os.path.join(top, d, "study.json"))
    ]
    sizes = {}
    for s in studies:
        for k, v in disk(s).items():
            sizes.setdefault(k, []).extend(v)
    print("| stage | jobs | seconds: min / median / max | peak memory, MB: median / max | CPU seconds, median | disk per job, MB: median / max |")
    print("|---|---:|---|---|---:|---|")
    for k in ("place", "simulate", "train", "report", "compare"):
        if k not in rows:
            continue
        s = [float(r["s"]) for r in rows[k]]
        rss = [r["peak_mb"] for r in rows[k] if r["peak_mb"] is not None]
        cpu = [float(r["cpu_time"]) for r in rows[k] if r.get("cpu_time") not in (None, "", "NA", "-")]
        mem = f"{statistics.median(rss):.0f} / {max(rss):.0f}" if rss else "–"
        cpu_s = f"{statistics.median(cpu):.0f}" if cpu else "–"
        mb = [b / 1e6 for b in sizes.get(k, [])]
        dsk = f"{statistics.median(mb):.1f} / {max(mb):.1f}" if mb else "–"
        print(
            f"| {k} | {len(s)} | {min(s):.0f} / {statistics.median(s):.0f} / {max(s):.0f} | {mem} | {cpu_s} | {dsk} |"
        )


if __name__ == "__main__":
    main()
