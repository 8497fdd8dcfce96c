# SPDX-License-Identifier: MIT
"""Issue 15, acceptance 4: each mistake is caught before any work starts, with
a message naming the field, and leaves the scene and the files unchanged."""

import os

import bpy
import numpy as np
import pytest

from endophoton_addon import export, guards, rig
from conftest import data_snapshot, mesh_object

# A 40 × 40 × 20 mm slab (metres) and a 6 mm box half pushed into it.
SLAB_V = np.array(
    [[-1, -1, -1], [1, -1, -1], [1, 1, -1], [-1, 1, -1], [-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], dtype=float
) * [0.02, 0.02, 0.02]
BOX_F = np.array([[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]])
CUBE_V = (
    np.array(
        [[-1, -1, -1], [1, -1, -1], [1, 1, -1], [-1, 1, -1], [-1, -1, 1], [1, -1, 1], [1, 1, 1], [-1, 1, 1]],
        dtype=float,
    )
    * 0.003
)


def _scene(tmp_path, polyp_priority=1):
    tissue = mesh_object("Tissue", SLAB_V, [BOX_F])
    tissue.endophoton.role = "TISSUE"
    polyp = mesh_object("Polyp", CUBE_V, [BOX_F])
    polyp.endophoton.role = "POLYP"
    polyp.endophoton.priority = polyp_priority
    rig.create_rig(bpy.context, target=(0, 0, 0.003))
    s = bpy.context.scene.endophoton
    s.quality, s.photons, s.grid_dir = "CUSTOM", 1000, str(tmp_path / "grids")
    return s


def _files(tmp_path):
    return sorted(os.path.relpath(os.path.join(d, f), tmp_path) for d, _, fs in os.walk(tmp_path) for f in fs)


def _assert_rejected(tmp_path, pattern):
    before, files = data_snapshot(), _files(tmp_path)
    with pytest.raises(RuntimeError, match=pattern):
        bpy.ops.endophoton.run_simulation()
    assert data_snapshot() == before
    assert _files(tmp_path) == files


def test_sizes_and_wall_thickness_in_mm(tmp_path):
    """2V/A of a slab W×W×T: 2·W²T / (2W² + 4WT); here W = 40, T = 20 mm -> 10 mm."""
    _scene(tmp_path)
    regions = export.export_regions(bpy.context.scene, bpy.context.view_layer, bpy.context.evaluated_depsgraph_get())
    sizes = {name: (extent, t, mfp) for name, extent, t, mfp in guards.region_sizes(regions)}
    w, t = 40.0, 20.0
    np.testing.assert_allclose(sizes["Tissue"][0], [w, w, t], rtol=1e-6)
    assert sizes["Tissue"][1] == pytest.approx(2 * w * w * t / (2 * w * w + 4 * w * t), rel=1e-6)
    assert sizes["Tissue"][2] == pytest.approx(10.0 / (20.0 + 200.0 * (1 - 0.9)), rel=1e-6)  # role default medium
    assert bpy.ops.endophoton.check_scene() == {"FINISHED"}
    report = bpy.context.scene.endophoton.scene_report
    assert "Tissue: 40×40×20 mm" in report and "Run: packets ≤ 1,000" in report


def test_wrong_unit_scale_is_refused(tmp_path):
    """The slab in millimetres read as metres' 1/1000: a 20 µm-thick 'colon'."""
    _scene(tmp_path)
    bpy.context.scene.unit_settings.scale_length = 0.001
    _assert_rejected(
        tmp_path,
        r"unit_settings.scale_length = 0.001 m per unit makes region 'Tissue' "
        r"0.01 mm thick, 0.04 transport mean free paths",
    )


def test_overlap_with_equal_priority_is_refused_by_name(tmp_path):
    _scene(tmp_path, polyp_priority=0)
    _assert_rejected(tmp_path, r"Objects '(Tissue|Polyp)' and '(Tissue|Polyp)' overlap with the same priority = 0")


def test_touching_regions_of_equal_priority_are_accepted(tmp_path):
    """Two slabs sharing a face (an MCML layer stack) do not overlap."""
    top = mesh_object("Top", SLAB_V + [0, 0, 0.02], [BOX_F])
    bottom = mesh_object("Bottom", SLAB_V, [BOX_F])
    for obj in (top, bottom):
        obj.endophoton.role = "TISSUE"
    regions = export.export_regions(bpy.context.scene, bpy.context.view_layer, bpy.context.evaluated_depsgraph_get())
    guards.check_overlaps(regions)  # no error


def test_large_run_asks_first(tmp_path):
    s = _scene(tmp_path)
    s.photons = 150_000_000
    _assert_rejected(
        tmp_path, r"this run is large: packets ≤ 150,000,000, records ≤ 150,000,000, " r"memory ≤ 28,610 MiB"
    )


def test_grid_folder_below_a_file_is_refused_up_front(tmp_path):
    s = _scene(tmp_path)
    blocker = tmp_path / "blocker"
    blocker.write_text("not a folder")
    s.grid_dir = str(blocker / "grids")
    _assert_rejected(tmp_path, r"simulation.grid_dir = '.*blocker/grids': '.*blocker' is a file, not a folder")


def test_voxel_size_too_small_is_refused_up_front(tmp_path):
    s = _scene(tmp_path)
    s.voxel_size = 0.00005  # 50 µm over a 40 × 40 × 23 mm scene: (800 + 1)² (460 + 1) ≈ 2.96e8 voxels
    _assert_rejected(tmp_path, r"simulation.voxel_size = 0.05 mm gives up to 2.9\de\+08 voxels")


@pytest.mark.parametrize(
    "scale, pattern",
    [
        # mm numbers in a metre scene: the 40 mm slab's numbers read as metres (×1000) -> 40 m across
        (1000.0, r"region 'Tissue' is 40 m across with unit_settings.scale_length = 1000 m per unit, larger than 1 m"),
        # ×100: 4 m across (the voxel guard used to catch this with the wrong advice)
        (100.0, r"region 'Tissue' is 4 m across .* larger than 1 m"),
    ],
)
def test_scale_up_is_refused_as_a_unit_mistake_with_the_fix(tmp_path, scale, pattern):
    """Issue 36, defect 5: scale-ups ran silently; now a region larger than 1 m is a unit mistake
    and the message says how to fix it."""
    _scene(tmp_path)
    bpy.context.scene.unit_settings.scale_length = scale
    _assert_rejected(tmp_path, pattern + r".*millimetre numbers in a metre scene.*Unit Scale to 0\.001")


def test_thickness_above_1000_transport_mfp_is_a_scale_up(tmp_path):
    """A 20 mm slab of a strongly scattering medium (μs' = 600 cm⁻¹): 10 mm = 6000 transport mfp."""
    s = _scene(tmp_path)
    tissue = bpy.data.objects["Tissue"]
    tissue.endophoton.medium.mus, tissue.endophoton.medium.g = 6000.0, 0.0
    s.output_grids = False
    _assert_rejected(tmp_path, r"region 'Tissue' is 10 mm thick .* more than 1000: no light crosses it.*Unit Scale")


def test_voxel_advice_names_a_size_that_fits(tmp_path):
    """The voxel guard's advice is a size, and that size passes."""
    s = _scene(tmp_path)
    s.voxel_size = 0.00005
    with pytest.raises(RuntimeError, match=r"choose a voxel size of at least ([\d.]+) mm") as caught:
        bpy.ops.endophoton.run_simulation()
    import re

    advised_mm = float(re.search(r"at least ([\d.]+) mm", str(caught.value)).group(1))
    regions = export.export_regions(bpy.context.scene, bpy.context.view_layer, bpy.context.evaluated_depsgraph_get())
    guards.check_voxels(regions, advised_mm * 1e-3, "Scene")  # no error


def test_unwritable_grid_folder_is_named_not_a_traceback(tmp_path, capfd):
    """Issue 36, defect 7: /proc/nope passes os.access for root; the folder check tries it."""
    s = _scene(tmp_path)
    s.grid_dir = "/proc/nope"
    _assert_rejected(tmp_path, r"simulation.grid_dir = '/proc/nope': '/proc' is not writable")
    assert "Traceback" not in capfd.readouterr().err
