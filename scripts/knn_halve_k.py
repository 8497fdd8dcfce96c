#!/usr/bin/env python3
"""Throwaway measurement (issue 34): the k-nearest estimate's bias estimated by halving k instead of the
scale, on the scenes of scripts/knn_bias.py. Scales grow as k^(1/4) (records on a 2-D surface x 2-D directions),
so a bias c s^2 gives L_k - L_{k/2} = bias_k (1 - 2^(-1/2)); the region's per-batch differences give its stderr.
Compared with the measured bias against NEE (independent run).

    PYTHONPATH=python /usr/bin/python3 scripts/knn_halve_k.py [--k 32]
"""
import argparse
import math

import numpy as np

import endophoton as ep
from endophoton.view.render import render_view
from knn_bias import scenes
from test_render_knn import _nee_view


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--k", type=int, default=32)
    a = ap.parse_args()
    f = 1.0 - 2.0**-0.5
    for sname, (scene, src, cam, size, nee_n, regions) in scenes().items():
        nee = _nee_view(scene, src, cam, size, nee_n).regions()
        run = ep.run(scene, src, 300_000, seed=2, spectral=True)
        full, half = (render_view(run, cam, size, size, estimator="knn", knn_k=k) for k in (a.k, a.k // 2))
        Pb = full.packets_per_batch
        for reg in regions:
            i = full.region_names.index(reg)
            L = full.region_batches["white_radiance"][i].sum() / Pb.sum()
            diff = (full.region_batches["white_radiance"][i] - half.region_batches["white_radiance"][i]) / f
            b, sb = diff.sum() / Pb.sum(), np.std(diff / Pb, ddof=1) / math.sqrt(Pb.size)
            meas = L - nee[reg]["white_radiance"]
            sm = math.hypot(full.regions()[reg]["white_radiance_stderr"], nee[reg]["white_radiance_stderr"])
            print(
                f"{sname} {reg}: halving-k bias {b / L:+.3f} ± {sb / L:.3f}; measured vs NEE {meas / L:+.3f} ± {sm / L:.3f}"
            )


if __name__ == "__main__":
    main()
