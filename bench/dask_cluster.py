#!/usr/bin/env python3
"""Distributed-run benchmark (not a test): what a Dask cluster costs and gives.

Prints Markdown tables (for docs/performance.md §8), each figure the mean +- sigma
over --repeats, on the seed's tissue (n = 1.1, mua = 20, mus = 200 cm^-1, g = 0.9,
semi-infinite box, pencil beam):

1. throughput (packets/s): local runs on 1 and 2 threads against a LocalCluster of
   1 and 2 single-threaded worker processes (the cluster is started and warmed up
   before the clock);
2. per-chunk overhead, 2 workers: (T(one-unit chunks) - T(one chunk per worker)) /
   (extra chunks), on units of 250 packets;
3. chunk size against balance, 2 workers: run time for 1 to 64 chunks per worker;
4. traffic: bytes a chunk ships back, without and with grids;
5. a beta sweep (the seed's scene, 3 angles, store N) on 2 workers against the
   local sweep on 2 threads.

Every distributed result is checked bit-identical to the local one (the sweep:
every CSV column but the wall-clock seconds). The machine's 1-minute load average
is printed first: figures taken on a loaded machine show orders of magnitude only.

    /usr/bin/python3 bench/dask_cluster.py [--quick] [--photons N] [--repeats R]

--quick (about a minute): 40 000 packets, 2 repeats, a smaller sweep. The default
run takes a few minutes.
"""
import argparse
import math
import os
import statistics
import sys
import tempfile
import time

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))
sys.path.insert(0, os.path.join(ROOT, "python"))

import endophoton as ep  # noqa: E402
from endophoton import _core, distributed  # noqa: E402
from endophoton.sweep.driver import default_flat_scene  # noqa: E402

OVERHEAD_UNIT = 250  # packets per unit in the per-chunk overhead and chunk-size runs


def scene_and_source():
    s = ep.Scene("cm", ambient_n=1.0)
    s.add_box("tissue", (-5, -5, -10), (5, 5, 0), ep.Medium(mua=20, mus=200, g=0.9, n=1.1))
    return s, ep.PencilSource((0, 0, 1), (0, 0, -1))


def timed(fn, repeats):
    """(last result, mean seconds, sigma seconds) of ``repeats`` calls."""
    out, ts = None, []
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        ts.append(time.perf_counter() - t)
    return out, statistics.mean(ts), (statistics.stdev(ts) if len(ts) > 1 else 0.0)


def pm(m, s, digits=3):
    return f"{m:.{digits}g} ± {s:.2g}"


def rate(n, m, s):
    """packets/s and its sigma (first-order propagation of the time's sigma)."""
    return pm(n / m, n * s / m**2)


def same(a, b):
    assert a.diffuse_reflectance == b.diffuse_reflectance and a.absorbed == b.absorbed, "not bit-identical"
    assert a.diffuse_reflectance_stderr == b.diffuse_reflectance_stderr, "not bit-identical"


def throughput(scene, src, n, R, clients):
    print("\n### Throughput (packets/s)\n\n| how | packets/s |\n|---|---|")
    kw = dict(photons=n, seed=1, record_escapes=False)
    ref = None
    for threads in (1, 2):
        ref, m, s = timed(lambda: ep.run(scene, src, threads=threads, **kw), R)
        print(f"| local, {threads} thread{'s' if threads > 1 else ''} | {rate(n, m, s)} |")
    for workers, client in clients.items():
        r, m, s = timed(lambda: ep.run(scene, src, client=client, **kw), R)
        same(r, ref)
        print(f"| LocalCluster, {workers} worker process{'es' if workers > 1 else ''} | {rate(n, m, s)} |")


def overhead_and_balance(scene, src, n, R, client):
    kw = dict(photons=n, seed=1, record_escapes=False, unit_size=OVERHEAD_UNIT)
    ref = ep.run(scene, src, threads=2, **kw)
    n_units = math.ceil(n / OVERHEAD_UNIT)

    def with_chunks(chunks):
        return timed(lambda: ep.run(scene, src, client=client, chunk_units=math.ceil(n_units / chunks), **kw), R)

    r_few, t_few, s_few = with_chunks(2)
    r_many, t_many, s_many = with_chunks(n_units)
    same(r_few, ref)
    same(r_many, ref)
    per, per_s = (t_many - t_few) / (n_units - 2), math.hypot(s_few, s_many) / (n_units - 2)
    print(f"\n### Per-chunk overhead (2 workers, {n_units} units of {OVERHEAD_UNIT} packets)\n")
    print(f"- 2 chunks: {pm(t_few, s_few)} s; {n_units} one-unit chunks: {pm(t_many, s_many)} s")
    print(f"- per chunk: **{per * 1e3:.1f} ms** (σ {per_s * 1e3:.1f} ms): task round trip, bytes, merge")
    print(f"\n### Chunk size against balance (2 workers, {n} packets)\n")
    print("| chunks | units per chunk | packets per chunk | seconds | overhead share |\n|---|---|---|---|---|")
    for per_worker in (1, 2, 4, 16, 64):
        chunks = min(2 * per_worker, n_units)
        r, m, s = with_chunks(chunks)
        same(r, ref)
        units = math.ceil(n_units / chunks)
        share = min(1.0, max(0.0, chunks * per / m))
        print(f"| {chunks} | {units} | {units * OVERHEAD_UNIT} | {pm(m, s)} | {100 * share:.0f} % |")


