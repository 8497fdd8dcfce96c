# SPDX-License-Identifier: MIT
"""Driven by test_background.py in its own `blender -b`: a small run, then a
huge one the test interrupts with one Ctrl-C; prints what is left."""

import os
import sys

import bpy

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from conftest import ensure_addon  # noqa: E402

grid_dir = sys.argv[sys.argv.index("--") + 1]
ensure_addon()
s = bpy.context.scene.endophoton
s.quality, s.photons, s.output_grids = "CUSTOM", 3_000, False
print("FIRST", bpy.ops.endophoton.run_simulation(), flush=True)
s.photons, s.allow_large_runs = 200_000_000, True
print("SECOND", bpy.ops.endophoton.run_simulation(), flush=True)
from endophoton_addon import results  # noqa: E402

print("RESULTS", [c.name for c in results.result_collections(bpy.context.scene)], flush=True)
