"""Light sources, in scene units.

Every source becomes a list of disk lights emitting into a cone with
directions uniform in solid angle. Emission samples come from the engine's
scrambled Halton sequence indexed by packet number.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from . import det
from .spectra import Spectrum
from .io import check_keys as _check_keys, float_array, real_or_none, shown
from .scene_schema import MAX_COORDINATE
from .units import unit_cm as _unit_cm


def _vec3(owner, field_name, v, unit_length=False):
    a = float_array(v)
    if a is None or a.shape != (3,) or not np.all(np.isfinite(a)):
        raise ValueError(f"{owner}.{field_name} = {shown(v)} must be 3 finite numbers")
    if unit_length:
        m = float(np.max(np.abs(a)))
        # Any non-zero length, as the schema says ("direction"): scaled by its largest component
        # first, the normalisation is exact in range for any length (the norm of (0, 0, 1e300)
        # would overflow to inf, that of (0, 0, 1e-300) underflow to 0).
        if not m > 0:
            raise ValueError(f"{owner}.{field_name} = {shown(v)} has zero length")
        a = a / m
        a = a / det.norm(a)  # not np.linalg.norm: the BLAS's sum differs by processor (endophoton.det)
    return a


def _nonneg(owner, field_name, v, hi=math.inf, positive=False):
    """``v`` as a float in [0, hi] ((0, hi] if ``positive``): ValueError naming ``owner.field_name`` otherwise."""
    x = real_or_none(v)
    if x is None or not math.isfinite(x) or x < 0 or x > hi or (positive and x == 0):
        lo = "(0" if positive else "[0"
        rng = f"{lo}, {hi:g}]" if math.isfinite(hi) else ("> 0" if positive else ">= 0")
        raise ValueError(f"{owner}.{field_name} = {shown(v)} must be a finite number {rng}")
    return x


class _Source:
    spectrum: Spectrum | None = None

    def native_lights(self, scene_unit_cm: float) -> list[dict]:
        raise NotImplementedError

    def native_body(self, scene_unit_cm: float) -> dict | None:
        """The opaque body light can land on (the endoscope head), or None."""
        return None

    def _spec(self):
        s = self.spectrum
        return None if s is None else (list(map(float, s.wavelength_nm)), list(map(float, s.values)))


@dataclass
class PencilSource(_Source):
    """Infinitely thin collimated beam from ``position`` along ``direction`` (scene units)."""

    position: tuple = (0.0, 0.0, 1.0)
    direction: tuple = (0.0, 0.0, -1.0)
    spectrum: Spectrum | None = None

    def __post_init__(self):
        self.position = _vec3("source", "position", self.position)
        self.direction = _vec3("source", "direction", self.direction, unit_length=True)

    def native_lights(self, scene_unit_cm):
        return [
            dict(
                position=self.position.tolist(),
                direction=self.direction.tolist(),
                radius=0.0,
                half_angle=0.0,
                spectrum=self._spec(),
            )
        ]


@dataclass(init=False)
class DiskSource(_Source):
    """Collimated beam with a uniform disk profile of ``radius`` about ``position`` (scene units).

    ``center=`` is accepted for ``position`` (the same point; one word per concept, docs/design.md).
    """

    position: tuple
    direction: tuple
    radius: float
    spectrum: Spectrum | None

    def __init__(self, position=None, direction=(0.0, 0.0, -1.0), radius=0.1, spectrum=None, *, center=None):
        if position is not None and center is not None:
            raise ValueError("source: give position or center (the same point), not both")
        point = center if position is None else position
        self.position = _vec3(
            "source", "position" if center is None else "center", (0.0, 0.0, 1.0) if point is None else point
        )
        self.direction = _vec3("source", "direction", direction, unit_length=True)
        self.radius = _nonneg("source", "radius", radius)
        self.spectrum = spectrum

    @property
    def center(self) -> np.ndarray:
        """The disk's centre: the same point as ``position``."""
        return self.position

    def native_lights(self, scene_unit_cm):
        return [
            dict(
                position=self.position.tolist(),
                direction=self.direction.tolist(),
                radius=self.radius,
                half_angle=0.0,
                spectrum=self._spec(),
            )
        ]


