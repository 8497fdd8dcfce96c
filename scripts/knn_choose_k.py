#!/usr/bin/env python3
"""Throwaway measurement (issue 34): choose the k-nearest estimate's k on the colon view (beta = 20 deg,
128 x 128): one records run, rendered with the kernel and knn at several k; one next-event run as the
unbiased reference for the region means and the contrast. CPU s = the run's + the render's (process time).

    PYTHONPATH=python /usr/bin/python3 scripts/knn_choose_k.py [--photons 200000] [--ks 8,16,32,64,128]
"""
import argparse
import json
import os
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "bench"))
import endophoton as ep  # noqa: E402
from colon_scene import colon_scene  # noqa: E402
from render_estimators import pixel_shares  # noqa: E402


def figures(view, cpu):
    con = view.contrast("polyp", "colon")
    reg = view.regions()
    se = con["red_green_stderr"]
    out = dict(
        cpu_s=cpu, red_green=con["red_green"], red_green_stderr=se, fom=1 / (se * se * cpu), **pixel_shares(view)
    )
    for name in ("polyp", "colon"):
        for key in ("white", "fluorescence"):
            out[f"{name}.{key}"] = (reg[name][key + "_radiance"], reg[name][key + "_radiance_stderr"])
    if view.estimator != "nee":
        b = view.kernel_summary()["bias"]
        out["bias_est"] = {n: (b[n]["white_bias"], b[n]["white_bias_stderr"]) for n in ("polyp", "colon")}
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--photons", type=int, default=200_000)
    ap.add_argument("--ks", default="8,16,32,64,128")
    ap.add_argument("--nee", type=int, default=1)
    a = ap.parse_args()
    scene, rig = colon_scene(beta_deg=20.0)
    res = {}
    c0 = time.process_time()
    run = ep.run(scene, rig, a.photons, seed=1, threads=2, spectral=True)
    run_cpu = time.process_time() - c0
    res["run_cpu_s"] = run_cpu
    for est, k in [("kernel", None)] + [("knn", int(k)) for k in a.ks.split(",")]:
        c0 = time.process_time()
        v = ep.render_view(run, estimator=est, threads=2, **({} if k is None else {"knn_k": k}))
        render = time.process_time() - c0
        res[est if k is None else f"knn{k}"] = dict(render_cpu_s=render, **figures(v, run_cpu + render))
        print(est, k, json.dumps(res[est if k is None else f"knn{k}"]), flush=True)
    if a.nee:
        c0 = time.process_time()
        run = ep.run(scene, rig, a.photons, seed=1, threads=2, spectral=True, record_escapes=False, view=True)
        v = ep.render_view(run, estimator="nee", threads=2)
        res["nee"] = figures(v, time.process_time() - c0)
        print("nee", json.dumps(res["nee"]), flush=True)
    with open(f"/tmp/knn_choose_k_{a.photons}.json", "w") as fh:
        json.dump(res, fh, indent=1)


if __name__ == "__main__":
    main()
