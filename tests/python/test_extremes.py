"""Extreme inputs: no absorption (albedo 1), mus = 1e5 cm^-1, g -> 1, packets launched
exactly on mesh vertices and edges, and a leak detector (no packet may ever be found
outside its slab).

Tolerance: |x - ref| < K_SIGMA sigma + ref_unc, with ref_unc justified case by case below.
"""
import math

import numpy as np
import pytest
from scipy import integrate

import endophoton as ep
from physics_helpers import (
    K_SIGMA,
    assert_energy_conserved,
    assert_no_nan,
    assert_same_within_stats,
    assert_within,
    cube_mesh,
    distance_to_box_surface,
    fresnel_unpolarized,
    hg_cdf,
    hg_pdf,
    semi_infinite_isotropic_reflectance,
)

DOWN = ep.PencilSource(position=(0.0, 0.0, 1.0), direction=(0.0, 0.0, -1.0))


def _deep_box(medium, unit="cm"):
    s = ep.Scene(unit=unit, ambient_n=1.0)
    s.add_box("tissue", min=(-100, -100, -10), max=(100, 100, 0), medium=medium)
    return s


# ----------------------------------------------------------------------------
# mua = 0: everything that is not cut comes back
# ----------------------------------------------------------------------------
@pytest.fixture(scope="module")
def no_absorption_runs():
    scene = _deep_box(ep.Medium(mua=0.0, mus=100.0, g=0.0, n=1.0))
    return {
        cap: ep.run(scene, DOWN, photons=20_000, seed=40 + i, threads=0, record_escapes=False, max_steps=cap)
        for i, cap in enumerate((100, 1600))
    }


@pytest.mark.parametrize("cap", [100, 1600])
def test_semi_infinite_no_absorption_reflects_all_but_the_cut(no_absorption_runs, cap):
    """mua = 0, matched boundary, semi-infinite: a random walk in a half space returns to the
    surface with probability 1, so Rsp + Rd -> 1. With a step cap the unreturned weight is
    tallied as cut: A = 0 and roulette = 0 exactly (weights never change), Tt = 0 (10 cm is
    ~1000 mean free paths, unreachable in <= 1600 steps), and Rsp + Rd + cut = 1."""
    res = no_absorption_runs[cap]
    assert_energy_conserved(res)
    assert res.absorbed == 0.0
    assert res.roulette == 0.0
    assert res.transmittance == 0.0 and res.missed == 0.0 and res.specular_reflectance == 0.0
    assert res.cut > 0.0
    assert abs(res.specular_reflectance + res.diffuse_reflectance + res.cut - 1.0) < 1e-9


def test_semi_infinite_no_absorption_cut_scales_as_inverse_sqrt_steps(no_absorption_runs):
    """The depth of the walk is a symmetric continuous 1-D random walk after the first step, so
    the probability of not having returned after n steps falls as n^(-1/2) (Sparre Andersen).
    Hence cut(1600) / cut(100) -> sqrt(100/1600) = 0.25. Tolerance: K_SIGMA sigma (propagated from
    both cuts) + 0.02 for the O(1/n) finite-n corrections (and the +-1 ambiguity in what counts
    as a step: S(n+1)/S(n) = 1 - 1/(2n) moves the ratio by ~0.001)."""
    a, b = no_absorption_runs[100], no_absorption_runs[1600]
    ratio = b.cut / a.cut
    sigma = ratio * math.hypot(a.cut_stderr / a.cut, b.cut_stderr / b.cut)
    assert_within("cut(1600)/cut(100)", ratio, sigma, 0.25, 0.02)


# ----------------------------------------------------------------------------
# mus = 1e5 cm^-1
# ----------------------------------------------------------------------------
@pytest.fixture(scope="module")
def huge_mus_runs():
    out = {}
    for i, (mua, mus) in enumerate(((10.0, 1e5), (0.1, 1e3))):
        out[(mua, mus)] = ep.run(
            _deep_box(ep.Medium(mua=mua, mus=mus, g=0.0, n=1.0)),
            DOWN,
            photons=60_000,
            seed=50 + i,
            threads=0,
            record_escapes=True,
        )
    return out


@pytest.mark.slow
def test_huge_mus_matches_chandrasekhar(huge_mus_runs):
    """mua = 10, mus = 1e5 (albedo 0.9999), g = 0, n = 1, semi-infinite: the exact result of
    transport theory is R = 1 - H(1) sqrt(1 - albedo) = 0.97142 (Chandrasekhar H-function,
    solved to < 1e-9: ref_unc = 1e-6). No NaN anywhere."""
    res = huge_mus_runs[(10.0, 1e5)]
    assert_energy_conserved(res)
    assert_no_nan(res)
    ref = semi_infinite_isotropic_reflectance(10.0, 1e5)
    assert ref == pytest.approx(0.971419, abs=2e-6)
    assert_within("Rd (mus = 1e5)", res.diffuse_reflectance, res.diffuse_reflectance_stderr, ref, 1e-6)
    assert res.transmittance == 0.0 and res.missed == 0.0 and res.cut == 0.0
    # the packets really did scatter on a 1e-5 cm scale: hundreds of scatterings on average
    assert res.escapes["scatterings"].mean() > 50
    # and they came out of the top face, never deeper than a few hundred mean free paths
    assert np.all(np.abs(res.escapes["position"][:, 2]) < 1e-5)
    assert float(res.escapes["max_depth"].max()) < 1.0


