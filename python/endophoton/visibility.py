"""How visible a target region (the polyp) is against a background region (the wall).

Contrasts are computed from the per-batch region sums of a rendered view
(``render.View``); their standard errors come from the delete-one-batch
jackknife over the packet-index batches (batches are independent replicas of
the experiment, so the jackknife is the batch-means error of a nonlinear
statistic):

    theta_(-b) = (S - S_b) / (P - P_b)          region means without batch b
    se^2 = (B - 1) / B * sum_b (f(theta_(-b)) - mean_b f(theta_(-b)))^2

* Weber contrast of a radiance: C = (L_target - L_background) / L_background.
* Red/green ratio contrast (photofrin fluorescence endoscopy): the ratio
  rho = mean R / mean G of a region's linear-sRGB fluorescence image, then
  C_rg = (rho_target - rho_background) / rho_background.

A contrast whose denominator is 0 is reported as None (never NaN).
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["jackknife", "weber", "contrast", "visibility_columns"]


def jackknife(sums: np.ndarray, packets_per_batch: np.ndarray, stat) -> tuple[float | None, float | None]:
    """Value and jackknife stderr of ``stat(means)`` where ``means = sums.sum(-1) / P``.

    sums : (..., B) per-batch sums; packets_per_batch : (B,); stat : function of an (...,) array -> float
    (may return None or a non-finite value when undefined; then (None, None)).
    """
    S = np.asarray(sums, dtype=np.float64)
    Pb = np.asarray(packets_per_batch, dtype=np.float64)
    P = Pb.sum()
    total = S.sum(axis=-1)
    value = stat(total / P)
    if value is None or not math.isfinite(value):
        return None, None
    B = Pb.size
    loo = []
    for b in range(B):
        v = stat((total - S[..., b]) / (P - Pb[b]))
        if v is None or not math.isfinite(v):
            return float(value), None
        loo.append(v)
    loo = np.asarray(loo)
    return float(value), float(math.sqrt((B - 1) / B * np.sum((loo - loo.mean()) ** 2)))


def weber(target: float, background: float) -> float | None:
    """(target - background) / background; None when the background is 0."""
    return (target - background) / background if background > 0 else None


def contrast(view, target: str, background: str) -> dict:
    """Visibility of region ``target`` against ``background`` in a rendered ``view``.

    Returns the CLI's ``contrast`` object: target, background, fluorescence (Weber contrast of the
    mean fluorescence radiance), white (the same in the white-light image), red_green (Weber contrast
    of the R/G ratio of the fluorescence image's mean linear sRGB), each with ``_stderr``.
    """
    ti, bi = view.region_index(target, "target"), view.region_index(background, "background")
    if ti == bi:
        raise ValueError(f"background = {background!r} is the target region; give two different regions")
    rb = view.region_batches
    out = {"target": target, "background": background}
    for key in ("fluorescence", "white"):
        s = rb[key + "_radiance"][[ti, bi]]
        out[key], out[key + "_stderr"] = jackknife(s, view.packets_per_batch, lambda m: weber(m[0], m[1]))
    rgb = rb["fluorescence_rgb"][[ti, bi]][:, :2]          # (2 regions, R G, B batches)

    def rg(m):
        if not (m[0, 1] > 0 and m[1, 1] > 0):
            return None
        return weber(m[0, 0] / m[0, 1], m[1, 0] / m[1, 1])
    out["red_green"], out["red_green_stderr"] = jackknife(rgb, view.packets_per_batch, rg)
    return out


def visibility_columns(result, target: str, background: str, **render_kwargs) -> dict:
    """Hook for the beta sweep: render the run's view and return flat, JSON-able columns
    ``fluorescence_contrast``, ``white_contrast``, ``red_green_contrast`` (each with ``_stderr``),
    plus ``target_pixels`` and ``background_pixels``. ``render_kwargs`` go to ``render_view``."""
    from .render import render_view

    view = render_view(result, **render_kwargs)
    c = contrast(view, target, background)
    cols = {}
    for key in ("fluorescence", "white", "red_green"):
        cols[key + "_contrast"] = c[key]
        cols[key + "_contrast_stderr"] = c[key + "_stderr"]
    cols["target_pixels"] = int(view.region_pixels[view.region_index(target, "target")])
    cols["background_pixels"] = int(view.region_pixels[view.region_index(background, "background")])
    return cols
