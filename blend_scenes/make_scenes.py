# SPDX-License-Identifier: MIT
"""Source of truth for the example scenes.

    blender -b --factory-startup --python blend_scenes/make_scenes.py

writes blend_scenes/flat_tissue.blend, blend_scenes/colon_polyp.blend and
blend_scenes/colon_polyp_spectral.blend
(metres, unit scale 1; no packed data).  Meshes are built from numpy arrays.
``-- --out DIR`` writes them to DIR instead (the tests compare the two).

flat_tissue.blend — the paper's setting: a 4 cm x 4 cm x 2 cm slab of tissue
(top face at z = 0), a sessile polyp (flattened sphere, 6 mm across, 2 mm
high above the surface, pushed 2 mm into it; role polyp, priority 1) and the
endoscope rig at β = 0, 1 cm above the polyp's top.

colon_polyp.blend — a colon segment 8 cm long along x, ~5 cm across, with
haustral folds (sinusoidal radius modulation) and a 3 mm wall: one closed,
watertight thick-walled tube whose ends are annulus rings.  A polyp sits on the
inner wall (bottom, between two folds) and the rig is inside the lumen 1 cm
from the polyp, tilting along the colon axis.

colon_polyp_spectral.blend — colon_polyp.blend with spectral media: the wall is
the "Colon mucosa (spectral)" tissue preset, the polyp "Adenomatous polyp
(spectral)" (docs/media.md).
"""

import math
import os
import sys

import bpy
import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(os.path.dirname(HERE), "addon"))

import addon_utils  # noqa: E402

MM = 1e-3


def _enable_addon():
    if not hasattr(bpy.types.Scene, "endophoton"):
        mod = addon_utils.enable("endophoton_addon", default_set=True)
        if mod is None:
            raise RuntimeError("could not enable the endophoton_addon add-on")
    from endophoton_addon import export, meshutil, rig

    return export, meshutil, rig


# --- geometry (numpy) ---------------------------------------------------------
def box_arrays(lo, hi):
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    v = np.array(
        [[x0, y0, z0], [x1, y0, z0], [x1, y1, z0], [x0, y1, z0], [x0, y0, z1], [x1, y0, z1], [x1, y1, z1], [x0, y1, z1]]
    )
    quads = np.array([[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]])
    return v, [quads]


def ellipsoid_arrays(center, radii, n_lon=48, n_lat=24):
    """Closed UV ellipsoid: quads between latitude rings, triangle fans at the poles."""
    lat = np.linspace(0.0, np.pi, n_lat + 1)[1:-1]  # ring polar angles
    lon = np.linspace(0.0, 2.0 * np.pi, n_lon, endpoint=False)
    st, ct = np.sin(lat)[:, None], np.cos(lat)[:, None]
    ring = np.stack([st * np.cos(lon), st * np.sin(lon), np.broadcast_to(ct, (len(lat), n_lon))], axis=-1)
    unit = np.concatenate([[[0.0, 0.0, 1.0]], ring.reshape(-1, 3), [[0.0, 0.0, -1.0]]])
    verts = unit * np.asarray(radii) + np.asarray(center)
    top, bottom = 0, len(unit) - 1
    idx = 1 + np.arange(len(lat) * n_lon).reshape(len(lat), n_lon)
    nxt = np.roll(idx, -1, axis=1)
    quads = np.stack([idx[:-1], idx[1:], nxt[1:], nxt[:-1]], axis=-1).reshape(-1, 4)
    cap_top = np.stack([np.full(n_lon, top), idx[0], nxt[0]], axis=-1)
    cap_bottom = np.stack([np.full(n_lon, bottom), nxt[-1], idx[-1]], axis=-1)
    return verts, [quads, cap_top, cap_bottom]


