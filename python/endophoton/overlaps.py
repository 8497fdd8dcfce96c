"""Regions of equal priority that overlap: the one rule of every path (JSON, Python API, sweeps,
the Blender add-on).

Where regions overlap, the one with the higher priority is the medium there. Two regions of the
same priority that share volume leave that choice to the order they were added in, which nobody
reads off a scene file or a Blender outliner: such a scene is refused, naming both regions and
their priority. Touching regions (stacked layers sharing a face) do not overlap.

The test (:func:`equal_priority_overlaps`): for each pair of regions of one priority whose
bounding boxes share volume, points on a grid of cell centres in the common box (offset by
irrational fractions of a cell, so no point lies on an axis-aligned face or edge) are tested for
being strictly inside both closed meshes, by the parity of a ray's crossings (one ray per point
in a fixed off-axis direction, Moller-Trumbore, numpy). Up to ``MAX_POINTS`` points, fewer for
large meshes (the cost is points x triangles, bounded by ``MAX_POINT_TRIANGLE_TESTS``). An
overlap thinner than the grid's cell can escape the test; a refused scene always overlaps.
"""
from __future__ import annotations

import numpy as np

from . import det

__all__ = ["equal_priority_overlaps", "check_overlaps", "MAX_POINTS", "MAX_POINT_TRIANGLE_TESTS"]

#: Most grid points tested per pair of regions (10 x 10 x 10).
MAX_POINTS = 1000
#: Most point-triangle ray tests per pair (the grid shrinks for large meshes, at least 3 x 3 x 3).
MAX_POINT_TRIANGLE_TESTS = 20_000_000
_DIRECTION = np.array([0.5773502691896258, 0.5773869, 0.5773136])  # off every axis and diagonal
_DIRECTION = _DIRECTION / det.norm(_DIRECTION)  # endophoton.det: the same ray on every machine
_OFFSETS = np.array([0.5 - 0.1180339887, 0.5 + 0.0729490169, 0.5 - 0.0450850160])  # golden-ratio fractions


def _inside(points: np.ndarray, vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Whether each point is inside the closed mesh: odd count of crossings of the ray from it."""
    tri = np.asarray(vertices, dtype=np.float64)[np.asarray(triangles, dtype=np.int64)]
    v0, e1, e2 = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    p = np.cross(_DIRECTION, e2)
    d = det.dot(e1, p)
    ok = np.abs(d) > 1e-300
    v0, e1, e2, p, inv = v0[ok], e1[ok], e2[ok], p[ok], 1.0 / d[ok]
    counts = np.zeros(len(points), dtype=np.int64)
    step = max(1, MAX_POINT_TRIANGLE_TESTS // max(1, 8 * len(v0)))  # points per block (memory)
    for lo in range(0, len(points), step):
        s = points[lo : lo + step, None, :] - v0[None, :, :]
        u = det.dot(s, p) * inv
        q = np.cross(s, e1[None, :, :])
        v = det.dot(q, _DIRECTION) * inv
        t = det.dot(q, e2) * inv
        hit = (u > 0) & (v > 0) & (u + v < 1) & (t > 0)
        counts[lo : lo + step] = hit.sum(axis=1)
    return counts % 2 == 1


def _grid(lo: np.ndarray, hi: np.ndarray, n: int) -> np.ndarray:
    """n^3 points at offset cell centres of the box [lo, hi]."""
    axes = [lo[a] + (np.arange(n) + _OFFSETS[a]) / n * (hi[a] - lo[a]) for a in range(3)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


def _grid_side(triangles: int) -> int:
    """Points a side of the test grid: the most n with n^3 <= MAX_POINTS and n^3 x triangles <=
    MAX_POINT_TRIANGLE_TESTS, at least 3. In integers: a cube root in floating point can round a
    perfect cube's either way, and differently by processor."""
    n = 3
    while (n + 1) ** 3 <= MAX_POINTS and (n + 1) ** 3 * triangles <= MAX_POINT_TRIANGLE_TESTS:
        n += 1
    return n


def _share_volume(a, b) -> bool:
    """Whether regions ``a`` and ``b`` (of one priority) hold a common grid point inside both."""
    va, vb = np.asarray(a.vertices, dtype=np.float64), np.asarray(b.vertices, dtype=np.float64)
    lo, hi = np.maximum(va.min(axis=0), vb.min(axis=0)), np.minimum(va.max(axis=0), vb.max(axis=0))
    size = float(np.max(np.maximum(va.max(axis=0), vb.max(axis=0)) - np.minimum(va.min(axis=0), vb.min(axis=0))))
    if np.any(hi - lo <= 1e-9 * size):
        return False  # bounding boxes apart or only touching
    pts = _grid(lo, hi, _grid_side(len(a.triangles) + len(b.triangles)))
    pts = pts[_inside(pts, va, a.triangles)]
    return bool(len(pts)) and bool(_inside(pts, vb, b.triangles).any())


def equal_priority_overlaps(regions) -> list[tuple[str, str, int]]:
    """(name, name, priority) of every pair of ``regions`` (objects with ``name``, ``priority``,
    ``vertices``, ``triangles``: a Scene's regions or the add-on's exports) of equal priority that
    share volume, in the order the regions are listed."""
    found = []
    regions = list(regions)
    for i, a in enumerate(regions):
        for b in regions[i + 1 :]:
            if int(a.priority) == int(b.priority) and _share_volume(a, b):
                found.append((a.name, b.name, int(a.priority)))
    return found


def check_overlaps(regions) -> None:
    """ValueError naming the first pair of ``regions`` of equal priority that overlap."""
    found = equal_priority_overlaps(regions)
    if found:
        a, b, priority = found[0]
        raise ValueError(
            f"regions '{a}' and '{b}' overlap with the same priority = {priority}: which medium fills the "
            "overlap would depend on the order they were added. Give the one that should own it a higher "
            "priority (e.g. the polyp above the wall)"
        )
