#!/usr/bin/env python3
"""Benchmark (not a test): the camera estimators side by side on the colon view (issue 34).

    /usr/bin/python3 bench/render_estimators.py [--photons 1000000] [--threads 0] [--seed 1] [--estimators kernel,nee]
        [--tau-cut 3] [--size 128] [--alpha 0.5] [--g-b 0.9]

The colon scene of bench/colon_scene.py, rig at beta = 20 deg, its camera at --size x --size pixels (default
128, issue 34's view; the rig camera's own is 256 x 256, which the frozen sections 12-14 used). Two runs with the
same seed: one records the escapes and renders them with the kernel estimate (estimator="kernel"), one
tallies the camera by next-event estimation (view=True, estimator="nee"). For each it prints the CPU
seconds of run + render (process time, all threads), the polyp's red/green contrast against the colon
with its batch-means stderr, the figure of merit FOM = 1 / (stderr^2 x CPU s), the share of tissue
pixels whose white radiance has a relative stderr <= 20 % and the share left at exactly 0, and the
run's packets per CPU second. A third run (no records, no camera) gives the throughput without either.
``--estimators kernel,knn,exitance,nee``: knn (the k-nearest estimate) and exitance (the exitance estimate)
render the kernel run's records, so their CPU seconds are that run's plus their own render. ``nee-lookback``:
the next-event estimate with the look-back (docs/render.md "Look-back next event"; its proposal's share --alpha
aimed at the camera, that lobe's HG --g-b).
``--seeds N``: N independent runs (seeds --seed, --seed + 1, ...) instead of one; prints each estimator's
contrast over the seeds, the standard deviation of those contrasts beside the root mean square of the reported
(jackknife) standard errors, and the FOM from each: the spread over seeds is the error the estimate really has,
so it tests the reported one.
"""
from __future__ import annotations

import argparse
import datetime as _dt
import math
import os
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, os.path.join(ROOT, "python"))
sys.path.insert(0, HERE)

import numpy as np  # noqa: E402

import endophoton as ep  # noqa: E402
from colon_scene import colon_scene  # noqa: E402


def pixel_shares(view) -> dict:
    """Share of the tissue pixels (white image) within 20 % relative stderr, and at exactly 0."""
    img = view.images["white"]
    tissue = view.region_map >= 0
    L, se = img["radiance"][tissue], img["radiance_stderr"][tissue]
    ok = (L > 0) & (se <= 0.2 * np.where(L > 0, L, 1.0))
    return dict(tissue_pixels=int(tissue.sum()), within_20=float(ok.mean()), zero=float((L == 0).mean()))


def measure(
    photons: int,
    threads: int = 0,
    seed: int = 1,
    estimators=("kernel", "nee"),
    tau_cut: float = 3.0,
    size: int = 128,
    alpha: float = 0.5,
    g_b: float = 0.9,
    plain: bool = True,
) -> dict:
    """The figures of one side-by-side comparison, as a dict per estimator (tau_cut: the next-event
    estimate's depth roulette, an optical depth; alpha, g_b: nee-lookback's proposal; plain: also time a run
    without records or camera)."""
    scene, rig = colon_scene(beta_deg=20.0)
    out, runs = {}, {}
    for name in estimators:
        tally = name.startswith("nee")
        nee_view = dict(tau_cut=tau_cut, width=size, height=size)
        if name == "nee-lookback":
            nee_view.update(look_back=True, look_back_alpha=alpha, look_back_g=g_b)
        kw = dict(record_escapes=False, view=nee_view) if tally else dict(record_escapes=True)
        key = name if tally else "records"  # kernel and knn render the same run's records
        c0, w0 = time.process_time(), time.perf_counter()
        if key not in runs:
            res = ep.run(scene, rig, photons, seed=seed, threads=threads, spectral=True, **kw)
            runs[key] = (res, time.process_time() - c0)
        res, run_cpu = runs[key]
        c0, c1 = time.process_time() - run_cpu, time.process_time()
        view = ep.render_view(res, estimator="nee" if tally else name, threads=threads, width=size, height=size)
        c2, w2 = time.process_time(), time.perf_counter()
        con = view.contrast("polyp", "colon")
        se = con["red_green_stderr"]
        cpu = c2 - c0
        out[name] = dict(
            run_cpu_s=c1 - c0,
            render_cpu_s=c2 - c1,
            cpu_s=cpu,
            wall_s=w2 - w0,
            red_green=con["red_green"],
            red_green_stderr=se,
            fom=1.0 / (se * se * cpu) if se else None,
            packets_per_cpu_s=photons / (c1 - c0),
            nee=view.nee,
            bounded=(res.camera_image or {}).get("bounded"),
            **pixel_shares(view),
        )
    if plain:
        c0 = time.process_time()
        ep.run(scene, rig, photons, seed=seed, threads=threads, spectral=True, record_escapes=False)
        out["plain_packets_per_cpu_s"] = photons / (time.process_time() - c0)
    return out


