# SPDX-License-Identifier: MIT
"""Acceptance 3 (error paths): bad input ends in an operator error naming the
object and field, and the scene stays exactly as it was."""

import math
import os

import bpy
import numpy as np
import pytest

from endophoton_addon import rig
from conftest import data_snapshot, mesh_object

BOX_V = (
    np.array(
        [[-1, -1, -1], [1, -1, -1], [1, 1, -1], [-1, 1, -1], [-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]],
        dtype=float,
    )
    * 0.02
)
BOX_F = np.array([[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]])


def _tissue(faces=BOX_F):
    obj = mesh_object("Tissue", BOX_V, [faces])
    obj.endophoton.role = "TISSUE"
    return obj


def _rig():
    return rig.create_rig(bpy.context, target=(0, 0, 0))


def _valid_scene():
    tissue = _tissue()
    root = _rig()
    s = bpy.context.scene.endophoton
    s.quality = "CUSTOM"
    s.photons = 1000
    return tissue, root


def _assert_rejected(pattern, invoke=False):
    before = data_snapshot()
    args = ("INVOKE_DEFAULT",) if invoke else ()
    with pytest.raises(RuntimeError, match=pattern):
        bpy.ops.endophoton.run_simulation(*args)
    assert data_snapshot() == before


def test_no_tissue():
    polyp = mesh_object("Polyp", BOX_V * 0.1, [BOX_F])
    polyp.endophoton.role = "POLYP"
    _rig()
    _assert_rejected(r"Scene 'Scene': no object has role 'tissue'")


def test_open_mesh():
    _tissue(faces=BOX_F[1:])
    _rig()
    _assert_rejected(r"Object 'Tissue': mesh is open \(4 boundary edges")


def test_open_mesh_through_invoke():
    _tissue(faces=BOX_F[1:])
    _rig()
    _assert_rejected(r"Object 'Tissue': mesh is open", invoke=True)


def test_open_after_modifiers():
    """The closed box becomes open through a Geometry Nodes modifier deleting its top."""
    tissue, _root = _valid_scene()
    modifier = tissue.modifiers.new("delete top", "NODES")
    group = bpy.data.node_groups.new("delete top", "GeometryNodeTree")
    group.inputs.new("NodeSocketGeometry", "Geometry")
    group.outputs.new("NodeSocketGeometry", "Geometry")
    gin, gout = group.nodes.new("NodeGroupInput"), group.nodes.new("NodeGroupOutput")
    delete = group.nodes.new("GeometryNodeDeleteGeometry")
    delete.domain = "FACE"
    normal = group.nodes.new("GeometryNodeInputNormal")
    sep = group.nodes.new("ShaderNodeSeparateXYZ")
    compare = group.nodes.new("FunctionNodeCompare")
    compare.data_type = "FLOAT"
    compare.operation = "GREATER_THAN"
    compare.inputs[1].default_value = 0.5
    group.links.new(normal.outputs[0], sep.inputs[0])
    group.links.new(sep.outputs["Z"], compare.inputs[0])
    group.links.new(gin.outputs[0], delete.inputs["Geometry"])
    group.links.new(compare.outputs[0], delete.inputs["Selection"])
    group.links.new(delete.outputs[0], gout.inputs[0])
    modifier.node_group = group
    _assert_rejected(r"Object 'Tissue': mesh is open \(.* after modifiers\)")


@pytest.mark.parametrize("axis", [0, 2])
def test_zero_scale_is_zero_volume_not_inward(axis):
    """A closed box scaled to 0 along an axis is named as flat, not as inward normals."""
    tissue, _root = _valid_scene()
    scale = [1.0, 1.0, 1.0]
    scale[axis] = 0.0
    tissue.scale = scale
    _assert_rejected(r"Object 'Tissue': mesh has zero volume \(signed volume .* m³ .*\): it is flat or scaled to 0")


def test_inverted_normals_still_named_inward():
    tissue, _root = _valid_scene()
    tissue.data.flip_normals()
    _assert_rejected(r"Object 'Tissue': normals point inward \(signed volume -.* m³\)")


def test_no_rig():
    _tissue()
    _assert_rejected(r"Scene 'Scene': simulation.rig is not set and the scene has no endoscope rig")


def test_zero_packets():
    _valid_scene()
    bpy.context.scene.endophoton.photons = 0
    _assert_rejected(r"Scene 'Scene': simulation.photons = 0 must be > 0")


def test_zero_store():
    _valid_scene()
    s = bpy.context.scene.endophoton
    s.mode = "STORE"
    s.store = 0
    _assert_rejected(r"Scene 'Scene': simulation.store = 0 must be > 0")


