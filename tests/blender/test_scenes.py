# SPDX-License-Identifier: MIT
"""blend_scenes/: the committed .blend files match make_scenes.py and hold the
scenes the issue describes."""

import math
import os
import subprocess

import bpy
import numpy as np
import pytest

from endophoton_addon import export, rig
from conftest import BLEND_DIR, ensure_addon

MM = 1e-3
SCENES = ("flat_tissue.blend", "colon_polyp.blend", "colon_polyp_spectral.blend")


def _open(path):
    bpy.ops.wm.open_mainfile(filepath=path)
    ensure_addon()
    return bpy.context.scene


def _world_vertices(obj):
    verts, _tris = export.mesh_arrays(obj, bpy.context.evaluated_depsgraph_get(), 1.0)
    return verts.astype(np.float64)


def _describe(path):
    """Everything that matters about a scene file, as comparable values."""
    scene = _open(path)
    out = {"unit": (scene.unit_settings.system, scene.unit_settings.scale_length), "objects": {}}
    for obj in sorted(scene.objects, key=lambda o: o.name):
        entry = {
            "type": obj.type,
            "parent": obj.parent.name if obj.parent else None,
            "matrix": np.round(np.array(obj.matrix_world), 9).tolist(),
        }
        if obj.type == "MESH":
            v = _world_vertices(obj)
            entry.update(
                vertices=len(obj.data.vertices),
                polygons=len(obj.data.polygons),
                bbox=np.round([v.min(0), v.max(0)], 9).tolist(),
            )
            s = obj.endophoton
            entry.update(
                role=s.role,
                tissue_preset=s.tissue_preset,
                priority=s.priority,
                medium=[round(getattr(s.medium, k), 6) for k in ("mua", "mus", "g", "n")],
                fluorophores=[(f.species, round(f.d, 6), round(f.c, 6)) for f in s.fluorophores],
            )
        if rig.is_rig(obj):
            r = obj.endophoton_rig
            entry["rig"] = [
                round(r.beta, 6),
                round(r.distance, 9),
                tuple(np.round(r.target, 9)),
                tuple(np.round(r.normal, 6)),
                tuple(np.round(r.tilt_axis, 6)),
            ]
        out["objects"][obj.name] = entry
    return out


