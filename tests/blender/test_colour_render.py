# SPDX-License-Identifier: MIT
"""Issue 15, acceptance 1: from the endoscope camera, a Cycles render of the
results of colon_polyp.blend with "fluorescent only, colour = wavelength"
shows the polyp's photofrin as a red region distinct from the collagen of the
wall, and the render with legend is written.

What the camera records is light leaving the tissue toward it, so the points
shown are the fluorescence records whose exit direction lies within the
camera cone (15°, ep.render_view's kernel angle) of the direction to the
camera; they glow in proportion to their energy and add up (emission +
transparent), and the tissue itself renders black and opaque, hiding what the
camera cannot see.

The polyp's and the wall's pixels come from the geometry alone: a ray from the
camera through each pixel centre, cast with Blender's own ray_cast against the
Colon and Polyp meshes, says which surface the pixel sees (masks eroded by two
pixels so points straddling an edge do not count).  Red/green is the ratio
of the summed red to the summed green over a mask's pixels (linear values from
an OpenEXR render); its standard error treats 12 x 12-pixel tiles as the
independent units (a tile is several point diameters across) with the
delta-method variance of a ratio of sums.
"""

import os

import bpy
import numpy as np
import pytest
from mathutils import Vector

from endophoton_addon import results, simulation
from conftest import open_blend

# 10^6 packets: the polyp fills ~1,300 of the 57,600 pixels and its red/green has a standard error
# of about 0.06 at this count (0.09 at 3 x 10^5, too few for the 4 σ test).
PACKETS = 1_000_000
SIZE = 240  # render width = height, pixels
TILE = 12  # pixels per side of the tiles that carry the standard error


def _render_linear(scene, path):
    """Render to OpenEXR (linear scene values, no view transform) and return (H, W, 3), row 0 at the bottom."""
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.render.filepath = path
    bpy.ops.render.render(write_still=True)
    image = bpy.data.images.load(path)
    w, h = image.size
    pixels = np.empty(w * h * 4, np.float32)
    image.pixels.foreach_get(pixels)
    bpy.data.images.remove(image)
    return pixels.reshape(h, w, 4)[..., :3].astype(np.float64)


def surface_seen(scene, camera, objects, size):
    """(size, size) index into ``objects`` of the surface each pixel centre sees (-1: none), rows bottom-up,
    by casting the pixel's ray from the camera against each object (object space) and keeping the nearest."""
    scene.render.resolution_x = scene.render.resolution_y = size
    frame = camera.data.view_frame(scene=scene)  # top-right, bottom-right, bottom-left, top-left (camera space)
    bottom_left, right, up = frame[2], frame[1] - frame[2], frame[3] - frame[2]
    origin = camera.matrix_world.translation
    rot = camera.matrix_world.to_3x3()
    seen = np.full((size, size), -1, dtype=np.int32)
    for row in range(size):
        for col in range(size):
            local = bottom_left + (col + 0.5) / size * right + (row + 0.5) / size * up
            direction = (rot @ local).normalized()
            nearest = np.inf
            for k, obj in enumerate(objects):
                inv = obj.matrix_world.inverted()
                o, d = inv @ origin, (inv.to_3x3() @ direction)
                hit, location, _n, _i = obj.ray_cast(o, d.normalized())
                if hit:
                    t = (obj.matrix_world @ location - origin).length
                    if t < nearest:
                        nearest, seen[row, col] = t, k
    return seen


def erode(mask, pixels):
    out = mask.copy()
    for _ in range(pixels):
        inner = out.copy()
        inner[1:, :] &= out[:-1, :]
        inner[:-1, :] &= out[1:, :]
        inner[:, 1:] &= out[:, :-1]
        inner[:, :-1] &= out[:, 1:]
        out = inner
    return out


