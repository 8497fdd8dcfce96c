#!/usr/bin/env python3
"""Throughput benchmark (not a test): packets/s and peak memory on 1 and 2 threads.

Scene: the seed's tissue (n = 1.1 against air, mua = 20, mus = 200 cm^-1, g = 0.9),
semi-infinite, built as a deep box (10 x 10 x 10 cm), pencil beam at normal incidence.
Each configuration runs in a fresh subprocess so that its peak RSS is its own.

    /usr/bin/python3 bench/throughput.py [--photons N] [--json OUT]
"""
import argparse
import json
import os
import subprocess
import sys

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))

CHILD = r"""
import json, sys, time
sys.path.insert(0, {py!r})
import endophoton as ep
cfg = json.loads(sys.argv[1])
s = ep.Scene('cm', ambient_n=1.0)
fl = [ep.Fluorophore('collagen', 0.2, 0.4)] if cfg['fluorescence'] else []
s.add_box('tissue', (-5, -5, -10), (5, 5, 0), ep.Medium(mua=20, mus=200, g=0.9, n=1.1), fluorophores=fl)
grids = ep.GridRequest(voxel_size=0.01, path=cfg['grid_path']) if cfg['grids'] else None
src = ep.PencilSource((0, 0, 1), (0, 0, -1))
ep.run(s, src, photons=2000, threads=cfg['threads'], record_escapes=False)  # warm-up
t = time.perf_counter()
r = ep.run(s, src, photons=cfg['photons'], threads=cfg['threads'], record_escapes=cfg['records'],
           safe_distance=cfg['safe_distance'], grids=grids)
dt = time.perf_counter() - t
# The process's own peak resident set (VmHWM). ru_maxrss is not used: Linux
# carries a parent's peak over fork + exec into the child's ru_maxrss.
peak_kb = next(int(l.split()[1]) for l in open('/proc/self/status') if l.startswith('VmHWM:'))
print(json.dumps(dict(cfg, seconds=dt, packets_per_s=r.photons / dt, peak_rss_mb=peak_kb / 1024.0,
                      diffuse_reflectance=r.diffuse_reflectance, rd_stderr=r.diffuse_reflectance_stderr)))
"""


def measure(cfg):
    code = CHILD.format(py=os.path.join(ROOT, "python"))
    out = subprocess.run([sys.executable, "-c", code, json.dumps(cfg)], check=True, capture_output=True, text=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--photons", type=int, default=400000)
    ap.add_argument("--json", default=None, help="also write the rows as JSON here")
    args = ap.parse_args()
    rows = []
    base = dict(
        photons=args.photons,
        fluorescence=False,
        grids=False,
        records=False,
        safe_distance=True,
        grid_path=os.path.join("/tmp", "endophoton_bench.vdb"),
    )
    configs = [
        dict(base, threads=1),
        dict(base, threads=2),
        dict(base, threads=1, safe_distance=False),
        dict(base, threads=2, fluorescence=True),
        dict(base, threads=2, fluorescence=True, grids=True),
        dict(base, threads=2, records=True),
    ]
    print(
        f"{'threads':>7} {'safe':>5} {'fluor':>5} {'grids':>5} {'records':>7} {'packets/s':>11} "
        f"{'peak MB':>8} {'Rd':>9} {'+-':>8}"
    )
    for cfg in configs:
        r = measure(cfg)
        rows.append(r)
        print(
            f"{r['threads']:>7} {str(r['safe_distance']):>5} {str(r['fluorescence']):>5} {str(r['grids']):>5} "
            f"{str(r['records']):>7} {r['packets_per_s']:>11.0f} {r['peak_rss_mb']:>8.1f} "
            f"{r['diffuse_reflectance']:>9.5f} {r['rd_stderr']:>8.5f}"
        )
    one, two = rows[0]["packets_per_s"], rows[1]["packets_per_s"]
    print(
        f"scaling 1 -> 2 threads: {two / one:.2f}x; per core (1 thread): {one:.0f} packets/s; "
        f"os.cpu_count() = {os.cpu_count()}"
    )
    if args.json:
        tmp = args.json + ".tmp"
        with open(tmp, "w") as fh:
            json.dump(rows, fh, indent=1)
        os.replace(tmp, args.json)


if __name__ == "__main__":
    main()
