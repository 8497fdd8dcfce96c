"""Where the endoscope head may be: in the ambient medium, clear of every region.

Two rules (docs/numerics.md, "The endoscope head at the extremes"):

* **The front face** (the disk of ``head_diameter_mm`` at the lens, which carries the light guides
  and the camera's aperture) must neither cross nor touch a region's surface. A face in the wall
  launches light inside the tissue and puts the camera there, and the engine's head body, opaque
  only to light arriving from the ambient, would let the light that leaves the wall under a touching
  face pass through it: :func:`check_rig` raises a ValueError naming the region and the rig's
  placement. The test is exact up to a contact tolerance (numpy, every triangle of every region
  against the closed disk): contact within ``FACE_TOLERANCE`` (|front| + radius) scene units counts,
  the engine's own crossing tolerance (docs/numerics.md, "Huge mus").
* **The body behind the face** (``head_length_mm``, 50 mm by default) may pass through a region:
  a straight 50 mm head in a 5 cm colon reaches the opposite wall. The engine stops light on the
  body only where the body lies in the ambient, so :func:`check_rig` returns a warning for the run's
  ``Result.warnings`` naming the region. The body is probed by 64 rays along its side, its back
  rim and back face (Embree; the probes stop where the scene's bounding box ends) and by every region
  vertex inside the cylinder. A head beyond the engine's coordinate limit is left to the engine, which
  refuses it by name.

Lengths in scene units. Dot products, lengths, sines and cosines are endophoton.det's, so that the
verdict and the warning are the same on every machine, as the run's bits are.
"""
from __future__ import annotations

import math

import numpy as np

from . import _core, det
from .io import shown
from .scene import Scene
from .scene_schema import MAX_COORDINATE
from .sources import EndoscopeRig
from .sweep.schema import beta_text

__all__ = ["check_rig", "face_contact", "FACE_TOLERANCE"]

#: Contact tolerance of the front face, relative to |front| + radius (the engine's 2e-6 crossing tolerance).
FACE_TOLERANCE = 2e-6
_PROBES = 64


def _segment_distance2(p, q, c):
    """Squared distance from point c (3,) to the segments p-q (K,3) (a zero-length segment is a point)."""
    e = q - p
    ee = det.dot(e, e)
    t = np.where(ee > 0, det.dot(c - p, e) / np.where(ee > 0, ee, 1.0), 0.0)
    d = p + np.clip(t, 0.0, 1.0)[:, None] * e - c
    return det.dot(d, d)


def face_contact(vertices, triangles, centre, normal, radius, tol) -> bool:
    """Whether a closed triangle mesh meets the closed disk (``centre``, unit ``normal``, ``radius``)
    within ``tol`` (scene units): a triangle crossing or touching the disk's plane inside the disk, or
    lying in it over the disk."""
    c = np.asarray(centre, dtype=np.float64)
    f = np.asarray(normal, dtype=np.float64)
    v = np.asarray(vertices, dtype=np.float64)
    s_v = det.dot(v - c, f)
    s = s_v[triangles]
    cand = np.flatnonzero((s.min(axis=1) <= tol) & (s.max(axis=1) >= -tol))
    if cand.size == 0:
        return False
    a = v[triangles[cand]]  # (K, 3, 3)
    s = s[cand]
    near = np.abs(s) <= tol
    proj = a - s[..., None] * f
    pts, ok = [proj[:, i] for i in range(3)], [near[:, i] for i in range(3)]
    for i, j in ((0, 1), (1, 2), (2, 0)):
        si, sj = s[:, i], s[:, j]
        cross = ((si > tol) & (sj < -tol)) | ((si < -tol) & (sj > tol))
        w = np.where(cross, si / np.where(cross, si - sj, 1.0), 0.0)
        pts.append(a[:, i] + w[:, None] * (a[:, j] - a[:, i]))
        ok.append(cross)
    r2 = (radius + tol) ** 2
    # The contact set of each triangle is the hull of its valid points: a point, a segment or the triangle.
    for i in range(6):
        for j in range(i, 6):
            both = ok[i] & ok[j]
            if both.any() and np.any(_segment_distance2(pts[i][both], pts[j][both], c) <= r2):
                return True
    flat = near.all(axis=1)  # lying in the plane: does the triangle cover the centre?
    if flat.any():
        p = proj[flat]
        sides = [det.dot(np.cross(p[:, (k + 1) % 3] - p[:, k], c - p[:, k]), f) for k in range(3)]
        inside = (np.minimum.reduce(sides) >= 0) | (np.maximum.reduce(sides) <= 0)
        if inside.any():
            return True
    return False


