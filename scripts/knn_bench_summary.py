#!/usr/bin/env python3
"""Throwaway (issue 34): medians and ranges of the repeated bench/render_estimators.py tables that
scripts/knn_bench_runs.sh wrote to /tmp/knn_bench/ (CPU s and FOM vary with the load; the estimates do not)."""
import glob
import re
import statistics
import sys

folder = sys.argv[1] if len(sys.argv) > 1 else "/tmp/knn_bench"
rows = {}
for path in sorted(glob.glob(f"{folder}/bench_*_*.txt")):
    n = int(re.search(r"bench_(\d+)_", path).group(1))
    for line in open(path):
        m = re.match(
            r"\| (kernel|knn|nee) \| ([\d.]+) \+ ([\d.]+) \| ([\d.-]+) ± ([\d.]+) \| ([\d.]+) \| ([\d.]+) % \| ([\d.]+) %",
            line,
        )
        if m:
            name, run, render, c, se, fom, w20, zero = m.groups()
            rows.setdefault((n, name), []).append((float(run), float(render), c, se, w20, zero))


def med(xs):
    return f"{statistics.median(xs):.1f} ({min(xs):.1f}–{max(xs):.1f})"


print(
    "| packets | estimator | CPU s run + render, median (range) | red/green contrast | FOM s⁻¹, median (range) | "
    "tissue px within 20 % | tissue px at 0 |"
)
print("|---|---|---|---|---|---|---|")
for (n, name), rs in sorted(rows.items()):
    cpu = [r[0] + r[1] for r in rs]
    se = float(rs[0][3])
    fom = [1 / (se * se * c) for c in cpu]
    print(
        f"| {n:,} | {name} | {med([r[0] for r in rs])} + {med([r[1] for r in rs])} | {rs[0][2]} ± {rs[0][3]} | "
        f"{med(fom)} | {rs[0][4]} % | {rs[0][5]} % |"
    )
print(f"({len(next(iter(rows.values())))} repeats each)")