def colon_arrays(length, radius, fold_depth, fold_period, wall, n_x=100, n_theta=64):
    """Closed thick-walled tube along +x with sinusoidal inner radius (haustral folds).

    Inner radius r(x) = radius - fold_depth (1 + cos(2π x / fold_period)) / 2;
    outer radius r(x) + wall.  Ends are annulus rings, so the solid is closed.
    """
    x = np.linspace(0.0, length, n_x)
    theta = np.linspace(0.0, 2.0 * np.pi, n_theta, endpoint=False)
    r_in = radius - fold_depth * 0.5 * (1.0 + np.cos(2.0 * np.pi * x / fold_period))
    r_out = r_in + wall
    ct, st = np.cos(theta)[None, :], np.sin(theta)[None, :]

    def surface(r):
        return np.stack(
            [np.broadcast_to(x[:, None], (n_x, n_theta)), r[:, None] * ct, r[:, None] * st], axis=-1
        ).reshape(-1, 3)

    verts = np.concatenate([surface(r_out), surface(r_in)])
    n = n_x * n_theta
    grid = np.arange(n).reshape(n_x, n_theta)
    a, b = grid[:-1], np.roll(grid, -1, axis=1)[:-1]
    c, d = np.roll(grid, -1, axis=1)[1:], grid[1:]
    outer = np.stack([a, b, c, d], axis=-1).reshape(-1, 4)  # faces away from the axis
    inner = np.stack([a, d, c, b], axis=-1).reshape(-1, 4) + n  # faces the lumen
    ring0_out, ring0_in = grid[0], grid[0] + n
    ring1_out, ring1_in = grid[-1], grid[-1] + n
    nxt = np.roll(np.arange(n_theta), -1)
    cap0 = np.stack([ring0_out, ring0_in, ring0_in[nxt], ring0_out[nxt]], axis=-1)  # faces -x
    cap1 = np.stack([ring1_out, ring1_out[nxt], ring1_in[nxt], ring1_in], axis=-1)  # faces +x
    return verts, [outer, inner, cap0, cap1]


# --- scene setup --------------------------------------------------------------
def _material(name, color):
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    bsdf = mat.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (*color, 1.0)
    bsdf.inputs["Roughness"].default_value = 0.45
    return mat


def _add_object(meshutil, name, arrays, role, material, collection):
    verts, faces = arrays
    mesh = meshutil.mesh_from_arrays(name, verts, faces)
    mesh.materials.append(material)
    obj = bpy.data.objects.new(name, mesh)
    collection.objects.link(obj)
    obj.endophoton.role = role  # loads the role's defaults (medium, priority, fluorophores)
    return obj


def _fresh_scene():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    export, meshutil, rig = _enable_addon()
    scene = bpy.context.scene
    scene.unit_settings.system = "METRIC"
    scene.unit_settings.scale_length = 1.0
    scene.unit_settings.length_unit = "MILLIMETERS"
    scene.render.engine = "CYCLES"
    scene.cycles.samples = 32
    scene.cycles.use_denoising = False
    scene.render.resolution_x, scene.render.resolution_y = 480, 360
    scene.render.film_transparent = False
    world = bpy.data.worlds.new("EP World")
    world.use_nodes = True
    world.node_tree.nodes["Background"].inputs["Color"].default_value = (0.01, 0.01, 0.012, 1.0)
    scene.world = world
    settings = scene.endophoton
    settings.quality = "PREVIEW"
    settings.voxel_size = 0.5 * MM
    settings.point_radius = 0.05 * MM
    return scene, export, meshutil, rig


def _check_closed(export, obj):
    depsgraph = bpy.context.evaluated_depsgraph_get()
    verts, tris = export.mesh_arrays(obj, depsgraph, 1.0)
    export.check_closed(obj.name, verts, tris)  # raises if open or inward


def _out_dir():
    argv = sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else []
    if "--out" in argv:
        return os.path.abspath(argv[argv.index("--out") + 1])
    return HERE