NAMES = ("kernel", "knn", "exitance", "nee", "nee-lookback")


def _num(x, digits: int) -> str:
    """x with `digits` decimals, or "n/a" where a contrast (too few records) has none."""
    return "n/a" if x is None else f"{x:.{digits}f}"


def table(m: dict, photons: int) -> str:
    rows = [
        "| estimator | CPU s (run + render) | red/green contrast | FOM (s^-1) | tissue px within 20 % | "
        "tissue px at 0 | packets / CPU s |",
        "|---|---|---|---|---|---|---|",
    ]
    for name in (k for k in NAMES if k in m):
        r = m[name]
        rows.append(
            f"| {name} | {r['run_cpu_s']:.1f} + {r['render_cpu_s']:.1f} | {_num(r['red_green'], 3)} ± "
            f"{_num(r['red_green_stderr'], 3)} | {_num(r['fom'], 1)} | {100 * r['within_20']:.1f} % | "
            f"{100 * r['zero']:.1f} % | {r['packets_per_cpu_s']:,.0f} |"
        )
    foms = {k: m[k]["fom"] for k in NAMES if k in m}
    ratios = ", ".join(
        f"{k} / kernel = {_num(f / foms['kernel'] if f and foms.get('kernel') else None, 1)}"
        for k, f in foms.items()
        if k != "kernel"
    )
    rows.append("")
    rows.append(
        f"FOM ratio {ratios}; packets / CPU s without records or camera: "
        f"{m['plain_packets_per_cpu_s']:,.0f} ({photons:,} packets, {_dt.date.today().isoformat()})"
    )
    return "\n".join(rows)


def seed_spread(rows: list) -> str:
    """Per estimator over the seeds' ``measure`` dicts: mean contrast, its standard deviation over the seeds
    (with a 68 % chi-square interval), the rms of the reported stderrs, mean CPU s, and the FOM from each."""
    from scipy.stats import chi2

    out = [
        "| estimator | seeds | mean red/green | sd over seeds (68 %) | rms reported stderr | sd / stderr | "
        "CPU s | FOM (sd) | FOM (stderr) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    fom = {}
    for name in (k for k in NAMES if k in rows[0]):
        c = np.array([r[name]["red_green"] for r in rows], dtype=float)
        se = np.array([r[name]["red_green_stderr"] for r in rows], dtype=float)
        cpu = float(np.mean([r[name]["cpu_s"] for r in rows]))
        n = c.size
        sd, rms = float(c.std(ddof=1)), float(np.sqrt(np.mean(se**2)))
        lo, hi = (sd * math.sqrt((n - 1) / chi2.ppf(q, n - 1)) for q in (0.84, 0.16))
        fom[name] = (1 / (sd**2 * cpu), 1 / (rms**2 * cpu))
        out.append(
            f"| {name} | {n} | {c.mean():.3f} | {sd:.4f} ({lo:.4f}–{hi:.4f}) | {rms:.4f} | {sd / rms:.2f} | "
            f"{cpu:.1f} | {fom[name][0]:.1f} | {fom[name][1]:.1f} |"
        )
    if "kernel" in fom:
        out.append("")
        out.append(
            "FOM / kernel's: "
            + ", ".join(
                f"{k} {f[0] / fom['kernel'][0]:.1f} (sd), {f[1] / fom['kernel'][1]:.1f} (stderr)"
                for k, f in fom.items()
                if k != "kernel"
            )
        )
    return "\n".join(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--photons", type=int, default=1_000_000)
    ap.add_argument("--threads", type=int, default=0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument(
        "--estimators",
        default="kernel,nee",
        help="comma-separated: kernel, knn, exitance, nee, nee-lookback (kernel first)",
    )
    ap.add_argument("--tau-cut", type=float, default=3.0)
    ap.add_argument("--size", type=int, default=128, help="image width = height in pixels")
    ap.add_argument("--alpha", type=float, default=0.5, help="nee-lookback: proposal share aimed at the camera")
    ap.add_argument("--g-b", type=float, default=0.9, help="nee-lookback: that lobe's HG asymmetry")
    ap.add_argument("--seeds", type=int, default=1, help="independent runs: report the spread over them")
    a = ap.parse_args(argv)
    if a.seeds > 1:
        est = tuple(a.estimators.split(","))
        rows = [
            measure(a.photons, a.threads, a.seed + i, est, a.tau_cut, a.size, a.alpha, a.g_b, plain=False)
            for i in range(a.seeds)
        ]
        print(seed_spread(rows))
        return 0
    m = measure(a.photons, a.threads, a.seed, tuple(a.estimators.split(",")), a.tau_cut, a.size, a.alpha, a.g_b)
    print(table(m, a.photons))
    for k in ("nee", "nee-lookback"):
        if k in m:
            print(f"{k} counters (tau_cut {a.tau_cut}):", m[k]["nee"], "thinned with no query:", m[k]["bounded"])
    return 0


if __name__ == "__main__":
    sys.exit(main())