@dataclass
class ConeSource(_Source):
    """Point (radius 0) or disk emitter into a cone of ``half_angle_deg`` about ``direction``,
    uniform in solid angle inside the cone."""

    position: tuple = (0.0, 0.0, 1.0)
    direction: tuple = (0.0, 0.0, -1.0)
    half_angle_deg: float = 7.5
    radius: float = 0.0
    spectrum: Spectrum | None = None

    def __post_init__(self):
        self.position = _vec3("source", "position", self.position)
        self.direction = _vec3("source", "direction", self.direction, unit_length=True)
        self.half_angle_deg = _nonneg("source", "half_angle_deg", self.half_angle_deg, 90.0)
        self.radius = _nonneg("source", "radius", self.radius)

    def native_lights(self, scene_unit_cm):
        return [
            dict(
                position=self.position.tolist(),
                direction=self.direction.tolist(),
                radius=self.radius,
                half_angle=math.radians(self.half_angle_deg),
                spectrum=self._spec(),
            )
        ]


def rotation_about(axis, angle_rad):
    """Rotation matrix (3x3) about a unit axis by angle_rad (Rodrigues). Computed with endophoton.det,
    so an endoscope's pose has the same bits on every machine."""
    a = np.asarray(axis, dtype=np.float64)
    a = a / det.norm(a)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + det.sin(angle_rad) * K + (1 - det.cos(angle_rad)) * det.matmul(K, K)


# The largest image side (pixels) a view renders (render._resolve_camera's limit).
MAX_IMAGE_SIDE = 8192


def is_image_side(x) -> bool:
    """Whether ``x`` is an image width or height: an integer (not a bool) in [1, MAX_IMAGE_SIDE] pixels."""
    return not isinstance(x, (bool, np.bool_)) and isinstance(x, (int, np.integer)) and 1 <= x <= MAX_IMAGE_SIDE


def _resolution(name: str, v) -> tuple:
    """``v`` as a (width, height) pair of integers in [1, MAX_IMAGE_SIDE] pixels."""
    bad = ValueError(f"{name} = {shown(v)} must be (width, height) in pixels, integers in [1, {MAX_IMAGE_SIDE}]")
    if isinstance(v, (str, bytes, dict)):
        raise bad
    try:
        w, h = v
    except (TypeError, ValueError):
        raise bad from None
    if not (is_image_side(w) and is_image_side(h)):
        raise bad
    return int(w), int(h)