@pytest.mark.slow
def test_huge_mus_scale_invariance(huge_mus_runs):
    """Similarity: in a semi-infinite, infinitely wide medium every length scales with 1/mu_t,
    so R depends only on the albedo and g: R(10, 1e5) = R(0.1, 1e3) within statistics
    (independent seeds: |diff| < K_SIGMA sqrt(s1^2 + s2^2))."""
    a, b = huge_mus_runs[(10.0, 1e5)], huge_mus_runs[(0.1, 1e3)]
    assert_energy_conserved(a)
    assert_energy_conserved(b)
    assert_no_nan(b)
    assert_same_within_stats(
        "Rd(10, 1e5) vs Rd(0.1, 1e3)",
        a.diffuse_reflectance,
        a.diffuse_reflectance_stderr,
        b.diffuse_reflectance,
        b.diffuse_reflectance_stderr,
    )
    # depths scale by exactly the same factor (100): compare the mean max_depth * mu_t
    da = a.escapes["max_depth"].astype(np.float64) * 1e5
    db = b.escapes["max_depth"].astype(np.float64) * 1e3
    assert_same_within_stats(
        "mean max_depth * mu_s",
        da.mean(),
        da.std(ddof=1) / math.sqrt(da.size),
        db.mean(),
        db.std(ddof=1) / math.sqrt(db.size),
    )


# ----------------------------------------------------------------------------
# g -> 1: no deflection
# ----------------------------------------------------------------------------
def _single_scatter_loss(g, mua_d):
    """Expected fractional loss of a packet scattered once at the top of the slab: it either
    turns back (mu < 0) or its remaining path d becomes d / mu: 1 - E[1{mu>0} exp(-mua d (1/mu - 1))]."""
    pts = [1 - 10.0**-k for k in range(1, 8)]
    val, _ = integrate.quad(
        lambda m: float(hg_pdf(g, m)) * (1 - math.exp(-mua_d * (1 / m - 1))),
        1e-12,
        1.0,
        points=pts,
        limit=2000,
        epsabs=1e-14,
    )
    return float(hg_cdf(g, 0.0)) + val


@pytest.mark.parametrize("g", [1.0, 0.9999])
def test_forward_peaked_scattering_is_beer_lambert_in_mua(g):
    """mua = 1, mus = 10, d = 0.1 cm, n = 1. For g = 1 scattering changes nothing, so
    Tt = exp(-mua d) exactly in expectation. For g = 0.9999 the mean deflection 1 - g = 1e-4:
    a transmitted path is >= d, so Tt <= exp(-mua d); and each of the ~mus d = 1 scattering
    events costs at most the single-scatter loss computed for a scattering at the very top
    (worst case), so Tt >= exp(-mua d) (1 - mus d * loss). ref_unc = that bound (~3e-5).
    Reflection needs a reversal: Rd < K_SIGMA sigma + 10 mus d P(mu < 0) (factor 10: longer paths and
    several scatterings)."""
    mua, mus, d = 1.0, 10.0, 0.1
    scene = ep.Scene(unit="cm")
    scene.add_box("slab", min=(-100, -100, -d), max=(100, 100, 0), medium=ep.Medium(mua=mua, mus=mus, g=g, n=1.0))
    res = ep.run(scene, DOWN, photons=100_000, seed=60, threads=0, record_escapes=True)
    assert_energy_conserved(res)
    ref = math.exp(-mua * d)
    loss = 0.0 if g == 1.0 else _single_scatter_loss(g, mua * d)
    assert loss < 1e-3
    unc = ref * mus * d * loss + 1e-12
    assert_within(f"Tt (g = {g})", res.transmittance, res.transmittance_stderr, ref, unc)
    p_back = 0.0 if g == 1.0 else float(hg_cdf(g, 0.0))
    assert res.diffuse_reflectance < K_SIGMA * res.diffuse_reflectance_stderr + 10 * mus * d * p_back + 1e-12
    # transmitted packets keep (almost) the beam direction
    tr = res.escapes["kind"] == 1
    if g == 1.0:
        assert res.diffuse_reflectance == 0.0
        assert np.allclose(res.escapes["direction"][tr], [0, 0, -1], atol=1e-6)
        assert np.allclose(res.escapes["position"][tr][:, :2], 0.0, atol=1e-6)
    else:
        assert np.median(-res.escapes["direction"][tr][:, 2]) > 0.999


