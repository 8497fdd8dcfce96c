"""The exitance estimate of the camera's radiance (``render_view(estimator="exitance")``, issue 34).

The kernel estimate keeps only the records that left toward the camera (within 15 deg: ~3 % of them). This one
uses every record that left near the pixel's surface point, and takes the share that goes toward the camera
from the region's angular distribution of exits, calibrated locally by the records that did leave toward it:

    L_p = (1 / P) sum_{j in ball_p} e_j h_{b, g, band(j)}(mu_p) c_{p, b} / (2 pi mu_p A_p)       [per cm^2 per sr]

- ball_p: the records of the pixel's region g within r_p of its surface point x_p, r_p = max(r0, the distance
  to the k-th nearest such record); A_p = f_p pi r_p^2 in cm^2, the part of the ball's disc that is region g's
  surface: f_p is the share of region g in the surface the camera's pixels see within r_p of x_p
  (:func:`region_share`). Near a region's edge the ball is partly another
  region's, whose records it does not gather; without f_p those pixels read dark (a 1.2 cm polyp seen through
  0.15 cm balls: its white-light Weber contrast -0.26 against the next-event estimate's -0.19). Where the k-th
  record sets r_p only the k - 1 records strictly inside count (the k-nearest density (k - 1) / V, unbiased for
  a uniform density).
- h_{b, g, band}(mu): the density of mu = cos(exit direction, normal) over [0, 1] of the exits of region g in a
  20 nm band, per batch b, as a Legendre series of ``LEGENDRE_TERMS`` terms (an orthogonal-series density
  estimate: coefficient (2l + 1) E[P_l(2 mu - 1)]); mu_p the cosine of the camera direction at x_p. With
  h / 2 pi the exits' density per steradian, azimuthally symmetric: diffuse light (many scatterings,
  fluorescence emitted isotropically) leaves so.
- c_{p, b}: where the exits are not azimuthally symmetric (oblique light, few scatterings), the records that
  left within kernel_angle_deg of the camera direction, O, against the share the table predicts for the same
  records, Q = sum e h(mu_c) Omega / 2 pi: c = O / Q over the records of region g in the 27 cells (edge s, one
  grid per region) around x_p, s set so that a pixel's 27 cells hold about ``CALIBRATION_RECORDS`` records.

Every factor is made per batch from the batch's own records, so the batches stay independent estimates and
the batch-means standard errors include the noise of the tables and of the calibration. The bias is that of
the assumptions: the blur of the ball (estimated, as the kernel's, by halving r_p: ``bias``) and the angular
distribution's variation within the calibration's cells (measured against the next-event estimate:
docs/render.md, docs/performance.md section 20).
"""
from __future__ import annotations

import math

import numpy as np

#: Records each pixel's ball holds at least (render_view's ``exit_k``); see docs/render.md for the choice.
EXIT_K = 256
#: Records of a pixel's calibration neighbourhood (27 cells), about.
CALIBRATION_RECORDS = 16384
#: Legendre terms of the angular tables (degree LEGENDRE_TERMS - 1 in mu).
LEGENDRE_TERMS = 5
#: Width of the angular tables' wavelength bands, nm, from 380 nm.
BAND_NM = 20.0
#: The angular tables' bands (380-780 nm).
N_BANDS = 20


def legendre_rows(mu, terms: int = LEGENDRE_TERMS) -> np.ndarray:
    """P_l(2 mu - 1) for l < terms, (N, terms): Bonnet's recursion (l + 1) P_{l+1} = (2l + 1) t P_l - l P_{l-1}."""
    t = 2.0 * np.asarray(mu, dtype=np.float64) - 1.0
    out = np.empty(t.shape + (terms,))
    out[..., 0] = 1.0
    if terms > 1:
        out[..., 1] = t
    for l in range(1, terms - 1):
        out[..., l + 1] = ((2 * l + 1) * t * out[..., l] - l * out[..., l - 1]) / (l + 1)
    return out


