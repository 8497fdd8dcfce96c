"""Exit directions of the escape records: elevation and azimuth in each exit's surface frame,
their (elevation ring, azimuth) histogram with batch-means errors, the azimuth asymmetry and
the chi-square test of azimuthal uniformity (the seed's Fig. 8/9)."""

from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np

from .batches import DEFAULT_BATCHES, _check_batches, _column, _packets, _unit_rows, batch_index
from .chi_square import chi2_sf


def ring_bin_edges(n_elev: int = 10, n_azim: int = 36) -> tuple[np.ndarray, np.ndarray]:
    """Bin edges in degrees: elevation ``[0, 90]`` in ``n_elev`` bins, azimuth ``[0, 360]`` in ``n_azim``."""
    return np.linspace(0.0, 90.0, n_elev + 1), np.linspace(0.0, 360.0, n_azim + 1)


def _light_positions(light_positions: Any) -> np.ndarray:
    lp = np.asarray(light_positions, dtype=np.float64)
    if lp.ndim == 1 and lp.shape == (3,):
        lp = lp[None, :]
    if lp.ndim != 2 or lp.shape[1] != 3 or lp.shape[0] == 0:
        raise ValueError(f"light_positions: shape {lp.shape} must be (L,3)")
    if not np.all(np.isfinite(lp)):
        raise ValueError("light_positions: contains non-finite values")
    return lp


def exit_angles(
    escapes: Mapping[str, Any], light_positions: Any, inward_tol: float = 1e-3, reference: Any = None
) -> tuple[np.ndarray, np.ndarray]:
    """Elevation and azimuth (degrees) of every exit direction in its local surface frame.

    Frame at each exit point (all vectors in world/scene coordinates):

    * ``n`` = the record's ``normal`` (normalised);
    * ``u`` (azimuth 0), default *light frame* (``reference=None``): projection
      of (light position - exit position) onto the tangent plane, normalised;
      the light is ``light_positions[record['light']]`` (scene units).
      *Fixed frame* (``reference`` = a world direction, 3 numbers): projection
      of ``reference`` onto the tangent plane (``light_positions`` and the
      ``light`` column are then not used).  If the projection is shorter than
      1e-6 of the vector's length (light straight above the exit point, or
      reference along the normal) ``u`` falls back to the projection of world
      +x, and if that is degenerate too (normal along x) to world +y;
    * ``v = n x u``.

    elevation = asin(d . n) in [0, 90] (0 grazing, 90 along the normal);
    azimuth = atan2(d . v, d . u) in [0, 360): 0 points toward the light,
    90 is counter-clockwise when seen from outside (looking down the normal),
    180 points away from the light (forward scattering of oblique light).

    Directions with ``d . n < -inward_tol`` point into the surface, which no
    escape record should do: ``ValueError`` naming ``direction``.  Values in
    ``[-inward_tol, 0)`` (float32 round-off at grazing exit) count as elevation 0.
    """
    pos = _column(escapes, "position", 2, 3).astype(np.float64)
    K = pos.shape[0]
    d = _unit_rows(_column(escapes, "direction", 2, 3, K), "direction")
    nrm = _unit_rows(_column(escapes, "normal", 2, 3, K), "normal")
    if reference is None:
        light = _column(escapes, "light", 1, None, K)
        if light.dtype.kind == "f":
            raise ValueError(f"escapes['light']: dtype {light.dtype} must be an integer type")
        lp = _light_positions(light_positions)
        light = light.astype(np.int64)
        if K and (light.min() < 0 or light.max() >= lp.shape[0]):
            raise ValueError(
                f"escapes['light']: index {int(light.max())} out of range for " f"{lp.shape[0]} light position(s)"
            )
        to_light = lp[light] - pos
    else:
        ref = np.asarray(reference, dtype=np.float64)
        if ref.shape != (3,) or not np.all(np.isfinite(ref)) or np.linalg.norm(ref) == 0:
            raise ValueError(f"reference = {reference!r} must be a finite non-zero 3-vector")
        to_light = np.broadcast_to(ref / np.linalg.norm(ref), (K, 3))
    cos_el = np.einsum("ij,ij->i", d, nrm)
    if K and cos_el.min() < -inward_tol:
        i = int(np.argmin(cos_el))
        raise ValueError(
            f"escapes['direction']: row {i} points into the surface " f"(direction . normal = {cos_el[i]:.3g})"
        )
    elev = np.degrees(np.arcsin(np.clip(cos_el, 0.0, 1.0)))

    dist = np.linalg.norm(to_light, axis=1)
    u = to_light - np.einsum("ij,ij->i", to_light, nrm)[:, None] * nrm
    ulen = np.linalg.norm(u, axis=1)
    bad = ulen <= 1e-6 * np.maximum(dist, 1e-300)
    if np.any(bad):
        for ref in (np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])):
            r = ref[None, :] - (nrm[bad] @ ref)[:, None] * nrm[bad]
            rlen = np.linalg.norm(r, axis=1)
            ok = rlen > 1e-6
            idx = np.flatnonzero(bad)[ok]
            u[idx] = r[ok]
            ulen[idx] = rlen[ok]
            bad[idx] = False
            if not np.any(bad):
                break
    u = u / ulen[:, None]
    v = np.cross(nrm, u)
    az = np.degrees(np.arctan2(np.einsum("ij,ij->i", d, v), np.einsum("ij,ij->i", d, u)))
    az = np.mod(az, 360.0)
    az[az >= 360.0] = 0.0  # mod can round up to 360 for tiny negative inputs
    return elev, az


