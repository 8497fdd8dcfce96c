# SPDX-License-Identifier: MIT
"""Issue 36, defect 8: run names readable in the list, paths stored //-relative in a saved .blend."""

import os

import bpy

from endophoton_addon import panels
from test_issue36_picture import _slab_run


def test_run_label_keeps_beta_and_time_whole():
    label = panels.run_label("EP β=+20.0° 20250105-071536")
    assert label == "β=+20.0° 07:15:36" and len(label) <= panels.SIDEBAR_CHARS - 8  # room for eye and X


def _volume_paths():
    return [v.filepath for v in bpy.data.volumes]


def test_paths_are_relative_in_a_saved_blend(ep, tmp_path):
    """A run in a saved .blend stores its .vdb //-relative; the saved file holds that."""
    blend = str(tmp_path / "scene.blend")
    bpy.ops.wm.save_as_mainfile(filepath=blend)
    bpy.context.scene.endophoton.grid_dir = "//grids"
    _slab_run(packets=1000, grids=True)
    assert _volume_paths() and all(p.startswith("//grids/") for p in _volume_paths())
    bpy.ops.wm.save_mainfile()
    bpy.ops.wm.open_mainfile(filepath=blend)
    assert _volume_paths() and all(p.startswith("//grids/") for p in _volume_paths())
    assert all(os.path.isfile(bpy.path.abspath(p)) for p in _volume_paths())


def test_absolute_paths_of_an_unsaved_file_become_relative_when_saved(ep, tmp_path):
    bpy.context.scene.endophoton.grid_dir = str(tmp_path / "grids")
    _slab_run(packets=1000, grids=True)
    assert all(os.path.isabs(p) for p in _volume_paths())
    blend = str(tmp_path / "later.blend")
    bpy.ops.wm.save_as_mainfile(filepath=blend)
    bpy.ops.wm.open_mainfile(filepath=blend)
    assert _volume_paths() and all(p.startswith("//grids/") for p in _volume_paths())
    assert all(os.path.isfile(bpy.path.abspath(p)) for p in _volume_paths())


def test_a_blend_opened_by_a_relative_path_keeps_absolute_grid_paths(ep, tmp_path, monkeypatch):
    """open_mainfile("blend_scenes/x.blend") leaves bpy.data.filepath relative; Blender
    resolves "//" against it without the working directory, so the run's grids must
    stay absolute to load (the docs/addon.md snippet in a clone under /tmp failed so)."""
    repo = tmp_path / "repo"
    (repo / "blend_scenes").mkdir(parents=True)
    bpy.ops.wm.save_as_mainfile(filepath=str(repo / "blend_scenes" / "scene.blend"))
    monkeypatch.chdir(repo)
    bpy.ops.wm.open_mainfile(filepath="blend_scenes/scene.blend")
    assert not os.path.isabs(bpy.data.filepath)
    bpy.context.scene.endophoton.grid_dir = str(tmp_path / "grids")
    _slab_run(packets=1000, grids=True)
    assert _volume_paths() and all(os.path.isabs(p) for p in _volume_paths())
    assert all(len(v.grids) > 0 for v in bpy.data.volumes)