def bands(wavelength_nm) -> np.ndarray:
    """The angular tables' band of each wavelength: 20 nm from 380 nm, the ends clamped."""
    b = np.floor((np.asarray(wavelength_nm, dtype=np.float64) - 380.0) / BAND_NM)
    return np.clip(np.nan_to_num(b, nan=0.0), 0, N_BANDS - 1).astype(np.int64)


def angular_tables(mu, region, band, batch, e, n_regions: int, B: int) -> np.ndarray:
    """Legendre coefficients (B, n_regions, bands, terms) of the density of mu over [0, 1] per batch, region
    and band, weighted by the records' energies e: a_l = (2l + 1) sum e P_l / sum e (0 where a cell has no
    energy). Its density at mu is ``density(a, legendre_rows(mu))``."""
    cell = (np.asarray(batch) * n_regions + np.asarray(region)) * N_BANDS + np.asarray(band)
    size = B * n_regions * N_BANDS
    rows = legendre_rows(mu)
    tot = np.bincount(cell, weights=e, minlength=size)[:size]
    mom = np.stack([np.bincount(cell, weights=e * rows[:, l], minlength=size)[:size] for l in range(rows.shape[1])], 1)
    coef = np.where(tot[:, None] > 0, mom / np.where(tot > 0, tot, 1.0)[:, None], 0.0) * (
        2 * np.arange(rows.shape[1]) + 1
    )
    return coef.reshape(B, n_regions, N_BANDS, rows.shape[1])


def density(coef_rows, rows) -> np.ndarray:
    """The tables' density of mu, sum_l a_l P_l, row by row; a truncated series can dip below 0: clamped."""
    return np.maximum(np.einsum("ij,ij->i", coef_rows, rows), 0.0)


def _cell_keys(pos, s: float) -> np.ndarray:
    """One int64 key per point of its grid cell of edge s (21 bits a coordinate, wrapped: distinct cells
    within 2^20 cells of each other never share a key)."""
    k = np.floor(np.asarray(pos) / s).astype(np.int64) & ((1 << 21) - 1)
    return (k[:, 0] << 42) | (k[:, 1] << 21) | k[:, 2]


_OFFSETS = np.array([(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)], dtype=np.float64)


def _neighbourhood_sums(rec_pos, values, batch, B: int, pix_pos, s: float) -> np.ndarray:
    """Per pixel and batch, the sums of the records' ``values`` (m, N) over the 27 cells of edge s around the
    pixel's own: (m, pixels, B)."""
    keys, inv = np.unique(_cell_keys(rec_pos, s), return_inverse=True)
    idx = inv * B + batch
    per_cell = np.stack([np.bincount(idx, weights=v, minlength=keys.size * B).reshape(keys.size, B) for v in values])
    out = np.zeros((len(values), pix_pos.shape[0], B))
    for off in _OFFSETS:
        k = _cell_keys(pix_pos + off * s, s)
        i = np.minimum(np.searchsorted(keys, k), keys.size - 1)
        found = keys[i] == k
        out[:, found] += per_cell[:, i[found]]
    return out


def _calibration_edge(rec_pos, pix_pos, s0: float, target: int) -> float:
    """The cell edge whose 27 cells around a pixel hold about ``target`` records (median over the pixels):
    records lie on surfaces, so a neighbourhood holds ~ s^2 of them; three corrections from s0."""
    s = s0
    ones, zero = np.ones((1, rec_pos.shape[0])), np.zeros(rec_pos.shape[0], dtype=np.int64)
    for _ in range(3):
        m = float(np.median(_neighbourhood_sums(rec_pos, ones, zero, 1, pix_pos, s)[0, :, 0]))
        s *= math.sqrt(target / max(m, 1.0))
    return s