def _placement(rig: EndoscopeRig) -> str:
    """The rig's placement for a message: β (degrees) as given (89.99999 is not 90) and the head's front."""
    where = f"rig.beta_deg = {beta_text(rig.beta_deg)}, " if rig.beta_deg is not None else ""
    return f"{where}head front at {np.round(rig.position, 6).tolist()}"


def _body_crossing(scene, rig: EndoscopeRig, radius: float, length: float) -> str | None:
    """Name of a region the body behind the face passes through (or '' for an unnamed one), else None."""
    f = rig.forward
    x, y = rig._R[:, 0], rig._R[:, 1]
    phi = 2.0 * math.pi * np.arange(_PROBES) / _PROBES
    rim = rig.position + radius * (det.cos(phi)[:, None] * x + det.sin(phi)[:, None] * y)
    back_rim = rim - length * f
    back = rig.position - length * f
    origins = np.vstack([rim, back_rim, np.broadcast_to(back, rim.shape)])
    ends = np.vstack([back_rim, np.roll(back_rim, -1, axis=0), back_rim])
    d = ends - origins
    tfar = det.norm(d)
    _, region, _, _ = _core.first_surfaces(scene.to_native(), origins, d / tfar[:, None], tfar, 0.0, 1)
    if np.any(region >= 0):
        return scene.regions[int(region[region >= 0][0])].name
    for r in scene.regions:
        rel = r.vertices.astype(np.float64) - rig.position
        ax = det.dot(rel, f)
        rad = det.norm(rel - ax[:, None] * f)
        if np.any((ax < 0) & (ax > -length) & (rad < radius)):
            return r.name
    return "" if np.any(region == -2) else None


def check_rig(scene, source) -> list[str]:
    """Check an EndoscopeRig's placement in an ep.Scene before a run (other sources pass): ValueError if
    its front face crosses or touches a region; returns the run's warnings (the body behind the face
    passing through a region), else []."""
    if not isinstance(source, EndoscopeRig) or not isinstance(scene, Scene):
        return []  # ep.run refuses a scene that is not an ep.Scene by name
    mm = 0.1 / float(scene.unit_cm)
    radius = 0.5 * source.head_diameter_mm * mm
    if radius <= 0:
        radius = (source.light_offset_mm + 0.5 * source.light_diameter_mm) * mm
    tol = FACE_TOLERANCE * (float(np.max(np.abs(source.position))) + radius)
    for r in scene.regions:
        if face_contact(r.vertices, r.triangles, source.position, source.forward, radius, tol):
            raise ValueError(
                f"source: the endoscope head's front face (lights and camera, head_diameter_mm = "
                f"{shown(float(source.head_diameter_mm))}) crosses or touches region '{r.name}' ({_placement(source)}, "
                "scene units): put the head in the ambient, e.g. a larger rig.distance or a smaller rig.beta_deg"
            )
    body = source.native_body(scene.unit_cm)
    if body is None or not scene.regions:
        return []
    if float(np.max(np.abs(source.position))) + body["radius"] > MAX_COORDINATE:
        return []  # the engine refuses such a head by name (its light positions); Embree could not take the probes
    lo = np.min([r.vertices.min(axis=0) for r in scene.regions], axis=0).astype(np.float64)
    hi = np.max([r.vertices.max(axis=0) for r in scene.regions], axis=0).astype(np.float64)
    reach = det.norm(np.maximum(np.abs(lo - source.position), np.abs(hi - source.position)))
    name = _body_crossing(scene, source, body["radius"], min(body["length"], reach + body["radius"]))
    if name is None:
        return []
    which = f"region '{name}'" if name else "a region"
    return [
        f"source: the endoscope head's body (head_length_mm = {shown(float(source.head_length_mm))} behind its front face) "
        f"passes through {which}; light is stopped by the body only where it lies in the ambient"
    ]
