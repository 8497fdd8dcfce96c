# SPDX-License-Identifier: MIT
"""The endoscope rig: an empty (the head frame) with two spot lights, a camera
and a display-only head mesh as children.

Head frame convention (shared with ep.EndoscopeRig): the head looks along its
local −Z (like a Blender camera); the lights sit at (±light_offset, 0, 0).
β and distance place the head by orbiting around a target point on the
surface, as ep.EndoscopeRig.from_beta does:

    z_head = R(tilt_axis, β) · normal          (viewing direction is −z_head)
    x_head = R(tilt_axis, β) · (tilt_axis × normal)
    y_head = R(tilt_axis, β) · tilt_axis
    origin = target + distance · z_head

The engine receives the empty's world matrix (rigid part, in metres), so a rig
moved by hand is simulated where it is.
"""

import math

import bpy
import numpy as np
from mathutils import Matrix, Vector

from . import meshutil, presets

PART_KEY = "endophoton_part"
LIGHT_PARTS = ("light_left", "light_right")


def beta_frame(beta, distance, target, normal, tilt_axis):
    """World matrix (mathutils.Matrix 4x4) of the head for β (radians) and distance."""
    n = Vector(normal)
    if n.length < 1e-12:
        raise ValueError("surface normal has zero length")
    n.normalize()
    t = Vector(tilt_axis)
    t = t - t.dot(n) * n
    if t.length < 1e-9:  # tilt axis parallel to the normal: pick any perpendicular
        t = n.orthogonal()
    t.normalize()
    x0 = t.cross(n)
    rot = Matrix.Rotation(beta, 3, t)
    x, y, z = rot @ x0, rot @ t, rot @ n
    origin = Vector(target) + distance * z
    m = Matrix.Identity(4)
    for row in range(3):
        m[row][0], m[row][1], m[row][2], m[row][3] = x[row], y[row], z[row], origin[row]
    return m


def rigid_world_matrix(obj, scale_length):
    """The object's world transform without scale/shear, translation in metres (numpy 4x4)."""
    loc, rot, _scale = obj.matrix_world.decompose()
    m = rot.to_matrix().to_4x4()
    m.translation = loc * scale_length
    return np.array(m, dtype=np.float64)


def light_axis_world(obj):
    """Unit viewing / light axis of the head in world space (= −Z of matrix_world)."""
    axis = -(obj.matrix_world.to_3x3() @ Vector((0.0, 0.0, 1.0)))
    return axis.normalized()


def is_rig(obj):
    return obj is not None and obj.type == "EMPTY" and obj.endophoton_rig.is_rig


def find_rigs(scene):
    return [obj for obj in scene.objects if is_rig(obj)]


def _children_by_part(obj):
    return {child.get(PART_KEY): child for child in obj.children if child.get(PART_KEY)}


def camera_of(obj):
    """The rig's camera object, or None when it is gone."""
    camera = _children_by_part(obj).get("camera")
    return camera if camera is not None and camera.type == "CAMERA" else None


def has_camera(obj):
    """True when the rig still has its camera (the endoscope view needs it)."""
    return camera_of(obj) is not None


def update_rig(obj):
    """Move the rig to its β/distance pose and resize its parts (property update)."""
    if not is_rig(obj):
        return
    settings = obj.endophoton_rig
    try:
        frame = beta_frame(settings.beta, settings.distance, settings.target, settings.normal, settings.tilt_axis)
    except ValueError:
        return  # a zero normal while the user types: keep the last pose
    obj.matrix_world = frame
    parts = _children_by_part(obj)
    sign = {"light_left": -1.0, "light_right": 1.0}
    for part in LIGHT_PARTS:
        light_obj = parts.get(part)
        if light_obj is None:
            continue
        light_obj.location = (sign[part] * settings.light_offset, 0.0, 0.0)
        light_obj.rotation_euler = (0.0, 0.0, 0.0)
        light = light_obj.data
        light.spot_size = max(settings.cone_angle, math.radians(1.0))
        light.shadow_soft_size = 0.5 * settings.light_diameter
    camera_obj = parts.get("camera")
    if camera_obj is not None:
        camera_obj.location = (0.0, 0.0, 0.0)
        camera_obj.rotation_euler = (0.0, 0.0, 0.0)
        camera_obj.data.angle = settings.camera_fov
        camera_obj.data.display_size = settings.head_diameter  # drawn at the head's size, not 1 m
    head = parts.get("head")
    if head is not None:
        r = 0.5 * settings.head_diameter
        head.scale = (r, r, r)
    obj.empty_display_size = 0.5 * settings.head_diameter


