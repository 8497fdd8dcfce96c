"""Light crosses the lumen on colon_polyp (issue 9): what the rule changes, and what it costs.

    /usr/bin/python3 bench/lumen_colon.py [--photons N] [--threads T]

bench/perf.py runs it for docs/performance.md §6.

Runs bench/colon_scene.py's tube with the rig inside (seed's tissue and
fluorophores) with the rule on and off, same seed, and prints one JSON object:
the balance terms of both runs, the share of records that are second or later
exits, the weight that crosses the lumen and lands on tissue, the part of it
that lands on the far wall (z > 0, the half of the tube opposite the polyp and
the rig's view; the landing point is found with the engine's scene ray query on
each record's ray), and packets per second of each run. Standard errors are
batch means over 50 blocks of consecutive packets. Throughput is wall-clock on
whatever machine runs it: state the load when quoting it.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import endophoton as ep  # noqa: E402
from endophoton import _core  # noqa: E402
from colon_scene import colon_scene  # noqa: E402

BATCHES = 50


def batch_mean(packet, values, photons):
    """Per-launched-packet mean of sum(values) and its batch-means standard error."""
    edges = np.linspace(0, photons, BATCHES + 1)
    b = np.clip(np.searchsorted(edges, packet, side="right") - 1, 0, BATCHES - 1)
    sums = np.bincount(b, weights=values, minlength=BATCHES)
    sizes = np.diff(np.floor(edges))
    x = sums / sizes
    mean = values.sum() / photons
    return float(mean), float(x.std(ddof=1) / np.sqrt(BATCHES))


# The engine's own ray query (every crossing along a ray), which the binding exposes to tests and
# benchmarks only: the package has no public ray cast.
ray_hits = _core._testing.intersect_all


def landing_z(native_scene, pos, dirs):
    """z of the first surface each ray enters (nan if none)."""
    out = np.full(len(pos), np.nan)
    for k, (p, d) in enumerate(zip(pos, dirs)):
        for t, _region, _prim, cos in ray_hits(native_scene, p.tolist(), d.tolist(), 1e-7, float("inf")):
            if cos < 0:
                out[k] = p[2] + t * d[2]
                break
    return out


def measure(photons, threads=2, seed=1):
    """The rule off and on, same seed: balance terms, exits, landings and speed of each (a JSON-able dict)."""
    scene, rig = colon_scene()
    out = {"photons": photons, "threads": threads, "seed": seed}
    runs = {}
    for lumen in (False, True):
        t0 = time.perf_counter()
        res = ep.run(scene, rig, photons=photons, seed=seed, threads=threads, lumen=lumen)
        dt = time.perf_counter() - t0
        runs[lumen] = res
        key = "with_rule" if lumen else "without_rule"
        out[key] = {k: [getattr(res, k), getattr(res, k + "_stderr")] for k in ep.FRACTIONS}
        out[key]["balance"] = sum(getattr(res, k) for k in ep.FRACTIONS)
        out[key]["seconds"] = dt
        out[key]["packets_per_s"] = photons / dt
        out[key]["records"] = int(len(res.escapes["weight"]))
        out[key]["interactions_per_packet"] = res.interactions
        out[key]["seconds_per_million_interactions"] = dt / (res.interactions * photons) * 1e6
    e = runs[True].escapes
    n = photons
    order = e["exit_order"]
    out["share_second_or_later_exits"] = float(np.mean(order >= 2))
    out["next_hit_counts"] = {
        name: int(np.count_nonzero(e["next_hit"] == c)) for c, name in enumerate(("away", "tissue", "head", "camera"))
    }
    w = e["weight"].astype(np.float64)
    packet = e["packet"].astype(np.int64)
    lands = e["next_hit"] == 1
    out["lumen_landing_weight"] = batch_mean(packet[lands], w[lands], n)
    # Where do the landings hit? The rays of the records that land, in metres.
    native = scene.to_native()
    pos = e["position"][lands].astype(np.float64)
    dirs = e["direction"][lands].astype(np.float64)
    dirs /= np.linalg.norm(dirs, axis=1)[:, None]
    z = landing_z(native, pos, dirs)
    far = np.nan_to_num(z, nan=-1.0) > 0.0
    out["far_wall_landing_weight"] = batch_mean(packet[lands][far], w[lands][far], n)
    out["landing_rays_without_entering_hit"] = int(np.count_nonzero(np.isnan(z)))
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--photons", type=int, default=20000)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)
    print(json.dumps(measure(args.photons, args.threads, args.seed), indent=1))


if __name__ == "__main__":
    main()
