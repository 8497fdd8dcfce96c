# SPDX-License-Identifier: MIT
"""Blender side of the results, from inputs this test makes itself: the
point-cloud builder (arrays shaped like the engine's escape records) and the
Volume object (a .vdb written here with pyopenvdb).  The end-to-end tests with
the real engine are in test_end_to_end.py."""

import bpy
import numpy as np
import pytest
from mathutils import Vector

from endophoton_addon import results

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
    positions, attrs = results.point_cloud_arrays(rec, scale_length)
    material = results._points_material("m", "WAVELENGTH", float(rec["energy"].max()), "run")
    obj = results.create_point_cloud("Photons", positions, attrs, 0.0001, material, "run")
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
    assert modifier.type == "NODES" and modifier.node_group.name == results.POINTS_GROUP
    assert any(n.bl_idname == "GeometryNodeMeshToPoints" for n in modifier.node_group.nodes)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    clouds = [inst.object.data for inst in depsgraph.object_instances
              if inst.object.type == "POINTCLOUD" and inst.object.original == obj]
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
        results.point_cloud_arrays(rec, 1.0)
    assert len(bpy.data.meshes) == before


def test_colour_mode_and_radius_update_results():
    rec = _records(np.random.default_rng(3), k=50)
    positions, attrs = results.point_cloud_arrays(rec, 1.0)
    material = results._points_material("m", "WAVELENGTH", 1.0, "run")
    obj = results.create_point_cloud("Photons", positions, attrs, 0.0001, material, "run")
    coll = bpy.data.collections.new("EP run")
    coll[results.RESULT_KEY] = True
    bpy.context.scene.collection.children.link(coll)
    coll.objects.link(obj)
    mode = material.node_tree.nodes[results.COLOUR_MODE_NODE].outputs[0]
    assert mode.default_value == 0.0
    settings = bpy.context.scene.endophoton
    settings.color_by = "ENERGY"
    assert mode.default_value == 1.0
    settings.point_radius = 0.0007
    ids = results._group_input_identifiers(obj.modifiers[0].node_group)
    assert obj.modifiers[0][ids["Radius"]] == pytest.approx(0.0007)


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
    active = _write_vdb(path, "absorbed", 0.001)   # 1 mm voxels, file in metres
    assert active > 0
    obj = results.create_volume("EP Grid", str(path), "absorbed", 2.0, 0.001, 50.0, scale_length, "run")
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
    assert nodes[results.DENSITY_NODE].outputs[0].default_value == pytest.approx(50.0)
    bpy.context.scene.endophoton.volume_density = 5.0   # no result collection: untouched
    assert nodes[results.DENSITY_NODE].outputs[0].default_value == pytest.approx(50.0)
