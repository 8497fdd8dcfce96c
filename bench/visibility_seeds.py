#!/usr/bin/env python3
"""How a beta sweep's common seed correlates its visibility contrasts, and what that does to
``visibility.fit_peak``'s flatness test and peak error (a measurement, not a test).

    /usr/bin/python3 bench/visibility_seeds.py [--reps 10] [--store 20000]

Runs ``--reps`` sweeps of ``ep.default_flat_scene()`` over beta = 0, 5, ..., 55 deg two ways: as
``ep.sweep`` runs them by default (the same seed at every beta, so packet k of every beta draws the
same random numbers) and with ``seed_per_beta=True`` (a seed of its own for every beta: independent
runs). Prints, per contrast:
the mean flatness chi-square (11 degrees of freedom: its mean is 11 for independent errors and a
contrast flat in beta), how many sweeps reject flatness at report.ALPHA, the correlation across the
sweeps of the values at betas 5 deg apart and 20 deg or more apart, and the fitted peak's spread over
the sweeps against the mean of its reported error. docs/render.md quotes a run of it.
"""
from __future__ import annotations

import argparse
import os
import sys

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "python"))

import endophoton as ep  # noqa: E402
from endophoton.report import ALPHA  # noqa: E402
from endophoton.view.visibility import fit_peak  # noqa: E402

BETAS = [5.0 * k for k in range(12)]
KEYS = ("red_green_contrast", "fluorescence_contrast")


def contrasts(rows):
    """{key: (values, stderrs)} over the betas; an undefined contrast is nan."""
    out = {}
    for key in KEYS:
        y = [np.nan if r[key] is None else r[key] for r in rows]
        se = [np.nan if r[key + "_stderr"] is None else r[key + "_stderr"] for r in rows]
        out[key] = (np.array(y, dtype=float), np.array(se, dtype=float))
    return out


def one_sweep(store, seed, seed_per_beta, view):
    """One sweep's contrasts: every beta with ``seed``, or with ``seed_per_beta`` beta k with its own
    seed (``sweep_schema.beta_seed``)."""
    res = ep.sweep(
        ep.default_flat_scene(),
        betas=BETAS,
        store=store,
        seed=seed,
        seed_per_beta=seed_per_beta,
        progress=False,
        visibility=view,
    )
    return contrasts(res.rows)


def summarise(label, sweeps):
    for key in KEYS:
        Y = np.array([s[key][0] for s in sweeps])
        fits = [fit_peak(BETAS, s[key][0], s[key][1], n_boot=400) for s in sweeps]
        chi2 = np.array([f["flat_chi2"] for f in fits])
        rejected = sum(f["flat_p"] is not None and f["flat_p"] < ALPHA for f in fits)
        C = np.corrcoef((Y - np.nanmean(Y, axis=0)).T)
        near = np.nanmean([C[i, i + 1] for i in range(len(BETAS) - 1)])
        far = np.nanmean([C[i, j] for i in range(len(BETAS)) for j in range(len(BETAS)) if j - i >= 4])
        peaks = np.array([f["x_peak"] for f in fits], dtype=float)
        errors = np.array([f["x_peak_stderr"] for f in fits], dtype=float)
        print(
            f"{label:>15} {key:>22}: mean chi2 {np.nanmean(chi2):6.1f} (dof {len(BETAS) - 1}), "
            f"flat rejected {rejected}/{len(sweeps)}; correlation 5 deg apart {near:+.2f}, >= 20 deg {far:+.2f}; "
            f"peak spread {np.nanstd(peaks, ddof=1):5.1f} deg, mean reported error {np.nanmean(errors):5.1f} deg"
        )


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--reps", type=int, default=10, help="sweeps of each kind")
    ap.add_argument("--store", type=int, default=20_000, help="records stored per beta")
    args = ap.parse_args()
    view = {"target": "polyp", "background": "tissue", "width": 96, "height": 96}
    common = [one_sweep(args.store, 100 + r, False, view) for r in range(args.reps)]
    own = [one_sweep(args.store, 100 + r, True, view) for r in range(args.reps)]
    print(f"{args.reps} sweeps of default_flat_scene, {args.store:,} records a beta, betas 0-55 deg:")
    summarise("same seed", common)
    summarise("seed per beta", own)


if __name__ == "__main__":
    main()
