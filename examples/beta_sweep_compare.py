# SPDX-License-Identifier: MIT
"""A β sweep from bpy that keeps every run and compares them.

    blender -b blend_scenes/colon_polyp.blend --python-exit-code 1 --python examples/beta_sweep_compare.py -- [PACKETS]

Each β is its own result collection (tagged with its parameters), so the runs
sit side by side in the outliner; the table compares the diffuse reflectance
(± its standard error) and the share of fluorescence that is photofrin's among
the records leaving the polyp.  The add-on's Sweep β operator
(`bpy.ops.endophoton.sweep_beta`) runs the paper's store-N sweep with plots;
this script shows the same idea with the Run operator and the kept results.
"""

import math
import sys

import addon_utils
import bpy
import numpy as np

if not hasattr(bpy.types.Scene, "endophoton"):
    addon_utils.enable("endophoton_addon", default_set=True)
from endophoton_addon import points as point_cloud, results  # noqa: E402

argv = sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else []
packets = int(argv[0]) if argv else 20_000
scene = bpy.context.scene
s = scene.endophoton
s.quality, s.mode, s.photons, s.output_grids = "CUSTOM", "PHOTONS", packets, False
rig = s.rig or next(o for o in scene.objects if o.type == "EMPTY" and o.endophoton_rig.is_rig)

for beta in (0.0, 20.0, 40.0):
    rig.endophoton_rig.beta = math.radians(beta)
    assert bpy.ops.endophoton.run_simulation() == {"FINISHED"}

print(f"{'β [deg]':>8} {'Rd':>8} {'± se':>7} {'photofrin share of polyp fluorescence':>38}")
for collection in results.result_collections(scene):
    params = collection[results.PARAMS_KEY]
    rd, rd_se = collection[results.SUMMARY_KEY]["totals"]["diffuse_reflectance"]
    points = point_cloud.points_objects(collection)[0]
    columns = point_cloud.read_point_columns(points.data)
    names = point_cloud.point_names(points)
    polyp = columns["region"] == names["region"].index("Polyp")
    fluorescent = polyp & columns["fluorescent"].astype(bool)
    photofrin = fluorescent & (columns["fluorophore"] == names["fluorophore"].index("photofrin"))
    share = photofrin.sum() / max(1, fluorescent.sum())
    share_se = math.sqrt(share * (1 - share) / max(1, fluorescent.sum()))  # binomial
    print(f"{params['beta_deg']:8.1f} {rd:8.4f} {rd_se:7.4f} {share:31.3f} ± {share_se:.3f}")