def calibration(rec, e, coef, px, preg, n_regions: int, theta_deg: float, s0: float) -> np.ndarray:
    """c (pixels, B): per batch, the energy of the region's records around each pixel that left within
    theta_deg of the direction to the camera, over the share the angular tables predict for them (1 where
    they predict none). Cells per region; a region with at most CALIBRATION_RECORDS records is one cell."""
    B = rec["Pb"].size
    to_cam = rec["cam"] - rec["pos"]
    to_cam /= np.maximum(np.linalg.norm(to_cam, axis=1), 1e-300)[:, None]
    mu_c = np.clip(np.einsum("ij,ij->i", rec["normal"], to_cam), 0.0, 1.0)
    omega = 2.0 * math.pi * (1.0 - math.cos(math.radians(theta_deg)))
    q = density(coef[rec["batch"], rec["region"], rec["band"]], legendre_rows(mu_c)) * omega / (2.0 * math.pi)
    o = np.einsum("ij,ij->i", rec["dir"], to_cam) >= math.cos(math.radians(theta_deg))
    c = np.ones((px.shape[0], B))
    for g in range(n_regions):
        pix = np.flatnonzero(preg == g)
        sel = np.flatnonzero((rec["region"] == g) & (e > 0))
        if pix.size == 0 or sel.size == 0:
            continue
        vals, batch = np.stack([e[sel] * o[sel], e[sel] * q[sel]]), rec["batch"][sel]
        if sel.size <= CALIBRATION_RECORDS:  # one cell: the region's sums per batch
            O, Q = (np.bincount(batch, weights=v, minlength=B)[:B] for v in vals)
        else:
            s = _calibration_edge(rec["pos"][sel], px[pix], s0, CALIBRATION_RECORDS)
            O, Q = _neighbourhood_sums(rec["pos"][sel], vals, batch, B, px[pix], s)
        c[pix] = np.where(Q > 0, O / np.where(Q > 0, Q, 1.0), 1.0)
    return c


def pixel_radii(index, e, px, preg, r0: float, k: int, threads: int, cancel=None):
    """Per pixel, its ball's radius r_p = max(r0 (a number, or one per pixel), d_k) over the records of its own
    region with energy e > 0 (d_k the distance to the k-th nearest, or the farthest where the region has fewer
    than k; infinite, so no estimate, where it has fewer than 2), and whether d_k set it. ``index``: the render's
    ``_core.ExitIndex`` of the records (d_k exact, the same on any thread count). None once ``cancel`` (a
    ``_core.CancelToken`` or None) is set."""
    r0 = np.broadcast_to(np.asarray(r0, dtype=np.float64), (px.shape[0],))
    dk = index.kth_distance(
        (np.asarray(e) > 0).astype(np.uint8),
        px,
        np.asarray(preg, dtype=np.int32),
        int(k),
        threads=int(threads),
        cancel=cancel,
    )
    if dk is None:
        return None
    return np.maximum(r0, dk), dk > r0


def region_share(px, preg, radius, threads: int) -> np.ndarray:
    """f_p (pixels,): the share of pixel p's own region in the surface the camera's pixels see within
    ``radius[p]`` of its surface point px[p]: the pixels q there with preg[q] == preg[p] over all of them (p
    itself among them, so f_p > 0; each pixel counts once: footprints within a ball are alike); 1 where the
    radius is not finite (no estimate there)."""
    from scipy.spatial import cKDTree

    share = np.ones(px.shape[0])
    ok = np.isfinite(radius) & (radius > 0)
    if not ok.any():
        return share
    everyone = cKDTree(px)
    for g in np.unique(preg[ok]):
        pix = np.flatnonzero(ok & (preg == g))
        others = px[preg != g]
        if others.shape[0] == 0:
            continue
        # a ball that reaches no pixel of another region is all its own (f_p = 1): only the rest are counted
        near, _ = cKDTree(others).query(px[pix], k=1, workers=threads or -1)
        pix = pix[near <= radius[pix]]
        if pix.size == 0:
            continue
        own = cKDTree(px[preg == g]).query_ball_point(px[pix], radius[pix], workers=threads or -1, return_length=True)
        total = everyone.query_ball_point(px[pix], radius[pix], workers=threads or -1, return_length=True)
        share[pix] = own / np.maximum(total, 1)
    return share