def traffic():
    """Bytes of one chunk's trace_units result on the seed scene (a small dome polyp)."""
    scene = default_flat_scene(polyp="dome", half_width_cm=2.0, thickness_cm=1.0, mesh_resolution=(8, 16))
    rig = ep.EndoscopeRig.from_beta(20, 1.0)
    native = scene.to_native()
    source = _core.Source(rig.native_lights(scene.unit_cm), body=rig.native_body(scene.unit_cm))
    print("\n### Traffic: bytes one chunk ships (fluorescent endoscope scene, 16 units of 1024 packets)\n")
    print("| what the run keeps | bytes per chunk | bytes per packet |\n|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        grid = dict(grid_voxel_size=0.05, grid_path=os.path.join(tmp, "g.vdb"), grid_per_fluorophore=True)
        for label, extra in (
            ("tallies only", dict(record_escapes=False)),
            ("+ escape records", dict(record_escapes=True)),
            ("+ grids, voxel 0.05 cm, per fluorophore", dict(record_escapes=True, **grid)),
        ):
            opts = dict(photons=16 * 1024, seed=1, unit_size=1024, **extra)
            data = _core.trace_units(native, source, _core.RunConfig(**opts), 0, 16)
            print(f"| {label} | {len(data):,} | {len(data) / (16 * 1024):.0f} |")


def sweep_rows_equal(a, b):
    def norm(v):
        return "nan" if isinstance(v, float) and math.isnan(v) else v

    strip = [{k: norm(v) for k, v in r.items() if k != "seconds"} for r in a.rows]
    return strip == [{k: norm(v) for k, v in r.items() if k != "seconds"} for r in b.rows]


def sweep(client, betas, store, R):
    scene = default_flat_scene()
    kw = dict(betas=betas, store=store, seed=1, progress=False, plots=False, report=False)
    local, m_l, s_l = timed(lambda: ep.sweep(scene, threads=2, **kw), R)
    dist, m_d, s_d = timed(lambda: ep.sweep(scene, client=client, **kw), R)
    assert sweep_rows_equal(local, dist), "sweep CSV differs"
    packets = sum(r["packets_traced"] for r in local.rows)
    print(f"\n### Beta sweep ({len(betas)} angles, store {store}, {packets:,} packets in all)\n")
    print("| how | seconds | packets/s |\n|---|---|---|")
    print(f"| local, 2 threads, one angle after another | {pm(m_l, s_l)} | {rate(packets, m_l, s_l)} |")
    print(f"| LocalCluster, 2 workers, all angles at once | {pm(m_d, s_d)} | {rate(packets, m_d, s_d)} |")
    print("\nThe sweep's CSV on the cluster equals the local one in every column but `seconds`.")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="smaller runs, 2 repeats (about a minute)")
    ap.add_argument("--photons", type=int, default=None, help="packets per throughput run (default 100000)")
    ap.add_argument("--repeats", type=int, default=None, help="repeats per figure (default 3)")
    args = ap.parse_args()
    n = args.photons or (40_000 if args.quick else 100_000)
    R = args.repeats or (2 if args.quick else 3)
    betas, store = ([0, 30], 500) if args.quick else ([0, 20, 40], 3000)
    scene, src = scene_and_source()
    t0 = time.perf_counter()
    print(
        f"Machine load (1-min average) {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores; "
        f"{n:,} packets, mean ± σ of {R} repeats; engine {_core.__version__}"
    )
    with distributed.connect("local:1") as one, distributed.connect("local:2") as two:
        for client in (one, two):  # warm-up: the workers import the package
            ep.run(scene, src, photons=2000, client=client)
        throughput(scene, src, n, R, {1: one, 2: two})
        overhead_and_balance(scene, src, n, R, two)
        traffic()
        sweep(two, betas, store, R)
    print(f"\n(bench took {time.perf_counter() - t0:.0f} s; load average now {os.getloadavg()[0]:.1f})")


if __name__ == "__main__":
    main()
