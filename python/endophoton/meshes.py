"""Closed triangle meshes for scene building; their check is the engine's (native/mesh_check.h).

All generators return ``(vertices, triangles)`` with ``vertices`` float32 (N,3)
in the caller's length unit and ``triangles`` uint32 (M,3) wound
counter-clockwise when seen from outside (outward normals), as
``docs/design.md`` requires.  The meshes are closed 2-manifolds: every edge is
shared by exactly two triangles, traversed in opposite directions.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from . import _core, det

__all__ = ["ellipsoid", "uv_sphere", "half_ellipsoid", "check_closed_mesh", "signed_volume"]


def _validate_counts(n_lat: int, n_lon: int, min_lat: int) -> None:
    if int(n_lat) < min_lat:
        raise ValueError(f"n_lat = {n_lat} must be >= {min_lat}")
    if int(n_lon) < 3:
        raise ValueError(f"n_lon = {n_lon} must be >= 3")


def _validate_axes(center: Sequence[float], radii: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    c = np.asarray(center, dtype=np.float64)
    r = np.asarray(radii, dtype=np.float64)
    if c.shape != (3,) or not np.all(np.isfinite(c)):
        raise ValueError(f"center = {center!r} must be 3 finite numbers")
    if r.shape != (3,) or not np.all(np.isfinite(r)) or np.any(r <= 0):
        raise ValueError(f"radii = {radii!r} must be 3 finite numbers > 0")
    return c, r


def _rings(thetas: np.ndarray, n_lon: int) -> np.ndarray:
    """Unit-sphere points on latitude rings (polar angle theta from +z), shape (len(thetas)*n_lon, 3).
    sin and cos are endophoton.det's, not numpy's (whose kernels differ by processor): a mesh is a scene
    input, the same bits on every machine."""
    phi = 2.0 * math.pi * np.arange(n_lon) / n_lon
    st, ct = det.sin(thetas)[:, None], det.cos(thetas)[:, None]
    pts = np.stack(
        [st * det.cos(phi)[None, :], st * det.sin(phi)[None, :], np.broadcast_to(ct, (thetas.size, n_lon))], axis=-1
    )
    return pts.reshape(-1, 3)


def _band(first_ring_start: int, n_rings: int, n_lon: int) -> list[tuple[int, int, int]]:
    """Quads between consecutive rings (ring k above ring k+1), split in two CCW triangles."""
    tris = []
    for k in range(n_rings - 1):
        a0 = first_ring_start + k * n_lon
        b0 = a0 + n_lon
        for j in range(n_lon):
            j1 = (j + 1) % n_lon
            a, a1, b, b1 = a0 + j, a0 + j1, b0 + j, b0 + j1
            # seen from outside, going down (+theta) then east (+phi) is counter-clockwise
            tris.append((a, b, b1))
            tris.append((a, b1, a1))
    return tris


def ellipsoid(
    center: Sequence[float] = (0.0, 0.0, 0.0),
    radii: Sequence[float] = (1.0, 1.0, 1.0),
    n_lat: int = 24,
    n_lon: int = 48,
) -> tuple[np.ndarray, np.ndarray]:
    """Closed UV ellipsoid with semi-axes ``radii`` (x, y, z) about ``center`` (caller's units).

    ``n_lat`` latitude bands between the poles, ``n_lon`` segments around.
    Returns float32 vertices and uint32 CCW-outward triangles.
    """
    _validate_counts(n_lat, n_lon, 2)
    c, r = _validate_axes(center, radii)
    thetas = math.pi * np.arange(1, n_lat) / n_lat
    ring = _rings(thetas, n_lon)
    verts = np.vstack([[0.0, 0.0, 1.0], ring, [0.0, 0.0, -1.0]])
    top, first, bottom = 0, 1, 1 + ring.shape[0]
    tris: list[tuple[int, int, int]] = []
    for j in range(n_lon):
        tris.append((top, first + j, first + (j + 1) % n_lon))
    tris += _band(first, n_lat - 1, n_lon)
    last = first + (n_lat - 2) * n_lon
    for j in range(n_lon):
        tris.append((bottom, last + (j + 1) % n_lon, last + j))
    v = verts * r[None, :] + c[None, :]
    return v.astype(np.float32), np.asarray(tris, dtype=np.uint32)


def uv_sphere(
    center: Sequence[float] = (0.0, 0.0, 0.0), radius: float = 1.0, n_lat: int = 24, n_lon: int = 48
) -> tuple[np.ndarray, np.ndarray]:
    """Closed UV sphere of ``radius`` about ``center`` (caller's units)."""
    return ellipsoid(center, (radius, radius, radius), n_lat, n_lon)


def half_ellipsoid(
    center: Sequence[float] = (0.0, 0.0, 0.0),
    radii: Sequence[float] = (1.0, 1.0, 1.0),
    n_lat: int = 12,
    n_lon: int = 48,
    upper: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """Closed half ellipsoid (a dome or a bowl) with a flat elliptic base through ``center``.

    ``upper=True``: the dome ``z >= center_z`` (base facing -z); ``upper=False``:
    the bowl ``z <= center_z`` (lid facing +z).  ``n_lat`` bands from the base
    rim to the pole.  Float32 vertices, uint32 CCW-outward triangles.
    """
    _validate_counts(n_lat, n_lon, 1)
    c, r = _validate_axes(center, radii)
    # build the upper dome in local coordinates, mirror for the bowl
    thetas = math.pi / 2.0 * np.arange(n_lat, 0, -1) / n_lat  # rim (pi/2) ... first ring below pole
    ring = _rings(thetas[::-1], n_lon)  # ordered pole-side ring first
    n_r = thetas.size
    verts = np.vstack([[0.0, 0.0, 1.0], ring, [0.0, 0.0, 0.0]])
    pole, first, base = 0, 1, 1 + ring.shape[0]
    tris: list[tuple[int, int, int]] = []
    for j in range(n_lon):
        tris.append((pole, first + j, first + (j + 1) % n_lon))
    tris += _band(first, n_r, n_lon)
    rim = first + (n_r - 1) * n_lon
    for j in range(n_lon):  # base disk, facing -z
        tris.append((base, rim + (j + 1) % n_lon, rim + j))
    t = np.asarray(tris, dtype=np.int64)
    if not upper:
        verts = verts * np.array([1.0, 1.0, -1.0])
        t = t[:, ::-1]  # mirroring flips the winding
    v = verts * r[None, :] + c[None, :]
    return v.astype(np.float32), np.ascontiguousarray(t).astype(np.uint32)


def signed_volume(vertices: np.ndarray, triangles: np.ndarray) -> float:
    """Signed volume (caller's units cubed); positive for a closed mesh with outward winding."""
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    a, b, c = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def check_closed_mesh(vertices: np.ndarray, triangles: np.ndarray, owner: str = "mesh") -> dict:
    """Raise ``ValueError`` unless the mesh is closed, consistently wound and outward.

    The rule has one owner, the engine's mesh checker (native/mesh_check.h, the
    same check every region gets in ``Scene.add_mesh``): finite coordinates, no
    degenerate triangle, every directed edge used once and its reverse once
    after welding coincident vertices (closed, consistently oriented), and a
    positive signed volume (outward normals).  The message names ``owner``, the
    field and the value.  Returns ``dict(signed_volume, bbox_min, bbox_max,
    welded_vertices)``.
    """
    return _core.check_mesh(owner, vertices, triangles)