def test_committed_blends_match_make_scenes(tmp_path):
    script = os.path.join(BLEND_DIR, "make_scenes.py")
    proc = subprocess.run(
        [
            bpy.app.binary_path,
            "-b",
            "--factory-startup",
            "--python-exit-code",
            "1",
            "--python",
            script,
            "--",
            "--out",
            str(tmp_path),
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    for name in SCENES:
        generated = _describe(str(tmp_path / name))
        committed = _describe(os.path.join(BLEND_DIR, name))
        assert committed == generated, f"{name} is out of date: rerun blend_scenes/make_scenes.py"


@pytest.mark.parametrize("name", SCENES)
def test_blend_is_small_and_self_contained(name):
    path = os.path.join(BLEND_DIR, name)
    assert not os.path.exists(path + "1"), "a .blend1 backup next to the scene"
    assert os.path.getsize(path) < 1_000_000
    _open(path)
    assert bpy.utils.blend_paths(absolute=True) == []  # no external files
    assert len(bpy.data.libraries) == 0
    for kind in ("images", "fonts", "sounds", "volumes"):
        assert all(block.packed_file is None for block in getattr(bpy.data, kind)), kind
    depsgraph = bpy.context.evaluated_depsgraph_get()
    regions = export.export_regions(bpy.context.scene, bpy.context.view_layer, depsgraph)  # closed, valid
    assert {r.role for r in regions} == {"TISSUE", "POLYP"}


def test_flat_tissue_is_the_papers_setting():
    scene = _open(os.path.join(BLEND_DIR, "flat_tissue.blend"))
    assert scene.unit_settings.scale_length == 1.0
    tissue, polyp = scene.objects["Tissue"], scene.objects["Polyp"]
    vt, vp = _world_vertices(tissue), _world_vertices(polyp)
    np.testing.assert_allclose(vt.min(0), (-0.02, -0.02, -0.02), atol=1e-7)  # 4 x 4 x 2 cm slab,
    np.testing.assert_allclose(vt.max(0), (0.02, 0.02, 0.0), atol=1e-7)  # top face at z = 0
    assert tissue.endophoton.role == "TISSUE" and polyp.endophoton.role == "POLYP"
    assert polyp.endophoton.priority > tissue.endophoton.priority
    width = vp.max(0) - vp.min(0)
    assert width[0] == pytest.approx(6 * MM, rel=0.01) and width[1] == pytest.approx(6 * MM, rel=0.01)
    assert vp[:, 2].min() < 0.0 < vp[:, 2].max() < width[0] / 2  # flattened, pushed into the surface
    assert [(f.species, round(f.d, 3), round(f.c, 3)) for f in tissue.endophoton.fluorophores] == [
        ("collagen", 0.2, 0.4)
    ]
    assert [(f.species, round(f.d, 3), round(f.c, 3)) for f in polyp.endophoton.fluorophores] == [
        ("collagen", 0.2, 0.4),
        ("photofrin", 0.1, 0.33),
    ]
    head = scene.endophoton.rig
    assert head is not None and head.endophoton_rig.beta == 0.0
    m = np.array(head.matrix_world)
    np.testing.assert_allclose(m[:3, 3], (0.0, 0.0, vp[:, 2].max() + 0.01), atol=1e-6)  # 1 cm above the polyp
    np.testing.assert_allclose(-m[:3, 2], (0.0, 0.0, -1.0), atol=1e-7)
    assert scene.camera is not None and scene.camera.parent == head


def test_colon_polyp_scene():
    scene = _open(os.path.join(BLEND_DIR, "colon_polyp.blend"))
    colon, polyp = scene.objects["Colon"], scene.objects["Polyp"]
    v = _world_vertices(colon)
    length = v[:, 0].max() - v[:, 0].min()
    across = v[:, 1].max() - v[:, 1].min()
    assert length > 0.06 and 0.045 < across < 0.065  # ~5 cm across
    r = np.hypot(v[:, 1], v[:, 2])
    # Two surfaces (outer, inner) with sinusoidal radius (haustral folds), wall 3 mm.
    inner = r < np.median(r)
    assert np.ptp(r[inner]) > 2 * MM  # folds
    depsgraph = bpy.context.evaluated_depsgraph_get()
    verts, tris = export.mesh_arrays(colon, depsgraph, 1.0)
    export.check_closed("Colon", verts, tris)  # watertight, outward
    assert polyp.endophoton.priority > colon.endophoton.priority
    head = scene.endophoton.rig
    pos = np.array(head.matrix_world)[:3, 3]
    assert np.hypot(pos[1], pos[2]) < r[inner].min() - 6 * MM  # head inside the lumen
    target = np.array(head.endophoton_rig.target)
    vp = _world_vertices(polyp)
    assert np.linalg.norm(vp - target, axis=1).min() < 1e-4  # aimed at the polyp
    assert np.linalg.norm(pos - target) == pytest.approx(0.01, abs=1e-6)
    axis = -np.array(head.matrix_world)[:3, 2]
    angle = math.atan2(np.linalg.norm(np.cross(axis, (0, 0, -1))), axis @ (0, 0, -1))
    assert angle == pytest.approx(abs(head.endophoton_rig.beta), abs=1e-6)


def test_colon_polyp_spectral_is_the_colon_with_spectral_presets(ep):
    """colon_polyp_spectral.blend is colon_polyp.blend but for the media: the wall exports as the colon_mucosa
    preset and the polyp as adenomatous_polyp, and the engine scene holds their spectra (docs/media.md)."""
    from endophoton_addon import sweep_blend

    plain = _describe(os.path.join(BLEND_DIR, "colon_polyp.blend"))
    spectral = _describe(os.path.join(BLEND_DIR, "colon_polyp_spectral.blend"))
    for entry in (*plain["objects"].values(), *spectral["objects"].values()):
        for key in ("medium", "tissue_preset"):
            entry.pop(key, None)
    assert plain == spectral
    _open(os.path.join(BLEND_DIR, "colon_polyp_spectral.blend"))
    depsgraph = bpy.context.evaluated_depsgraph_get()
    regions = export.export_regions(bpy.context.scene, bpy.context.view_layer, depsgraph)
    assert {r.name: r.medium["preset"] for r in regions} == {"Colon": "colon_mucosa", "Polyp": "adenomatous_polyp"}
    scene = sweep_blend.blender_regions_to_scene(ep, regions)
    assert {r.name: r.medium for r in scene.regions} == {
        "Colon": ep.media.preset("colon_mucosa"),
        "Polyp": ep.media.preset("adenomatous_polyp"),
    }


@pytest.mark.parametrize("name", SCENES)
def test_scene_opens_framed_in_mm(name):
    """The 3D views look at the tissue from about its size, clip at 0.1 mm, and
    the rig's camera is drawn at the head's size (12 mm), not 1 m."""
    _open(os.path.join(BLEND_DIR, name))
    tissue = [o for o in bpy.data.objects if o.type == "MESH" and o.endophoton.role == "TISSUE"][0]
    size = max(tissue.dimensions)
    views = [
        space
        for screen in bpy.data.screens
        for area in screen.areas
        for space in area.spaces
        if space.type == "VIEW_3D"
    ]
    assert views
    for space in views:
        assert space.clip_start <= 0.0001 + 1e-9 and space.clip_end >= 1.0
        assert 0.5 * size <= space.region_3d.view_distance <= 5 * size
    camera = [o for o in bpy.data.objects if o.type == "CAMERA"][0]
    assert camera.data.display_size == pytest.approx(0.012, rel=1e-3)


def test_colon_polyp_head_stays_in_the_lumen_over_the_default_sweep():
    """The default sweep's last angle, 55 deg, keeps the 12 mm head's face clear of the haustral
    fold beside the polyp (the folds are 3 mm deep; at 4 mm the face met the fold at 55 deg and the
    main job's colon sweep was refused), and 60 deg is refused by name: the face reaches the fold."""
    from endophoton_addon import sweep_blend

    scene = _open(os.path.join(BLEND_DIR, "colon_polyp.blend"))
    res = sweep_blend.sweep_blend(scene, betas=[55], store=50, seed=1, threads=1, progress=False)
    assert [r["beta_deg"] for r in res.rows] == [55.0] and res.rows[0]["records"] == 50
    with pytest.raises(ValueError, match=r"rig\.beta_deg = 60 the endoscope head enters the tissue.*'Colon'"):
        sweep_blend.sweep_blend(scene, betas=[60], store=50, seed=1, threads=1, progress=False)