# ----------------------------------------------------------------------------
# Packets launched exactly on a vertex / an edge
# ----------------------------------------------------------------------------
BOX_LO, BOX_HI = (-1.0, -1.0, -1.0), (1.0, 1.0, 0.0)
N_IN = 1.4
S3, S2 = 1 / math.sqrt(3), 1 / math.sqrt(2)
LAUNCHES = {
    # name: (position, direction, incidence angle on every face that meets the point)
    "corner_vertex": ((1.0, 1.0, 0.0), (-S3, -S3, -S3), math.acos(S3)),
    "diagonal_end_vertex": ((-1.0, -1.0, 0.0), (S3, S3, -S3), math.acos(S3)),
    "box_edge_midpoint": ((1.0, 0.0, 0.0), (-S2, 0.0, -S2), math.radians(45.0)),
    "top_diagonal_midpoint": ((0.0, 0.0, 0.0), (0.0, 0.0, -1.0), 0.0),
}


def _box_scene(builder):
    s = ep.Scene(unit="cm", ambient_n=1.0)
    m = ep.Medium(mua=1.0, mus=10.0, g=0.9, n=N_IN)
    if builder == "add_mesh":
        v, t = cube_mesh(BOX_LO, BOX_HI)  # top face split along the diagonal (-1,-1,0)-(1,1,0)
        s.add_mesh("block", v, t, m)
    else:
        s.add_box("block", min=BOX_LO, max=BOX_HI, medium=m)
    return s


@pytest.mark.parametrize("builder", ["add_mesh", "add_box"])
@pytest.mark.parametrize("launch", sorted(LAUNCHES))
def test_launch_on_vertex_or_edge_never_leaks(builder, launch):
    """Source point exactly on a vertex / an edge, pointing into the box. The direction makes
    the same angle with every face through the point, so the specular part is Fresnel R(theta)
    whichever face the engine picks. Nothing may miss, every escape must be on the box
    surface going outward, and all the rest is conserved."""
    pos, direction, theta = LAUNCHES[launch]
    res = ep.run(
        _box_scene(builder),
        ep.PencilSource(position=pos, direction=direction),
        photons=20_000,
        seed=70,
        threads=0,
        record_escapes=True,
    )
    assert_energy_conserved(res)
    assert_no_nan(res)
    assert res.missed == 0.0
    assert res.cut == 0.0
    R = fresnel_unpolarized(1.0, N_IN, theta)
    assert_within(f"Rsp ({launch})", res.specular_reflectance, res.specular_reflectance_stderr, R, 1e-12)
    esc = res.escapes
    assert len(esc["weight"]) > 1000
    # every packet entered at the launch point
    assert np.allclose(esc["entry"], pos, atol=1e-6)
    # escapes are on the surface of the box, leaving it
    dist = distance_to_box_surface(esc["position"], BOX_LO, BOX_HI)
    assert float(dist.max()) < 1e-5, f"an escape {float(dist.max())} cm away from the box surface"
    nrm = esc["normal"].astype(np.float64)
    assert np.allclose(np.linalg.norm(nrm, axis=1), 1.0, atol=1e-6)
    assert np.all(np.einsum("ij,ij->i", esc["direction"].astype(np.float64), nrm) > 0)
    # the normal is the outward normal of a face the exit point lies on
    p = esc["position"].astype(np.float64)
    lo, hi = np.array(BOX_LO), np.array(BOX_HI)
    axis = np.argmax(np.abs(nrm), axis=1)
    side = np.sign(nrm[np.arange(len(nrm)), axis])
    plane = np.where(side > 0, hi[axis], lo[axis])
    assert np.allclose(np.abs(nrm[np.arange(len(nrm)), axis]), 1.0, atol=1e-6)
    assert np.allclose(p[np.arange(len(p)), axis], plane, atol=1e-5)
    # nothing was ever outside the box while inside it: depth below the entry point along
    # the entry direction is bounded by the box's extent along that direction
    assert float(esc["max_depth"].max()) <= math.sqrt(2 * 2 + 2 * 2 + 1) + 1e-6


# ----------------------------------------------------------------------------
# Leak detector: no packet may be found deeper than its slab
# ----------------------------------------------------------------------------
@pytest.mark.slow
def test_no_packet_ever_deeper_than_the_slab():
    """1e6 packets in the MCML slab geometry (0.02 cm thick, 200 cm wide, n = 1.4). Every escape
    record's max_depth (deepest point below the entry surface, in cm) must be <= 0.02 cm: a
    larger value means a packet crossed a face without the crossing being seen (and kept
    scattering outside the slab as if inside)."""
    scene = ep.Scene(unit="cm")
    scene.add_box("slab", min=(-100, -100, -0.02), max=(100, 100, 0), medium=ep.Medium(10, 90, 0.75, 1.4))
    res = ep.run(scene, DOWN, photons=1_000_000, seed=80, threads=0, record_escapes=True)
    assert_energy_conserved(res)
    md = res.escapes["max_depth"]
    bad = md > 0.02 + 1e-6
    assert not bad.any(), (
        f"{int(bad.sum())} of {len(md)} escaped packets were deeper than the slab "
        f"(max {float(md.max()):.4f} cm; packets {res.escapes['packet'][bad][:10].tolist()})"
    )
