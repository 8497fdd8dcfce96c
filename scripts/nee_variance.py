#!/usr/bin/env python3
"""Throwaway measurement (issue 34, bench/frozen/nee_cost.md): what dominates the stderr of the next-event
estimate's red/green contrast (polyp against colon, fluorescence image, linear sRGB) on the colon view.

It needs every score, which the engine does not hand out: build with this scratch patch (not committed)
at the end of next_event in native/camera_tally.cpp, just before the score is pushed:

    if (std::getenv("EP_NEE_DUMP")) {  // SCRATCH: one record of 9 doubles per score
        static thread_local FILE* f = nullptr;
        if (!f) { char nm[256]; snprintf(nm, 256, "%s.%p", std::getenv("EP_NEE_DUMP"), (void*)&f);
                  f = std::fopen(nm, "wb"); }
        double rec[9] = {double(e.packet), double(pixel), double(e.fluorescent), e.lambda_nm, value, p_hg,
                         tau, rf.l1 * unit_cm, q};
        std::fwrite(rec, sizeof rec, 1, f); std::fflush(f);
    }

    /usr/bin/python3 scripts/nee_variance.py 30000            # run, dump, analyse
    /usr/bin/python3 scripts/nee_variance.py 30000 --reuse    # analyse the dump of an earlier run

The look-back (docs/performance.md §17): `--look-back ALPHA:G_B` (or `off`) runs it at 128 x 128 (the rig camera's
256 x 256 otherwise) and reads records of 11 doubles: the 9 above, then the look-back's weight ratio
p_HG / q of the virtual event being scored (1 for a real one) and its kind: 1 a virtual event, 2 a real
fluorescence event, 3 a real event whose flight from an armed scattering was not clear, 0 a real event with
nothing armed (two thread-locals the scratch patch sets around the camera_event / offer_camera calls in
look_back_event, interact() and zone_steps()). The p_HG groups then hold p_HG x ratio, and four more groups
split the scores by kind.

Linearised, ln(1 + C) = ln R_p - ln G_p - ln R_c + ln G_c, so each score adds R/R_p - G/G_p (polyp pixels)
or G/G_c - R/R_c (colon pixels) to its packet's influence; the contrast's relative variance is the variance
of the packets' influences over N. A group of scores (by p_HG, by optical depth, by emission band) is
credited with the variance of the packets' influences counting that group's scores only.
"""
import glob
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "bench"))
sys.path.insert(0, os.path.join(HERE, "..", "python"))

import endophoton as ep  # noqa: E402
from endophoton.view import colour  # noqa: E402
from endophoton.view.render import _gains, emission_filter_function  # noqa: E402
from colon_scene import colon_scene  # noqa: E402


def main(photons: int, reuse: bool, dump: str = "/tmp/nee_dump.bin", look_back: str | None = None) -> None:
    scene, rig = colon_scene(beta_deg=20.0)
    view, size, cols = True, {}, 9
    if look_back:  # "off": plain next-event at 128 x 128, records of 11 doubles
        size, cols = dict(width=128, height=128), 11
        view = dict(**size)
        if look_back != "off":
            a, g = map(float, look_back.split(":"))
            view.update(look_back=True, look_back_alpha=a, look_back_g=g)
    if not reuse:
        for f in glob.glob(dump + ".*"):
            os.remove(f)
        os.environ["EP_NEE_DUMP"] = dump
    # (with --reuse a short run, for the view's region map only)
    n = 2000 if reuse else photons
    res = ep.run(scene, rig, n, seed=1, threads=1, spectral=True, record_escapes=False, view=view)
    os.environ.pop("EP_NEE_DUMP", None)
    view = ep.render_view(res, estimator="nee", threads=1, **size)
    d = np.concatenate([np.fromfile(f).reshape(-1, cols) for f in glob.glob(dump + ".*")])
    pk, px, fl, lam, val, phg, tau = d[:, :7].T
    ratio, virtual = (d[:, 9], d[:, 10]) if cols == 11 else (np.ones(len(d)), np.zeros(len(d)))
    phg = phg * ratio
    pk = pk.astype(int)
    reg = view.region_map.ravel()[px.astype(int)]
    light = getattr(rig, "spectrum", None)
    T, _ = emission_filter_function("auto", light)
    rgb = colour.xyz_to_linear_srgb(colour.cmf_xyz(lam) * np.clip(T(lam), 0, 1)[:, None], _gains("white", light))
    R, G = rgb[:, 0] * val * fl, rgb[:, 1] * val * fl
    ip, ic = view.region_index("polyp"), view.region_index("colon")
    Rp, Gp, Rc, Gc = (R[reg == ip].sum(), G[reg == ip].sum(), R[reg == ic].sum(), G[reg == ic].sum())
    infl = np.where(reg == ip, R / Rp - G / Gp, np.where(reg == ic, G / Gc - R / Rc, 0.0)) * photons

    def var(mask):
        c = np.bincount(pk, weights=np.where(mask, infl, 0.0), minlength=photons)
        return c.var() / photons

    total = var(np.ones(len(pk), bool))
    print(f"relative stderr of 1 + C from the scores: {np.sqrt(total):.3f} ({len(pk):,} scores)")
    groups = [
        (f"p_HG in [{lo}, {hi}) sr^-1", (phg >= lo) & (phg < hi)) for lo, hi in [(0, 0.1), (0.1, 1), (1, 5), (5, 99)]
    ]
    groups += [
        (f"tau in [{lo}, {hi})", (tau >= lo) & (tau < hi)) for lo, hi in [(0, 0.5), (0.5, 1.5), (1.5, 3), (3, 99)]
    ]
    groups += [("polyp pixels", reg == ip), ("colon pixels", reg == ic)]
    if cols == 11:
        groups += [("virtual events (look-back)", virtual == 1), ("real: nothing armed", virtual == 0),
                   ("real: fluorescence event", virtual == 2), ("real: flight not clear", virtual == 3)]  # fmt: skip
    groups += [(f"emission {b}", (lam >= lo) & (lam < hi) & (fl > 0)) for b, lo, hi in
               [("< 540 nm", 0, 540), ("540-600 nm", 540, 600), ("> 600 nm", 600, 2000)]]  # fmt: skip
    print("| scores | share of scores | share of the variance | share of polyp R | share of polyp G |")
    print("|---|---|---|---|---|")
    for name, m in groups:
        pr, pg = R[m & (reg == ip)].sum() / Rp, G[m & (reg == ip)].sum() / Gp
        print(f"| {name} | {m.mean():.3f} | {var(m) / total:.3f} | {pr:.3f} | {pg:.3f} |")
    c = np.bincount(pk, weights=infl, minlength=photons)
    dev = np.sort((c - c.mean()) ** 2)[::-1]
    print(f"packets: top 0.1 % carry {dev[: photons // 1000].sum() / dev.sum():.3f} of the variance, "
          f"top 1 % {dev[: photons // 100].sum() / dev.sum():.3f}")  # fmt: skip


if __name__ == "__main__":
    lb = sys.argv[sys.argv.index("--look-back") + 1] if "--look-back" in sys.argv else None
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 30000, "--reuse" in sys.argv, look_back=lb)
