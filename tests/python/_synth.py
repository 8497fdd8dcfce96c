"""Synthetic inputs shared by tests: escape records with known distributions, and a small polyp scene.

The records need no engine (``make_records``, ``lambertian_records``; ``RecordsResult`` stands in for an
``ep.Result``): every column of docs/design.md's escape-record table is
filled, with the distributions chosen by the test so the expected answers can
be computed analytically. ``polyp_box_scene`` is the wall-and-polyp box scene the
render and visibility tests trace.
"""

from __future__ import annotations

import numpy as np

import endophoton as ep


def local_frame(normal, to_light):
    """(u, v, n) of analysis.exit_angles: u = tangent projection of to_light, v = n x u."""
    n = np.asarray(normal, float)
    n = n / np.linalg.norm(n, axis=-1, keepdims=True)
    t = np.asarray(to_light, float)
    u = t - np.sum(t * n, axis=-1, keepdims=True) * n
    with np.errstate(divide="ignore", invalid="ignore"):  # degenerate rows: tests set directions themselves
        u = u / np.linalg.norm(u, axis=-1, keepdims=True)
    v = np.cross(n, u)
    return u, v, n


def direction_from_angles(elev_deg, az_deg, u, v, n):
    """World direction with the given local elevation/azimuth (degrees)."""
    e = np.radians(np.asarray(elev_deg, float))[..., None]
    a = np.radians(np.asarray(az_deg, float))[..., None]
    return np.cos(e) * (np.cos(a) * u + np.sin(a) * v) + np.sin(e) * n


def sample_uniform_hemisphere(rng, k):
    """Elevations/azimuths (deg) uniform in solid angle over the hemisphere: sin(elev) ~ U(0,1)."""
    return np.degrees(np.arcsin(rng.random(k))), 360.0 * rng.random(k)


def sample_lambertian(rng, k):
    """Cosine-weighted (Lambertian) directions: sin^2(elev) ~ U(0,1)."""
    return np.degrees(np.arcsin(np.sqrt(rng.random(k)))), 360.0 * rng.random(k)


def make_records(
    elev_deg,
    az_deg,
    rng,
    light_positions=((0.35, 0.0, 1.0), (-0.35, 0.0, 1.0)),
    normal=(0.0, 0.0, 1.0),
    packets=None,
    energy=None,
    max_depth=None,
    spot_sd=0.2,
):
    """Escape-record dict for the given local exit angles on the plane z = 0 (or a given normal).

    Exit points scatter (Gaussian, sd ``spot_sd``) about the point below their
    light; the light of record i is i % L (as the engine's light = packet % L).
    """
    elev_deg = np.asarray(elev_deg, float)
    k = elev_deg.size
    lp = np.asarray(light_positions, float)
    L = lp.shape[0]
    packet = np.arange(k, dtype=np.uint64) if packets is None else np.asarray(packets, dtype=np.uint64)
    light = (packet % L).astype(np.uint8)
    pos = np.zeros((k, 3))
    pos[:, :2] = lp[light][:, :2] + spot_sd * rng.standard_normal((k, 2))
    nrm = np.broadcast_to(np.asarray(normal, float), (k, 3)).copy()
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    u, v, n = local_frame(nrm, lp[light] - pos)
    d = direction_from_angles(elev_deg, az_deg, u, v, n)
    en = rng.random(k) if energy is None else np.asarray(energy, float)
    md = 0.1 * rng.random(k) if max_depth is None else np.asarray(max_depth, float)
    return {
        "position": pos.astype(np.float32),
        "direction": d.astype(np.float32),
        "normal": nrm.astype(np.float32),
        "weight": en.astype(np.float64),
        "energy": en.astype(np.float64),
        "wavelength": np.full(k, 500.0, np.float32),
        "fluorescent": np.ones(k, np.uint8),
        "fluorophore": np.zeros(k, np.int32),
        "max_depth": md.astype(np.float32),
        "entry": pos.astype(np.float32),
        "scatterings": np.ones(k, np.uint32),
        "region": np.zeros(k, np.int32),
        "packet": packet,
        "light": light,
        "kind": np.zeros(k, np.uint8),
    }


def random_rotation(rng):
    """A uniformly random proper rotation matrix (QR of a Gaussian matrix)."""
    q, r = np.linalg.qr(rng.standard_normal((3, 3)))
    q = q * np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return q


def polyp_box_scene(c_photofrin=0.33):
    """Collagen wall box (6 x 6 x 2 cm) with a higher-priority polyp box (1.2 x 1.2 x 0.6 cm) at its top
    face holding collagen and photofrin at concentration ``c_photofrin`` (the seed's d, c); mua 1, mus 10,
    g 0, n 1, in cm."""
    m = ep.Medium(mua=1.0, mus=10.0, g=0.0, n=1.0)
    s = ep.Scene(unit="cm")
    s.add_box("wall", (-3, -3, -2), (3, 3, 0), m, fluorophores=[ep.Fluorophore("collagen", 0.2, 0.4)])
    s.add_box(
        "polyp",
        (-0.6, -0.6, -0.3),
        (0.6, 0.6, 0.3),
        m,
        priority=1,
        fluorophores=[ep.Fluorophore("collagen", 0.2, 0.4), ep.Fluorophore("photofrin", 0.1, c_photofrin)],
    )
    return s


class RecordsResult:
    """A stand-in for ep.Result built from synthetic escape records."""

    def __init__(self, scene, escapes, packets, source=None):
        self.scene, self.escapes, self.source = scene, escapes, source
        self.packets_traced = self.photons = packets


def lambertian_records(n, half=1.0, wavelength=500.0, seed=1):
    """n records uniform on [-half, half]^2 at z = 0 with cosine-weighted directions: radiance
    L = n / (P A pi) per packet (A = (2 half)^2 cm^2), the same in every direction."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-half, half, size=(n, 2))
    u1, u2 = rng.random(n), rng.random(n)
    r, phi = np.sqrt(u1), 2 * np.pi * u2
    d = np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(1 - u1)], axis=1)
    wl = np.broadcast_to(np.asarray(wavelength, dtype=np.float32), (n,)).copy()
    return {
        "position": np.column_stack([xy, np.zeros(n)]).astype(np.float32),
        "direction": d.astype(np.float32),
        "normal": np.tile(np.float32([0, 0, 1]), (n, 1)),
        "weight": np.ones(n),
        "energy": 500.0 / wl.astype(np.float64),
        "wavelength": wl,
        "fluorescent": np.zeros(n, np.uint8),
        "packet": np.arange(n, dtype=np.uint64),
        "region": np.zeros(n, np.int32),
    }


def hollow_box(outer, inner):
    """One region's mesh: an outer box facing out and an inner cavity facing into the cavity
    (half sides ``outer`` > ``inner`` about the origin, scene units)."""
    from endophoton.mesh_io import box_mesh

    vo, to = box_mesh((-outer,) * 3, (outer,) * 3)
    vi, ti = box_mesh((-inner,) * 3, (inner,) * 3)
    v = np.vstack([vo, vi]).astype(np.float32)
    t = np.vstack([to, ti[:, ::-1] + len(vo)]).astype(np.uint32)
    return v, t
