#!/usr/bin/env python3
"""Throwaway measurement (issue 34): the k-nearest estimate's bias on the three scenes of
tests/python/test_render_nee.py, against the next-event image (one run) and the aperture camera
(another run's records, which the knn also renders), for several k; and its own bias estimate.

    PYTHONPATH=python /usr/bin/python3 scripts/knn_bias.py [--ks 8,32,128] [--records 300000]
"""
import argparse
import json
import math
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "tests", "python"))
import endophoton as ep  # noqa: E402
from endophoton.view.camera import Camera  # noqa: E402
from endophoton.view.render import render_view  # noqa: E402
import test_render_nee as T  # noqa: E402
from test_render_knn import _nee_view  # noqa: E402
from _synth import polyp_box_scene  # noqa: E402


def scenes():
    flat_cam = Camera.look_at((0.3, 0, 2.0), (0, 0, 0), up=(0, 1, 0), fov_deg=20, aperture_radius=0.4)
    box_cam = Camera.look_at((0.6, 0.3, 2.5), (0, 0, 0), up=(0, 1, 0), fov_deg=40, aperture_radius=0.3)
    colon, rig = T._colon()
    return {
        "flat": (T._slab(mua=1.0, mus=30.0, g=0.8, n=1.4), T._disk(0.4), flat_cam, 6, 30_000, ("tissue",)),
        "polyp_box": (
            polyp_box_scene(),
            ep.DiskSource(position=(0, 0, 2), direction=(0, 0, -1), radius=1.0),
            box_cam,
            8,
            30_000,
            ("wall", "polyp"),
        ),
        "colon": (colon, rig, Camera.from_rig(rig, aperture_radius=0.002), 16, 50_000, ("polyp", "colon")),
    }


def region_stats(view, name, key, aperture=False):
    i = view.region_names.index(name)
    m = view.region_map == i
    if aperture:
        L, S = view.aperture[key]["radiance"][m], view.aperture[key]["radiance_stderr"][m]
        return float(L.mean()), math.sqrt(float(np.sum(S**2))) / L.size
    r = view.regions()[name]
    return r[key + "_radiance"], r[key + "_radiance_stderr"]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--ks", default="8,32,128")
    ap.add_argument("--records", type=int, default=300_000)
    ap.add_argument("--only", default=None)
    a = ap.parse_args()
    out = {}
    for sname, (scene, src, cam, size, nee_n, regions) in scenes().items():
        if a.only and sname not in a.only.split(","):
            continue
        nee = _nee_view(scene, src, cam, size, nee_n)
        rec_run = ep.run(scene, src, a.records, seed=2, spectral=True)
        kern = render_view(rec_run, cam, size, size, estimator="kernel")
        views = {"kernel": kern}
        for k in map(int, a.ks.split(",")):
            views[f"knn{k}"] = render_view(rec_run, cam, size, size, estimator="knn", knn_k=k)
        res = {}
        for vname, v in views.items():
            row = {}
            summ = v.kernel_summary()["bias"]
            for reg in regions:
                for key in ("white", "fluorescence"):
                    L, s = region_stats(v, reg, key)
                    N, sn = region_stats(nee, reg, key)
                    A, sa = region_stats(kern, reg, key, aperture=True)
                    b, sb = summ[reg][key + "_bias"], summ[reg][key + "_bias_stderr"]
                    row[f"{reg}.{key}"] = dict(
                        L=L,
                        s=s,
                        vs_nee=(L - N) / (math.hypot(s, sn) or 1),
                        ratio_nee=L / N if N else None,
                        vs_ap=(L - A) / (math.hypot(s, sa) or 1),
                        ratio_ap=L / A if A else None,
                        bias_est=b,
                        bias_est_s=sb,
                        nee=N,
                        nee_s=sn,
                        ap=A,
                        ap_s=sa,
                    )
            for key in ("white",):
                n_, k_ = nee.images[key], v.images[key]
                chi, dof = T._pixel_chi2(n_["radiance"], n_["radiance_stderr"], k_["radiance"], k_["radiance_stderr"])
                row[f"pix_chi2_nee.{key}"] = (chi, dof)
                ap_ = kern.aperture[key]
                chi, dof = T._pixel_chi2(ap_["radiance"], ap_["radiance_stderr"], k_["radiance"], k_["radiance_stderr"])
                row[f"pix_chi2_ap.{key}"] = (chi, dof)
                tissue = v.region_map >= 0
                row["zero_share"] = float((k_["radiance"][tissue] == 0).mean())
            res[vname] = row
        out[sname] = res
        print(sname, json.dumps(res, indent=1))
    with open("/tmp/knn_bias.json", "w") as fh:
        json.dump(out, fh, indent=1)


if __name__ == "__main__":
    main()
