#!/usr/bin/env python3
"""Distributed-run benchmark (not a test): what a Dask cluster costs and gives.

Prints, for the seed's tissue (n = 1.1, mua = 20, mus = 200 cm^-1, g = 0.9,
semi-infinite box, pencil beam), each figure as mean +- sigma over --repeats:

1. throughput (packets/s): local 1 and 2 threads; LocalCluster of 1 and 2
   single-threaded worker processes (the cluster is started before the clock);
2. per-chunk overhead: (T(1-unit chunks) - T(one chunk per worker)) / (extra chunks),
   on a run whose units are small (64 packets);
3. chunk size against balance: run time for 1, 2, 4, 16 and 64 chunks per worker.

Every distributed result is also checked bit-identical to the local one.

    /usr/bin/python3 bench/dask_cluster.py [--photons N] [--repeats R]
"""
import argparse
import os
import statistics
import sys
import time

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))
sys.path.insert(0, os.path.join(ROOT, "python"))

import endophoton as ep  # noqa: E402
from endophoton import distributed  # noqa: E402


def scene_and_source():
    s = ep.Scene("cm", ambient_n=1.0)
    s.add_box("tissue", (-5, -5, -10), (5, 5, 0), ep.Medium(mua=20, mus=200, g=0.9, n=1.1))
    return s, ep.PencilSource((0, 0, 1), (0, 0, -1))


def timed(fn, repeats):
    out, ts = None, []
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        ts.append(time.perf_counter() - t)
    return out, statistics.mean(ts), (statistics.stdev(ts) if len(ts) > 1 else 0.0)


def fmt(m, s):
    return f"{m:9.3g} +- {s:.2g}"


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--photons", type=int, default=200000)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    scene, src = scene_and_source()
    n, R = args.photons, args.repeats
    kw = dict(photons=n, seed=1, record_escapes=False)
    print(
        f"# {n} packets, {R} repeats, machine load: {os.getloadavg()[0]:.2f} (1-min average) on "
        f"{os.cpu_count()} cores"
    )
    ref = None
    print("\n## throughput (packets/s)")
    for threads in (1, 2):
        ref, m, s = timed(lambda: ep.run(scene, src, threads=threads, **kw), R)
        print(f"local {threads} thread(s)        {fmt(n / m, n * s / m**2)}")
    for workers in (1, 2):
        with distributed.connect(f"local:{workers}") as client:
            ep.run(scene, src, photons=2000, client=client)  # warm-up: workers import the package
            r, m, s = timed(lambda: ep.run(scene, src, client=client, **kw), R)
            assert r.diffuse_reflectance == ref.diffuse_reflectance, "not bit-identical"
            print(f"LocalCluster {workers} worker(s)  {fmt(n / m, n * s / m**2)}")
            if workers != 2:
                continue
            unit = r.unit_size
            n_units = -(-n // unit)
            print(f"\n## per-chunk overhead (2 workers, {n_units} units of {unit} packets)")
            _, t_few, s_few = timed(lambda: ep.run(scene, src, client=client, chunk_units=-(-n_units // 2), **kw), R)
            _, t_many, s_many = timed(lambda: ep.run(scene, src, client=client, chunk_units=1, **kw), R)
            per = (t_many - t_few) / (n_units - 2)
            print(
                f"2 chunks: {fmt(t_few, s_few)} s; {n_units} chunks: {fmt(t_many, s_many)} s; "
                f"per chunk: {per * 1e3:.2f} ms (sigma {1e3 * (s_few + s_many) / (n_units - 2):.2f} ms)"
            )
            print("\n## chunk size against balance (2 workers): seconds")
            for per_worker in (1, 2, 4, 16, 64):
                chunks = 2 * per_worker
                _, m, s = timed(lambda: ep.run(scene, src, client=client, chunk_units=-(-n_units // chunks), **kw), R)
                print(f"{chunks:4d} chunks ({-(-n_units // chunks):4d} units each): {fmt(m, s)}")


if __name__ == "__main__":
    main()
