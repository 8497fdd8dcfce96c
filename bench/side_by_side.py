"""Packets/s before and after, side by side: one engine build against another, in fresh processes,
interleaved (wall clock and CPU time; best of --repeats). Not a test, and on a shared machine only
"measured under load" figures: the load-independent measure is bench/callgrind_steps.py.

    /usr/bin/python3 bench/side_by_side.py --before /tmp/base --after python [--repeats 2]

Each --before / --after is a directory holding an `endophoton` package (with its _core module).
"""
from __future__ import annotations

import argparse
import json
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import run_all  # noqa: E402  (run_child: one measured run in a fresh process)

PLAN = [
    ("seed_tissue", dict(scene="seed_tissue"), 200_000),
    ("mcml_slab", dict(scene="mcml_slab"), 1_000_000),
    ("colon", dict(scene="colon"), 60_000),
    ("colon+grids", dict(scene="colon", voxel=2e-4, grid_path="/tmp/ep-sbs-grid.vdb"), 60_000),
]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--before", required=True)
    ap.add_argument("--after", required=True)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--json", default=None)
    a = ap.parse_args()
    rows = []
    for key, cfg, n in PLAN:
        for threads in (1, 2):
            row = dict(config=key, threads=threads, packets=n)
            for rep in range(a.repeats):
                for tag, py in (("before", a.before), ("after", a.after)):
                    r = run_all.run_child(
                        dict(cfg, key=key, photons=n, threads=threads, py=os.path.abspath(py), warmup=2000)
                    )
                    row[tag] = max(row.get(tag, 0), r["pps"])
                    row[tag + "_cpu"] = max(row.get(tag + "_cpu", 0), r["pp_cpu_s"])
            rows.append(row)
            print(
                f"{key:12s} {threads} thr: before {row['before']:9.0f}/s ({row['before_cpu']:9.0f}/CPU-s)  "
                f"after {row['after']:9.0f}/s ({row['after_cpu']:9.0f}/CPU-s)  x{row['after'] / row['before']:.2f}",
                flush=True,
            )
    if a.json:
        with open(a.json + ".tmp", "w") as fh:
            json.dump(rows, fh, indent=1)
        os.replace(a.json + ".tmp", a.json)


if __name__ == "__main__":
    main()