@dataclass
class EndoscopeRig(_Source):
    """The endoscope head of the seed's §5: two disk lights and a pinhole camera.

    ``transform`` is the 4x4 head-to-world matrix (scene units), e.g. Blender's
    ``matrix_world`` of the rig empty; its scale is ignored. In the head frame the
    rig looks along local -Z (Blender's camera convention), the camera lens is at
    the origin and the two light guides sit at (+-light_offset_mm, 0, 0).

    Dimensions are physical, in mm, close to a colonoscope tip: head 12 mm
    across, light guides 3 mm across, 3.5 mm from the centre.

    With ``body=True`` (default) the head is an opaque, black cylinder of
    ``head_diameter_mm`` reaching ``head_length_mm`` behind its front face, with
    the camera's aperture (``camera_aperture_mm`` across, at the lens) on that
    face: light that comes back onto the head is tallied ``occluded``, light on
    the aperture ``camera_collected`` (docs/design.md, "Light crosses the lumen").

    ``cone_angle_deg`` is the FULL apex angle alpha of each light's cone (the
    seed uses alpha = 15 deg, i.e. 7.5 deg half angle); directions are uniform
    in solid angle inside the cone. The light spectrum defaults to flat white
    over 400-700 nm.
    """

    transform: np.ndarray = field(default_factory=lambda: np.eye(4))
    head_diameter_mm: float = 12.0
    light_diameter_mm: float = 3.0
    light_offset_mm: float = 3.5
    cone_angle_deg: float = 15.0
    camera_fov_deg: float = 120.0
    camera_resolution: tuple = (256, 256)
    spectrum: Spectrum | None = None
    beta_deg: float | None = None
    head_length_mm: float = 50.0
    camera_aperture_mm: float = 2.0
    body: bool = True

    def __post_init__(self):
        M = float_array(self.transform)
        if M is None or M.shape != (4, 4) or not np.all(np.isfinite(M)):
            raise ValueError(f"rig.transform = {shown(self.transform)} must be a finite 4x4 matrix")
        R = M[:3, :3]
        scales = det.norm(R.T)  # each column's length
        if np.any(scales < 1e-12):
            raise ValueError("rig.transform has a zero-length axis")
        self.transform = M
        self._R = R / scales
        for name in (
            "head_diameter_mm",
            "light_diameter_mm",
            "light_offset_mm",
            "head_length_mm",
            "camera_aperture_mm",
        ):
            setattr(self, name, _nonneg("rig", name, getattr(self, name), MAX_COORDINATE))
        self.cone_angle_deg = _nonneg("rig", "cone_angle_deg", self.cone_angle_deg, 180.0)
        self.camera_fov_deg = _nonneg("rig", "camera_fov_deg", self.camera_fov_deg, 179.0, positive=True)
        if not isinstance(self.body, (bool, np.bool_)):
            raise ValueError(f"rig.body = {self.body!r} must be True or False")
        self.body = bool(self.body)
        self.camera_resolution = _resolution("rig.camera_resolution", self.camera_resolution)
        if self.camera_aperture_mm > self.head_diameter_mm:
            raise ValueError(
                f"rig.camera_aperture_mm = {self.camera_aperture_mm} is wider than the head "
                f"(head_diameter_mm = {self.head_diameter_mm})"
            )
        if self.light_offset_mm + 0.5 * self.light_diameter_mm > 0.5 * self.head_diameter_mm + 1e-9:
            raise ValueError(
                f"rig.light_offset_mm = {self.light_offset_mm} puts the light guides outside the "
                f"head (head_diameter_mm = {self.head_diameter_mm})"
            )

    # ---- geometry in world / scene units ----------------------------------
    @property
    def position(self) -> np.ndarray:
        return self.transform[:3, 3].copy()

    @property
    def forward(self) -> np.ndarray:
        return -self._R[:, 2]

    @property
    def up(self) -> np.ndarray:
        return self._R[:, 1].copy()

    def light_positions(self, scene_unit: str | float) -> np.ndarray:
        """World positions (scene units) of the two lights, shape (2, 3)."""
        ucm = scene_unit if isinstance(scene_unit, float) else _unit_cm(scene_unit)
        off = self.light_offset_mm * 0.1 / ucm
        return np.array([self.position + det.matvec(self._R, np.array([s * off, 0.0, 0.0])) for s in (+1.0, -1.0)])

    def camera(self, scene_unit: str | float = "cm") -> dict:
        return dict(
            position=self.position,
            forward=self.forward,
            up=self.up,
            fov_deg=self.camera_fov_deg,
            resolution=tuple(self.camera_resolution),
        )

    def native_lights(self, scene_unit_cm):
        r = 0.5 * self.light_diameter_mm * 0.1 / scene_unit_cm
        half = math.radians(0.5 * self.cone_angle_deg)
        return [
            dict(position=p.tolist(), direction=self.forward.tolist(), radius=r, half_angle=half, spectrum=self._spec())
            for p in self.light_positions(float(scene_unit_cm))
        ]

    def native_body(self, scene_unit_cm):
        if not self.body or self.head_diameter_mm <= 0 or self.head_length_mm <= 0:
            return None
        mm = 0.1 / float(scene_unit_cm)
        return dict(
            front=self.position.tolist(),
            axis=self.forward.tolist(),
            radius=0.5 * self.head_diameter_mm * mm,
            length=self.head_length_mm * mm,
            camera=self.position.tolist(),
            camera_radius=0.5 * self.camera_aperture_mm * mm,
        )

    @classmethod
    def from_beta(
        cls, beta_deg: float, distance: float, point=(0.0, 0.0, 0.0), normal=(0.0, 0.0, 1.0), tilt_axis=None, **kwargs
    ) -> "EndoscopeRig":
        """Place the head ``distance`` (scene units) from the surface ``point``, looking at it,
        tilted by ``beta_deg`` from the surface ``normal``.

        The head orbits the point: its viewing axis always passes through the
        point, and the rotation by beta is about ``tilt_axis`` (default: the
        world Y axis projected onto the tangent plane, or X if Y is parallel to
        the normal). The light guides lie in the plane of tilt, so at beta > 0 one
        light is nearer the surface than the other.
        """
        beta, dist = real_or_none(beta_deg), real_or_none(distance)
        if beta is None or not abs(beta) < 90:  # nan fails too
            raise ValueError(f"rig.beta_deg = {shown(beta_deg)} must be a finite angle in (-90, 90) degrees")
        if dist is None or not 0 < dist < math.inf:
            raise ValueError(f"rig.distance = {shown(distance)} must be a positive number (scene units)")
        beta_deg, distance = beta, dist
        p = _vec3("rig", "point", point)
        n = _vec3("rig", "normal", normal, unit_length=True)
        if tilt_axis is None:
            ref = np.array([0.0, 1.0, 0.0]) if abs(n[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
        else:
            ref = _vec3("rig", "tilt_axis", tilt_axis, unit_length=True)
        # endophoton.det, not np.dot / @ / np.linalg.norm: the pose is a scene input (same bits everywhere)
        axis = ref - det.dot(ref, n) * n
        if det.norm(axis) < 1e-9:
            raise ValueError(f"rig.tilt_axis = {tilt_axis!r} is parallel to the normal")
        axis /= det.norm(axis)
        view = det.matvec(rotation_about(axis, math.radians(beta_deg)), n)  # from the point to the head
        z = view
        x = np.cross(axis, z)  # elementwise products and differences: correctly rounded everywhere
        x /= det.norm(x)
        y = np.cross(z, x)
        M = np.eye(4)
        M[:3, 0], M[:3, 1], M[:3, 2] = x, y, z
        M[:3, 3] = p + distance * view
        rig = cls(transform=M, **kwargs)
        rig.beta_deg = float(beta_deg)
        return rig


#: The head's settings a SCENE.json ``endoscope`` source may give (beside its placement).
_RIG_JSON_HEAD_KEYS = frozenset(
    {
        "head_diameter_mm",
        "light_diameter_mm",
        "light_offset_mm",
        "cone_angle_deg",
        "camera_fov_deg",
        "head_length_mm",
        "camera_aperture_mm",
        "body",
    }
)


def source_from_dict(d: dict):
    """Build a source from the SCENE.json ``source`` object."""
    if not isinstance(d, dict) or "type" not in d:
        raise ValueError(f"source = {d!r} must be an object with a 'type'")
    kind = d["type"]
    body = {k: v for k, v in d.items() if k != "type"}
    if kind == "pencil":
        _check_keys("source", body, {"position", "direction"})
        return PencilSource(**body)
    if kind == "disk":
        _check_keys("source", body, {"direction", "radius"}, extra={"position", "center"})
        if ("position" in body) == ("center" in body):
            raise ValueError("source: give exactly one of 'position' or 'center' (the disk's centre)")
        return DiskSource(**body)
    if kind == "cone":
        _check_keys("source", body, {"position", "direction", "half_angle_deg"}, extra={"radius"})
        return ConeSource(**body)
    if kind == "endoscope":
        if "transform" in body:
            _check_keys("source", body, {"transform"}, extra=_RIG_JSON_HEAD_KEYS)
            return EndoscopeRig(**body)
        _check_keys(
            "source", body, {"beta_deg", "distance"}, extra={"point", "normal", "tilt_axis"} | _RIG_JSON_HEAD_KEYS
        )
        return EndoscopeRig.from_beta(**body)
    raise ValueError(f"source.type = {kind!r} must be one of 'pencil', 'disk', 'cone', 'endoscope'")
