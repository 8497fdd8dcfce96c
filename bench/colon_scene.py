"""The colon benchmark scene: bench/scenes/colon.json (data: media, fluorophores, the rig) and its
meshes, bench/scenes/colon_tube.ply and colon_polyp.ply, which this module generates.

A thick-walled tube along +x with haustral folds (the inner radius dips by ``fold_depth`` once per
``fold_period``), closed by annulus rings at both ends, a polyp (ellipsoid, higher priority) on the
inner wall at the bottom, and the endoscope rig inside the lumen looking at the polyp. Tissue and
fluorophores are the seed's (oracles §5): n = 1.1, mua = 20, mus = 200 cm^-1, g = 0.9, collagen
d = 0.2, c = 0.4 in the wall; collagen and photofrin (d = 0.1, c = 0.33) in the polyp. Built in
metres, like the Blender scenes.

    /usr/bin/python3 bench/colon_scene.py          # writes the two PLY files and colon.json again
    scene, rig = colon_scene()                     # the scene as the CLI reads it (n_x, n_theta: others)
"""
from __future__ import annotations

import json
import math
import os
import sys
import tempfile

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
SCENES = os.path.join(HERE, "scenes")
sys.path.insert(0, os.path.join(os.path.dirname(HERE), "python"))

import endophoton as ep  # noqa: E402
from endophoton import meshes  # noqa: E402

CM = 0.01  # metres per cm
TISSUE = {"mua": 20.0, "mus": 200.0, "g": 0.9, "n": 1.1}
COLLAGEN, PHOTOFRIN = {"name": "collagen", "d": 0.2, "c": 0.4}, {"name": "photofrin", "d": 0.1, "c": 0.33}


def tube_mesh(length, radius, fold_depth, fold_period, wall, n_x=100, n_theta=64):
    """Closed thick-walled tube along +x from x = 0 to ``length`` (caller's units).

    Inner radius r(x) = radius - fold_depth * (1 + cos(2 pi x / fold_period)) / 2,
    outer radius r(x) + wall. Returns float32 vertices and uint32 triangles with
    outward winding: the outer skin faces away from the axis, the inner skin faces
    the lumen (the lumen is outside the solid), the end rings face -x and +x.
    """
    x = np.linspace(0.0, length, n_x)
    th = 2 * math.pi * np.arange(n_theta) / n_theta
    r_in = radius - fold_depth * 0.5 * (1 + np.cos(2 * math.pi * x / fold_period))
    rings = []
    for r in (r_in + wall, r_in):
        p = np.empty((n_x, n_theta, 3))
        p[..., 0] = x[:, None]
        p[..., 1] = r[:, None] * np.cos(th)[None, :]
        p[..., 2] = r[:, None] * np.sin(th)[None, :]
        rings.append(p.reshape(-1, 3))
    v = np.vstack(rings)
    n = n_x * n_theta
    idx = np.arange(n).reshape(n_x, n_theta)
    i0, i1 = idx[:-1, :], idx[1:, :]  # ring i, ring i+1
    j0, j1 = i0, np.roll(i0, -1, axis=1)  # angle j, j+1 on ring i
    k0, k1 = i1, np.roll(i1, -1, axis=1)  # angle j, j+1 on ring i+1
    tris = []
    # Outer skin, normal away from the axis: with e_x the x tangent and e_t the angular one,
    # e_t x e_x is the outward radial direction, so (i,j) -> (i+1,j+1) -> (i+1,j) and
    # (i,j) -> (i,j+1) -> (i+1,j+1) wind counter-clockwise seen from outside.
    tris.append(np.stack([j0, k1, k0], -1).reshape(-1, 3))
    tris.append(np.stack([j0, j1, k1], -1).reshape(-1, 3))
    # Inner skin (vertex offset n): the opposite winding, normals toward the axis (the lumen).
    tris.append(np.stack([j0, k0, k1], -1).reshape(-1, 3) + n)
    tris.append(np.stack([j0, k1, j1], -1).reshape(-1, 3) + n)
    # End rings: x = 0 faces -x, x = length faces +x.
    a_out, a_in = idx[0], idx[0] + n
    b_out, b_in = idx[-1], idx[-1] + n
    nx = np.roll(np.arange(n_theta), -1)
    tris.append(np.stack([a_out, a_in, a_in[nx]], -1))
    tris.append(np.stack([a_out, a_in[nx], a_out[nx]], -1))
    tris.append(np.stack([b_out, b_out[nx], b_in[nx]], -1))
    tris.append(np.stack([b_out, b_in[nx], b_in], -1))
    t = np.vstack(tris)
    v32, t32 = v.astype(np.float32), t.astype(np.uint32)
    meshes.check_closed_mesh(v32, t32)
    vol = meshes.signed_volume(v32, t32)
    if not vol > 0:
        raise AssertionError(f"tube mesh has signed volume {vol}: inward winding")
    return v32, t32