@pytest.mark.parametrize(
    "field,pattern",
    [
        ("mua", r"Object 'Tissue': medium.mua = nan must be a finite number >= 0"),
        ("mus", r"Object 'Tissue': medium.mus = nan must be"),
        ("g", r"Object 'Tissue': medium.g = nan must be a finite number in \[-1, 1\]"),
        ("n", r"Object 'Tissue': medium.n = nan must be a finite number >= 1"),
    ],
)
def test_nan_medium(field, pattern):
    tissue, _root = _valid_scene()
    setattr(tissue.endophoton.medium, field, math.nan)
    _assert_rejected(pattern)


def test_nan_fluorophore():
    tissue, _root = _valid_scene()
    tissue.endophoton.fluorophores[0].c = math.nan
    _assert_rejected(r"Object 'Tissue': fluorophores\[0\] \(collagen\).c = nan must be")


def test_out_of_range_medium():
    tissue, _root = _valid_scene()
    tissue.endophoton.medium.g = 1.5
    _assert_rejected(r"Object 'Tissue': medium.g = 1.5 must be a finite number in \[-1, 1\]")


def test_nan_rig_distance():
    _tissue, root = _valid_scene()
    root.endophoton_rig.distance = math.nan
    _assert_rejected(r"Object 'EP Endoscope': endophoton_rig.distance = nan must be a finite number")


def test_nan_voxel_size():
    _valid_scene()
    bpy.context.scene.endophoton.voxel_size = math.nan
    _assert_rejected(r"Scene 'Scene': simulation.voxel_size = nan must be a finite number > 0")


@pytest.mark.parametrize(
    "switches, pattern",
    [
        (
            dict(grid_absorbed=False, grid_fluorescent_light=False, grid_emission=False),
            r"simulation\.grid_absorbed, grid_fluorescent_light and grid_emission are all off",
        ),
        (
            dict(grid_fluorescent_light=False, grid_per_fluorophore=True),
            r"simulation\.grid_per_fluorophore needs simulation\.grid_fluorescent_light on",
        ),
    ],
)
def test_grid_quantities_that_write_nothing_are_refused(switches, pattern):
    _valid_scene()
    s = bpy.context.scene.endophoton
    s.output_grids = True
    for name, value in switches.items():
        setattr(s, name, value)
    _assert_rejected(r"Scene 'Scene': " + pattern)


def test_emission_grids_alone_need_a_fluorophore():
    tissue, _root = _valid_scene()
    tissue.endophoton.fluorophores.clear()
    s = bpy.context.scene.endophoton
    s.output_grids, s.grid_absorbed, s.grid_fluorescent_light = True, False, False
    _assert_rejected(r"Scene 'Scene': simulation\.grid_emission is the only grid on, and no object has a fluorophore")


@pytest.mark.parametrize(
    "field, limits",
    [
        ("point_radius", ">= 0"),
        ("camera_cone_deg", r"in \[0.1, 90\]"),
        ("volume_decades", ">= 0.1"),
        ("volume_density", ">= 0"),
    ],
)
def test_nan_display_setting(field, limits):
    """A FloatProperty's min/max let NaN through; the run names the display field."""
    _valid_scene()
    setattr(bpy.context.scene.endophoton, field, math.nan)
    _assert_rejected(rf"Scene 'Scene': simulation.{field} = nan must be a finite number {limits}")


def test_role_on_non_mesh():
    _valid_scene()
    curve = bpy.data.objects.new("Wire", bpy.data.curves.new("Wire", "CURVE"))
    bpy.context.scene.collection.objects.link(curve)
    curve.endophoton.role = "TISSUE"
    _assert_rejected(r"Object 'Wire': role is tissue but the object is a curve")


def test_previous_result_survives_a_rejected_run():
    """A rejected re-run must not remove the previous run's collection."""
    _valid_scene()
    previous = bpy.data.collections.new("EP previous")
    previous["endophoton_result"] = True
    bpy.context.scene.collection.children.link(previous)
    bpy.context.scene.endophoton.result_collection = previous
    bpy.context.scene.endophoton.photons = 0
    _assert_rejected(r"simulation.photons = 0")
    assert bpy.context.scene.endophoton.result_collection == previous


def _assert_engine_rejected(pattern, capfd):
    """The run is refused with "Engine rejected the input: ..." matching ``pattern``, prints no
    traceback (the worker's error is bad input, not a failure) and leaves the scene as it was."""
    capfd.readouterr()
    _assert_rejected(r"^Error: Engine rejected the input: " + pattern)
    out, err = capfd.readouterr()
    assert "Traceback" not in out + err
    assert "run failed" not in out + err


