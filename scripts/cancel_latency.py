"""Cancel latency (issue 36): the time from CancelToken.cancel() to ep.run returning its partial
result, on the colon benchmark scene (bench/colon_scene.py), at 1 and 2 threads, with and
without escape records and grids. Prints figures; it is a measurement, not a test.

    nice /usr/bin/python3 scripts/cancel_latency.py [--after 2] [--repeat 3] [--photons 50000000]

Each case starts ep.run in a thread, cancels after ``--after`` seconds and times cancel() -> return
(the median and maximum of ``--repeat`` runs): what a caller (the add-on's worker) waits. The add-on's
whole wait after Esc, view and grids included, is scripts/cancel_latency_blender.py's figure.
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import threading
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(os.path.dirname(HERE), "bench"))

from colon_scene import colon_scene  # noqa: E402  (puts the worktree's python/ first)

import endophoton as ep  # noqa: E402


def one(scene, rig, threads, records, grids, after_s, photons, unit_size, folder):
    """(latency s, merged packets, cancelled) of one run cancelled after ``after_s`` seconds."""
    token = ep.CancelToken()
    kw = {"photons": photons, "seed": 1, "threads": threads, "record_escapes": records, "unit_size": unit_size}
    if grids:
        kw["grids"] = ep.GridRequest(voxel_size=0.0005, path=os.path.join(folder, "cancel.vdb"))
    out = {}

    def body():
        out["result"] = ep.run(scene, rig, cancel=token, **kw)
        out["end"] = time.perf_counter()

    worker = threading.Thread(target=body)
    worker.start()
    time.sleep(after_s)
    t_cancel = time.perf_counter()
    token.cancel()
    worker.join()
    res = out["result"]
    return out["end"] - t_cancel, res.photons, res.cancelled


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--after", type=float, default=2.0, help="seconds before cancel()")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--photons", type=int, default=50_000_000, help="a count the run cannot reach before the cancel")
    ap.add_argument("--unit-size", type=int, default=0, help="packets per unit (0: the engine's choice)")
    a = ap.parse_args(argv)
    scene, rig = colon_scene()
    print(f"colon scene, cancel after {a.after:g} s, photons={a.photons:,}, unit_size={a.unit_size or 'auto'}")
    print(f"{'threads':>7} {'records':>7} {'grids':>5} {'median ms':>10} {'max ms':>8} {'merged packets':>15}")
    with tempfile.TemporaryDirectory() as folder:
        for threads in (1, 2):
            for records, grids in ((False, False), (True, False), (False, True), (True, True)):
                lat, packets = [], []
                for _ in range(a.repeat):
                    dt, n, cancelled = one(scene, rig, threads, records, grids, a.after, a.photons, a.unit_size, folder)
                    if not cancelled:
                        raise SystemExit("the run ended before the cancel: raise --photons")
                    lat.append(dt)
                    packets.append(n)
                lat.sort()
                print(
                    f"{threads:>7} {str(records):>7} {str(grids):>5} {1e3 * lat[len(lat) // 2]:>10.1f} "
                    f"{1e3 * lat[-1]:>8.1f} {packets[-1]:>15,}",
                    flush=True,
                )


if __name__ == "__main__":
    main()
