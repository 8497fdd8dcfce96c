# SPDX-License-Identifier: MIT
"""The fast tier's Blender smoke test (``bash scripts/test.sh --fast`` runs this file alone): the add-on
registers and finds the engine, and one small run through the operator puts its records in the scene."""

import bpy

from conftest import open_blend


def test_addon_runs_a_small_store_run_into_the_scene(ep, tmp_path):
    scene = open_blend("flat_tissue.blend", tmp_path)
    settings = scene.endophoton
    settings.quality = "CUSTOM"
    settings.mode = "STORE"
    settings.store = 500
    settings.fluorescent_only = True
    settings.output_grids = False
    assert bpy.ops.endophoton.run_simulation() == {"FINISHED"}
    points = [o for o in settings.result_collection.objects if o.type == "MESH"]
    assert len(points) == 1 and len(points[0].data.vertices) == 500
    assert not [o for o in settings.result_collection.objects if o.type == "VOLUME"]
