"""Trends over a sweep: plain least-squares lines and polynomial peaks, and the check that
numpy.polyfit is posed on the values (used by plots, report and visibility)."""

from __future__ import annotations

from typing import Sequence

import numpy as np


def polyfit_ready(x, y, deg: int, w=None) -> bool:
    """Whether ``numpy.polyfit(x, y, deg, w=w)`` is posed on these values: more points than ``deg``,
    x, y and w finite, and the least-squares system polyfit hands to LAPACK finite. polyfit scales
    each column of the (weighted) Vandermonde matrix by its norm; x values so close together near 0
    that a column's norm underflows to 0 (x spaced 1e-200 apart), or so large that a power
    overflows, make that matrix inf/NaN, and LAPACK's DLASCL then ends the whole process (Blender
    with it). Every polyfit of the package (:func:`linear_fit`, :func:`poly_peak`,
    ``visibility.fit_peak``) asks this first and returns its not-fitted outcome when the answer is False."""
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    if x.ndim != 1 or y.shape != x.shape or x.size <= int(deg) or int(deg) < 0:
        return False
    w = np.ones_like(x) if w is None else np.asarray(w, dtype=np.float64)
    if w.shape != x.shape or not (np.isfinite(x).all() and np.isfinite(y).all() and np.isfinite(w).all()):
        return False
    with np.errstate(all="ignore"):
        lhs = np.vander(x, int(deg) + 1) * w[:, None]
        scale = np.sqrt((lhs * lhs).sum(axis=0))
        scaled = lhs / scale
        rhs = y * w
    return bool(np.isfinite(scale).all() and (scale > 0).all() and np.isfinite(scaled).all() and np.isfinite(rhs).all())


def linear_fit(x: Sequence[float], y: Sequence[float]) -> dict:
    """Least-squares line y = slope x + intercept; returns slope, intercept and R^2 (nan-safe; nan where
    no line is posed, :func:`polyfit_ready`)."""
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    ok = np.isfinite(x) & np.isfinite(y)
    x, y = x[ok], y[ok]
    if x.size < 2 or np.ptp(x) == 0 or not polyfit_ready(x, y, 1):
        return {"slope": float("nan"), "intercept": float("nan"), "r2": float("nan"), "n": int(x.size)}
    slope, intercept = np.polyfit(x, y, 1)
    resid = y - (slope * x + intercept)
    sst = float(np.sum((y - y.mean()) ** 2))
    r2 = 1.0 - float(np.sum(resid**2)) / sst if sst > 0 else float("nan")
    return {"slope": float(slope), "intercept": float(intercept), "r2": r2, "n": int(x.size)}


def pearson_r(x: Sequence[float], y: Sequence[float]) -> float:
    """Pearson correlation coefficient of finite pairs (nan if undefined)."""
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    ok = np.isfinite(x) & np.isfinite(y)
    x, y = x[ok], y[ok]
    if x.size < 3 or np.std(x) == 0 or np.std(y) == 0:
        return float("nan")
    return float(np.corrcoef(x, y)[0, 1])


def poly_peak(x: Sequence[float], y: Sequence[float], deg: int = 6, n_grid: int = 4001) -> dict:
    """Fit a polynomial (numpy.polyfit, unweighted, as the seed paper) and locate its maximum.

    The degree is ``min(deg, number of points - 1)``.  The maximum is searched
    on a grid of ``n_grid`` points over ``[min(x), max(x)]`` (no extrapolation).
    Returns ``deg`` (used), ``coeffs`` (highest power first), ``x_peak``,
    ``y_peak``, ``interior`` (True if the maximum is not at an end of the range)
    and ``local_maxima`` (x of interior local maxima, from the derivative's
    real roots with negative second derivative).
    """
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    ok = np.isfinite(x) & np.isfinite(y)
    x, y = x[ok], y[ok]
    if x.size < 2 or not polyfit_ready(x, y, min(deg, x.size - 1)):
        return {
            "deg": 0,
            "coeffs": [],
            "x_peak": float("nan"),
            "y_peak": float("nan"),
            "interior": False,
            "local_maxima": [],
        }
    d = int(min(deg, x.size - 1))
    coeffs = np.polyfit(x, y, d)
    grid = np.linspace(x.min(), x.max(), n_grid)
    vals = np.polyval(coeffs, grid)
    k = int(np.argmax(vals))
    dp = np.polyder(coeffs)
    ddp = np.polyder(dp)
    local = []
    if dp.size > 1:
        for r in np.roots(dp):
            if (
                abs(r.imag) < 1e-9 * max(1.0, abs(r.real))
                and x.min() < r.real < x.max()
                and np.polyval(ddp, r.real) < 0
            ):
                local.append(float(r.real))
    return {
        "deg": d,
        "coeffs": [float(c) for c in coeffs],
        "x_peak": float(grid[k]),
        "y_peak": float(vals[k]),
        "interior": 0 < k < n_grid - 1,
        "local_maxima": sorted(local),
    }
