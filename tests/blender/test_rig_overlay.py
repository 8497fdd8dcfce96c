# SPDX-License-Identifier: MIT
"""Issue 36, defect 9: the viewport shows where the rig's lights and camera point — the light axes
and cones, the camera's frustum and the target — in step with the rig's properties."""

import math

import bpy
import pytest
from mathutils import Vector

import endophoton_addon
from endophoton_addon import rig, rig_overlay


def _angle(a, b):
    return math.degrees((a[1] - a[0]).angle(b[1] - b[0]))


def _rig(beta_deg=0.0):
    root = rig.create_rig(bpy.context, target=(0.0, 0.0, 0.0))
    root.endophoton_rig.beta = math.radians(beta_deg)
    bpy.context.view_layer.update()
    return root


@pytest.mark.parametrize("beta_deg", [0.0, 30.0])
def test_light_axes_point_along_the_head_and_pass_the_target(beta_deg):
    root = _rig(beta_deg)
    s = root.endophoton_rig
    lines = rig_overlay.rig_lines(root)
    axis = rig.light_axis_world(root)
    light_axes = lines["light"][0::5]  # each light: its axis, then four cone edges
    assert len(light_axes) == 2
    for start, end in light_axes:
        assert (end - start).normalized().dot(axis) == pytest.approx(1.0, abs=1e-6)
        # at the target's depth the axis passes within the light offset of the target
        t = (Vector(s.target) - start).dot(axis)
        assert (start + t * axis - Vector(s.target)).length == pytest.approx(s.light_offset, rel=1e-4)


def test_cone_edges_open_at_half_the_cone_angle_and_follow_it():
    root = _rig()
    s = root.endophoton_rig
    for cone_deg in (15.0, 40.0):
        s.cone_angle = math.radians(cone_deg)
        lines = rig_overlay.rig_lines(root)["light"]
        axis, edges = lines[0], lines[1:5]
        assert all(_angle(axis, e) == pytest.approx(cone_deg / 2, abs=1e-4) for e in edges)


def test_frustum_follows_the_field_of_view_and_distance():
    root = _rig()
    s = root.endophoton_rig
    for fov_deg, distance in ((120.0, 0.01), (60.0, 0.02)):
        s.camera_fov, s.distance = math.radians(fov_deg), distance
        camera = rig_overlay.rig_lines(root)["camera"]
        eye, corner = camera[0]
        half = math.degrees(math.atan(math.sqrt(2.0) * math.tan(math.radians(fov_deg / 2))))
        assert math.degrees((corner - eye).angle(rig.light_axis_world(root))) == pytest.approx(half, abs=1e-4)
        assert (corner - eye).dot(rig.light_axis_world(root)) == pytest.approx(distance, rel=1e-5)
    target = rig_overlay.rig_lines(root)["target"]
    centre = (target[0][0] + target[0][1]) / 2
    assert (centre - Vector(s.target)).length < 1e-9


def test_the_draw_handler_is_registered_and_draws_nothing_without_a_window():
    assert (bpy.types.SpaceView3D, rig_overlay.draw) in endophoton_addon._DRAW_HANDLES
    _rig()
    assert bpy.context.scene.endophoton.show_rig_overlay
