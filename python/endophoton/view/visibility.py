"""How visible a target region (the polyp) is against a background region (the wall).

Contrasts are computed from the per-batch region sums of a rendered view
(``render.View``); their standard errors come from the delete-one-batch
jackknife over the packet-index batches (batches are independent replicas of
the experiment, so the jackknife is the batch-means error of a nonlinear
statistic):

    theta_(-b) = (S - S_b) / (P - P_b)          region means without batch b
    se^2 = (B - 1) / B * sum_b (f(theta_(-b)) - mean_b f(theta_(-b)))^2

* Weber contrast of a radiance: C = (L_target - L_background) / L_background.
* Michelson contrast: M = (L_target - L_background) / (L_target + L_background), in [-1, 1].
* Red/green ratio contrast (photofrin fluorescence endoscopy): the ratio
  rho = mean R / mean G of a region's linear-sRGB fluorescence image, then
  C_rg = (rho_target - rho_background) / rho_background.

The background is a whole region, or the surround: the wall seen in a ring of pixels around the target
(:func:`surround_mask`, docs/render.md). A contrast whose denominator is 0 is reported as None (never NaN).
"""
from __future__ import annotations

import math

import numpy as np

from ..analysis import chi2_sf, polyfit_ready
from . import colour

__all__ = [
    "jackknife",
    "weber",
    "michelson",
    "contrast",
    "fit_peak",
    "SURROUND_PX",
    "surround_mask",
    "pixel_group_batches",
]


def jackknife(sums: np.ndarray, packets_per_batch: np.ndarray, stat) -> tuple[float | None, float | None]:
    """Value and jackknife stderr of ``stat(means)`` where ``means = sums.sum(-1) / P``.

    sums : (..., B) per-batch sums; packets_per_batch : (B,); stat : function of an (...,) array -> float
    (may return None or a non-finite value when undefined; then (None, None)).

    A value is defined only with its standard error (every result carries one): when ``stat`` is
    undefined without some batch (say the background's green comes from that batch alone), the
    estimate rests on too few batches to have an error, and both are None.
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
            return None, None
        loo.append(v)
    loo = np.asarray(loo)
    return float(value), float(math.sqrt((B - 1) / B * np.sum((loo - loo.mean()) ** 2)))


def weber(target: float, background: float) -> float | None:
    """(target - background) / background; None when the background is 0."""
    return (target - background) / background if background > 0 else None


def michelson(target: float, background: float) -> float | None:
    """(target - background) / (target + background); None when both are 0."""
    total = target + background
    return (target - background) / total if total > 0 else None


#: Default width of the surround ring, pixels (docs/render.md, "Contrast against the surroundings").
SURROUND_PX = 8


def surround_mask(region_map, target_index: int, width_px: float, background_index: int | None = None) -> np.ndarray:
    """The pixels of the ring around the target: pixels that see a surface (``region_map`` >= 0), not the
    target, whose centre lies within ``width_px`` pixels (Euclidean, centre to centre) of a target pixel;
    with ``background_index`` only those that see that region. A boolean (H, W) mask."""
    from scipy.ndimage import distance_transform_edt

    rmap = np.asarray(region_map)
    t = rmap == int(target_index)
    if not t.any():
        return np.zeros(rmap.shape, dtype=bool)
    ring = (~t) & (rmap >= 0) & (distance_transform_edt(~t) <= float(width_px))
    if background_index is not None:
        ring &= rmap == int(background_index)
    return ring


def pixel_group_batches(view, mask) -> dict:
    """Per-batch sums of a group of pixels (``mask``, (H, W) booleans) divided by its pixel count, as
    ``view.region_batches`` holds them per region: ``{name}_radiance`` (B,), ``{name}_rgb`` (3, B, linear
    sRGB, white balanced) and ``{name}_camera_rg`` (2, B) for name in white, fluorescence."""
    m = np.asarray(mask, dtype=bool)
    n = int(m.sum())
    if n == 0:
        raise ValueError("pixel group: no pixel")
    Pb = np.asarray(view.packets_per_batch, dtype=np.float64)
    g = np.ones(3) if getattr(view, "gains", None) is None else np.asarray(view.gains, dtype=np.float64)
    out = {}
    for name in ("white", "fluorescence"):
        out[name + "_radiance"] = (view.pixel_batches[name][m] * Pb).sum(axis=0) / n
        sums = view.pixel_colour_sums[name]
        xyz = sums["xyz"][m].sum(axis=0) / n  # (3, B)
        out[name + "_rgb"] = colour.XYZ_TO_SRGB @ (xyz * g[:, None])
        out[name + "_camera_rg"] = sums["camera_rg"][m].sum(axis=0) / n
    return out


def _region_group(view, index: int) -> dict:
    """:func:`pixel_group_batches`' dict of one whole region, from ``view.region_batches``."""
    rb = view.region_batches
    keys = [f"{n}_{k}" for n in ("white", "fluorescence") for k in ("radiance", "rgb", "camera_rg")]
    return {k: np.asarray(rb[k][index]) for k in keys}


