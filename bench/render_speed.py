#!/usr/bin/env python3
"""Benchmark (not a test): seconds per endoscope image at each kernel size and resolution.

    /usr/bin/python3 bench/render_speed.py [--photons N]

Runs the colon scene of bench/colon_scene.py (rig at beta = 20 deg, scene in metres) once, then
renders the rig camera's view with ep.render_view at 64^2, 128^2 and 256^2 pixels (--sizes) and kernel radii
of 1, 2 (the default) and 4 pixel footprints (--factors; kernel angle 15 deg). For each it prints the wall
seconds of render_view, its peak memory (tracemalloc), the median relative standard error of the white image over the
pixels that see tissue, and the kernel's estimated bias in the polyp's mean white radiance
(4/3 (L_h - L_h/2), in units of its stderr). bench/perf.py runs it for docs/performance.md §7.
"""
from __future__ import annotations

import argparse
import datetime as _dt
import os
import sys
import time
import tracemalloc

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, os.path.join(ROOT, "python"))
sys.path.insert(0, HERE)

import numpy as np  # noqa: E402

import endophoton as ep  # noqa: E402
from colon_scene import colon_scene  # noqa: E402
from endophoton.view.render import render_view  # noqa: E402

BUDGET = dict(memory_budget_bytes=16 * 2**30)  # 1024^2 needs ~5 GB, beyond the default 4 GiB (view.budget)


def measure(photons: int, sizes=(64, 128, 256), factors=(1, 2, 4)) -> tuple[list[dict], dict]:
    scene, rig = colon_scene(beta_deg=20.0)
    t0 = time.perf_counter()
    res = ep.run(scene, rig, photons=photons, seed=1, spectral=True)
    run_s = time.perf_counter() - t0
    rows = []
    for n in sizes:
        footprint = render_view(res, None, n, n, **BUDGET).kernel["radius"] / 2  # the default radius is 2 footprints
        for factor in factors:
            t0 = time.perf_counter()
            view = render_view(res, None, n, n, kernel_radius=factor * footprint, **BUDGET)
            seconds = time.perf_counter() - t0
            tracemalloc.start()  # a second pass, for the peak of numpy's allocations
            view = render_view(res, None, n, n, kernel_radius=factor * footprint, **BUDGET)
            peak = tracemalloc.get_traced_memory()[1]
            tracemalloc.stop()
            img = view.images["white"]
            hit = view.region_map >= 0
            L, se = img["radiance"][hit], img["radiance_stderr"][hit]
            lit = L > 0
            rel = float(np.median(se[lit] / L[lit])) if lit.any() else float("nan")
            bias = view.kernel_summary()["bias"].get("polyp", {})
            z = bias["white_bias"] / bias["white_bias_stderr"] if bias.get("white_bias_stderr") else float("nan")
            polyp = view.regions().get("polyp", {})
            rows.append(
                dict(
                    pixels=n,
                    factor=factor,
                    radius_mm=view.kernel["radius"] * scene.unit_cm * 10,
                    seconds=seconds,
                    peak_mib=peak / 2**20,
                    median_rel_se=float(rel),
                    lit=float(lit.mean()),
                    polyp_bias_sigma=float(z),
                    polyp_rel_se=polyp.get("white_radiance_stderr", 0) / polyp["white_radiance"]
                    if polyp.get("white_radiance")
                    else float("nan"),
                )
            )
            print(
                f"{n:4d}^2  r = {factor} px ({rows[-1]['radius_mm']:.3f} mm): {seconds:6.2f} s  {peak / 2**20:.0f} MiB  "
                f"lit {lit.mean():.2f}  median rel. se {rel:.3f}  polyp rel. se {rows[-1]['polyp_rel_se']:.4f}  "
                f"polyp bias {z:+.2f} sigma",
                flush=True,
            )
    load = os.getloadavg()
    meta = dict(
        photons=photons,
        records=int(len(res.escapes["weight"])),
        run_s=run_s,
        date=_dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        load=load,
    )
    return rows, meta


def table(rows, meta) -> str:
    """The measurements as Markdown: what was run, the table, and how to read it."""
    lines = [
        f"`bench/render_speed.py`, measured {meta['date']}: colon scene (bench/colon_scene.py, metres), rig at "
        f"beta = 20 deg, {meta['photons']:,} packets, {meta['records']:,} escape records (run {meta['run_s']:.1f} s). "
        "`ep.render_view` with the rig's camera, kernel angle 15 deg, all cores; seconds of one pass, peak memory "
        "(tracemalloc) of a second. The kernel radius is in "
        "pixel footprints at the median surface depth (2 is the default). `lit`: share of the pixels that see "
        "tissue whose kernel holds records (the rig's 120 deg view is mostly dark wall beyond the two light spots); "
        "`median rel. se`: median over the lit pixels of the white image's batch-means relative standard error; "
        "`polyp bias`: the kernel's estimated bias of the polyp's mean white radiance, 4/3 (L(r) - L(r/2)), in "
        "units of its standard error.",
        "",
        "| pixels | kernel radius | seconds / image | peak MiB | lit | median rel. se (pixel) | polyp rel. se "
        "(region) | polyp bias / σ |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['pixels']}² | {r['factor']} px ({r['radius_mm']:.3f} mm) | {r['seconds']:.2f} | "
            f"{r['peak_mib']:.0f} | {100 * r['lit']:.0f} % | {r['median_rel_se']:.3f} | {r['polyp_rel_se']:.4f} | "
            f"{r['polyp_bias_sigma']:+.2f} |"
        )
    lines += [
        "",
        "Larger kernels gather more records per pixel (lower noise, more time in the gather) and blur "
        "more (bias grows as r²); more pixels cost primary rays and gathers in proportion.",
        "",
    ]
    return "\n".join(lines) + "\n"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--photons", type=int, default=150_000)
    ap.add_argument("--sizes", default="64,128,256", help="image sides, e.g. 128,256,512,1024")
    ap.add_argument("--factors", default="1,2,4", help="kernel radii in pixel footprints")
    args = ap.parse_args()
    rows, meta = measure(args.photons, *(tuple(int(v) for v in a.split(",")) for a in (args.sizes, args.factors)))
    print(f"load average {meta['load'][0]:.1f} / {meta['load'][1]:.1f} / {meta['load'][2]:.1f}")
    print(table(rows, meta))
    return 0


if __name__ == "__main__":
    sys.exit(main())
