"""Scene build time and packets/s against the mesh's size: colon_polyp's tube at finer tessellations.

    /usr/bin/python3 bench/mesh_size.py [--photons N] [--quick]

bench/perf.py runs it for docs/performance.md §10.

For each tessellation (rings along the tube x points around it) of bench/colon_scene.py's tube,
with the same polyp and rig: the engine scene's build (``Scene.to_native()``: the mesh checks,
Embree's BVH, the triangle grid and its per-triangle data) in seconds on a fresh engine scene,
then packets per second of one run at 1 thread after a 2,000-packet warm-up, and the per-cube
cache store it built. Prints one JSON object. Wall-clock figures: state the machine's load when
quoting them.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import endophoton as ep  # noqa: E402
from colon_scene import colon_scene  # noqa: E402

#: (rings along the tube, points around it); the first is bench/colon_scene.py's default.
SIZES = ((100, 64), (200, 128), (400, 256), (800, 512))


def measure(sizes=SIZES, photons=30_000, threads=1, seed=3):
    """One row per tessellation: triangles, build_s, pps, store_mb (see the module's docstring)."""
    rows = []
    for n_x, n_theta in sizes:
        scene, rig = colon_scene(n_x=n_x, n_theta=n_theta)
        ep.forget_native_scenes()
        t0 = time.perf_counter()
        native = scene.to_native()
        build_s = time.perf_counter() - t0
        ep.run(scene, rig, photons=2000, threads=threads, seed=1)
        r = ep.run(scene, rig, photons=photons, threads=threads, seed=seed)
        rows.append(
            dict(
                n_x=n_x,
                n_theta=n_theta,
                triangles=int(sum(len(reg.triangles) for reg in scene.regions)),
                build_s=build_s,
                photons=photons,
                threads=threads,
                pps=photons / r.seconds,
                store_mb=native.cache_store_bytes / 2**20,
            )
        )
        ep.forget_native_scenes(scene)
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--photons", type=int, default=30_000)
    ap.add_argument("--quick", action="store_true", help="the two smallest tessellations only")
    a = ap.parse_args(argv)
    print(json.dumps(measure(SIZES[:2] if a.quick else SIZES, photons=a.photons), indent=1))


if __name__ == "__main__":
    main()