def _frame_views(objects):
    """Open framed: every 3D view looks at the objects from 1.5× their size,
    with clip distances for a mm-sized scene (0.1 mm to 10 m)."""
    from mathutils import Vector

    corners = [obj.matrix_world @ Vector(c) for obj in objects for c in obj.bound_box]
    lo = Vector(tuple(min(c[i] for c in corners) for i in range(3)))
    hi = Vector(tuple(max(c[i] for c in corners) for i in range(3)))
    for screen in bpy.data.screens:
        for area in screen.areas:
            for space in area.spaces:
                if space.type != "VIEW_3D":
                    continue
                space.clip_start, space.clip_end = 0.1 * MM, 10.0
                space.region_3d.view_location = (lo + hi) / 2
                space.region_3d.view_distance = 1.5 * (hi - lo).length


def _save(name):
    os.makedirs(_out_dir(), exist_ok=True)
    path = os.path.join(_out_dir(), name)
    bpy.context.preferences.filepaths.save_version = 0  # no .blend1 backups
    bpy.ops.wm.save_as_mainfile(filepath=path, compress=True, relative_remap=True)
    print(f"wrote {path} ({os.path.getsize(path) / 1024:.0f} KiB)")
    return path


def make_flat_tissue():
    scene, export, meshutil, rig = _fresh_scene()
    coll = scene.collection
    tissue = _add_object(
        meshutil,
        "Tissue",
        box_arrays((-0.02, -0.02, -0.02), (0.02, 0.02, 0.0)),
        "TISSUE",
        _material("Tissue", (0.80, 0.38, 0.33)),
        coll,
    )
    polyp = _add_object(
        meshutil,
        "Polyp",
        ellipsoid_arrays((0.0, 0.0, 0.0), (3 * MM, 3 * MM, 2 * MM)),
        "POLYP",
        _material("Polyp", (0.70, 0.20, 0.22)),
        coll,
    )
    for obj in (tissue, polyp):
        _check_closed(export, obj)
    polyp_top = (0.0, 0.0, 2 * MM)
    rig.create_rig(bpy.context, target=polyp_top, normal=(0, 0, 1), tilt_axis=(0, 1, 0), beta=0.0, distance=10 * MM)
    _frame_views((tissue, polyp))
    return _save("flat_tissue.blend")


def make_colon_polyp(spectral=False):
    """colon_polyp.blend (the paper's constant media), or with ``spectral`` colon_polyp_spectral.blend: the same
    scene with the spectral presets colon mucosa (wall) and adenomatous polyp (docs/media.md)."""
    scene, export, meshutil, rig = _fresh_scene()
    coll = scene.collection
    length, radius, fold_depth, period, wall = 0.08, 0.025, 3 * MM, 0.02, 3 * MM
    colon = _add_object(
        meshutil,
        "Colon",
        colon_arrays(length, radius, fold_depth, period, wall),
        "TISSUE",
        _material("Colon", (0.80, 0.40, 0.35)),
        coll,
    )
    # Between two folds (cos = -1 at x = 5 cm, inner radius = `radius`), on the bottom.
    x_polyp = 0.05
    center = (x_polyp, 0.0, -radius)
    polyp = _add_object(
        meshutil,
        "Polyp",
        ellipsoid_arrays(center, (4 * MM, 4 * MM, 2.5 * MM)),
        "POLYP",
        _material("Polyp", (0.70, 0.20, 0.22)),
        coll,
    )
    for obj in (colon, polyp):
        _check_closed(export, obj)
    if spectral:
        colon.endophoton.tissue_preset = "COLON_MUCOSA"
        polyp.endophoton.tissue_preset = "ADENOMATOUS_POLYP"
    top = (x_polyp, 0.0, -radius + 2.5 * MM)
    rig.create_rig(
        bpy.context, target=top, normal=(0, 0, 1), tilt_axis=(0, 1, 0), beta=math.radians(20.0), distance=10 * MM
    )
    _frame_views((colon, polyp))
    return _save("colon_polyp_spectral.blend" if spectral else "colon_polyp.blend")


def main():
    make_flat_tissue()
    make_colon_polyp()
    make_colon_polyp(spectral=True)


if __name__ == "__main__":
    main()
