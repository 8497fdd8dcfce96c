# SPDX-License-Identifier: MIT
"""Issue 36, through the operators: the export holds positions and every record column, the legend
and Render with Legend are there right after a run, Add Endoscope makes its camera the scene
camera, Render with Legend renders from the run's endoscope camera with Cycles, and a colon built
from scratch (cylinder + Solidify + sphere) renders from the endoscope camera with a legend."""

import json
import math

import bpy
import numpy as np
import pytest

from endophoton_addon import legend_render, points, simulation
from conftest import mesh_object

BOX_V = np.array(
    [[-1, -1, -1], [1, -1, -1], [1, 1, -1], [-1, 1, -1], [-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], dtype=float
) * [0.02, 0.02, 0.005]
BOX_F = [np.array([[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]])]


def _slab_run(packets=3000, grids=False):
    """A 5 mm tissue slab, a rig added through the operator, one run through the operator."""
    tissue = mesh_object("Tissue", BOX_V, BOX_F)
    tissue.endophoton.role = "TISSUE"
    bpy.context.scene.cursor.location = (0.0, 0.0, 0.0)
    assert bpy.ops.endophoton.add_endoscope() == {"FINISHED"}
    s = bpy.context.scene.endophoton
    s.quality, s.mode, s.photons = "CUSTOM", "PHOTONS", packets
    s.output_grids = grids
    jobs = []
    prepare = simulation.prepare_job

    def keep(context, interactive=False):
        jobs.append(prepare(context, interactive))
        return jobs[-1]

    simulation.prepare_job = keep
    try:
        assert bpy.ops.endophoton.run_simulation() == {"FINISHED"}
    finally:
        simulation.prepare_job = prepare
    return jobs[0], s.result_collection


def test_export_writes_positions_first_and_every_record_column(ep, tmp_path):
    """Defect 1: CSV, NPZ and JSON of Export Result hold the exit positions (metres, first) and
    every column of the engine's records, equal to the engine's values."""
    job, _collection = _slab_run()
    escapes = job.result.escapes
    engine_columns = list(escapes)
    assert "position" in engine_columns
    expected = ["position"] + [c for c in engine_columns if c != "position"]
    paths = {}
    for fmt in ("CSV", "NPZ", "JSON"):
        paths[fmt] = str(tmp_path / f"photons.{fmt.lower()}")
        assert bpy.ops.endophoton.export_result(filepath=paths[fmt], format=fmt) == {"FINISHED"}
    with np.load(paths["NPZ"]) as npz:
        assert [k for k in npz.files if k != "summary_json"] == expected
        for column in engine_columns:
            want = np.asarray(escapes[column])
            if want.dtype.kind == "f":
                np.testing.assert_allclose(npz[column], want, rtol=1e-6, atol=1e-9, err_msg=column)
            else:
                np.testing.assert_array_equal(npz[column].astype(np.int64), want.astype(np.int64), err_msg=column)
    with open(paths["CSV"]) as f:
        header = f.readline().strip().split(",")
    flat = []
    for column in expected:
        width = np.asarray(escapes[column]).reshape(len(escapes["weight"]), -1).shape[1]
        flat += [f"{column}_{a}" for a in "xyz"] if width == 3 else [column]
    assert header == flat and header[:3] == ["position_x", "position_y", "position_z"]
    table = np.loadtxt(paths["CSV"], delimiter=",", skiprows=1, ndmin=2)
    np.testing.assert_allclose(table[:, :3], np.asarray(escapes["position"]), rtol=1e-6, atol=1e-9)
    np.testing.assert_array_equal(table[:, header.index("packet")], np.asarray(escapes["packet"]))
    with open(paths["JSON"]) as f:
        assert json.load(f)["summary"]["records"] == len(escapes["weight"])


def test_packet_index_above_32_bits_survives_the_point_cloud():
    """The uint64 packet column is kept whole (two 32-bit attributes) for packets past 2^32."""
    packets = np.array([0, 5, 2**31 + 7, 2**40 + 3], dtype=np.uint64)
    rec = {"position": np.zeros((4, 3), np.float32), "packet": packets, "weight": np.ones(4)}
    positions, attrs = points.point_cloud_arrays(rec, 1.0)
    material = bpy.data.materials.new("m")
    obj = points.create_point_cloud("P", positions, attrs, 0.001, material, "run")
    np.testing.assert_array_equal(points.record_columns(obj, 1.0)["packet"], packets)


def test_legend_and_render_button_appear_right_after_a_run(ep):
    """Defect 3: right after a run (Colour By never touched) the legend rows are filled, so the
    Results panel shows the legend and Render with Legend."""
    _job, collection = _slab_run()
    s = bpy.context.scene.endophoton
    assert s.legend_header.startswith("Wavelength [nm]") and len(s.legend) > 0
    assert points.legend_of(points.points_objects(collection)[0]).caption() == s.legend_header


def test_add_endoscope_makes_its_camera_the_scene_camera():
    """Defect 4: a new file's factory camera does not stay the scene camera."""
    scene = bpy.context.scene
    factory = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    scene.collection.objects.link(factory)
    scene.camera = factory
    assert bpy.ops.endophoton.add_endoscope() == {"FINISHED"}
    root = bpy.context.view_layer.objects.active
    assert scene.camera is not factory and scene.camera.parent == root and scene.camera.type == "CAMERA"


def test_render_with_legend_uses_the_runs_endoscope_camera_and_cycles(ep, tmp_path):
    """Defect 4: in EEVEE with another scene camera, Render with Legend renders from the run's rig
    camera with Cycles and denoising off, says so, and puts the scene's settings back."""
    _job, collection = _slab_run()
    scene = bpy.context.scene
    other = bpy.data.objects.new("Side", bpy.data.cameras.new("Side"))
    scene.collection.objects.link(other)
    scene.camera = other
    scene.render.engine = "BLENDER_EEVEE"
    scene.cycles.use_denoising = True
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = 48, 48, 100
    legend_render.RENDER_SAMPLES, samples = 2, legend_render.RENDER_SAMPLES
    try:
        path = str(tmp_path / "legend.png")
        assert bpy.ops.endophoton.render_legend(filepath=path) == {"FINISHED"}
    finally:
        legend_render.RENDER_SAMPLES = samples
    image = next(im for im in bpy.data.images if bpy.path.abspath(im.filepath) == path)
    rig_camera = bpy.data.objects["EP Endoscope Camera"]
    assert image["endophoton_camera"] == rig_camera.name
    assert scene.camera is other and scene.render.engine == "BLENDER_EEVEE" and scene.cycles.use_denoising
    assert legend_render.run_camera(scene, collection)[0] is rig_camera


def _colon_from_scratch():
    """A colon wall made the way a user makes one: a cylinder (radius 15 mm, 60 mm long) with a
    Solidify modifier (3 mm wall) and a sphere polyp (4 mm) on its inner wall; roles set in the
    Object panel's Role field (which loads the role's defaults)."""
    bpy.ops.mesh.primitive_cylinder_add(vertices=48, radius=0.015, depth=0.06, end_fill_type="NOTHING")
    wall = bpy.context.active_object
    wall.name = "Colon"
    solidify = wall.modifiers.new("Solidify", "SOLIDIFY")
    solidify.thickness = 0.003
    solidify.offset = 1.0  # outward: the lumen stays 15 mm across
    wall.endophoton.role = "TISSUE"
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.004, location=(0.0, -0.0145, 0.0))
    polyp = bpy.context.active_object
    polyp.name = "Polyp"
    polyp.endophoton.role = "POLYP"
    return wall, polyp


