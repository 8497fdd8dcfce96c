"""Packets/s before and after, side by side: one engine build against another, in fresh processes,
interleaved (wall clock and CPU time; best of --repeats). Not a test, and on a shared machine only
"measured under load" figures: the load-independent measure is bench/callgrind_steps.py.

    /usr/bin/python3 bench/side_by_side.py --before /tmp/base --after python [--repeats 2]
    /usr/bin/python3 bench/side_by_side.py --build-before 37f845d --after python

Each --before / --after is a directory holding an `endophoton` package (with its _core module);
--build-before COMMIT builds that commit's package first (bench/baseline.json's commit is the
issue-11 baseline), from `git archive` into /tmp/ep-baseline-COMMIT (the repository is not touched).
bench/run_all.py --baseline-py DIR calls compare() for docs/performance.md §9. MCML's own figures
(no MCML build here) are in bench/baseline.json, from issue 11.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)
import run_all  # noqa: E402  (run_child: one measured run in a fresh process)

PLAN = [
    ("seed_tissue", dict(scene="seed_tissue"), 200_000),
    ("mcml_slab", dict(scene="mcml_slab"), 1_000_000),
    ("colon", dict(scene="colon"), 60_000),
    ("colon+grids", dict(scene="colon", voxel=2e-4, grid_path="/tmp/ep-sbs-grid.vdb"), 60_000),
]


def build_package(commit: str, dest: str | None = None) -> str:
    """Build ``commit``'s engine (Release, no tests) and return the directory that holds its package."""
    dest = dest or f"/tmp/ep-baseline-{commit}"
    src = os.path.join(dest, "src")
    if not os.path.isdir(src):
        os.makedirs(src)
        archive = subprocess.run(["git", "-C", ROOT, "archive", commit], check=True, capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", src], input=archive, check=True)
    build = os.path.join(dest, "build")
    cfg = ["cmake", "-S", src, "-B", build, "-DCMAKE_BUILD_TYPE=Release", "-DENDOPHOTON_BUILD_TESTS=OFF"]
    subprocess.run(cfg + [f"-DPython3_EXECUTABLE={sys.executable}"], check=True, capture_output=True)
    subprocess.run(["cmake", "--build", build, "-j2"], check=True, capture_output=True)
    return os.path.join(src, "python")


def compare(before: str, after: str, repeats: int = 2, plan=PLAN, report=print) -> list[dict]:
    """Best of ``repeats`` interleaved runs of each configuration with each package, 1 and 2 threads."""
    rows = []
    for key, cfg, n in plan:
        for threads in (1, 2):
            row = dict(config=key, threads=threads, packets=n)
            for rep in range(repeats):
                for tag, py in (("before", before), ("after", after)):
                    r = run_all.run_child(
                        dict(cfg, key=key, photons=n, threads=threads, py=os.path.abspath(py), warmup=2000)
                    )
                    row[tag] = max(row.get(tag, 0), r["pps"])
                    row[tag + "_cpu"] = max(row.get(tag + "_cpu", 0), r["pp_cpu_s"])
            rows.append(row)
            report(
                f"{key:12s} {threads} thr: before {row['before']:9.0f}/s ({row['before_cpu']:9.0f}/CPU-s)  "
                f"after {row['after']:9.0f}/s ({row['after_cpu']:9.0f}/CPU-s)  x{row['after'] / row['before']:.2f}"
            )
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    who = ap.add_mutually_exclusive_group(required=True)
    who.add_argument("--before", help="directory holding the 'before' endophoton package")
    who.add_argument("--build-before", metavar="COMMIT", help="build this commit's package and use it")
    ap.add_argument("--after", required=True)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--json", default=None)
    a = ap.parse_args()
    before = a.before or build_package(a.build_before)
    rows = compare(before, a.after, a.repeats, report=lambda s: print(s, flush=True))
    if a.json:
        run_all.atomic_write_text(os.path.abspath(a.json), json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