def red_over_green(rgb, mask, tile=TILE):
    """ΣR/ΣG over the mask's pixels and its standard error, tiles as independent units (delta method):
    var(q) = n/(n-1) Σ_t (R_t - q G_t)² / (Σ_t G_t)² over the n tiles holding mask pixels."""
    h, w, _ = rgb.shape
    tile_of = (np.arange(h)[:, None] // tile) * ((w + tile - 1) // tile) + np.arange(w)[None, :] // tile
    ids = tile_of[mask]
    r = np.bincount(ids, weights=rgb[..., 0][mask])
    g = np.bincount(ids, weights=rgb[..., 1][mask])
    used = np.bincount(ids) > 0
    r, g = r[used], g[used]
    n = len(r)
    q = r.sum() / g.sum()
    var = n / (n - 1) * np.sum((r - q * g) ** 2) / g.sum() ** 2
    return q, float(np.sqrt(var)), n


def test_polyp_photofrin_renders_red_from_endoscope(ep, tmp_path, out_dir):
    scene = open_blend("colon_polyp.blend", tmp_path)
    s = scene.endophoton
    s.quality, s.mode, s.photons, s.output_grids = "CUSTOM", "PHOTONS", PACKETS, False
    s.fluorescent_only = True  # the engine keeps only the records shown
    camera = next(o for o in scene.objects if o.type == "CAMERA")
    scene.camera = camera
    tissue = [bpy.data.objects["Colon"], bpy.data.objects["Polyp"]]
    seen = surface_seen(scene, camera, tissue, SIZE)
    wall_mask, polyp_mask = erode(seen == 0, 2), erode(seen == 1, 2)
    assert polyp_mask.sum() > 500 and wall_mask.sum() > 500, (polyp_mask.sum(), wall_mask.sum())

    job = simulation.prepare_job(bpy.context)
    job.start()
    job.wait()
    collection = simulation.finish_job(bpy.context, job)
    assert collection is not None
    # The camera's view: the records' light on opaque black tissue, nothing else.
    black = bpy.data.materials.new("black tissue")
    black.use_nodes = True
    black.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (0, 0, 0, 1)
    black.node_tree.nodes["Principled BSDF"].inputs["Specular"].default_value = 0.0
    for obj in scene.objects:
        obj.hide_render = obj.name not in collection.all_objects and obj not in tissue
    for obj in tissue:
        obj.data.materials.clear()
        obj.data.materials.append(black)
    scene.world = None
    render = scene.render
    render.engine = "CYCLES"
    scene.cycles.device, scene.cycles.samples, scene.cycles.use_denoising = "CPU", 16, False
    scene.cycles.transparent_max_bounces = 64
    render.resolution_x, render.resolution_y, render.resolution_percentage = SIZE, SIZE, 100
    s.point_radius = 0.00015

    s.color_by, s.filter_fluorescent, s.filter_toward_camera = "WAVELENGTH", True, True
    rgb = _render_linear(scene, os.path.join(out_dir, "colon_polyp_fluorescent_wavelength.exr"))
    (qp, sp, tp), (qw, sw, tw) = red_over_green(rgb, polyp_mask), red_over_green(rgb, wall_mask)
    sigma = np.hypot(sp, sw)
    print(
        f"red/green polyp {qp:.3f}±{sp:.3f} ({polyp_mask.sum()} px, {tp} tiles), "
        f"wall {qw:.3f}±{sw:.3f} ({wall_mask.sum()} px, {tw} tiles), difference {(qp - qw) / sigma:.1f} σ"
    )
    assert rgb[polyp_mask].sum() > 0 and rgb[wall_mask].sum() > 0
    assert qp - qw > 4 * sigma

    # The legend: wavelength in nm over the shown (fluorescent) records.
    legend = results.legend_of(results.points_objects(collection)[0])
    assert legend.unit == "nm" and legend.lo >= 380 and legend.hi <= 830 and legend.hi > 600
    assert s.legend_header.startswith("Wavelength [nm]") and len(s.legend) >= 2
    path = os.path.join(out_dir, "colon_polyp_with_legend.png")
    bpy.ops.endophoton.render_legend(filepath=path)
    image = bpy.data.images.load(path, check_existing=True)
    assert image.size[0] > render.resolution_x  # the render plus the colour bar beside it
    assert image.get(results.RUN_KEY) == collection.get(results.RUN_KEY)