def write_ply(path, v, t):
    """Binary little-endian PLY of float32 vertices ``v`` and uint32 triangles ``t`` (mesh_io.load_mesh reads it)."""
    head = (
        f"ply\nformat binary_little_endian 1.0\nelement vertex {len(v)}\nproperty float x\nproperty float y\n"
        f"property float z\nelement face {len(t)}\nproperty list uchar uint vertex_indices\nend_header\n"
    )
    faces = np.zeros(len(t), dtype=[("n", "u1"), ("i", "<u4", 3)])
    faces["n"], faces["i"] = 3, t
    with open(path, "wb") as fh:
        fh.write(head.encode("ascii") + np.asarray(v, "<f4").tobytes() + faces.tobytes())


def write_scene(directory, beta_deg=20.0, length_cm=8.0, radius_cm=2.5, polyp_radii_cm=(0.3, 0.3, 0.2), n_x=100,
                n_theta=64, distance_cm=1.0):  # fmt: skip
    """Writes colon.json and its two meshes into ``directory``; returns the JSON's path."""
    v, t = tube_mesh(length_cm * CM, radius_cm * CM, 0.5 * CM, 2.0 * CM, 0.3 * CM, n_x=n_x, n_theta=n_theta)
    write_ply(os.path.join(directory, "colon_tube.ply"), v, t)
    # Polyp half inside the wall at the bottom, in the valley between two folds (r_in = radius).
    x0 = (math.floor(length_cm / 2.0 / 2) + 0.5) * 2.0
    base = np.array([x0, 0.0, -radius_cm]) * CM
    pv, pt = meshes.ellipsoid(tuple(base), tuple(r * CM for r in polyp_radii_cm), n_lat=24, n_lon=48)
    write_ply(os.path.join(directory, "colon_polyp.ply"), pv, pt)
    top = base + np.array([0.0, 0.0, polyp_radii_cm[2] * CM])
    doc = {
        "name": "colon",
        "description": "bench/colon_scene.py: a folded colon tube with a polyp (seed's tissue, collagen, "
        "photofrin), the endoscope rig at beta 20 deg, 1 cm from the polyp; metres",
        "unit": "m",
        "ambient_n": 1.0,
        "regions": [
            {"name": "colon", "priority": 0, "medium": TISSUE, "mesh": "colon_tube.ply", "fluorophores": [COLLAGEN]},
            {
                "name": "polyp",
                "priority": 1,
                "medium": TISSUE,
                "mesh": "colon_polyp.ply",
                "fluorophores": [COLLAGEN, PHOTOFRIN],
            },
        ],
        "source": {
            "type": "endoscope",
            "beta_deg": beta_deg,
            "distance": distance_cm * CM,
            "point": top.tolist(),
            "normal": [0, 0, 1],
            "tilt_axis": [0, 1, 0],
        },
        "run": {"photons": 150000, "seed": 1},
    }
    path = os.path.join(directory, "colon.json")
    with open(path, "w", encoding="utf-8") as fh:
        json.dump(doc, fh, indent=1)
    return path


def load(path):
    """(scene, source) of a SCENE.json file, as the CLI reads it."""
    with open(path, encoding="utf-8") as fh:
        doc = json.load(fh)
    return ep.Scene.from_dict(doc, base_dir=os.path.dirname(path)), ep.source_from_dict(doc["source"])


def colon_scene(beta_deg=20.0, n_x=100, n_theta=64):
    """(scene in metres, EndoscopeRig): bench/scenes/colon.json, or the tube tessellated n_x x n_theta."""
    if (beta_deg, n_x, n_theta) == (20.0, 100, 64):
        return load(os.path.join(SCENES, "colon.json"))
    with tempfile.TemporaryDirectory() as tmp:
        return load(write_scene(tmp, beta_deg=beta_deg, n_x=n_x, n_theta=n_theta))


if __name__ == "__main__":
    print(write_scene(SCENES))
