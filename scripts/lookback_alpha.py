#!/usr/bin/env python3
"""Throwaway measurement (docs/performance.md §17): the look-back's alpha and g_b on the colon view, 128 x 128.

    /usr/bin/python3 scripts/lookback_alpha.py --photons 200000 --seeds 1,2 --grid 0:0.9,0.3:0.9,0.6:0.9,0.3:0.8

Per seed, plain nee first, then nee-lookback for each alpha:g_b, interleaved; prints one JSON line per run.
"""
import argparse
import json
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "bench"))
from render_estimators import measure  # noqa: E402

ap = argparse.ArgumentParser()
ap.add_argument("--photons", type=int, default=200_000)
ap.add_argument("--seeds", default="1")
ap.add_argument("--grid", default="0:0.9,0.3:0.9,0.6:0.9")
ap.add_argument("--threads", type=int, default=2)
a = ap.parse_args()
for seed in (int(x) for x in a.seeds.split(",")):
    for cfg in ["nee"] + a.grid.split(","):
        alpha, g_b = (0.0, 0.0) if cfg == "nee" else map(float, cfg.split(":"))
        name = "nee" if cfg == "nee" else "nee-lookback"
        r = measure(a.photons, a.threads, seed, (name,), 3.0, 128, alpha, g_b, plain=False)[name]
        keep = {k: r[k] for k in ("run_cpu_s", "cpu_s", "red_green", "red_green_stderr", "fom", "within_20", "zero")}
        print(json.dumps(dict(seed=seed, config=cfg, photons=a.photons, **keep, counters=r["nee"])), flush=True)
