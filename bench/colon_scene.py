"""A colon-like benchmark scene built with the package API only (no Blender).

A thick-walled tube along +x with haustral folds (the inner radius dips by
``fold_depth`` once per ``fold_period``), closed by annulus rings at both ends,
a polyp (ellipsoid, higher priority) on the inner wall at the bottom, and the
endoscope rig inside the lumen looking at the polyp. Tissue and fluorophores
are the seed's (oracles §5): n = 1.1, mua = 20, mus = 200 cm^-1, g = 0.9,
collagen d = 0.2, c = 0.4 in the wall; collagen and photofrin (d = 0.1,
c = 0.33) in the polyp. Built in metres, like the Blender scenes.

    from colon_scene import colon_scene
    scene, rig = colon_scene()
"""
from __future__ import annotations

import math

import numpy as np

import endophoton as ep
from endophoton import meshes

CM = 0.01  # metres per cm


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


def colon_scene(
    beta_deg=20.0,
    length_cm=8.0,
    radius_cm=2.5,
    fold_depth_cm=0.5,
    fold_period_cm=2.0,
    wall_cm=0.3,
    polyp_radii_cm=(0.3, 0.3, 0.2),
    distance_cm=1.0,
    n_x=100,
    n_theta=64,
):
    """(scene in metres, EndoscopeRig) of the colon-like tube with a polyp and the rig."""
    tissue = ep.Medium(mua=20.0, mus=200.0, g=0.9, n=1.1)
    collagen = ep.Fluorophore("collagen", 0.2, 0.4)
    photofrin = ep.Fluorophore("photofrin", 0.1, 0.33)
    v, t = tube_mesh(
        length_cm * CM, radius_cm * CM, fold_depth_cm * CM, fold_period_cm * CM, wall_cm * CM, n_x=n_x, n_theta=n_theta
    )
    scene = ep.Scene(unit="m", ambient_n=1.0)
    scene.add_mesh("colon", v, t, tissue, priority=0, fluorophores=[collagen])
    # Polyp half inside the wall at the bottom, in the valley between two folds (r_in = radius).
    x0 = (math.floor(length_cm / fold_period_cm / 2) + 0.5) * fold_period_cm
    base = np.array([x0, 0.0, -radius_cm]) * CM
    pv, pt = meshes.ellipsoid(tuple(base), tuple(r * CM for r in polyp_radii_cm), n_lat=24, n_lon=48)
    scene.add_mesh("polyp", pv, pt, tissue, priority=1, fluorophores=[ep.Fluorophore("collagen", 0.2, 0.4), photofrin])
    top = base + np.array([0.0, 0.0, polyp_radii_cm[2] * CM])
    rig = ep.EndoscopeRig.from_beta(beta_deg, distance_cm * CM, point=tuple(top), normal=(0, 0, 1), tilt_axis=(0, 1, 0))
    return scene, rig


def seed_tissue_box():
    """The seed's tissue as a deep box (semi-infinite for mut' = 40 cm^-1), cm; pencil beam."""
    s = ep.Scene("cm", ambient_n=1.0)
    s.add_box("tissue", (-5, -5, -10), (5, 5, 0), ep.Medium(mua=20, mus=200, g=0.9, n=1.1))
    return s, ep.PencilSource((0, 0, 1), (0, 0, -1))


def mcml_slab():
    """Oracles §1: n = 1, mua = 10, mus = 90, g = 0.75, d = 0.02 cm; pencil beam."""
    s = ep.layered_slab([(ep.Medium(mua=10, mus=90, g=0.75, n=1.0), 0.02)], unit="cm")
    return s, ep.PencilSource((0, 0, 1), (0, 0, -1))


def semi_infinite_n15():
    """Oracles §2: n = 1.5, mua = 10, mus = 90, g = 0, semi-infinite (box 10 cm deep); pencil beam."""
    s = ep.Scene("cm", ambient_n=1.0)
    s.add_box("tissue", (-5, -5, -10), (5, 5, 0), ep.Medium(mua=10, mus=90, g=0.0, n=1.5))
    return s, ep.PencilSource((0, 0, 1), (0, 0, -1))