def _group_contrasts(t: dict, b: dict, packets_per_batch, channels: str) -> dict:
    """Weber and Michelson contrasts of both images' radiance and the red/green contrast, target group
    ``t`` against background group ``b`` (dicts of :func:`pixel_group_batches`), with jackknife errors."""
    out = {}
    for key in ("fluorescence", "white"):
        s = np.stack([t[key + "_radiance"], b[key + "_radiance"]])
        out[key], out[key + "_stderr"] = jackknife(s, packets_per_batch, lambda m: weber(m[0], m[1]))
        out[key + "_michelson"], out[key + "_michelson_stderr"] = jackknife(
            s, packets_per_batch, lambda m: michelson(m[0], m[1])
        )
    key = "fluorescence_rgb" if channels == "srgb" else "fluorescence_camera_rg"
    rgb = np.stack([t[key][:2], b[key][:2]])  # (2 groups, R G, B batches)

    def rg(m):
        if not (m[0, 1] > 0 and m[1, 1] > 0):
            return None
        return weber(m[0, 0] / m[0, 1], m[1, 0] / m[1, 1])

    out["red_green"], out["red_green_stderr"] = jackknife(rgb, packets_per_batch, rg)
    return out


def contrast(
    view, target: str, background: str | None, channels: str = "srgb", surround_px: float | None = None
) -> dict:
    """Visibility of region ``target`` against its background in a rendered ``view``.

    The background is the whole region ``background`` (``surround_px`` None), or the surround: the pixels
    within ``surround_px`` pixels of the target that see a surface (:func:`surround_mask`), only those of
    region ``background`` when one is named. Returns the CLI's ``contrast`` object: target, background,
    surround_px, background_pixels, fluorescence (Weber contrast of the mean fluorescence radiance), white
    (the same in the white-light image), fluorescence_michelson, white_michelson (Michelson contrasts),
    red_green (Weber contrast of the R/G ratio of the fluorescence image's mean linear sRGB), each with
    ``_stderr``.

    ``channels="camera"`` takes R and G from camera-like, non-negative sensitivities instead: each
    record's linear-sRGB R and G with negative parts clipped to 0. Saturated red (photofrin at 630 nm) or
    blue-green light has a negative linear-sRGB G, so under blue excitation the sRGB ratio can be
    undefined (None) where the camera ratio is not.
    """
    if channels not in ("srgb", "camera"):
        raise ValueError(f"channels = {channels!r} must be 'srgb' or 'camera'")
    ti = view.region_index(target, "target")
    if surround_px is None:
        if background is None:
            raise ValueError("background = None: name a background region or give surround_px")
        bi = view.region_index(background, "background")
        if ti == bi:
            raise ValueError(f"background = {background!r} is the target region; give two different regions")
        t, b, nb = _region_group(view, ti), _region_group(view, bi), int(view.region_pixels[bi])
    else:
        if isinstance(surround_px, bool) or not isinstance(surround_px, (int, float)) or not surround_px >= 1:
            raise ValueError(f"surround_px = {surround_px!r} must be a number of pixels >= 1")
        bi = None if background is None else view.region_index(background, "background")
        if bi == ti:
            raise ValueError(f"background = {background!r} is the target region; give two different regions")
        ring = surround_mask(view.region_map, ti, surround_px, bi)
        nb = int(ring.sum())
        if nb == 0:
            raise ValueError(f"surround_px = {surround_px!r}: no background pixel lies in the ring around {target!r}")
        t, b = pixel_group_batches(view, view.region_map == ti), pixel_group_batches(view, ring)
    out = {"target": target, "background": background, "surround_px": surround_px, "background_pixels": nb}
    out.update(_group_contrasts(t, b, view.packets_per_batch, channels))
    return out


def _not_fitted(n: int) -> dict:
    """:func:`fit_peak`'s outcome when there is no fit (fewer than 3 points, or none posed)."""
    return {
        "x_peak": None,
        "x_max": None,
        "x_peak_stderr": None,
        "x_peak_lo": None,
        "x_peak_hi": None,
        "y_peak": None,
        "interior": False,
        "vertex": False,
        "coeffs": [],
        "n": int(n),
        "flat_chi2": None,
        "flat_dof": None,
        "flat_p": None,
    }


