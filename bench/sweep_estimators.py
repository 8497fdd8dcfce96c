#!/usr/bin/env python3
"""Benchmark (not a test): the main job's colon sweep with each camera estimator, side by side (issue 34).

    /usr/bin/python3 bench/sweep_estimators.py [--betas 0,20,40] [--light white] [--estimators kernel,nee]
        [--err 0.05] [--cap 1500000] [--store 250000] [--out /tmp/sweep_estimators]

Runs ``python3 -m endophoton sweep --blend blend_scenes/colon_polyp.blend`` as the main job does (polyp against
its 8-pixel surround on the colon, 128 x 128 view, ``--target-contrast red_green_camera:ERR --max-packets
CAP``) once per estimator, one after the other, and prints per β the packets behind the view, whether the
target was reached, the camera-channel red/green contrast and the white-light Weber contrast with their
batch-means errors; then per estimator the CPU seconds of the whole sweep (Blender's process and its threads:
the children's user + system time, the store runs included), the CPU seconds per β and the figure of merit
FOM = 1 / (stderr^2 x CPU s per β) of both contrasts, from the β's mean squared error. Needs the add-on's
path (ENDOPHOTON_ADDON_PATH, set here to addon/) and Blender, as the main job does.
"""
from __future__ import annotations

import argparse
import csv
import datetime as _dt
import os
import resource
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)


def _children_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _sweep(estimator, args) -> tuple[list[dict], float]:
    out = os.path.join(args.out, f"{estimator}_{args.light}")
    cmd = [
        "/usr/bin/python3", "-m", "endophoton", "sweep", "--blend", os.path.join(ROOT, "blend_scenes", "colon_polyp.blend"),
        "--betas", args.betas, "--store", str(args.store), "--target", "Polyp", "--background", "Colon",
        "--surround", "8", "--target-contrast", f"red_green_camera:{args.err}", "--max-packets", str(args.cap),
        "--view-size", "128", "--estimator", estimator, "--light", args.light, "--no-progress", "--out", out,
    ]  # fmt: skip
    env = dict(os.environ, ENDOPHOTON_ADDON_PATH=os.path.join(ROOT, "addon"))
    before = _children_cpu()
    subprocess.run(cmd, check=True, env=env, cwd=ROOT, stdout=subprocess.DEVNULL)
    cpu = _children_cpu() - before
    with open(os.path.join(out, "sweep.csv"), encoding="utf-8") as fh:
        return list(csv.DictReader(fh)), cpu


def _num(row, key) -> float:
    return float(row[key]) if row.get(key) not in (None, "") else float("nan")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--betas", default="0,20,40")
    p.add_argument("--light", default="white", choices=("white", "blue"))
    p.add_argument("--estimators", default="kernel,nee")
    p.add_argument("--err", type=float, default=0.05)
    p.add_argument("--cap", type=int, default=1_500_000)
    p.add_argument("--store", type=int, default=250_000)
    p.add_argument("--out", default="/tmp/sweep_estimators")
    args = p.parse_args(argv)
    print(
        f"# colon sweep by estimator, {_dt.datetime.now(_dt.timezone.utc):%Y-%m-%d %H:%M} UTC, load {os.getloadavg()[0]:.1f}"
    )
    print(
        f"# betas {args.betas}, light {args.light}, target red_green_camera <= {args.err}, cap {args.cap}, store {args.store}\n"
    )
    print("| estimator | β | view packets | reached | red/green (camera) | white Weber |")
    print("|---|---|---|---|---|---|")
    summary = []
    for est in args.estimators.split(","):
        rows, cpu = _sweep(est, args)
        for r in rows:
            print(
                f"| {est} | {_num(r, 'beta_deg'):g} | {int(_num(r, 'view_packets')):,} | {r['target_reached']} | "
                f"{_num(r, 'red_green_camera_contrast'):.3f} ± {_num(r, 'red_green_camera_contrast_stderr'):.4f} | "
                f"{_num(r, 'white_contrast'):.3f} ± {_num(r, 'white_contrast_stderr'):.4f} |"
            )
        per_beta = cpu / len(rows)
        foms = []
        for key in ("red_green_camera_contrast_stderr", "white_contrast_stderr"):
            mse = sum(_num(r, key) ** 2 for r in rows) / len(rows)
            foms.append(1.0 / (mse * per_beta))
        summary.append((est, cpu, per_beta, foms))
    print("\n| estimator | CPU s (sweep) | CPU s per β | FOM red/green camera (s⁻¹) | FOM white Weber (s⁻¹) |")
    print("|---|---|---|---|---|")
    for est, cpu, per_beta, (f_rg, f_w) in summary:
        print(f"| {est} | {cpu:.0f} | {per_beta:.1f} | {f_rg:.2f} | {f_w:.1f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