@pytest.mark.slow
def test_colon_from_scratch_renders_from_the_endoscope_camera_with_a_legend(ep, tmp_path):
    """Acceptance: cylinder + Solidify + sphere, roles in the panel, Add Endoscope aimed at the polyp,
    a run and Render with Legend: the picture comes from the endoscope camera, with the legend."""
    _colon_from_scratch()
    scene = bpy.context.scene
    scene.cursor.location = (0.0, -0.0105, 0.0)  # the polyp's top, seen from the lumen
    assert bpy.ops.endophoton.add_endoscope() == {"FINISHED"}
    root = bpy.context.view_layer.objects.active
    root.endophoton_rig.normal = (0.0, 1.0, 0.0)
    root.endophoton_rig.tilt_axis = (0.0, 0.0, 1.0)
    root.endophoton_rig.distance = 0.008
    s = scene.endophoton
    s.quality, s.mode, s.photons = "CUSTOM", "PHOTONS", 20_000
    s.output_grids = False
    s.grid_dir = str(tmp_path)
    assert bpy.ops.endophoton.run_simulation() == {"FINISHED"}
    assert s.legend_header and len(s.legend) > 0
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = 64, 64, 100
    legend_render.RENDER_SAMPLES, samples = 4, legend_render.RENDER_SAMPLES
    try:
        assert bpy.ops.endophoton.render_legend() == {"FINISHED"}
    finally:
        legend_render.RENDER_SAMPLES = samples
    image = next(im for im in bpy.data.images if im.get("endophoton_camera"))
    assert scene.camera.name == image["endophoton_camera"] == "EP Endoscope Camera"
    w, h = image.size
    assert w > h  # the render with the colour bar beside it
    pixels = np.empty(w * h * 4, np.float32)
    image.pixels.foreach_get(pixels)
    rgb = pixels.reshape(h, w, 4)[:, :, :3]
    assert rgb.std() > 0.02  # not one flat grey frame
    assert math.isclose(scene.unit_settings.scale_length, 1.0)
