# SPDX-License-Identifier: MIT
"""The endoscope rig: creation, sizes, β/distance pose (acceptance 4)."""

import math

import bpy
import numpy as np
import pytest
from mathutils import Vector

from endophoton_addon import rig, simulation
from conftest import mesh_object

MM = 1e-3


def _angle(a, b):
    """Angle between two vectors in radians, computed in float64 (atan2 is exact near 0)."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    return math.atan2(np.linalg.norm(np.cross(a, b)), float(a @ b))


def _parts(root):
    return {child.get(rig.PART_KEY): child for child in root.children}


def test_add_endoscope_creates_sized_rig():
    bpy.context.scene.cursor.location = (0.01, 0.02, 0.0)
    assert bpy.ops.endophoton.add_endoscope() == {"FINISHED"}
    root = bpy.context.scene.endophoton.rig
    assert root is not None and root.type == "EMPTY" and root.endophoton_rig.is_rig
    parts = _parts(root)
    assert set(parts) == {"light_left", "light_right", "camera", "head"}
    for name in ("light_left", "light_right"):
        light = parts[name]
        assert light.type == "LIGHT" and light.data.type == "SPOT"
        assert light.data.spot_size == pytest.approx(math.radians(15.0), abs=1e-6)
        assert light.data.shadow_soft_size == pytest.approx(1.5 * MM)  # 3 mm light guide
    assert parts["light_left"].location.x == pytest.approx(-3.5 * MM)
    assert parts["light_right"].location.x == pytest.approx(3.5 * MM)
    assert parts["camera"].type == "CAMERA"
    assert parts["camera"].data.angle == pytest.approx(math.radians(120.0), abs=1e-6)
    assert parts["camera"].data.clip_start < 1 * MM
    assert bpy.context.scene.camera == parts["camera"]
    # Head mesh: 12 mm across, display only.
    head = parts["head"]
    assert head.hide_render
    assert head.dimensions.x == pytest.approx(12 * MM, rel=1e-3)
    s = root.endophoton_rig
    assert s.head_diameter == pytest.approx(12 * MM) and s.light_diameter == pytest.approx(3 * MM)
    # β = 0 at the 3D cursor: 1 cm above it, looking straight down.
    assert tuple(root.matrix_world.translation) == pytest.approx((0.01, 0.02, 0.01), abs=1e-9)
    assert tuple(rig.light_axis_world(root)) == pytest.approx((0.0, 0.0, -1.0), abs=1e-9)


def test_sizes_follow_unit_scale():
    bpy.context.scene.unit_settings.scale_length = 0.001  # 1 Blender unit = 1 mm
    root = rig.create_rig(bpy.context)
    s = root.endophoton_rig
    assert s.head_diameter == pytest.approx(12.0)
    assert s.distance == pytest.approx(10.0)
    params = rig.rig_parameters(root, 0.001)
    assert params["head_diameter_mm"] == pytest.approx(12.0)
    assert params["light_offset_mm"] == pytest.approx(3.5)
    world = rig.rigid_world_matrix(root, 0.001)
    assert world[2, 3] == pytest.approx(0.01)  # 10 BU = 10 mm = 0.01 m


@pytest.mark.parametrize("normal,tilt", [((0, 0, 1), (0, 1, 0)), ((0.3, -0.2, 0.9), (1, 0.5, 0.1))])
def test_beta_orbits_target(normal, tilt):
    target = Vector((0.004, -0.002, 0.001))
    root = rig.create_rig(bpy.context, target=target, normal=normal, tilt_axis=tilt)
    n = np.array(normal, dtype=np.float64)
    n /= np.linalg.norm(n)
    for beta_deg in (0.0, 10.0, 25.0, -40.0, 60.0):
        root.endophoton_rig.beta = math.radians(beta_deg)
        root.endophoton_rig.distance = 0.012
        bpy.context.view_layer.update()  # children's matrix_world
        matrix = np.array(root.matrix_world, dtype=np.float64)
        axis = -matrix[:3, 2]  # light / viewing axis = -Z of the rig
        # β within 1e-6 rad (Blender stores matrices in float32).
        assert _angle(axis, -n) == pytest.approx(abs(root.endophoton_rig.beta), abs=1e-6)
        origin = matrix[:3, 3]
        assert np.linalg.norm(origin - target) == pytest.approx(0.012, abs=1e-8)
        # The viewing axis passes through the target point.
        assert np.linalg.norm(origin + 0.012 * axis - np.array(target)) == pytest.approx(0.0, abs=1e-8)
        # The lights follow: each light's world axis is the head's axis.
        for part in rig.LIGHT_PARTS:
            light = np.array(_parts(root)[part].matrix_world, dtype=np.float64)
            assert _angle(-light[:3, 2], axis) == pytest.approx(0.0, abs=1e-6)


def _flat_scene():
    verts = (
        np.array(
            [[-1, -1, -1], [1, -1, -1], [1, 1, -1], [-1, 1, -1], [-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]],
            dtype=float,
        )
        * 0.02
    )
    quads = np.array([[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]])
    tissue = mesh_object("Tissue", verts, [quads])
    tissue.endophoton.role = "TISSUE"
    s = bpy.context.scene.endophoton
    s.output_grids = False
    return tissue


@pytest.mark.parametrize("beta_deg", [0.0, 20.0, -35.0, 60.0])
def test_engine_rig_follows_beta(ep, beta_deg):
    """Moving β moves the engine's sources: the engine gets the rig's world
    matrix, its light directions make angle β with the surface normal (1e-6 rad)
    and the rig equals ep.EndoscopeRig.from_beta for the same β and distance."""
    _flat_scene()
    root = rig.create_rig(bpy.context, target=(0, 0, 0), normal=(0, 0, 1), tilt_axis=(0, 1, 0))
    root.endophoton_rig.beta = math.radians(beta_deg)
    job = simulation.prepare_job(bpy.context)
    engine_rig = job.engine_rig
    beta = abs(root.endophoton_rig.beta)  # the float32 value Blender stored
    # Light axis in world = -Z of the rig's matrix_world.
    np.testing.assert_allclose(engine_rig.forward, -np.array(root.matrix_world)[:3, 2], atol=1e-7)
    lights = engine_rig.native_lights(job.engine_scene.unit_cm)
    assert len(lights) == 2
    for light in lights:
        assert _angle(light["direction"], (0.0, 0.0, -1.0)) == pytest.approx(beta, abs=1e-6)
        assert light["half_angle"] == pytest.approx(math.radians(7.5), abs=1e-6)
        assert light["radius"] == pytest.approx(1.5e-3, rel=1e-6)  # metres
    reference = ep.EndoscopeRig.from_beta(
        beta_deg=beta_deg, distance=0.01, point=(0, 0, 0), normal=(0, 0, 1), tilt_axis=(0, 1, 0)
    )
    np.testing.assert_allclose(engine_rig.transform, reference.transform, atol=1e-7)
    np.testing.assert_allclose(engine_rig.light_positions("m"), reference.light_positions("m"), atol=1e-7)
    # Light guides 3.5 mm either side of the axis, in the plane of tilt (x, z).
    positions = engine_rig.light_positions("m")
    assert np.linalg.norm(positions[0] - positions[1]) == pytest.approx(7e-3, rel=1e-6)
    assert np.all(np.abs(positions[:, 1]) < 1e-9)