def _bin_angles(elev: np.ndarray, az: np.ndarray, n_elev: int, n_azim: int) -> tuple[np.ndarray, np.ndarray]:
    ie = np.minimum((elev / (90.0 / n_elev)).astype(np.int64), n_elev - 1)
    ia = np.minimum((az / (360.0 / n_azim)).astype(np.int64), n_azim - 1)
    return ie, ia


def exit_direction_histogram(
    escapes: Mapping[str, Any],
    light_positions: Any,
    n_elev: int = 10,
    n_azim: int = 36,
    n_batches: int = DEFAULT_BATCHES,
    n_packets: int | None = None,
    return_batches: bool = False,
    reference: Any = None,
):
    """Histogram of exit directions over (elevation ring, azimuth bin), as the seed's Fig. 8/9.

    Parameters
    ----------
    escapes : escape-record dict (needs ``position``, ``direction``, ``normal``,
        ``light``, ``packet``).
    light_positions : (L,3) light positions in scene units; ``record['light']``
        indexes it.
    n_elev, n_azim : number of elevation bins over [0, 90] deg (default 10 of 9 deg)
        and azimuth bins over [0, 360) deg (default 36 of 10 deg).  Bin
        ``[i, j]`` covers elevations ``[i*90/n_elev, (i+1)*90/n_elev)`` (the last
        includes 90) and azimuths ``[j*360/n_azim, (j+1)*360/n_azim)``.
    n_batches, n_packets : batch-means setup (see module docstring).
    return_batches : also return the (B, n_elev, n_azim) per-batch counts.
    reference : ``None`` = light frame (azimuth 0 toward the record's light);
        a world direction = fixed frame (azimuth 0 along its tangent projection);
        see :func:`exit_angles`.

    Returns
    -------
    counts : (n_elev, n_azim) float array, number of records per bin.
    stderr : (n_elev, n_azim) float array, sqrt(B) * sd(batch counts).
    batches : (B, n_elev, n_azim) float array, only if ``return_batches``.

    The angle conventions are those of :func:`exit_angles`.
    """
    if int(n_elev) < 1 or int(n_azim) < 1:
        raise ValueError(f"n_elev = {n_elev}, n_azim = {n_azim} must be >= 1")
    B = _check_batches(n_batches)
    packet = _packets(escapes)
    elev, az = exit_angles(escapes, light_positions, reference=reference)
    if elev.shape[0] != packet.shape[0]:
        raise ValueError(f"escapes['packet']: {packet.shape[0]} rows, expected {elev.shape[0]}")
    batch, _ = batch_index(packet, B, n_packets)
    ie, ia = _bin_angles(elev, az, n_elev, n_azim)
    flat = (batch * n_elev + ie) * n_azim + ia
    per_batch = np.bincount(flat, minlength=B * n_elev * n_azim).astype(np.float64)
    per_batch = per_batch.reshape(B, n_elev, n_azim)
    counts = per_batch.sum(axis=0)
    stderr = math.sqrt(B) * np.std(per_batch, axis=0, ddof=1)
    if return_batches:
        return counts, stderr, per_batch
    return counts, stderr


def azimuth_asymmetry(counts: np.ndarray, rings: Sequence[int] | slice | None = None) -> float:
    """Mean cosine of the azimuth, ``sum(c cos(phi)) / sum(c)``, over the chosen elevation rings.

    ``phi`` is the bin-centre azimuth.  0 means no preferred direction, negative
    values mean the exits lean toward azimuth 180 deg (away from the light),
    positive toward the light.  ``counts`` is (n_elev, n_azim) or (B, n_elev, n_azim)
    (then one value per batch is returned as an array).
    """
    c = np.asarray(counts, dtype=np.float64)
    if c.ndim not in (2, 3):
        raise ValueError(f"counts: shape {c.shape} must be (n_elev, n_azim) or (B, n_elev, n_azim)")
    n_azim = c.shape[-1]
    phi = np.radians((np.arange(n_azim) + 0.5) * 360.0 / n_azim)
    sel = c[..., rings if rings is not None else slice(None), :]
    num = (sel * np.cos(phi)).sum(axis=(-2, -1))
    den = sel.sum(axis=(-2, -1))
    with np.errstate(divide="ignore", invalid="ignore"):
        out = np.where(den > 0, num / np.where(den > 0, den, 1.0), np.nan)
    return float(out) if out.ndim == 0 else out


def azimuthal_uniformity_test(counts: np.ndarray) -> np.ndarray:
    """Pearson chi-square test of azimuthal uniformity, one p-value per elevation ring.

    ``counts`` is the (n_elev, n_azim) histogram of *record counts* (not
    weights).  For ring i with total N_i the expected count per azimuth bin is
    E = N_i / n_azim, X^2 = sum (c - E)^2 / E, dof = n_azim - 1, and the p-value
    is P(chi2_dof >= X^2).  Rings with no records get ``nan``.  Small p means
    the ring is not azimuthally uniform (expected at beta = 0 only: uniform).
    """
    c = np.asarray(counts, dtype=np.float64)
    if c.ndim != 2 or c.shape[1] < 2:
        raise ValueError(f"counts: shape {c.shape} must be (n_elev, n_azim) with n_azim >= 2")
    if np.any(c < 0) or not np.all(np.isfinite(c)):
        raise ValueError("counts: must be finite and >= 0")
    n_azim = c.shape[1]
    out = np.full(c.shape[0], np.nan)
    for i, row in enumerate(c):
        tot = row.sum()
        if tot <= 0:
            continue
        e = tot / n_azim
        x2 = float(np.sum((row - e) ** 2) / e)
        out[i] = chi2_sf(x2, n_azim - 1)
    return out
