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
pixels so points straddling an edge do not count).  Red/green is the ratio of
the summed red to the summed green over a mask's pixels (linear values from
OpenEXR renders).  Its noise is the Monte Carlo noise of the records, so the
standard error comes from batch means, as ep.render_view's do: the records are
split into contiguous packet-index batches (ep.analysis.batch_index), each
batch's points are rendered alone (the render is linear in the points, so the
batches' images sum to the whole), and the polyp-minus-wall difference of the
pooled ratios gets a delete-one-batch jackknife standard error.  (Pixel tiles
as units underestimate it about twofold: seed-to-seed spread 0.18 and 0.13 at
3 x 10^5 packets against tile errors of 0.10 and 0.06.)
"""

import os

import bpy
import numpy as np

from endophoton_addon import points, results, simulation
from conftest import open_blend

# 4 x 10^6 packets: the polyp fills ~1,300 of the 57,600 pixels; the jackknife error of the polyp-minus-
# wall red/green is 0.11 at 2 x 10^6 packets (4.4 σ) and 0.074 here (7.3 σ) against a difference of ~0.5.
PACKETS = 4_000_000
BATCHES = 10
SIZE = 240  # render width = height, pixels


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


def jackknife_difference(sums):
    """Pooled red/green of the polyp minus the wall's, and its delete-one-batch jackknife standard error.

    ``sums``: (B, 4) per batch: red and green summed over the polyp's pixels, then over the wall's."""
    sums = np.asarray(sums, dtype=np.float64)

    def diff(t):
        return t[0] / t[1] - t[2] / t[3]

    total = sums.sum(axis=0)
    leave_out = np.array([diff(total - row) for row in sums])
    b = len(sums)
    return diff(total), float(np.sqrt((b - 1) / b * np.sum((leave_out - leave_out.mean()) ** 2)))


def test_polyp_photofrin_renders_red_from_endoscope(ep, tmp_path, out_dir):
    import endophoton.analysis  # noqa: F401  (ep.analysis.batch_index: render_view's batches)

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
    cloud = points.points_objects(collection)[0]
    mesh = cloud.data
    shown = np.empty(len(mesh.vertices), bool)
    mesh.attributes[points.SHOW_ATTR].data.foreach_get("value", shown)
    # Vertices are the run's records in order (fluorescent_only: every record is a point).
    packet = np.asarray(job.result.escapes["packet"])
    assert len(packet) == len(shown)
    batch, _ = ep.analysis.batch_index(packet, BATCHES, int(job.result.packets_traced))
    sums = []
    for b in range(BATCHES):  # each batch's points alone, colours and strengths unchanged
        mesh.attributes[points.SHOW_ATTR].data.foreach_set("value", shown & (batch == b))
        mesh.update()
        rgb = _render_linear(scene, os.path.join(str(tmp_path), f"batch{b}.exr"))
        sums.append([rgb[..., c][m].sum() for m in (polyp_mask, wall_mask) for c in (0, 1)])
    mesh.attributes[points.SHOW_ATTR].data.foreach_set("value", shown)
    mesh.update()
    difference, sigma = jackknife_difference(sums)
    total = np.sum(sums, axis=0)
    print(
        f"red/green polyp {total[0] / total[1]:.3f}, wall {total[2] / total[3]:.3f} "
        f"({polyp_mask.sum()} / {wall_mask.sum()} px, {int(shown.sum()):,} points, {BATCHES} batches): "
        f"difference {difference:.3f} ± {sigma:.3f} = {difference / sigma:.1f} σ"
    )
    assert total[1] > 0 and total[3] > 0 and np.all(np.asarray(sums)[:, [1, 3]] > 0)
    assert difference > 4 * sigma

    # The legend: wavelength in nm over the shown (fluorescent) records.
    legend = points.legend_of(points.points_objects(collection)[0])
    assert legend.unit == "nm" and legend.lo >= 380 and legend.hi <= 830 and legend.hi > 600
    assert s.legend_header.startswith("Wavelength [nm]") and len(s.legend) >= 2
    path = os.path.join(out_dir, "colon_polyp_with_legend.png")
    bpy.ops.endophoton.render_legend(filepath=path)
    image = bpy.data.images.load(path, check_existing=True)
    assert image.size[0] > render.resolution_x  # the render plus the colour bar beside it
    assert image.get(results.RUN_KEY) == collection.get(results.RUN_KEY)