def _head_mesh(name):
    """Unit-radius closed cylinder from z=0 back to z=+2.5 (scaled by the head radius)."""
    verts, faces = meshutil.cylinder_arrays(32, 2.5)
    return meshutil.mesh_from_arrays(name, verts, faces)


def create_rig(
    context,
    target=(0.0, 0.0, 0.0),
    normal=(0.0, 0.0, 1.0),
    tilt_axis=(0.0, 1.0, 0.0),
    beta=0.0,
    distance=None,
    name="EP Endoscope",
):
    """Create the rig in the active collection and return its empty.

    Sizes are converted from the colonoscope defaults in mm to Blender units
    with the scene's unit scale.
    """
    scene = context.scene
    mm = 1e-3 / scene.unit_settings.scale_length  # one millimetre in Blender units
    collection = context.collection or scene.collection

    root = bpy.data.objects.new(name, None)
    root.empty_display_type = "PLAIN_AXES"
    collection.objects.link(root)
    s = root.endophoton_rig
    s.is_rig = True

    def child(obj, part):
        obj[PART_KEY] = part
        obj.parent = root
        collection.objects.link(obj)
        return obj

    for part, label in zip(LIGHT_PARTS, ("L", "R")):
        light = bpy.data.lights.new(f"{name} Light {label}", "SPOT")
        light.energy = 0.005  # W (Blender point-light power): ~4 W/m² at 1 cm, for the viewport/render only
        light.spot_blend = 0.15
        light.show_cone = True
        child(bpy.data.objects.new(light.name, light), part)

    cam = bpy.data.cameras.new(f"{name} Camera")
    cam.clip_start = 0.1 * mm
    cam.clip_end = 1000.0 * mm
    child(bpy.data.objects.new(cam.name, cam), "camera")

    head = child(bpy.data.objects.new(f"{name} Head", _head_mesh(f"{name} Head")), "head")
    head.display_type = "WIRE"
    head.hide_render = True
    head.hide_select = True

    # Setting the properties runs update_rig once each; set sizes first.
    s.head_diameter = presets.RIG_HEAD_DIAMETER_MM * mm
    s.light_diameter = presets.RIG_LIGHT_DIAMETER_MM * mm
    s.light_offset = presets.RIG_LIGHT_OFFSET_MM * mm
    s.cone_angle = math.radians(presets.RIG_CONE_ANGLE_DEG)
    s.camera_fov = math.radians(presets.RIG_CAMERA_FOV_DEG)
    s.target = target
    s.normal = normal
    s.tilt_axis = tilt_axis
    s.distance = presets.RIG_DEFAULT_DISTANCE_MM * mm if distance is None else distance
    s.beta = beta
    update_rig(root)

    scene.camera = camera_of(root)  # the endoscope's view is the picture a render should show
    if scene.endophoton.rig is None:
        scene.endophoton.rig = root
    return root


def rig_parameters(obj, scale_length):
    """Geometry of the rig in the engine's keyword units (mm, degrees)."""
    s = obj.endophoton_rig
    to_mm = scale_length * 1e3
    return {
        "head_diameter_mm": s.head_diameter * to_mm,
        "light_diameter_mm": s.light_diameter * to_mm,
        "light_offset_mm": s.light_offset * to_mm,
        "cone_angle_deg": math.degrees(s.cone_angle),
        "camera_fov_deg": math.degrees(s.camera_fov),
    }
