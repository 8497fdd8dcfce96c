# SPDX-License-Identifier: MIT
"""Blender side of the results, from inputs this test makes itself: the
point-cloud builder (arrays shaped like the engine's escape records) and the
Volume object (a .vdb written here with pyopenvdb).  The end-to-end tests with
the real engine are in test_end_to_end.py."""

import importlib
import os
import re

import bpy
import numpy as np
import pytest
from mathutils import Vector

from endophoton_addon import node_utils, points, results, volumes

K = 2_000


def _records(rng, k=K):
    direction = rng.normal(size=(k, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    return {
        "position": (rng.random((k, 3)) * 0.02 - 0.01).astype(np.float32),
        "direction": direction.astype(np.float32),
        "normal": np.tile(np.float32([0, 0, 1]), (k, 1)),
        "weight": rng.random(k),
        "energy": rng.random(k) * 1.3,
        "wavelength": (400.0 + 300.0 * rng.random(k)).astype(np.float32),
        "fluorescent": (rng.random(k) < 0.3).astype(np.uint8),
        "fluorophore": rng.integers(-1, 2, k).astype(np.int32),
        "max_depth": (rng.random(k) * 0.1).astype(np.float32),
        "light": rng.integers(0, 2, k).astype(np.uint8),
        "kind": np.zeros(k, np.uint8),
        "region": rng.integers(0, 2, k).astype(np.int32),
        "scatterings": rng.integers(0, 50, k).astype(np.uint32),
        "packet": np.arange(k, dtype=np.uint64),
        "exit_order": rng.integers(1, 4, k).astype(np.uint32),
        "next_hit": rng.integers(0, 4, k).astype(np.uint8),
    }


def _attr(mesh, name):
    attribute = mesh.attributes[name]
    width = 3 if attribute.data_type == "FLOAT_VECTOR" else 1
    dtype = {"FLOAT": np.float32, "FLOAT_VECTOR": np.float32, "INT": np.int32, "BOOLEAN": bool}[attribute.data_type]
    out = np.empty(len(attribute.data) * width, dtype=dtype)
    attribute.data.foreach_get("vector" if width == 3 else "value", out)
    return out.reshape(-1, width) if width == 3 else out


@pytest.mark.parametrize("scale_length", [1.0, 0.001])
def test_point_cloud_from_records(scale_length):
    bpy.context.scene.unit_settings.scale_length = scale_length
    rec = _records(np.random.default_rng(7))
    positions, attrs = points.point_cloud_arrays(rec, scale_length)
    material = points._points_material("m", "run")
    obj = points.create_point_cloud("Photons", positions, attrs, 0.0001, material, "run")
    bpy.context.scene.collection.objects.link(obj)

    mesh = obj.data
    assert len(mesh.vertices) == K and len(mesh.edges) == 0 and len(mesh.polygons) == 0
    co = np.empty(K * 3, np.float32)
    mesh.vertices.foreach_get("co", co)
    np.testing.assert_allclose(co.reshape(-1, 3) * scale_length, rec["position"], rtol=1e-6, atol=1e-9)
    assert _attr(mesh, "weight").sum() == pytest.approx(rec["weight"].sum(), rel=1e-6)
    assert _attr(mesh, "energy").sum() == pytest.approx(rec["energy"].sum(), rel=1e-6)
    assert _attr(mesh, "wavelength").sum() == pytest.approx(rec["wavelength"].astype(np.float64).sum(), rel=1e-6)
    assert _attr(mesh, "fluorescent").sum() == rec["fluorescent"].sum()
    assert _attr(mesh, "fluorophore").sum() == rec["fluorophore"].sum()
    assert _attr(mesh, "depth").sum() == pytest.approx(rec["max_depth"].astype(np.float64).sum(), rel=1e-5)
    np.testing.assert_array_equal(_attr(mesh, "direction"), rec["direction"])
    np.testing.assert_array_equal(_attr(mesh, "exit_order"), rec["exit_order"])
    np.testing.assert_array_equal(_attr(mesh, "next_hit"), rec["next_hit"])
    assert mesh.attributes["fluorescent"].data_type == "BOOLEAN"

    # The Geometry Nodes modifier turns it into a point cloud with the attributes.
    modifier = obj.modifiers[0]
    assert modifier.type == "NODES" and modifier.node_group.name == points.POINTS_GROUP
    assert any(n.bl_idname == "GeometryNodeMeshToPoints" for n in modifier.node_group.nodes)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    clouds = [
        inst.object.data
        for inst in depsgraph.object_instances
        if inst.object.type == "POINTCLOUD" and inst.object.original == obj
    ]
    assert len(clouds) == 1
    cloud = clouds[0]
    assert len(cloud.points) == K
    weights = np.empty(K, np.float32)
    cloud.attributes["weight"].data.foreach_get("value", weights)
    assert weights.sum() == pytest.approx(rec["weight"].sum(), rel=1e-6)
    assert cloud.materials[0].original == material


def test_point_cloud_rejects_mismatched_columns():
    rec = _records(np.random.default_rng(1), k=10)
    rec["weight"] = rec["weight"][:9]
    before = len(bpy.data.meshes)
    with pytest.raises(ValueError, match="escape column 'weight' has shape"):
        points.point_cloud_arrays(rec, 1.0)
    assert len(bpy.data.meshes) == before


# IEC 61966-2-1 XYZ -> linear sRGB, and CIE 1931 (CIE 15 table) at three lines.
SRGB = np.array([[3.2406, -1.5372, -0.4986], [-0.9689, 1.8758, 0.0415], [0.0557, -0.2040, 1.0570]])
CIE_TABLE = {450: (0.3362, 0.0380, 1.7721), 530: (0.1655, 0.8620, 0.0422), 630: (0.6424, 0.2650, 0.0000)}


def test_wavelength_colour_is_the_packages_conversion(ep):
    """One owner: the add-on's wavelength colour is endophoton.view.colour's CIE 1931 -> white-balanced
    linear sRGB (negatives clipped); the hue of each spectral line is that of the CIE table's XYZ
    through the IEC matrix (recomputed here): red at photofrin's 630 nm, green at 530 nm, blue at
    collagen's 450 nm; the legend swatches keep the hue with largest channel 1, the far red included."""
    from endophoton_addon import colour_maps

    nm = np.array(sorted(CIE_TABLE), dtype=float)
    gains = importlib.import_module('endophoton.view.colour').white_balance_gains(None)
    rgb = colour_maps.wavelength_rgb(nm)
    table = np.maximum((np.array([CIE_TABLE[k] for k in sorted(CIE_TABLE)]) * gains) @ SRGB.T, 0.0)
    np.testing.assert_allclose(rgb, table, atol=0.1)
    assert rgb.argmax(axis=1).tolist() == [2, 1, 0]
    assert rgb[2, 1] < 0.1 * rgb[2, 0]  # 630 nm is red, not orange
    swatches = colour_maps.wavelength_swatches([450.0, 530.0, 630.0, 690.0])
    np.testing.assert_allclose(swatches.max(axis=1)[:3], 1.0)
    assert swatches[3, 0] > 5 * swatches[3, 1]  # photofrin's 690 nm band stays red
    assert np.all(swatches >= 0) and np.all(swatches <= 1)
    # The far red of the fluorescence lines (719, 799 nm) at full brightness and red, never black
    # (issue 36): the swatch shows the hue; the fit's tails (green beyond ~710 nm) are not used.
    far = colour_maps.wavelength_swatches([719.0, 799.0])
    np.testing.assert_allclose(far[:, 0], 1.0)
    assert np.all(far[:, 1:] < 0.1)


def _points_in_collection(rec):
    positions, attrs = points.point_cloud_arrays(rec, 1.0)
    material = points._points_material("m", "run")
    names = {"fluorophore": ["collagen", "photofrin"], "region": ["Colon", "Polyp"]}
    obj = points.create_point_cloud("Photons", positions, attrs, 0.0001, material, "run", names=names)
    coll = bpy.data.collections.new("EP run")
    coll[results.RESULT_KEY] = True
    bpy.context.scene.collection.children.link(coll)
    coll.objects.link(obj)
    bpy.context.scene.endophoton.result_collection = coll
    points.recolour(obj, bpy.context.scene.endophoton)
    return obj


def _colours(obj):
    attribute = obj.data.attributes[points.COLOUR_ATTR]
    out = np.empty(len(attribute.data) * 4, np.float32)
    attribute.data.foreach_get("color", out)
    return out.reshape(-1, 4)[:, :3]


@pytest.mark.parametrize(
    "color_by", ["WAVELENGTH", "FLUORESCENT", "FLUOROPHORE", "REGION", "DEPTH", "ENERGY", "SCATTERINGS"]
)
def test_colour_by_each_attribute_with_legend(color_by):
    """Each mapping writes one colour per record into the named attribute
    ep_colour; records alike in the attribute get one colour, the legend gives
    the attribute's range (recomputed here) with units."""
    rec = _records(np.random.default_rng(3), k=400)
    obj = _points_in_collection(rec)
    settings = bpy.context.scene.endophoton
    settings.color_by = color_by
    rgb = _colours(obj)
    legend = points.legend_of(obj)
    assert legend is not None and legend.entries and legend.shown == legend.total == 400
    if color_by == "WAVELENGTH":
        red = rgb[rec["wavelength"] > 615]
        green = rgb[(rec["wavelength"] > 520) & (rec["wavelength"] < 545)]
        assert np.all(red[:, 0] > red[:, 1]) and np.all(green[:, 1] > green[:, 0])
        assert legend.unit == "nm"
        assert legend.lo == pytest.approx(rec["wavelength"].min()) and legend.hi == pytest.approx(
            rec["wavelength"].max()
        )
    elif color_by in ("FLUORESCENT", "FLUOROPHORE", "REGION"):
        column = {"FLUORESCENT": "fluorescent", "FLUOROPHORE": "fluorophore", "REGION": "region"}[color_by]
        codes = rec[column].astype(int)
        for code in np.unique(codes):
            assert len(np.unique(rgb[codes == code], axis=0)) == 1
        assert len(np.unique(rgb, axis=0)) == len(np.unique(codes))
        labels = [label for _c, label in legend.entries]
        expected = {
            "FLUORESCENT": ["excitation light", "fluorescence"],
            "FLUOROPHORE": ["none", "collagen", "photofrin"],
            "REGION": ["Colon", "Polyp"],
        }[color_by]
        assert labels == expected
    else:
        column, scale, unit = {
            "DEPTH": ("max_depth", 10.0, "mm"),
            "ENERGY": ("energy", 1.0, "500 nm photons"),
            "SCATTERINGS": ("scatterings", 1.0, "events"),
        }[color_by]
        values = rec[column].astype(np.float64) * scale
        assert legend.unit == unit
        assert legend.lo == pytest.approx(values.min(), rel=1e-5) and legend.hi == pytest.approx(values.max(), rel=1e-5)
        # Monotone ramp: the brightest colour (sum) belongs to the largest value's end.
        order = np.argsort(values)
        assert rgb[order[-1]].sum() > rgb[order[0]].sum()


def test_filters_and_radius_update_results():
    """Filters hide records through the named attribute ep_show (the points
    modifier's selection): counts recomputed from the records."""
    rec = _records(np.random.default_rng(5), k=300)
    obj = _points_in_collection(rec)
    settings = bpy.context.scene.endophoton

    def shown():
        attribute = obj.data.attributes[points.SHOW_ATTR]
        out = np.empty(len(attribute.data), bool)
        attribute.data.foreach_get("value", out)
        return out

    settings.filter_fluorescent = True
    np.testing.assert_array_equal(shown(), rec["fluorescent"].astype(bool))
    settings.filter_fluorophore = "photofrin"
    np.testing.assert_array_equal(shown(), rec["fluorescent"].astype(bool) & (rec["fluorophore"] == 1))
    settings.filter_fluorescent = False
    settings.filter_fluorophore = "ANY"
    settings.filter_region = "Polyp"
    np.testing.assert_array_equal(shown(), rec["region"] == 1)
    assert points.legend_of(obj).shown == int((rec["region"] == 1).sum())
    settings.point_radius = 0.0007
    ids = node_utils.group_input_identifiers(obj.modifiers[0].node_group)
    assert obj.modifiers[0][ids["Radius"]] == pytest.approx(0.0007)


def test_legend_png_is_written_whole_or_not_at_all(ep, tmp_path, monkeypatch):
    """The legend PNG goes through the package's atomic write: a complete PNG replaces the file; a
    failing savefig, a figure that is no PNG, a missing folder or a path that is a folder raise a
    RuntimeError naming the path and leave the old file (or none) and no temporary file."""
    from matplotlib.figure import Figure

    from endophoton_addon import colour_maps

    legend = points.legend_of(_points_in_collection(_records(np.random.default_rng(3), k=50)))
    path = tmp_path / "l.png"
    assert colour_maps.legend_figure(legend, str(path)) == str(path)
    png = path.read_bytes()
    assert png.startswith(colour_maps.PNG_SIGNATURE) and len(png) > 1000
    assert os.listdir(tmp_path) == ["l.png"]

    def torn(fig, fname, **kwargs):
        fname.write(colour_maps.PNG_SIGNATURE + b"half")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(Figure, "savefig", torn)
    with pytest.raises(RuntimeError, match=rf"^legend: matplotlib could not make the PNG for '{re.escape(str(path))}'"):
        colour_maps.legend_figure(legend, str(path))
    monkeypatch.setattr(Figure, "savefig", lambda fig, fname, **kwargs: fname.write(b""))
    with pytest.raises(RuntimeError, match=r"matplotlib made no PNG for .*l\.png' \(0 bytes\); nothing written"):
        colour_maps.legend_figure(legend, str(path))
    assert path.read_bytes() == png and os.listdir(tmp_path) == ["l.png"]
    monkeypatch.undo()

    missing = tmp_path / "missing" / "l.png"
    with pytest.raises(RuntimeError, match=rf"^legend: could not write '{re.escape(str(missing))}': No such file"):
        colour_maps.legend_figure(legend, str(missing))
    (tmp_path / "d.png").mkdir()
    with pytest.raises(RuntimeError, match=r"^legend: could not write '.*d\.png': Is a directory"):
        colour_maps.legend_figure(legend, str(tmp_path / "d.png"))
    assert sorted(os.listdir(tmp_path)) == ["d.png", "l.png"] and os.listdir(tmp_path / "d.png") == []


@pytest.mark.parametrize("color_by, title", [("FLUORESCENT", "Fluorescent"), ("DEPTH", "Depth [mm]")])
def test_legend_when_the_filters_show_nothing(color_by, title):
    """A filter that hides every record gives 'none shown (0/N)', no range and no swatch;
    showing records again gives the range and the count back."""
    rec = _records(np.random.default_rng(5), k=300)
    rec["fluorophore"][:] = -1  # no record has a fluorophore: filtering by one shows nothing
    obj = _points_in_collection(rec)
    settings = bpy.context.scene.endophoton
    settings.color_by = color_by
    settings.filter_fluorophore = "collagen"
    assert not _attr(obj.data, points.SHOW_ATTR).any()
    assert settings.legend_header == f"{title}: none shown (0/300)"
    assert len(settings.legend) == 0 and points.legend_of(obj).entries == []
    settings.filter_fluorophore = "ANY"
    assert settings.legend_header.endswith(" · 300/300 shown") and "none" not in settings.legend_header
    assert len(settings.legend) > 0


@pytest.mark.parametrize("field", ["point_radius", "camera_cone_deg"])
def test_nan_display_setting_changes_no_result(field):
    """NaN in a display setting (which a FloatProperty's min/max let through) leaves the
    shown result as it was and the legend's header names the field; Show Result reports it."""
    rec = _records(np.random.default_rng(5), k=300)
    obj = _points_in_collection(rec)
    settings = bpy.context.scene.endophoton
    settings.filter_toward_camera = True  # the camera cone is used
    ids = node_utils.group_input_identifiers(obj.modifiers[0].node_group)
    radius = obj.modifiers[0][ids["Radius"]]
    show = _attr(obj.data, points.SHOW_ATTR).copy()
    setattr(settings, field, float("nan"))
    message = f"Scene 'Scene': simulation.{field} = nan must be a finite number"
    assert settings.legend_header.startswith(message)
    assert obj.modifiers[0][ids["Radius"]] == radius
    np.testing.assert_array_equal(_attr(obj.data, points.SHOW_ATTR), show)
    with pytest.raises(RuntimeError, match=message.replace("(", r"\(")):
        bpy.ops.endophoton.result_activate()


def _write_vdb(path, name, voxel_size):
    import pyopenvdb as vdb

    grid = vdb.FloatGrid()
    grid.name = name
    grid.gridClass = vdb.GridClass.FOG_VOLUME
    grid.transform = vdb.createLinearTransform(voxelSize=voxel_size)
    dense = np.zeros((12, 12, 12), np.float32)
    dense[2:10, 2:10, 2:10] = np.linspace(0.1, 2.0, 8, dtype=np.float32)[None, None, :]
    grid.copyFromArray(dense)
    vdb.write(str(path), grids=[grid])
    return int(grid.activeVoxelCount())


@pytest.mark.parametrize("scale_length", [1.0, 0.01])
def test_volume_object_loads_grid(tmp_path, scale_length):
    path = tmp_path / "grid.vdb"
    active = _write_vdb(path, "absorbed", 0.001)  # 1 mm voxels, file in metres
    assert active > 0
    obj = volumes.create_volume("EP Grid", str(path), "absorbed", 2.0, 0.001, scale_length, "run")
    bpy.context.scene.collection.objects.link(obj)
    volume = obj.data
    assert volume.grids.load()
    assert [g.name for g in volume.grids] == ["absorbed"]
    assert volume.grids[0].data_type == "FLOAT"
    # Metres in the file -> Blender units through the object scale.
    assert tuple(obj.scale) == pytest.approx((1 / scale_length,) * 3)
    bpy.context.view_layer.update()
    evaluated = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
    corners = np.array([evaluated.matrix_world @ Vector(c) for c in evaluated.bound_box])
    lo_m, hi_m = corners.min(axis=0) * scale_length, corners.max(axis=0) * scale_length
    # Active voxels are indices 2..9 (1 mm); Blender bounds volumes by 8^3 leaf
    # nodes, so the box covers [2, 10) mm and stays within the two leaves [0, 16) mm.
    assert np.all(lo_m <= 0.002 + 1e-6) and np.all(lo_m >= -0.001)
    assert np.all(hi_m >= 0.009 - 1e-6) and np.all(hi_m <= 0.0165)
    # Material: density from the named grid, normalised and scaled.
    nodes = volume.materials[0].node_tree.nodes
    attribute = next(n for n in nodes if n.bl_idname == "ShaderNodeAttribute")
    assert attribute.attribute_name == "absorbed"
    assert nodes[volumes.DENSITY_NODE].outputs[0].default_value == pytest.approx(0.2)
    bpy.context.scene.endophoton.volume_density = 5.0  # no result collection: untouched
    assert nodes[volumes.DENSITY_NODE].outputs[0].default_value == pytest.approx(0.2)


def test_volume_scale_own_shared_log_and_ramp_per_grid(tmp_path):
    """Two grids of one run, maxima 2 and 8: Own Max divides each by its own,
    Shared by 8, Log switches the log branch; each grid has its own ramp."""
    coll = bpy.data.collections.new("EP run")
    coll[results.RESULT_KEY] = True
    bpy.context.scene.collection.children.link(coll)
    objs = {}
    for name, peak in (("absorbed", 2.0), ("fluorescence", 8.0)):
        path = tmp_path / f"{name}.vdb"
        _write_vdb(path, name, 0.001)
        objs[name] = volumes.create_volume(f"EP Grid {name}", str(path), name, peak, 0.001, 1.0, "run")
        coll.objects.link(objs[name])
    settings = bpy.context.scene.endophoton

    def node(name, key):
        return objs[name].data.materials[0].node_tree.nodes[key].outputs[0].default_value

    settings.volume_scale = "SHARED"
    assert node("absorbed", volumes.INV_PEAK_NODE) == pytest.approx(0.125)
    assert node("fluorescence", volumes.INV_PEAK_NODE) == pytest.approx(0.125)
    assert node("absorbed", volumes.LOG_NODE) == 0.0
    settings.volume_scale = "OWN"
    assert node("absorbed", volumes.INV_PEAK_NODE) == pytest.approx(0.5)
    assert node("fluorescence", volumes.INV_PEAK_NODE) == pytest.approx(0.125)
    settings.volume_scale, settings.volume_decades = "LOG", 4.0
    assert node("absorbed", volumes.LOG_NODE) == 1.0 and node("absorbed", volumes.DECADES_NODE) == 4.0
    settings.volume_density = 3.0
    assert node("fluorescence", volumes.DENSITY_NODE) == pytest.approx(3.0)

    def ramp(name):
        nodes = objs[name].data.materials[0].node_tree.nodes
        r = next(n for n in nodes if n.bl_idname == "ShaderNodeValToRGB")
        return [tuple(e.color)[:3] for e in r.color_ramp.elements]

    assert ramp("absorbed") != ramp("fluorescence")
    assert ramp("absorbed")[-1] == pytest.approx(volumes.GRID_RAMPS["absorbed"][-1])


def test_wavelength_colour_without_package_says_so_in_panel(tmp_path):
    """The add-on registers and draws without the package; colouring points by wavelength then
    needs endophoton.view.colour and leaves a plain message in the legend instead of a traceback."""
    import sys

    from endophoton_addon import colour_maps, package_finder
    from conftest import ensure_addon

    obj = _points_in_collection(_records(np.random.default_rng(5), k=50))
    settings = bpy.context.scene.endophoton
    saved = {k: v for k, v in sys.modules.items() if k == "endophoton" or k.startswith("endophoton.")}
    for k in saved:
        del sys.modules[k]
    try:
        ensure_addon(package_path=str(tmp_path))  # a folder without the package
        package_finder.forget()
        with pytest.raises(package_finder.EngineMissing, match="EndoPhoton engine not found"):
            colour_maps.wavelength_rgb([500.0])
        settings.color_by = "WAVELENGTH"
        assert points.recolour(obj, settings) is None
        assert settings.legend_header.startswith("Cannot colour the points: EndoPhoton engine not found")
        assert len(settings.legend) == 0
    finally:
        sys.modules.update(saved)
        ensure_addon()
        package_finder.forget()
    assert points.recolour(obj, settings).unit == "nm"


def test_toward_camera_filter_and_energy_glow():
    """Toward Camera shows the records whose exit direction is within the cone of the direction
    to the scene camera (angles recomputed here with arccos); each shown point glows with its
    energy over the shown records' mean energy."""
    rec = _records(np.random.default_rng(11), k=2000)
    obj = _points_in_collection(rec)
    scene = bpy.context.scene
    camera = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
    scene.collection.objects.link(camera)
    camera.location = (0.003, -0.002, 0.03)
    scene.camera = camera
    bpy.context.view_layer.update()
    settings = scene.endophoton
    settings.camera_cone_deg = 30.0
    settings.filter_toward_camera = True

    to_cam = np.array([0.003, -0.002, 0.03]) - rec["position"].astype(np.float64)
    angle = np.degrees(np.arccos(np.clip(np.sum(rec["direction"] * to_cam, 1) / np.linalg.norm(to_cam, axis=1), -1, 1)))
    expected = angle <= 30.0
    clear = np.abs(angle - 30.0) > 1e-3  # leave rounding at the cone's edge out of the verdict
    show = _attr(obj.data, points.SHOW_ATTR)
    assert 20 < expected.sum() < 1000
    np.testing.assert_array_equal(show[clear], expected[clear])
    strength = _attr(obj.data, points.STRENGTH_ATTR)
    np.testing.assert_allclose(strength, rec["energy"] / rec["energy"][show].mean(), rtol=1e-5)
    settings.filter_toward_camera = False
    assert _attr(obj.data, points.SHOW_ATTR).all()
