"""Analysis of the surface photon map (escape records) of an EndoPhoton run.

Everything here is pure numpy and works on the ``escapes`` dict described in
``docs/design.md`` (one row per escaped packet, in packet order).  Only the
keys a function needs are validated; malformed input raises ``ValueError``
whose message names the offending key.

Units
-----
* positions (``position``, light and camera positions): scene units;
* ``max_depth``: cm (as recorded by the engine);
* ``energy``: weight x 500 nm / wavelength (dimensionless, see design.md);
* angles: degrees unless a name ends in ``_rad``.

Standard errors: batch means
----------------------------
Every statistic carries a standard error computed by *batch means*.  The packet
index range ``[0, P)`` (``P`` = number of packets traced, default
``max(packet) + 1``) is split into ``B`` contiguous batches (``B = 20`` by
default); batch ``b`` holds the packets ``[floor(b P / B), floor((b+1) P / B))``
and therefore every record of those packets.  Packets are independent, so the
batches are independent replicas of the experiment.

* mean-type statistic per packet (e.g. energy per packet traced): evaluated per
  batch (batch sum / packets in the batch); value = overall estimate;
  stderr = sd(batch values, ddof=1) / sqrt(B);
* ratio statistic (e.g. important fraction = important / stored, mean energy per
  stored record): the ratio is computed per batch; value = overall ratio;
  stderr = sd(batch ratios, ddof=1) / sqrt(B) (batches whose denominator is 0 are
  left out and B is reduced accordingly);
* sum-type statistic (a histogram count = sum of the B batch counts):
  stderr = sqrt(B) * sd(batch counts, ddof=1), i.e. B times the standard error
  of the batch mean;
* maximum (``max_depth``): the maximum has no batch-means standard error; we
  report the per-batch maxima's mean and sd as a spread measure
  (:func:`max_depth_spread`).

Undefined values: these are numeric helpers, and an undefined statistic (a ratio
over nothing, a fit through fewer than two points) is ``nan`` here, the working
value of numpy arithmetic.  A result the package returns turns it into ``None``
(:func:`endophoton.io.no_nan`: the sweep rows, ``report.compute_trends``).
"""

from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np

__all__ = [
    "DEFAULT_BATCHES",
    "batch_index",
    "batch_se",
    "exit_direction_histogram",
    "exit_angles",
    "important_mask",
    "important_fraction",
    "total_energy",
    "mean_energy_per_record",
    "record_rate",
    "max_depth",
    "max_depth_spread",
    "azimuthal_uniformity_test",
    "chi2_sf",
    "azimuth_asymmetry",
    "ring_bin_edges",
    "linear_fit",
    "pearson_r",
    "poly_peak",
]

DEFAULT_BATCHES = 20


# --------------------------------------------------------------------------
# validation helpers
# --------------------------------------------------------------------------


def _column(
    escapes: Mapping[str, Any], key: str, ndim: int, width: int | None = None, n: int | None = None
) -> np.ndarray:
    """Return ``escapes[key]`` as a numpy array after checking its shape.

    Raises ``ValueError`` naming ``key`` when it is missing, has the wrong shape,
    the wrong row count, or contains non-finite values.
    """
    if not isinstance(escapes, Mapping):
        raise ValueError(f"escapes must be a dict of numpy arrays, got {type(escapes).__name__}")
    if key not in escapes or escapes[key] is None:
        raise ValueError(f"escapes: missing key '{key}'")
    a = np.asarray(escapes[key])
    if a.ndim != ndim or (width is not None and a.shape[1] != width):
        want = f"(K,{width})" if width is not None else "(K,)"
        raise ValueError(f"escapes['{key}']: shape {a.shape} must be {want}")
    if n is not None and a.shape[0] != n:
        raise ValueError(f"escapes['{key}']: {a.shape[0]} rows, expected {n} (same as 'packet')")
    if a.dtype.kind not in "biuf":
        raise ValueError(f"escapes['{key}']: dtype {a.dtype} is not numeric")
    if a.dtype.kind == "f" and a.size and not np.all(np.isfinite(a)):
        raise ValueError(f"escapes['{key}']: contains non-finite values")
    return a


