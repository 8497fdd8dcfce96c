"""Camera importance (seed paper, section 5 / Fig. 6): which escape records the endoscope's
camera sees, leaving toward it; the pinhole frame is the view's :class:`endophoton.Camera`'s."""

from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np

from ..io import shown
from ..view.camera import Camera
from .batches import DEFAULT_BATCHES, _batch_sums, _check_batches, _column, _packets, _ratio_with_se, _unit_rows
from .batches import batch_index


def _camera_field(camera: Any, name: str) -> Any:
    if isinstance(camera, Mapping):
        if name not in camera:
            raise ValueError(f"camera: missing key '{name}'")
        return camera[name]
    if not hasattr(camera, name):
        raise ValueError(f"camera: missing attribute '{name}'")
    return getattr(camera, name)


def _camera(camera: Any) -> dict:
    """The pinhole frame (:meth:`Camera.frame`) of ``camera``: a dict or an object with position, forward,
    up, fov_deg and resolution = (width, height)."""
    cam = Camera(*(_camera_field(camera, k) for k in ("position", "forward", "up", "fov_deg")))
    res = _camera_field(camera, "resolution")
    try:
        width, height = (int(r) for r in res)
    except (TypeError, ValueError):
        raise ValueError(f"camera.resolution = {shown(res)} must be (width, height) > 0") from None
    return cam.frame(width, height)


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
    ``resolution`` = (width, height) in pixels: the pinhole of :class:`endophoton.Camera`
    (its rules and its frame, :meth:`Camera.frame`).
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
