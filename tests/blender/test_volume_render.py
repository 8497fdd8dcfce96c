# SPDX-License-Identifier: MIT
"""Issue 15, acceptance 2: every grid of a run renders in Cycles, each alone,
in its own ramp's colour.

Cause of the former failure (about half the grids rendered empty, which ones
following the Volume datablock's name): Cycles 3.4 shifts the bounding mesh of
a volume by up to 0.1/dim *grid units*, hashed from the datablock's name; with
grids in metres that is many voxels (see grid_volumes.RENDER_GRID_SUFFIX).  The
add-on now renders a copy of the grids in voxel index space."""

import os

import bpy
import numpy as np
import pytest

from endophoton_addon import results, simulation
from endophoton_addon import volumes as grid_volumes
from conftest import open_blend


def _render_alone(scene, volume, path):
    """Render ``volume`` alone (all else hidden); linear RGB pixels, (h*w, 3)."""
    for obj in scene.objects:
        obj.hide_render = obj is not volume
    scene.render.filepath = path
    bpy.ops.render.render(write_still=True)
    image = bpy.data.images.load(path)
    try:
        image.colorspace_settings.name = "Non-Color"  # the stored sRGB values, decoded below
        pixels = np.empty(image.size[0] * image.size[1] * 4, np.float32)
        image.pixels.foreach_get(pixels)
    finally:
        bpy.data.images.remove(image)
    srgb = pixels.reshape(-1, 4)[:, :3].astype(np.float64)
    # IEC 61966-2-1 sRGB decoding, independent of Blender's colour management
    return np.where(srgb <= 0.04045, srgb / 12.92, ((srgb + 0.055) / 1.055) ** 2.4)


def _channel_order(stops):
    """Channel pairs (i, j) with stop[i] > stop[j] at every stop of a ramp: any
    sum of such colours (emission along a ray, scattering by the coloured
    medium) keeps that order, so the rendered pixels must too."""
    stops = np.asarray(stops)
    return {(i, j) for i in range(3) for j in range(3) if np.all(stops[:, i] > stops[:, j])}


@pytest.mark.parametrize("blend", ["flat_tissue.blend", "colon_polyp.blend"])
def test_each_grid_renders_alone(ep, tmp_path, out_dir, blend):
    scene = open_blend(blend, tmp_path)
    s = scene.endophoton
    s.quality, s.photons, s.grid_per_fluorophore, s.output_points = "CUSTOM", 20_000, True, False
    job = simulation.prepare_job(bpy.context)
    job.start()
    job.wait()
    collection = simulation.finish_job(bpy.context, job)
    volumes = [o for o in collection.objects if o.type == "VOLUME"]
    current = set(grid_volumes.GRID_RAMPS) - set(grid_volumes.LEGACY_RAMP_NAMES)  # a new run writes the new names
    assert {o["endophoton_grid"] for o in volumes} == current
    cycles_copy = grid_volumes.render_grid_path(job.inputs.grid_path)
    assert os.path.isfile(cycles_copy)
    assert all(os.path.normpath(bpy.path.abspath(o.data.filepath)) == cycles_copy for o in volumes)
    scene.world = None  # black background: any lit pixel is the grid's glow
    render = scene.render
    render.engine = "CYCLES"
    scene.cycles.device, scene.cycles.samples, scene.cycles.use_denoising = "CPU", 8, False
    scene.view_settings.view_transform, scene.view_settings.look = "Standard", "None"
    scene.view_settings.exposure, scene.view_settings.gamma = 0.0, 1.0
    render.resolution_x, render.resolution_y, render.resolution_percentage = 160, 120, 100
    render.image_settings.file_format = "PNG"
    lit, order = {}, {}
    for volume in volumes:
        name = volume["endophoton_grid"]
        rgb = _render_alone(scene, volume, os.path.join(out_dir, f"{blend[:-6]}_grid_{name}.png"))
        mask = rgb.max(axis=1) > 0.05
        lit[name] = int(mask.sum())
        mean = rgb[mask].mean(axis=0) if mask.any() else np.zeros(3)
        order[name] = {(i, j) for i in range(3) for j in range(3) if mean[i] > mean[j]}
    print(blend, lit, order)
    assert all(n > 100 for n in lit.values()), f"grids rendering (nearly) empty: {lit}"
    # each grid glows in its own ramp's hue; the four ramps' channel orders differ
    for name, stops in grid_volumes.GRID_RAMPS.items():
        if name in grid_volumes.LEGACY_RAMP_NAMES:
            continue
        expected = _channel_order(stops)
        assert len(expected) >= 2 and expected <= order[name], (name, expected, order[name])
    results.remove_run(collection)
    assert not os.path.exists(cycles_copy) and not os.path.exists(job.inputs.grid_path)
