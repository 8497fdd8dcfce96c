# SPDX-License-Identifier: MIT
"""A rig you can aim: the viewport draws each endoscope rig's light axes and light cones (their full
apex angle), the camera's frustum (its field of view) out to the rig's distance, and the target
point.  The lines are computed from the rig's properties and its empty's matrix at every redraw,
so they follow β, distance, tip sizes and a hand-moved empty at once (no datablock is made).

:func:`rig_lines` is the geometry (no GPU: tests call it); :func:`draw` is the 3D view's
POST_VIEW draw handler, registered by the add-on's registration loop (``DRAW_HANDLERS``).
"""

import math

import bpy
from mathutils import Vector

from . import rig

LIGHT_COLOUR = (1.0, 0.85, 0.2, 1.0)
CAMERA_COLOUR = (0.3, 0.8, 1.0, 1.0)
TARGET_COLOUR = (1.0, 0.3, 0.3, 1.0)


def _reach(settings):
    """How far the lines go: past the target (1.5 × distance), at least two head diameters."""
    return max(1.5 * settings.distance, 2.0 * settings.head_diameter, 1e-9)


def rig_lines(rig_obj):
    """{"light": [(a, b), ...], "camera": [...], "target": [...]} line segments in world space
    (Vector pairs) for the rig ``rig_obj``: each light's axis and four edges of its cone, the
    camera's frustum to the rig's distance (reach), and a cross at the target point."""
    s = rig_obj.endophoton_rig
    matrix = rig_obj.matrix_world
    reach = _reach(s)
    lines = {"light": [], "camera": [], "target": []}
    half_cone = 0.5 * s.cone_angle
    for x in (-s.light_offset, s.light_offset):
        origin = Vector((x, 0.0, 0.0))
        lines["light"].append((origin, origin + Vector((0.0, 0.0, -reach))))
        for cx, cy in ((1, 0), (-1, 0), (0, 1), (0, -1)):
            edge = Vector((cx * math.sin(half_cone), cy * math.sin(half_cone), -math.cos(half_cone)))
            lines["light"].append((origin, origin + reach * edge))
    depth = min(reach, s.distance) if s.distance > 0 else reach
    side = depth * math.tan(0.5 * s.camera_fov)
    corners = [Vector((sx * side, sy * side, -depth)) for sx, sy in ((1, 1), (-1, 1), (-1, -1), (1, -1))]
    eye = Vector((0.0, 0.0, 0.0))
    lines["camera"] += [(eye, c) for c in corners] + [(corners[i], corners[(i + 1) % 4]) for i in range(4)]
    world = {key: [(matrix @ a, matrix @ b) for a, b in segments] for key, segments in lines.items()}
    target, size = Vector(s.target), 0.25 * s.head_diameter
    for axis in ((1, 0, 0), (0, 1, 0), (0, 0, 1)):
        offset = size * Vector(axis)
        world["target"].append((target - offset, target + offset))
    return world


def _shader():
    import gpu

    for name in ("UNIFORM_COLOR", "3D_UNIFORM_COLOR"):  # 4.x name first, then 3.x
        try:
            return gpu.shader.from_builtin(name)
        except (ValueError, SystemError):
            continue
    return None


def draw():
    """POST_VIEW: the aiming lines of every rig of the scene (Endoscope > Show Aim Lines)."""
    context = bpy.context
    scene = context.scene
    if scene is None or not getattr(scene, "endophoton", None) or not scene.endophoton.show_rig_overlay:
        return
    rigs = [obj for obj in scene.objects if rig.is_rig(obj) and obj.visible_get()]
    if not rigs:
        return
    from gpu_extras.batch import batch_for_shader

    shader = _shader()
    if shader is None:
        return
    colours = {"light": LIGHT_COLOUR, "camera": CAMERA_COLOUR, "target": TARGET_COLOUR}
    for rig_obj in rigs:
        for key, segments in rig_lines(rig_obj).items():
            coords = [tuple(p) for segment in segments for p in segment]
            batch = batch_for_shader(shader, "LINES", {"pos": coords})
            shader.bind()
            shader.uniform_float("color", colours[key])
            batch.draw(shader)


# (space type, callback, region type, draw type): added and removed by the registration loop.
DRAW_HANDLERS = ((bpy.types.SpaceView3D, draw, "WINDOW", "POST_VIEW"),)
CLASSES = ()