def fit_peak(x, y, y_stderr, n_boot: int = 2000, seed: int = 12345) -> dict:
    """Where a contrast peaks over beta, and how sure we are.

    A weighted least-squares parabola (weights 1/stderr^2) through the 5 points around the largest
    value (all points if fewer) gives the peak: its vertex if the parabola opens downward and the
    vertex lies inside the fitted range, else the best end of the range. The uncertainty is a
    parametric bootstrap: y is redrawn from N(y, stderr) ``n_boot`` times (fixed ``seed``, so the
    answer is reproducible) and the whole fit repeated, the choice of the five points included;
    ``x_peak_stderr`` is the sd of the bootstrap peaks and ``x_peak_lo``/``x_peak_hi`` their
    16th/84th percentiles. ``interior`` tells whether the peak lies strictly inside the swept range
    (else the maximum may lie outside it); ``vertex`` whether it is the parabola's maximum (False:
    the parabola has none inside the fitted points, and ``x_peak`` is merely the better end of
    them). ``x_max`` is the x of the largest point. Fewer than 3 finite points, or points no
    parabola can be fitted to (:func:`polyfit_ready`), give the not-fitted outcome: every number
    None, ``coeffs`` empty.

    Whether y depends on x at all: ``flat_chi2`` is the chi-square of every point about their
    weighted mean, ``flat_dof`` = n - 1 and ``flat_p`` its p-value. With independent errors and no
    dependence on x (one true value) the chi-square has n - 1 degrees of freedom; a large ``flat_p``
    means the largest value is not a maximum but noise, whatever the fit gives.

    The test and the bootstrap take the points' errors as independent. Errors that are positively
    correlated, as in a beta sweep, where every beta runs the same seed, make the test conservative:
    the chi-square is smaller than with independent errors (bench/visibility_seeds.py: a flat
    contrast over 12 betas had a mean chi-square of 6.8 in 10 sweeps, against 10.0 with a seed per
    beta).
    """
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    se = np.asarray(y_stderr, dtype=np.float64)
    ok = np.isfinite(x) & np.isfinite(y) & np.isfinite(se) & (se > 0)
    x, y, se = x[ok], y[ok], se[ok]
    if x.size < 3:
        return _not_fitted(x.size)
    order = np.argsort(x)
    x, y, se = x[order], y[order], se[order]
    k = int(np.argmax(y))

    def peak(yy):
        # The five points around the largest value of yy: chosen again for every bootstrap draw, so
        # that a rival point nearly as large elsewhere in the sweep widens the peak's spread.
        j = int(np.argmax(yy))
        lo, hi = max(0, min(j - 2, x.size - 5)), min(x.size, max(j + 3, 5))
        xs = x[lo:hi]
        with np.errstate(divide="ignore", over="ignore"):
            w = 1.0 / se[lo:hi]  # inf for a stderr of 5e-324: not posed
        if not polyfit_ready(xs, yy[lo:hi], 2, w):
            return None
        c = np.polyfit(xs, yy[lo:hi], 2, w=w)
        if c[0] < 0:
            v = -c[1] / (2 * c[0])
            if xs[0] < v < xs[-1]:
                return float(v), c, True, xs
        grid = np.array([xs[0], xs[-1]])
        return float(grid[np.argmax(np.polyval(c, grid))]), c, False, xs

    fit = peak(y)
    if fit is None:
        return _not_fitted(x.size)
    x0, c0, vertex, xs = fit
    rng = np.random.default_rng(seed)
    boots = [peak(y + rng.standard_normal(y.size) * se) for _ in range(int(n_boot))]
    boots = np.array([b[0] for b in boots if b is not None])  # a draw that overflows is no fit
    spread = boots.size >= 2
    w = 1.0 / se**2
    flat_chi2 = float(np.sum(((y - np.sum(w * y) / np.sum(w)) / se) ** 2))
    return {
        "x_peak": x0,
        "x_max": float(x[k]),
        "x_peak_stderr": float(np.std(boots, ddof=1)) if spread else None,
        "x_peak_lo": float(np.percentile(boots, 16)) if spread else None,
        "x_peak_hi": float(np.percentile(boots, 84)) if spread else None,
        "y_peak": float(np.polyval(c0, x0)),
        "interior": bool(x[0] < x0 < x[-1]),
        "vertex": vertex,
        "coeffs": [float(v) for v in c0],
        "fit_range": [float(xs[0]), float(xs[-1])],
        "n": int(x.size),
        "flat_chi2": flat_chi2,
        "flat_dof": int(x.size) - 1,
        "flat_p": chi2_sf(flat_chi2, int(x.size) - 1),
    }
