"""Main job, Blender part: one beta of the sweep as a scene you can open.

Run inside Blender on blend_scenes/flat_tissue.blend:

    blender -b blend_scenes/flat_tissue.blend --python scripts/main_job_scene.py -- --out DIR --beta 30

It sets the rig's beta, runs the engine through the add-on (surface point cloud
and volume grids), saves DIR/scene_beta<B>.blend, renders DIR/render_beta<B>.png
with Cycles and appends what it made, with the run's totals, to DIR/report.md
(--section FILE: writes that section to FILE instead, for a caller that appends it later).
"""
import argparse
import math
import os
import sys

import bpy
import numpy as np


def main(argv):
    ap = argparse.ArgumentParser(prog="main_job_scene.py")
    ap.add_argument("--out", required=True)
    ap.add_argument("--beta", type=float, default=30.0)
    ap.add_argument("--store", type=int, default=100_000)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--voxel", type=float, default=0.0004, help="voxel size in metres")
    ap.add_argument("--samples", type=int, default=32)
    ap.add_argument("--section", default=None, help="write the report's section to this file (default: append)")
    args = ap.parse_args(argv)
    out = os.path.abspath(args.out)
    os.makedirs(out, exist_ok=True)

    # the add-on: installed in Blender, else the source tree's addon/ (or $ENDOPHOTON_ADDON_PATH)
    repo = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    sys.path.append(os.environ.get("ENDOPHOTON_ADDON_PATH") or os.path.join(repo, "addon"))
    from endophoton_addon.sweep_blend import enable_addon

    enable_addon()
    from endophoton_addon import simulation

    scene = bpy.context.scene
    rig = scene.endophoton.rig or next(o for o in scene.objects if o.endophoton_rig.is_rig)
    rig.endophoton_rig.beta = math.radians(args.beta)  # an ANGLE property: radians inside
    bpy.context.view_layer.update()
    s = scene.endophoton
    s.quality = "CUSTOM"
    s.mode = "STORE"
    s.store = args.store
    s.fluorescent_only = True
    s.seed = args.seed
    s.output_points = True
    s.output_grids = True
    s.voxel_size = args.voxel
    s.grid_dir = out
    job = simulation.prepare_job(bpy.context)
    job.start()
    while not job.wait(0.1):
        pass
    if simulation.finish_job(bpy.context, job) is None:
        raise SystemExit("main job: the run was cancelled")
    result = job.result

    tag = f"beta{args.beta:g}"
    blend_path = os.path.join(out, f"scene_{tag}.blend")
    bpy.ops.wm.save_as_mainfile(filepath=blend_path, copy=True)

    render = scene.render
    render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = args.samples
    scene.cycles.use_denoising = False
    render.resolution_x, render.resolution_y, render.resolution_percentage = 640, 480, 100
    render.image_settings.file_format = "PNG"
    render.filepath = os.path.join(out, f"render_{tag}.png")
    bpy.ops.render.render(write_still=True)
    image = bpy.data.images.load(render.filepath)
    px = np.empty(image.size[0] * image.size[1] * 4, np.float32)
    image.pixels.foreach_get(px)
    rgb_std = float(px.reshape(-1, 4)[:, :3].std())

    lines = ["", f"## One angle in Blender: beta = {args.beta:g} deg", ""]
    lines.append(f"- Scene with the surface point cloud and the volume grids: `{os.path.basename(blend_path)}`")
    lines.append(
        f"- Cycles render ({args.samples} samples, 640x480, pixel std {rgb_std:.3f}): "
        f"`{os.path.basename(render.filepath)}`"
    )
    if result is not None:
        lines.append(f"- Packets traced to store {args.store} fluorescent surface photons: {result.packets_traced}")
        for k in ("specular_reflectance", "diffuse_reflectance", "absorbed"):
            lines.append(f"- {k}: {getattr(result, k):.5f} +- {getattr(result, k + '_stderr'):.5f}")
        if result.grid_path:
            lines.append(f"- Volume grids: `{os.path.basename(result.grid_path)}` ({', '.join(result.grid_names)})")
    from endophoton.io import atomic_write_text  # the package the add-on runs (found by enable_addon)

    if args.section is not None:
        atomic_write_text(args.section, "\n".join(lines) + "\n")
    else:
        report = os.path.join(out, "report.md")
        text = open(report, encoding="utf-8").read() if os.path.exists(report) else "# EndoPhoton main job\n"
        atomic_write_text(report, text.rstrip("\n") + "\n" + "\n".join(lines) + "\n")
    print(f"main job scene: {blend_path}, {render.filepath}")


if __name__ == "__main__":
    argv = sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else []
    main(argv)