def _packets(escapes: Mapping[str, Any]) -> np.ndarray:
    p = _column(escapes, "packet", 1)
    if p.dtype.kind == "f":
        raise ValueError(f"escapes['packet']: dtype {p.dtype} must be an integer type")
    if p.size and p.dtype.kind == "i" and p.min() < 0:
        raise ValueError("escapes['packet']: negative packet index")
    return p.astype(np.int64)


def _unit_rows(a: np.ndarray, key: str) -> np.ndarray:
    a = a.astype(np.float64)
    norm = np.linalg.norm(a, axis=1)
    if a.shape[0] and np.any(norm < 1e-12):
        raise ValueError(f"escapes['{key}']: zero-length vector in row {int(np.argmax(norm < 1e-12))}")
    return a / norm[:, None]


def _check_batches(n_batches: int) -> int:
    if isinstance(n_batches, bool) or not isinstance(n_batches, (int, np.integer)) or n_batches < 2:
        raise ValueError(f"n_batches = {n_batches!r} must be an integer >= 2")
    return int(n_batches)


# --------------------------------------------------------------------------
# batch means
# --------------------------------------------------------------------------


def batch_index(
    packet: np.ndarray, n_batches: int = DEFAULT_BATCHES, n_packets: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Assign each record to a contiguous packet-index batch.

    Parameters
    ----------
    packet : (K,) integer array of packet indices.
    n_batches : number of batches B (>= 2).
    n_packets : number of packets traced P (default ``max(packet) + 1``).

    Returns
    -------
    batch : (K,) int array, batch id of each record in ``[0, B)``.
    packets_per_batch : (B,) int array, number of *packets* (not records) in
        each batch; batch ``b`` covers ``[floor(b P/B), floor((b+1) P/B))``.
    """
    B = _check_batches(n_batches)
    packet = np.asarray(packet).astype(np.int64)
    if n_packets is None:
        P = int(packet.max()) + 1 if packet.size else 0
    else:
        P = int(n_packets)
        if packet.size and int(packet.max()) >= P:
            raise ValueError(f"escapes['packet']: index {int(packet.max())} >= n_packets = {P}")
    if P < B:
        raise ValueError(f"n_packets = {P} must be >= n_batches = {B} for batch means")
    edges = (np.arange(B + 1, dtype=np.int64) * P) // B
    batch = np.searchsorted(edges, packet, side="right") - 1
    return batch.astype(np.int64), np.diff(edges)


def batch_se(values: np.ndarray) -> float:
    """Standard error of the mean of independent batch values: sd(ddof=1)/sqrt(B).

    Non-finite batch values (e.g. a ratio with an empty denominator) are left
    out; with fewer than two finite values the result is ``nan``.
    """
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    if v.size < 2:
        return float("nan")
    return float(np.std(v, ddof=1) / math.sqrt(v.size))


def _batch_sums(batch: np.ndarray, values: np.ndarray, B: int) -> np.ndarray:
    return np.bincount(batch, weights=np.asarray(values, dtype=np.float64), minlength=B)[:B]


def _ratio_with_se(num_b: np.ndarray, den_b: np.ndarray) -> tuple[float, float, np.ndarray]:
    """Overall ratio sum(num)/sum(den) and the batch-means stderr of per-batch ratios."""
    den_tot = float(np.sum(den_b))
    value = float(np.sum(num_b)) / den_tot if den_tot > 0 else float("nan")
    with np.errstate(divide="ignore", invalid="ignore"):
        ratios = np.where(den_b > 0, num_b / np.where(den_b > 0, den_b, 1.0), np.nan)
    return value, batch_se(ratios), ratios


# --------------------------------------------------------------------------
# exit directions
# --------------------------------------------------------------------------


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


# --------------------------------------------------------------------------
# chi-square test (regularised incomplete gamma written out, no scipy)
# --------------------------------------------------------------------------


def _gammainc_lower_series(a: float, x: float) -> float:
    """Regularised lower incomplete gamma P(a, x) by its power series (x < a + 1)."""
    term = 1.0 / a
    total = term
    ap = a
    for _ in range(100000):
        ap += 1.0
        term *= x / ap
        total += term
        if abs(term) < abs(total) * 1e-16:
            break
    return total * math.exp(-x + a * math.log(x) - math.lgamma(a))


def _gammainc_upper_cf(a: float, x: float) -> float:
    """Regularised upper incomplete gamma Q(a, x) by Lentz's continued fraction (x >= a + 1)."""
    tiny = 1e-300
    b = x + 1.0 - a
    c = 1.0 / tiny
    d = 1.0 / b
    h = d
    for i in range(1, 100000):
        an = -i * (i - a)
        b += 2.0
        d = an * d + b
        if abs(d) < tiny:
            d = tiny
        c = b + an / c
        if abs(c) < tiny:
            c = tiny
        d = 1.0 / d
        delta = d * c
        h *= delta
        if abs(delta - 1.0) < 1e-16:
            break
    return math.exp(-x + a * math.log(x) - math.lgamma(a)) * h


def chi2_sf(x: float, dof: int) -> float:
    """Survival function P(X >= x) of the chi-square distribution with ``dof`` degrees of freedom."""
    if dof <= 0:
        raise ValueError(f"dof = {dof} must be > 0")
    if not math.isfinite(x):
        return 0.0 if x > 0 else 1.0
    if x <= 0:
        return 1.0
    a = 0.5 * dof
    xx = 0.5 * x
    if xx < a + 1.0:
        return max(0.0, 1.0 - _gammainc_lower_series(a, xx))
    return _gammainc_upper_cf(a, xx)


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


# --------------------------------------------------------------------------
# camera importance
# --------------------------------------------------------------------------


def _camera_field(camera: Any, name: str) -> Any:
    if isinstance(camera, Mapping):
        if name not in camera:
            raise ValueError(f"camera: missing key '{name}'")
        return camera[name]
    if not hasattr(camera, name):
        raise ValueError(f"camera: missing attribute '{name}'")
    return getattr(camera, name)


def _camera(camera: Any) -> dict:
    pos = np.asarray(_camera_field(camera, "position"), dtype=np.float64)
    fwd = np.asarray(_camera_field(camera, "forward"), dtype=np.float64)
    up = np.asarray(_camera_field(camera, "up"), dtype=np.float64)
    for name, v in (("position", pos), ("forward", fwd), ("up", up)):
        if v.shape != (3,) or not np.all(np.isfinite(v)):
            raise ValueError(f"camera.{name} = {v.tolist()} must be 3 finite numbers")
    fov = float(_camera_field(camera, "fov_deg"))
    if not (0.0 < fov < 180.0):
        raise ValueError(f"camera.fov_deg = {fov} must be in (0, 180)")
    res = tuple(int(r) for r in _camera_field(camera, "resolution"))
    if len(res) != 2 or min(res) <= 0:
        raise ValueError(f"camera.resolution = {res} must be (width, height) > 0")
    fn = np.linalg.norm(fwd)
    if fn < 1e-12:
        raise ValueError("camera.forward is a zero vector")
    f = fwd / fn
    r = np.cross(f, up)
    rn = np.linalg.norm(r)
    if rn < 1e-9 * max(np.linalg.norm(up), 1e-300):
        raise ValueError("camera.up is parallel to camera.forward")
    r /= rn
    u = np.cross(r, f)
    w, h = res
    t = math.tan(math.radians(fov) / 2.0)
    tx, ty = (t, t * h / w) if w >= h else (t * w / h, t)
    return dict(position=pos, forward=f, right=r, up=u, tan_x=tx, tan_y=ty)


def important_mask(escapes: Mapping[str, Any], camera: Any, max_angle_deg: float = 15.0) -> np.ndarray:
    """Boolean (K,) mask of *important* records (seed paper, §5 / Fig. 6).

    A record is important when

    1. its exit point is visible in the pinhole camera: in front of the camera
       (positive depth along ``forward``) and its perspective projection lies in
       the image rectangle.  ``fov_deg`` is the full field of view across the
       larger image dimension (Blender's AUTO sensor fit); the other dimension
       gets ``tan(fov/2) * smaller/larger``.  Occlusion is not tested (the
       paper's flat scene has none);
    2. the angle between its exit direction and the direction from the exit
       point to the camera position is <= ``max_angle_deg``.

    ``camera`` is a dict or an object with ``position`` (scene units),
    ``forward``, ``up`` (need not be orthogonal to forward), ``fov_deg`` and
    ``resolution`` = (width, height) in pixels.
    """
    cam = _camera(camera)
    if not (0.0 <= float(max_angle_deg) <= 180.0):
        raise ValueError(f"max_angle_deg = {max_angle_deg} must be in [0, 180]")
    pos = _column(escapes, "position", 2, 3).astype(np.float64)
    d = _unit_rows(_column(escapes, "direction", 2, 3, pos.shape[0]), "direction")
    rel = pos - cam["position"]
    z = rel @ cam["forward"]
    x = rel @ cam["right"]
    y = rel @ cam["up"]
    with np.errstate(divide="ignore", invalid="ignore"):
        visible = (z > 0) & (np.abs(x) <= cam["tan_x"] * z) & (np.abs(y) <= cam["tan_y"] * z)
    to_cam = -rel
    dist = np.linalg.norm(to_cam, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        cosang = np.einsum("ij,ij->i", d, to_cam) / dist
    cosang = np.where(dist > 0, cosang, -1.0)
    return visible & (cosang >= math.cos(math.radians(float(max_angle_deg))) - 1e-12)


def important_fraction(
    escapes: Mapping[str, Any],
    camera: Any,
    max_angle_deg: float = 15.0,
    n_batches: int = DEFAULT_BATCHES,
    n_packets: int | None = None,
    return_batches: bool = False,
):
    """Fraction of stored records that are *important* (see :func:`important_mask`).

    Ratio statistic: value = (#important) / (#records); stderr = sd over the B
    packet batches of the per-batch fraction / sqrt(B).  Returns
    ``(value, stderr)`` (dimensionless), plus the per-batch fractions when
    ``return_batches``.
    """
    B = _check_batches(n_batches)
    packet = _packets(escapes)
    mask = important_mask(escapes, camera, max_angle_deg)
    if mask.shape[0] != packet.shape[0]:
        raise ValueError(f"escapes['packet']: {packet.shape[0]} rows, expected {mask.shape[0]}")
    if packet.size == 0:
        raise ValueError("escapes['packet']: no records")
    batch, _ = batch_index(packet, B, n_packets)
    num = _batch_sums(batch, mask.astype(np.float64), B)
    den = _batch_sums(batch, np.ones(packet.size), B)
    value, se, ratios = _ratio_with_se(num, den)
    return (value, se, ratios) if return_batches else (value, se)


# --------------------------------------------------------------------------
# energy, record rate, depth
# --------------------------------------------------------------------------


def total_energy(
    escapes: Mapping[str, Any],
    n_packets: int | None = None,
    per_packet: bool = False,
    n_batches: int = DEFAULT_BATCHES,
    return_batches: bool = False,
):
    """Total energy of the escape records (units of ``energy``: weight x 500 nm / lambda).

    ``per_packet=False`` (default): value = sum of ``energy`` over all records.
    ``per_packet=True``: value = that sum / P, the energy escaping per packet
    traced (P = ``n_packets``, default ``max(packet)+1``).

    Standard error: per batch b the energy per packet e_b = (sum of energy in
    batch b) / (packets in batch b); se(per packet) = sd(e_b)/sqrt(B); the total
    is P x (energy per packet), so se(total) = P x se(per packet).
    Returns ``(value, stderr)`` (+ per-batch per-packet values if ``return_batches``).
    """
    B = _check_batches(n_batches)
    packet = _packets(escapes)
    e = _column(escapes, "energy", 1, None, packet.shape[0]).astype(np.float64)
    batch, ppb = batch_index(packet, B, n_packets)
    P = int(ppb.sum())
    sums = _batch_sums(batch, e, B)
    per = sums / ppb
    se_per = batch_se(per)
    total = float(e.sum())
    if per_packet:
        out = (total / P, se_per)
    else:
        out = (total, P * se_per)
    return (*out, per) if return_batches else out


def mean_energy_per_record(
    escapes: Mapping[str, Any],
    n_packets: int | None = None,
    n_batches: int = DEFAULT_BATCHES,
    return_batches: bool = False,
):
    """Mean ``energy`` per stored record (ratio statistic: per-batch ratio, sd/sqrt(B)).

    The seed's "total energy of the N stored photons" is N times this value.
    """
    B = _check_batches(n_batches)
    packet = _packets(escapes)
    e = _column(escapes, "energy", 1, None, packet.shape[0]).astype(np.float64)
    if packet.size == 0:
        raise ValueError("escapes['packet']: no records")
    batch, _ = batch_index(packet, B, n_packets)
    value, se, ratios = _ratio_with_se(_batch_sums(batch, e, B), _batch_sums(batch, np.ones(e.size), B))
    return (value, se, ratios) if return_batches else (value, se)


def record_rate(
    escapes: Mapping[str, Any], n_packets: int, n_batches: int = DEFAULT_BATCHES, return_batches: bool = False
):
    """Records stored per packet traced (records / P), with batch-means stderr.

    In store-N mode the number of packets traced is N / rate, so its relative
    stderr equals the relative stderr of the rate (delta method).
    """
    B = _check_batches(n_batches)
    packet = _packets(escapes)
    batch, ppb = batch_index(packet, B, n_packets)
    per = _batch_sums(batch, np.ones(packet.size), B) / ppb
    value = packet.size / float(ppb.sum())
    se = batch_se(per)
    return (value, se, per) if return_batches else (value, se)


def max_depth(escapes: Mapping[str, Any]) -> float:
    """Deepest ``max_depth`` over all records, in cm (positive = below the entry surface).

    The seed paper plots this as a negative number (about -0.12 cm).
    """
    md = _column(escapes, "max_depth", 1)
    if md.size == 0:
        raise ValueError("escapes['max_depth']: no records")
    return float(md.max())


def max_depth_spread(
    escapes: Mapping[str, Any],
    n_batches: int = DEFAULT_BATCHES,
    n_packets: int | None = None,
    return_batches: bool = False,
):
    """Uncertainty proxy for :func:`max_depth`: mean and sd (ddof=1) of the B per-batch maxima (cm).

    A sample maximum has no batch-means standard error (it is not an average);
    the spread of the batch maxima shows how much the deepest record fluctuates
    between independent sub-runs of P/B packets.  Note the batch maxima are
    biased low relative to the full-run maximum.  Batches without records are
    left out.
    """
    B = _check_batches(n_batches)
    packet = _packets(escapes)
    md = _column(escapes, "max_depth", 1, None, packet.shape[0]).astype(np.float64)
    if md.size == 0:
        raise ValueError("escapes['max_depth']: no records")
    batch, _ = batch_index(packet, B, n_packets)
    mx = np.full(B, -np.inf)
    np.maximum.at(mx, batch, md)
    mx = np.where(np.isfinite(mx), mx, np.nan)
    good = mx[np.isfinite(mx)]
    mean = float(good.mean())
    sd = float(good.std(ddof=1)) if good.size > 1 else float("nan")
    return (mean, sd, mx) if return_batches else (mean, sd)


# --------------------------------------------------------------------------
# trends over the sweep (plain least squares, used by plots and report)
# --------------------------------------------------------------------------


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
