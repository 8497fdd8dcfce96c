"""The camera that looks at a scene: a pinhole with an optional thin-lens aperture.

Conventions (:meth:`Camera.frame`, which ``analysis.important_mask`` uses too; Blender's camera's):
``fov_deg`` is the full field of view across the larger image dimension;
image x points along ``right = forward x up``, image y along the true up;
pixel row 0 is the top row. Lengths are in scene units.

The frame and the pixels' solid angles are part of what a run with ``view=`` hands the engine
(view.nee.camera_view_options): they are computed with endophoton.det (tan, atan, dot, norm), never
math's, numpy's dispatched loops or the BLAS, so that they have the same bits on every x86-64 machine.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .. import det
from ..io import real_or_none, shown
from ..scene_schema import MAX_COORDINATE
from ..sources import _vec3


#: Batches of the view's batch-means standard errors unless a call names n_batches (one owner: render, nee and
#: budget read it).
DEFAULT_VIEW_BATCHES = 20


@dataclass
class Camera:
    """A pinhole camera at ``position`` looking along ``forward``.

    position, forward, up : scene units / directions (up need not be orthogonal to forward)
    fov_deg : full field of view across the larger image dimension, in (0, 179]
    aperture_radius : radius of the thin lens, scene units; 0 = pinhole (no aperture image)
    focus_distance : depth of the plane in focus, scene units along forward;
        None = the surface depth at the image centre (autofocus)
    """

    position: tuple
    forward: tuple
    up: tuple = (0.0, 0.0, 1.0)
    fov_deg: float = 60.0
    aperture_radius: float = 0.0
    focus_distance: float | None = None

    def __post_init__(self):
        self.position = _vec3("camera", "position", self.position)
        self.forward = _vec3("camera", "forward", self.forward, unit_length=True)
        self.up = _vec3("camera", "up", self.up, unit_length=True)
        if abs(det.dot(self.forward, self.up)) > 1 - 1e-9:
            raise ValueError(f"camera.up = {self.up.tolist()} is parallel to the viewing direction")
        self.fov_deg = _positive("fov_deg", self.fov_deg, 179.0)
        a = real_or_none(self.aperture_radius)
        if a is None or not 0 <= a <= MAX_COORDINATE:
            raise ValueError(
                f"camera.aperture_radius = {shown(self.aperture_radius)} must be a finite number in "
                f"[0, {MAX_COORDINATE:g}] (scene units)"
            )
        self.aperture_radius = a
        if self.focus_distance is not None:
            self.focus_distance = _positive("focus_distance", self.focus_distance, MAX_COORDINATE)

    @classmethod
    def look_at(
        cls, position, look_at, up=(0.0, 0.0, 1.0), fov_deg=60.0, aperture_radius=0.0, focus_distance=None
    ) -> "Camera":
        """Camera at ``position`` looking at the point ``look_at`` (scene units)."""
        p = _vec3("camera", "position", position)
        t = _vec3("camera", "look_at", look_at)
        if det.norm(t - p) < 1e-12 * (1 + det.norm(p)):
            raise ValueError(f"camera.look_at = {list(look_at)!r} equals camera.position")
        return cls(p, t - p, up, fov_deg, aperture_radius, focus_distance)

    @classmethod
    def from_dict(cls, d) -> "Camera":
        """The SCENE.json ``camera`` object: position, look_at, up, fov_deg, optional aperture_radius."""
        from ..io import check_keys

        check_keys("camera", d, {"position", "look_at", "up", "fov_deg"}, extra={"aperture_radius", "focus_distance"})
        return cls.look_at(
            d["position"], d["look_at"], d["up"], d["fov_deg"], d.get("aperture_radius", 0.0), d.get("focus_distance")
        )

    @classmethod
    def from_rig(cls, rig, aperture_radius=0.0) -> "Camera":
        """The endoscope rig's own camera (its lens at the head centre, looking along the head axis)."""
        c = rig.camera()
        return cls(c["position"], c["forward"], c["up"], c["fov_deg"], aperture_radius)

    def frame(self, width: int, height: int) -> dict:
        """The pinhole frame of a ``width`` x ``height`` pixel image: ``position``; the orthonormal
        ``forward``, ``right`` = forward x up and true ``up`` = right x forward; and the image's
        half-extents on the plane at depth 1, ``tan_x``, ``tan_y``: ``fov_deg`` spans the larger image
        side (Blender's AUTO sensor fit), the other gets tan(fov/2) * smaller/larger. The one owner of
        the convention (``analysis.important_mask`` and the render use it)."""
        if isinstance(width, bool) or isinstance(height, bool) or int(width) <= 0 or int(height) <= 0:
            raise ValueError(f"camera.resolution = {(width, height)} must be (width, height) > 0")
        w, h = int(width), int(height)
        f = self.forward / det.norm(self.forward)
        r = np.cross(f, self.up)  # elementwise products and differences: correctly rounded everywhere
        r /= det.norm(r)
        u = np.cross(r, f)
        t = det.tan(math.radians(self.fov_deg) / 2.0)  # radians(): one correctly rounded product
        tx, ty = (t, t * h / w) if w >= h else (t * w / h, t)
        return dict(position=np.asarray(self.position, dtype=np.float64), forward=f, right=r, up=u, tan_x=tx, tan_y=ty)

    def primary_rays(self, width: int, height: int) -> np.ndarray:
        """Unit directions (H*W, 3) through the pixel centres, row-major from the top-left pixel."""
        fr = self.frame(width, height)
        x = ((np.arange(width) + 0.5) / width * 2.0 - 1.0) * fr["tan_x"]
        y = (1.0 - (np.arange(height) + 0.5) / height * 2.0) * fr["tan_y"]
        X, Y = np.meshgrid(x, y)
        d = fr["forward"] + X.reshape(-1, 1) * fr["right"] + Y.reshape(-1, 1) * fr["up"]
        return d / np.linalg.norm(d, axis=1, keepdims=True)

    def project(self, points, width: int, height: int) -> np.ndarray:
        """Pixel index (row * width + column) of points (N,3) through the pinhole; -1 outside the image."""
        fr = self.frame(width, height)
        rel = np.asarray(points, dtype=np.float64) - self.position
        z = rel @ fr["forward"]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = (rel @ fr["right"]) / z / fr["tan_x"]
            v = (rel @ fr["up"]) / z / fr["tan_y"]
        ok = (z > 0) & (np.abs(u) < 1) & (np.abs(v) < 1)
        col = np.floor((np.where(ok, u, 0) + 1) / 2 * width).astype(np.int64).clip(0, width - 1)
        row = np.floor((1 - np.where(ok, v, 0)) / 2 * height).astype(np.int64).clip(0, height - 1)
        return np.where(ok, row * width + col, -1)

    def pixel_solid_angles(self, width: int, height: int) -> np.ndarray:
        """Exact solid angle (sr) of each pixel (H*W,) seen from the lens centre.

        A rectangle [x1,x2] x [y1,y2] on the plane at distance 1 subtends
        F(x2,y2) - F(x1,y2) - F(x2,y1) + F(x1,y1), F(x, y) = atan(x y / sqrt(1 + x^2 + y^2)).
        """
        fr = self.frame(width, height)
        xe = (np.arange(width + 1) / width * 2.0 - 1.0) * fr["tan_x"]
        ye = (1.0 - np.arange(height + 1) / height * 2.0) * fr["tan_y"]
        X, Y = np.meshgrid(xe, ye)
        F = det.atan(X * Y / np.sqrt(1 + X * X + Y * Y))
        om = F[1:, 1:] - F[1:, :-1] - F[:-1, 1:] + F[:-1, :-1]
        return np.abs(om).reshape(-1)

    def to_dict(self) -> dict:
        return dict(
            position=self.position.tolist(),
            forward=self.forward.tolist(),
            up=self.up.tolist(),
            fov_deg=self.fov_deg,
            aperture_radius=self.aperture_radius,
            focus_distance=self.focus_distance,
        )


def _positive(name, v, hi=math.inf) -> float:
    """``v`` as a float in (0, hi] (finite): ValueError naming camera.``name`` otherwise."""
    x = real_or_none(v)
    if x is None or not math.isfinite(x) or x <= 0 or x > hi:
        rng = f"in (0, {hi:g}]" if math.isfinite(hi) else "> 0"
        raise ValueError(f"camera.{name} = {shown(v)} must be a finite number {rng}")
    return x