def test_engine_rejects_a_self_intersecting_mesh(capfd, tmp_path):
    """Repro A (D3, D4): the engine's mesh check ends the run as bad input, and the grid folder
    the run would have made for its file is not left behind."""
    tissue = mesh_object("Tissue", np.concatenate([BOX_V, BOX_V * 0.5]), [BOX_F, BOX_F + 8])
    tissue.endophoton.role = "TISSUE"
    _rig()
    s = bpy.context.scene.endophoton
    s.quality = "CUSTOM"
    s.photons = 1000
    s.output_grids = True
    s.grid_dir = str(tmp_path / "new" / "a" / "b")
    _assert_engine_rejected(r"region 'Tissue': mesh intersects itself", capfd)
    assert os.listdir(tmp_path) == []


def test_engine_rejects_fluorescent_only_store_without_fluorophores(capfd):
    """Repro B (D3): the message names the add-on's fields."""
    tissue, _root = _valid_scene()
    tissue.endophoton.fluorophores.clear()
    s = bpy.context.scene.endophoton
    s.mode = "STORE"
    s.store = 10
    s.fluorescent_only = True
    _assert_engine_rejected(
        r"simulation\.store = 10 with simulation\.fluorescent_only = True needs a fluorophore", capfd
    )


def test_failed_run_removes_only_the_folders_it_made(tmp_path, monkeypatch):
    """D4: a run that fails after its checks removes the (empty) folders it made, and only those."""
    from endophoton_addon import simulation

    _valid_scene()
    s = bpy.context.scene.endophoton
    s.output_grids = True
    (tmp_path / "kept").mkdir()
    s.grid_dir = str(tmp_path / "kept" / "new" / "deeper")

    def broken_run(self):
        assert os.path.isdir(os.path.dirname(self.inputs.grid_path))  # made for the run
        raise RuntimeError("disk on fire")

    monkeypatch.setattr(simulation.SimulationJob, "_run", broken_run)
    before = data_snapshot()
    with pytest.raises(RuntimeError, match="EndoPhoton run failed: RuntimeError: disk on fire"):
        bpy.ops.endophoton.run_simulation()
    assert data_snapshot() == before
    assert os.listdir(tmp_path) == ["kept"] and os.listdir(tmp_path / "kept") == []


def _result_with_camera():
    """A small run (a coloured point cloud, the active result) and a scene camera."""
    _valid_scene()
    s = bpy.context.scene.endophoton
    s.output_grids = False
    s.output_points = True
    assert bpy.ops.endophoton.run_simulation() == {"FINISHED"}
    scene = bpy.context.scene
    camera = bpy.data.objects.new("Cam", bpy.data.cameras.new("Cam"))
    camera.location = (0.0, 0.0, 0.2)
    scene.collection.objects.link(camera)
    scene.camera = camera
    scene.render.engine = "CYCLES"
    scene.cycles.samples = 1
    scene.cycles.use_denoising = False
    scene.render.resolution_x, scene.render.resolution_y = 32, 24
    return scene


def test_render_legend_unwritable_path_is_named_before_rendering():
    """D5: a path that cannot be written (under a regular file: root may write anywhere else)
    is refused by name before the render, and no datablock (no Render Result) is left."""
    _result_with_camera()
    before = data_snapshot()
    with pytest.raises(RuntimeError, match=r"render_legend\.filepath = '/etc/passwd/x\.png': '/etc/passwd' is a file"):
        bpy.ops.endophoton.render_legend(filepath="/etc/passwd/x.png")
    assert data_snapshot() == before


def test_render_legend_writes_only_the_png(tmp_path):
    """D5: the linear render it exposes is a temporary file, not left beside the PNG."""
    _result_with_camera()
    path = tmp_path / "l.png"
    assert bpy.ops.endophoton.render_legend(filepath=str(path)) == {"FINISHED"}
    assert os.listdir(tmp_path) == ["l.png"]
    assert bpy.data.images.load(str(path), check_existing=True).size[0] > 32


def test_render_legend_failing_write_leaves_no_file_and_no_image(tmp_path, monkeypatch):
    """D5: when the legend PNG cannot be made (savefig fails after writing part of it), the operator
    reports it by path, the old PNG stays whole, no temporary file is left and no image of ours
    stays in the .blend."""
    from matplotlib.figure import Figure

    _result_with_camera()
    path = tmp_path / "l.png"
    path.write_bytes(b"old")
    before = data_snapshot()

    def torn(fig, fname, **kwargs):
        fname.write(b"\x89PNG\r\n\x1a\nhalf")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(Figure, "savefig", torn)
    with pytest.raises(RuntimeError, match=r"legend: matplotlib could not make the PNG for '.*l\.png'.*No space left"):
        bpy.ops.endophoton.render_legend(filepath=str(path))
    assert path.read_bytes() == b"old" and os.listdir(tmp_path) == ["l.png"]
    after = data_snapshot()
    after["images"] = [name for name in after["images"] if name != "Render Result"]
    assert after == before
