# SPDX-License-Identifier: MIT
"""Meshes -> engine arrays: modifiers applied, world space, unit scale, winding."""

import bpy
import numpy as np
import pytest

from endophoton_addon import export
from endophoton_addon.errors import InputError
from conftest import mesh_object

CUBE_V = np.array(
    [[-1, -1, -1], [1, -1, -1], [1, 1, -1], [-1, 1, -1], [-1, -1, 1], [1, -1, 1], [1, 1, 1], [-1, 1, 1]], dtype=float
)
CUBE_F = [np.array([[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]])]


def _arrays(obj, scale=None):
    depsgraph = bpy.context.evaluated_depsgraph_get()
    if scale is None:
        scale = bpy.context.scene.unit_settings.scale_length
    return export.mesh_arrays(obj, depsgraph, scale)


def _signed_volume(v, t):
    v = v.astype(np.float64)
    a, b, c = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum()) / 6.0


def test_world_space_and_dtypes():
    obj = mesh_object("Cube", CUBE_V, CUBE_F)
    obj.location = (1.0, 2.0, 3.0)
    obj.rotation_euler = (0.0, 0.0, np.pi / 2)
    obj.scale = (2.0, 1.0, 1.0)
    bpy.context.view_layer.update()
    v, t = _arrays(obj)
    assert v.dtype == np.float32 and v.shape == (8, 3)
    assert t.dtype == np.uint32 and t.shape == (12, 3)
    expected = np.array([tuple(obj.matrix_world @ vert.co) for vert in obj.data.vertices])
    np.testing.assert_allclose(v, expected, atol=1e-6)
    # Rotated 90° about z with x scale 2: extent is 2 along y, 4 along ... check the box.
    np.testing.assert_allclose(v.min(axis=0), (0.0, 0.0, 2.0), atol=1e-6)
    np.testing.assert_allclose(v.max(axis=0), (2.0, 4.0, 4.0), atol=1e-6)
    assert _signed_volume(v, t) == pytest.approx(16.0, rel=1e-6)


def test_unit_scale_converts_to_metres():
    bpy.context.scene.unit_settings.scale_length = 0.001  # 1 BU = 1 mm
    obj = mesh_object("Cube", CUBE_V * 10.0, CUBE_F)  # 20 mm cube
    v, _t = _arrays(obj)
    np.testing.assert_allclose(v.max(axis=0) - v.min(axis=0), (0.02, 0.02, 0.02), rtol=1e-6)


def test_modifiers_are_applied():
    obj = mesh_object("Cube", CUBE_V, CUBE_F)
    subsurf = obj.modifiers.new("subsurf", "SUBSURF")
    subsurf.levels = 2
    array = obj.modifiers.new("array", "ARRAY")
    array.count = 2
    array.relative_offset_displace = (3.0, 0.0, 0.0)  # two separate closed blobs
    v, t = _arrays(obj)
    assert len(t) == 2 * 6 * 16 * 2  # 2 copies x 6 faces x 16 quads x 2 triangles
    assert v[:, 0].max() > 5.0  # the array copy is there
    export.check_closed("Cube", v, t)  # still closed and outward


def test_mirrored_object_keeps_outward_winding():
    obj = mesh_object("Cube", CUBE_V, CUBE_F)
    obj.scale = (-1.0, 1.0, 1.0)
    bpy.context.view_layer.update()
    v, t = _arrays(obj)
    assert _signed_volume(v, t) == pytest.approx(8.0, rel=1e-6)


def test_open_mesh_is_rejected():
    obj = mesh_object("Lid", CUBE_V, [CUBE_F[0][1:]])  # top face missing
    v, t = _arrays(obj)
    with pytest.raises(InputError, match=r"Object 'Lid': mesh is open \(4 boundary edges"):
        export.check_closed("Lid", v, t)


def test_inward_normals_are_rejected():
    obj = mesh_object("Inside", CUBE_V, [CUBE_F[0][:, ::-1]])
    v, t = _arrays(obj)
    with pytest.raises(InputError, match="Object 'Inside': normals point inward"):
        export.check_closed("Inside", v, t)


def test_export_regions_collects_role_objects_with_settings():
    tissue = mesh_object("Tissue", CUBE_V, CUBE_F)
    tissue.endophoton.role = "TISSUE"
    polyp = mesh_object("Polyp", CUBE_V * 0.5, CUBE_F)
    polyp.endophoton.role = "POLYP"
    mesh_object("Ignored", CUBE_V, CUBE_F)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    regions = export.export_regions(bpy.context.scene, bpy.context.view_layer, depsgraph)
    by_name = {r.name: r for r in regions}
    assert set(by_name) == {"Tissue", "Polyp"}
    assert by_name["Tissue"].fluorophores == [("collagen", pytest.approx(0.2), pytest.approx(0.4))]
    assert [f[0] for f in by_name["Polyp"].fluorophores] == ["collagen", "photofrin"]
    assert by_name["Polyp"].fluorophores[1][1:] == (pytest.approx(0.1), pytest.approx(0.33))
    assert by_name["Polyp"].priority > by_name["Tissue"].priority
    # The seed paper's tissue (oracles §5): n = 1.1, mua = 20, mus = 200 cm^-1, g = 0.9.
    assert by_name["Tissue"].medium == {"mua": 20.0, "mus": 200.0, "g": pytest.approx(0.9), "n": pytest.approx(1.1)}


def test_spectral_preset_is_exported_by_name_until_a_field_is_edited(ep):
    """Choosing a spectral tissue preset sends its ep.media name (the engine builds the spectra from it); editing
    a medium field by hand turns the menu back to Custom and the constant medium shown is exported."""
    from endophoton_addon import presets, sweep_blend

    tissue = mesh_object("Tissue", CUBE_V, CUBE_F)
    tissue.endophoton.role = "TISSUE"
    tissue.endophoton.tissue_preset = "COLON_MUCOSA"
    shown = presets.TISSUE_PRESETS["COLON_MUCOSA"].medium
    medium, _priority, _fl = export.validate_object_settings(tissue)
    assert medium["preset"] == "colon_mucosa"
    assert {k: medium[k] for k in shown} == pytest.approx(shown)
    (region,) = export.export_regions(bpy.context.scene, bpy.context.view_layer, bpy.context.evaluated_depsgraph_get())
    scene = sweep_blend.blender_regions_to_scene(ep, [region])
    assert scene.regions[0].medium == ep.media.preset("colon_mucosa") and scene.regions[0].medium.spectral
    tissue.endophoton.medium.mua = 5.0  # a hand edit ends the spectral preset
    assert tissue.endophoton.tissue_preset == "CUSTOM"
    medium, _priority, _fl = export.validate_object_settings(tissue)
    assert "preset" not in medium and medium["mua"] == 5.0
    tissue.endophoton.tissue_preset = "ADENOMATOUS_POLYP"
    tissue.endophoton.role = "POLYP"  # the role's defaults are a hand edit too: back to the paper's medium
    assert tissue.endophoton.tissue_preset == "CUSTOM"
    assert "preset" not in export.validate_object_settings(tissue)[0]
