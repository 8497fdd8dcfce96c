"""Numerical extremes of the transport engine, each checked against an expected value.

See docs/numerics.md, which says for every case what the engine does and
points here. References are written in this file (or in physics_helpers, whose
formulas come from the oracles), never taken from the engine:

* Fresnel: the oracle's sin/tan form (``fresnel_oracle`` below);
* |g| = 1: Beer-Lambert for g = 1, the one-dimensional "rod" model for g = -1
  (every scattering reverses the direction, so a normally incident pencil beam
  stays on the axis):  k = sqrt(mua (mua + 2 mus)),
  R = mus sinh(kd) / (k cosh(kd) + mut sinh(kd)),  T = k / (k cosh(kd) + mut sinh(kd));
* huge mus: Chandrasekhar's H-function reflectance of a semi-infinite
  isotropic medium, and the similarity relation R(mua, mus; L) = R(k mua, k mus; L/k);
* the MCML slab (oracles §1) and the semi-infinite mismatched medium (§2).

Statistical tolerance: |x - ref| < K_SIGMA sigma + ref_unc (physics_helpers.assert_within).
"""
import math

import numpy as np
import pytest

import endophoton as ep
from endophoton import _core

from physics_helpers import (
    K_SIGMA,
    fresnel_unpolarized,
    assert_energy_conserved,
    assert_no_nan,
    assert_same_within_stats,
    assert_within,
    semi_infinite_isotropic_reflectance,
)

DOWN = (0.0, 0.0, -1.0)
VDH_RD, VDH_TT, VDH_UNC = 0.09739, 0.66096, 0.5e-5  # oracles §1 (van de Hulst, 5 decimals)
SEMI_INF_R, SEMI_INF_UNC = 0.2600, 0.001  # oracles §2 (Giovanelli); spread of the 3 published values


def fresnel_oracle(n1, n2, theta):
    """Unpolarised Fresnel reflectance from n1 into n2 at incidence angle theta (rad), written from
    the oracle: R = 1/2 [sin^2(i-t)/sin^2(i+t) + tan^2(i-t)/tan^2(i+t)]; ((n1-n2)/(n1+n2))^2 at
    normal incidence; 1 beyond the critical angle and at grazing incidence (limit theta -> 90 deg)."""
    if theta >= math.pi / 2:
        return 1.0  # grazing: the oracle's formula is 0/0 there; the limit is total reflection
    return fresnel_unpolarized(n1, n2, theta)


def rod_model(mua, mus, d):
    """(R, T) of a slab in which every scattering reverses the direction (g = -1), matched boundaries."""
    mut = mua + mus
    k = math.sqrt(mua * (mua + 2 * mus))
    if k == 0:
        return mus * d / (1 + mus * d), 1 / (1 + mus * d)
    den = k * math.cosh(k * d) + mut * math.sinh(k * d)
    return mus * math.sinh(k * d) / den, k / den


def slab(medium, d, unit="cm", ambient_n=1.0, top=0.0, width=1000.0):
    return ep.layered_slab([(medium, d)], unit=unit, width=width, ambient_n=ambient_n, top=top)


def run(scene, source, photons, **kw):
    kw.setdefault("seed", 1)
    kw.setdefault("threads", 2)
    kw.setdefault("record_escapes", False)
    return ep.run(scene, source, photons=photons, **kw)


def pencil(z=1.0):
    return ep.PencilSource(position=(0, 0, z), direction=DOWN)


# =========================================================================== g -> +-1


@pytest.mark.parametrize("g", [1.0, -1.0])
def test_hg_sampler_at_unit_g_is_a_delta(g):
    """|g| = 1: no deflection (g = 1) or reversal (g = -1), exactly."""
    c = _core._testing.sample_hg_cos(g, 10_000, 3)
    assert np.all(c == g)


@pytest.mark.parametrize("g", [1 - 1e-9, -1 + 1e-9])
@pytest.mark.parametrize("x0", [1e-12, 1e-10])
def test_hg_sampler_tail_near_unit_g(g, x0):
    """For g = +-(1 - eps), x = 1 - |cos| has CDF 1 - eps / sqrt(eps^2 + 2 x) (integral of the HG
    density near the peak), so most samples round to cos = +-1 in double (median x = 1.5 eps^2)
    and the observable part is the tail: P(x > x0) = eps / sqrt(eps^2 + 2 x0). Binomial K_SIGMA sigma.
    (The sample mean is no test here: E[x] = eps comes from events of probability ~eps.)"""
    n = 400_000
    c = _core._testing.sample_hg_cos(g, n, 3)
    assert np.all(np.isfinite(c)) and c.min() >= -1 and c.max() <= 1
    eps = 1 - abs(g)
    x = 1 - np.sign(g) * c
    p = eps / math.sqrt(eps * eps + 2 * x0)
    k = int(np.count_nonzero(x > x0))
    assert_within(f"P(1-|cos| > {x0}) at g={g}", k / n, math.sqrt(p * (1 - p) / n), p)


def test_hg_sampler_isotropic_branch():
    """|g| < 1e-6 uses the exact isotropic branch (the inverse CDF divides by 2g): cos uniform on
    [-1, 1], mean g ~ 0 and variance 1/3 (3 standard errors; se of the variance from the
    uniform's fourth moment: Var(c^2) = 1/5 - 1/9)."""
    n = 400_000
    c = _core._testing.sample_hg_cos(1e-7, n, 3)
    assert c.min() >= -1 and c.max() <= 1
    assert abs(c.mean() - 1e-7) < K_SIGMA * math.sqrt(1 / 3 / n)
    assert abs(np.mean(c * c) - 1 / 3) < K_SIGMA * math.sqrt((1 / 5 - 1 / 9) / n)


@pytest.mark.parametrize("g", [1.0, 1 - 1e-9])
def test_forward_delta_scattering_is_beer_lambert(g):
    """g = 1: scattering never deflects, so the slab transmits exp(-mua d) (implicit capture
    multiplies the weight by mus/mut per interaction: E[(mus/mut)^K] = exp(-mua d) for
    K ~ Poisson(mut d)) and nothing comes back."""
    mua, mus, d = 2.0, 30.0, 0.1
    r = run(slab(ep.Medium(mua=mua, mus=mus, g=g, n=1.0), d), pencil(), 20_000)
    assert_energy_conserved(r)
    assert r.specular_reflectance == 0
    assert r.diffuse_reflectance <= K_SIGMA * r.diffuse_reflectance_stderr + 1e-12
    if g == 1:
        assert r.diffuse_reflectance == 0
    assert_within(f"Tt(g={g})", r.transmittance, r.transmittance_stderr, math.exp(-mua * d))


@pytest.mark.parametrize("g", [-1.0, -1 + 1e-9])
@pytest.mark.parametrize("mua", [2.0, 0.0])
def test_backward_delta_scattering_is_rod_model(g, mua):
    mus, d = 30.0, 0.1
    R, T = rod_model(mua, mus, d)
    r = run(slab(ep.Medium(mua=mua, mus=mus, g=g, n=1.0), d), pencil(), 20_000)
    assert_energy_conserved(r)
    assert_within(f"Rd(g={g}, mua={mua})", r.diffuse_reflectance, r.diffuse_reflectance_stderr, R)
    assert_within(f"Tt(g={g}, mua={mua})", r.transmittance, r.transmittance_stderr, T)
    if mua == 0:
        assert r.absorbed == 0 and r.roulette == 0


# =========================================================================== mus = 0, mua = 0


def test_clear_matched_region_transmits_everything_exactly():
    r = run(slab(ep.Medium(mua=0, mus=0, g=0, n=1.0), 0.1), pencil(), 5_000)
    assert r.transmittance == 1.0 and r.transmittance_stderr == 0.0
    assert r.specular_reflectance == r.diffuse_reflectance == r.absorbed == r.cut == r.missed == 0


def f32_thickness(top, bottom):
    """Thickness of a layer as the engine sees it: vertices are float32 (docs/design.md)."""
    return float(np.float32(top)) - float(np.float32(bottom))


def test_non_scattering_absorber_is_beer_lambert():
    """mus = 0: the region has no interactions; the engine applies W -> W exp(-mua t) along each
    straight segment, so Tt = exp(-mua d) for every packet, to rounding, with no statistical error.
    d is the float32 thickness (0.2 cm is stored as 0.2000000030 cm: 1.5e-8 relative)."""
    mua, d = 5.0, 0.2
    r = run(slab(ep.Medium(mua=mua, mus=0, g=0, n=1.0), d), pencil(), 4_000)
    assert r.specular_reflectance == 0 and r.diffuse_reflectance == 0
    assert abs(r.absorbed + r.transmittance - 1) < 1e-12
    assert r.transmittance == pytest.approx(math.exp(-mua * f32_thickness(0.0, -d)), rel=1e-12)
    assert r.transmittance_stderr < 1e-12
    assert abs(r.transmittance - math.exp(-mua * d)) < 1e-7  # the float32 geometry is the only deviation


def test_conservative_scattering_loses_no_weight():
    """mua = 0: weights stay 1, so there is no absorption and no roulette; Rd + Tt = 1."""
    r = run(slab(ep.Medium(mua=0, mus=50, g=0.8, n=1.4), 0.1), pencil(), 10_000)
    assert r.absorbed == 0 and r.roulette == 0 and r.cut == 0
    assert abs(r.specular_reflectance + r.diffuse_reflectance + r.transmittance - 1) < 1e-12
    assert r.specular_reflectance == pytest.approx(fresnel_oracle(1.0, 1.4, 0.0), rel=1e-12)


def test_clear_mismatched_slab_sums_internal_reflections():
    """mua = mus = 0, n = 1.5 in air: Rsp = R deterministically; inside, every face reflects with
    probability R, so Tt = (1-R)/(1+R) and Rd = R(1-R)/(1+R) (geometric series)."""
    R = fresnel_oracle(1.0, 1.5, 0.0)
    r = run(slab(ep.Medium(mua=0, mus=0, g=0, n=1.5), 0.1), pencil(), 40_000)
    assert r.specular_reflectance == pytest.approx(R, rel=1e-12)
    assert_within("Tt clear n=1.5", r.transmittance, r.transmittance_stderr, (1 - R) / (1 + R))
    assert_within("Rd clear n=1.5", r.diffuse_reflectance, r.diffuse_reflectance_stderr, R * (1 - R) / (1 + R))
    assert_energy_conserved(r)


def test_beam_that_meets_nothing_is_missed():
    r = run(slab(ep.Medium(mua=1, mus=10, g=0, n=1.4), 0.1), ep.PencilSource((0, 0, 1), (0, 0, 1)), 1_000)
    assert r.missed == 1.0 and r.specular_reflectance == r.absorbed == 0


def _cube(medium, half=0.5):
    s = ep.Scene("cm")
    s.add_box("cube", (-half,) * 3, (half,) * 3, medium)
    return s


def test_total_internal_reflection_trap_is_cut_by_max_steps():
    """Inside a clear n = 1.5 cube, the direction (1,1,1)/sqrt(3) meets every face at 54.7 deg,
    beyond the critical angle 41.8 deg, and mirror reflections keep it so: the packet never
    leaves. The step cap ends it and its weight is tallied as cut."""
    s = _cube(ep.Medium(mua=0, mus=0, g=0, n=1.5))
    r = run(s, ep.PencilSource((0.1, 0.2, 0.05), (1, 1, 1)), 200, max_steps=1000)
    assert r.cut == 1.0 and r.diffuse_reflectance == r.transmittance == r.absorbed == 0
    assert_energy_conserved(r)


@pytest.mark.slow
def test_total_internal_reflection_trap_hits_the_safety_cap():
    """Without a user cap the engine's own ceiling (1e7 events per packet) ends the trap.
    One packet is one work unit, so no batch-means stderr exists: the stderr comes from the
    per-packet second moment, sqrt(sum w^2) / N = 1 for one packet of weight 1 (finite,
    conservative), and the result says how many packets the cap ended."""
    s = _cube(ep.Medium(mua=0, mus=0, g=0, n=1.5))
    r = run(s, ep.PencilSource((0.1, 0.2, 0.05), (1, 1, 1)), 1, threads=1)
    assert r.cut == 1.0 and r.diffuse_reflectance == r.transmittance == r.absorbed == r.missed == 0
    assert r.cut_stderr == 1.0 and r.absorbed_stderr == 0.0
    assert r.capped_packets == 1 and any("step or path cap" in w for w in r.warnings)


# =========================================================================== huge mus


@pytest.fixture(scope="module")
def huge_mus_runs():
    """Semi-infinite isotropic medium, mua = 1, mus = 1e6 cm^-1 (albedo 1 - 1e-6), and the same
    medium scaled by k = 1e-2 (mua = 0.01, mus = 1e4, geometry 100x larger)."""
    out = {}
    for k in (1.0, 1e-2):
        L = 1.0 / k
        s = ep.Scene("cm")
        s.add_box("tissue", (-L, -L, -L), (L, L, 0), ep.Medium(mua=1 * k, mus=1e6 * k, g=0.0, n=1.0))
        out[k] = run(s, pencil(0.1 / k), 2_000, record_escapes=True)
    return out


@pytest.mark.slow
def test_huge_mus_is_finite_and_conserves_energy(huge_mus_runs):
    for r in huge_mus_runs.values():
        assert_no_nan(r)
        assert_energy_conserved(r)
        assert r.cut == 0 and r.missed == 0


@pytest.mark.slow
def test_huge_mus_matches_chandrasekhar(huge_mus_runs):
    ref = semi_infinite_isotropic_reflectance(1.0, 1e6)  # = 1 - H(1) sqrt(1e-6) = 0.99709
    for k, r in huge_mus_runs.items():
        assert_within(f"R(mus=1e6, k={k})", r.diffuse_reflectance, r.diffuse_reflectance_stderr, ref, 1e-6)
        assert_within(f"A(mus=1e6, k={k})", r.absorbed, r.absorbed_stderr, 1 - ref, 1e-6)


def test_huge_mus_similarity_relation(huge_mus_runs):
    a, b = huge_mus_runs[1.0], huge_mus_runs[1e-2]
    # Independent-sample bound (conservative: the two runs use the same random numbers) ...
    assert_same_within_stats(
        "R(mua, mus) vs R(k mua, k mus)",
        a.diffuse_reflectance,
        a.diffuse_reflectance_stderr,
        b.diffuse_reflectance,
        b.diffuse_reflectance_stderr,
    )

    # ... and the paired difference packet by packet, with its own standard error from the records.
    def per_packet(r):
        w = np.zeros(r.photons)
        np.add.at(w, r.escapes["packet"].astype(np.int64), r.escapes["weight"])
        return w

    diff = per_packet(a) - per_packet(b)
    se = diff.std(ddof=1) / math.sqrt(diff.size)
    assert abs(diff.mean()) <= K_SIGMA * se + 1e-12, (diff.mean(), se)
    # The scaled trajectories are the same walks: almost every packet leaves with the same weight.
    assert np.mean(np.abs(diff) < 1e-6) > 0.9


# =========================================================================== grazing incidence


@pytest.mark.parametrize("deg", [60.0, 85.0, 89.0, 89.9, 89.99, 89.999])
def test_grazing_incidence_specular_is_fresnel(deg):
    """The first ambient->tissue crossing removes W*R(theta) deterministically (MCML's Rsp),
    so Rsp equals the Fresnel reflectance to rounding, up to grazing incidence."""
    th = math.radians(deg)
    h = 0.01
    src = ep.PencilSource((-h * math.tan(th), 0, h), (math.sin(th), 0, -math.cos(th)))
    r = run(slab(ep.Medium(mua=10, mus=90, g=0.75, n=1.5), 0.02), src, 2_000)
    assert r.specular_reflectance == pytest.approx(fresnel_oracle(1.0, 1.5, th), rel=1e-9, abs=1e-12)
    assert r.missed == 0
    assert_energy_conserved(r)


def test_fresnel_tends_to_one_at_grazing_incidence():
    degs = (89.0, 89.9, 89.99, 89.999, 89.9999, 89.99999)
    Rs = [_core._testing.fresnel(math.cos(math.radians(deg)), 1.0, 1.5) for deg in degs]
    for deg, R in zip(degs, Rs):
        assert abs(R - fresnel_oracle(1.0, 1.5, math.radians(deg))) < 1e-9
    # 1 - R ~ cos(theta) near grazing: 1e-6 of 1 - R per 1e-6 rad in this range
    assert all(b > a for a, b in zip(Rs, Rs[1:])) and 1 - Rs[-1] < 2e-6
    assert _core._testing.fresnel(0.0, 1.0, 1.5) == 1.0 and _core._testing.fresnel(0.0, 1.5, 1.0) == 1.0


def test_beam_parallel_to_the_surface_never_enters():
    """At exactly 90 deg a beam above the top face never crosses it: the irradiance on the
    surface is zero (the Fresnel limit R -> 1 says the same), so the weight is `missed`."""
    r = run(slab(ep.Medium(mua=10, mus=90, g=0.75, n=1.5), 0.02), ep.PencilSource((-3, 0, 0.01), (1, 0, 0)), 2_000)
    assert r.missed == 1.0 and r.specular_reflectance == 0 and r.absorbed == 0


def test_beam_in_the_plane_of_a_face_enters_through_the_edge():
    """A beam travelling exactly in the plane of the top face of a box meets the box's side face
    on its (closed) edge, at normal incidence: Rsp = ((n-1)/(n+1))^2 and it enters."""
    n = 1.5
    s = ep.Scene("cm")
    s.add_box("tissue", (-1, -1, -1), (1, 1, 0), ep.Medium(mua=10, mus=90, g=0.75, n=n))
    r = run(s, ep.PencilSource((-3, 0, 0), (1, 0, 0)), 2_000)
    assert r.specular_reflectance == pytest.approx(((n - 1) / (n + 1)) ** 2, rel=1e-12)
    assert r.missed == 0 and r.absorbed > 0
    assert_energy_conserved(r)


# =========================================================================== total internal reflection

N_GLASS = 1.5
THETA_C = math.asin(1.0 / N_GLASS)


@pytest.mark.parametrize("delta", [1e-3, 1e-6, 1e-8])
def test_fresnel_just_below_critical_angle(delta):
    th = THETA_C - delta
    R = _core._testing.fresnel(math.cos(th), N_GLASS, 1.0)
    assert R < 1
    assert abs(R - fresnel_oracle(N_GLASS, 1.0, th)) < 1e-9


@pytest.mark.parametrize("delta", [1e-9, 1e-6, 1e-3])
def test_fresnel_beyond_critical_angle_is_total(delta):
    assert _core._testing.fresnel(math.cos(THETA_C + delta), N_GLASS, 1.0) == 1.0


def test_fresnel_at_exactly_the_critical_angle():
    # cos(theta_c) is rounded, so the engine sees theta_c +- 1 ulp: either TIR or R = 1 - O(1e-8).
    assert abs(_core._testing.fresnel(math.cos(THETA_C), N_GLASS, 1.0) - 1.0) < 1e-6
    assert _core._testing.fresnel(math.sqrt(1 - (1 / N_GLASS) ** 2), N_GLASS, 1.0) == pytest.approx(1.0, abs=1e-6)


def _glass_slab_source(theta):
    """Point source in the middle of a clear 0.1 cm glass slab, aiming at the top face at theta."""
    s = slab(ep.Medium(mua=0, mus=0, g=0, n=N_GLASS), 0.1)
    return s, ep.PencilSource((0, 0, -0.05), (math.sin(theta), 0, math.cos(theta)))


def test_transport_beyond_critical_angle_never_escapes():
    s, src = _glass_slab_source(THETA_C + 1e-6)
    r = run(s, src, 200, max_steps=200)
    assert r.cut == 1.0 and r.diffuse_reflectance == r.transmittance == 0


def test_transport_just_below_critical_angle_escapes_with_fresnel_odds():
    """Every face is met at theta_c - 1e-6 (mirror reflections keep the angle), and each meeting
    transmits with probability 1 - R. With a cap of M boundary events the packet is cut with
    probability R^M and escapes otherwise."""
    th = THETA_C - 1e-6
    R = fresnel_oracle(N_GLASS, 1.0, th)
    M = 80
    N = 8_000
    s, src = _glass_slab_source(th)
    r = run(s, src, N, max_steps=M)
    p = R**M
    assert_within("cut fraction = R^M", r.cut, math.sqrt(p * (1 - p) / N), p)
    assert abs(r.cut + r.diffuse_reflectance + r.transmittance - 1) < 1e-12


# =========================================================================== matched indices


def test_matched_ambient_has_no_fresnel():
    n = 1.3
    clear = run(slab(ep.Medium(mua=0, mus=0, g=0, n=n), 0.1, ambient_n=n), pencil(), 2_000)
    assert clear.specular_reflectance == 0 and clear.transmittance == 1.0
    mua, d = 4.0, 0.1
    absorbing = run(slab(ep.Medium(mua=mua, mus=0, g=0, n=n), d, ambient_n=n), pencil(), 4_000)
    assert absorbing.specular_reflectance == 0 and absorbing.diffuse_reflectance == 0
    assert absorbing.transmittance == pytest.approx(math.exp(-mua * f32_thickness(0.0, -d)), rel=1e-12)


def test_interface_between_identical_media_is_invisible():
    """The MCML slab cut into two touching layers of the same medium still matches van de Hulst."""
    m = ep.Medium(mua=10, mus=90, g=0.75, n=1.0)
    s = ep.layered_slab([(m, 0.007), (m, 0.013)], unit="cm")
    r = run(s, pencil(), 200_000)
    assert_within("Rd split slab", r.diffuse_reflectance, r.diffuse_reflectance_stderr, VDH_RD, VDH_UNC)
    assert_within("Tt split slab", r.transmittance, r.transmittance_stderr, VDH_TT, VDH_UNC)
    assert_energy_conserved(r)


# =========================================================================== vertices and edges


def fan_top_box(half=5.0, depth=5.0):
    """Closed box whose top face (z = 0) is a fan of 4 triangles around its centre vertex (0,0,0)."""
    v = np.array(
        [
            [-half, -half, -depth],
            [half, -half, -depth],
            [half, half, -depth],
            [-half, half, -depth],
            [-half, -half, 0],
            [half, -half, 0],
            [half, half, 0],
            [-half, half, 0],
            [0, 0, 0],
        ],
        dtype=np.float32,
    )
    t = np.array(
        [
            [4, 5, 8],
            [5, 6, 8],
            [6, 7, 8],
            [7, 4, 8],  # top fan (+z)
            [0, 2, 1],
            [0, 3, 2],  # bottom (-z)
            [0, 1, 5],
            [0, 5, 4],
            [2, 3, 7],
            [2, 7, 6],  # -y, +y
            [0, 4, 7],
            [0, 7, 3],
            [1, 2, 6],
            [1, 6, 5],
        ],
        dtype=np.uint32,
    )  # -x, +x
    return v, t


@pytest.mark.parametrize("x", [0.0, 0.37])
def test_beam_on_a_vertex_enters_once(x):
    """A pencil beam exactly on the vertex shared by four triangles crosses the surface once:
    Rsp is one Fresnel reflection, and the semi-infinite result matches oracles §2 as it does
    off the vertex (x = 0.37)."""
    v, t = fan_top_box()
    s = ep.Scene("cm")
    s.add_mesh("tissue", v, t, ep.Medium(mua=10, mus=90, g=0.0, n=1.5))
    r = run(s, ep.PencilSource((x, 0, 1), DOWN), 100_000)
    assert r.specular_reflectance == pytest.approx(0.04, rel=1e-12) and r.missed == 0
    total = r.specular_reflectance + r.diffuse_reflectance
    assert_within(f"Rsp+Rd (beam at x={x})", total, r.diffuse_reflectance_stderr, SEMI_INF_R, SEMI_INF_UNC)
    assert_energy_conserved(r)


@pytest.mark.parametrize(
    "direction", [(1, 1, 1), (-1, 1, -1), (1, 1, 0), (1, 0, 0)], ids=["vertex", "vertex2", "edge", "face-diagonal"]
)
def test_exit_through_vertex_or_edge(direction):
    """From the centre of a clear, matched cube the packet leaves exactly through a corner, an edge
    or the diagonal edge of a face's triangulation: it must escape, once, with its full weight."""
    s = _cube(ep.Medium(mua=0, mus=0, g=0, n=1.0))
    r = run(s, ep.PencilSource((0, 0, 0), direction), 100, record_escapes=True)
    assert r.transmittance == 1.0 and r.cut == 0 and r.missed == 0
    assert len(r.escapes["weight"]) == 100
    corner = 0.5 * np.sign(direction)
    assert np.allclose(r.escapes["position"], corner, atol=1e-6)


def test_absorbing_exit_through_vertex_is_beer_lambert():
    mua = 2.0
    s = _cube(ep.Medium(mua=mua, mus=0, g=0, n=1.0))
    r = run(s, ep.PencilSource((0, 0, 0), (1, 1, 1)), 4_000)
    assert r.transmittance == pytest.approx(math.exp(-mua * math.sqrt(3) / 2), rel=1e-12)


# =========================================================================== mm and m scenes

# The MCML slab in mm, cm and m at the origin: test_invariance.py (test_units_give_the_same_physics,
# test_each_unit_matches_van_de_hulst_and_reports_depth_in_cm). Here: far from the origin, in metres.


def _far_slab(offset_cm, unit="m"):
    per_cm = 1.0 / ep.unit_cm(unit)
    s = slab(
        ep.Medium(mua=10, mus=90, g=0.75, n=1.0), 0.02 * per_cm, unit=unit, width=1000 * per_cm, top=offset_cm * per_cm
    )
    return run(s, ep.PencilSource((0, 0, (offset_cm + 1) * per_cm), DOWN), 100_000)


def test_mcml_slab_one_metre_from_the_origin():
    r = _far_slab(100.0)
    assert_within("Rd at z = 1 m", r.diffuse_reflectance, r.diffuse_reflectance_stderr, VDH_RD, VDH_UNC)
    assert_within("Tt at z = 1 m", r.transmittance, r.transmittance_stderr, VDH_TT, VDH_UNC)


def test_mcml_slab_ten_metres_from_the_origin():
    """At |p| = 1000 cm float32 vertices are spaced 6e-5 cm (0.3% of the 0.02 cm slab) and Embree's
    hit distances carry ~1e-4 cm of rounding; the engine refines distances in double and looks
    behind the packet for crossings rounding put there. The engine before commit f1b941d (ray
    queries starting 4e-7 |p| ahead of the packet) lost 2.7% of Tt here (16 sigma at 1e5 packets)."""
    r = _far_slab(1000.0)
    assert_within("Rd at z = 10 m", r.diffuse_reflectance, r.diffuse_reflectance_stderr, VDH_RD, VDH_UNC)
    assert_within("Tt at z = 10 m", r.transmittance, r.transmittance_stderr, VDH_TT, VDH_UNC)


# =========================================================================== 1e9 packets: the pieces


def _disk_cone_lights():
    return [
        dict(
            position=[0.0, 0.0, 1.0], direction=[0.0, 0.0, -1.0], radius=0.2, half_angle=math.radians(10), spectrum=None
        )
    ]


@pytest.mark.parametrize("first", [0, 2**33, 2**40])
def test_emission_far_into_the_sequence(first):
    """Packet indices beyond 2^32 give valid emission samples: finite, on the disk, inside the cone,
    in the default 400-700 nm band; the base-2 Halton coordinate (disk radius: u = (r/R)^2) of 1024
    consecutive packets starting at a multiple of 1024 is the lattice j/1024 shifted by one offset
    below 1/1024, exactly as at the start of the sequence; and the samples are not those of
    packets 0..1023."""
    R, half = 0.2, math.radians(10)
    src = _core.Source(_disk_cone_lights())
    pos, dirs, wl, light = _core._testing.emit(src, 7, first, 1024, True)
    for a in (pos, dirs, wl):
        assert np.all(np.isfinite(a))
    assert np.all(light == 0)
    assert np.allclose(pos[:, 2], 1.0, atol=1e-15)
    r2 = (pos[:, 0] ** 2 + pos[:, 1] ** 2) / R**2
    assert r2.max() <= 1 + 1e-12
    assert np.allclose(np.linalg.norm(dirs, axis=1), 1, atol=1e-12)
    assert np.all(-dirs[:, 2] >= math.cos(half) - 1e-12)
    assert wl.min() >= 400 and wl.max() <= 700
    u = np.sort(r2)
    assert np.allclose(np.diff(u) * 1024, 1.0, atol=1e-6) and u[0] < 1 / 1024  # lattice j/1024 + offset
    if first:
        pos0, dirs0, wl0, _ = _core._testing.emit(src, 7, 0, 1024, True)
        assert not np.allclose(dirs, dirs0) and not np.allclose(wl, wl0)
        assert np.all(np.any(pos != pos0, axis=1))


def test_two_lights_alternate_far_into_the_sequence():
    rig = ep.EndoscopeRig.from_beta(20.0, 1.0)
    src = _core.Source(rig.native_lights(1.0))
    _, _, _, light = _core._testing.emit(src, 1, 2**40 + 1, 6, False)
    assert light.tolist() == [1, 0, 1, 0, 1, 0]


def test_packet_request_above_2_pow_32_is_not_truncated():
    """A request of 2^32 + 5 packets reaches the engine intact (a 32-bit truncation would run 5):
    the progress callback sees total = 2^32 + 5, the run is stopped from the callback, and the
    unit size is the one chosen for N >= 6.6e7 (65536). How many units were merged before the
    stop depends on timing, so every assertion holds for any count, 0 and 1 included (one unit:
    stderrs from the per-packet variance, finite)."""
    N = 2**32 + 5
    seen = []

    def progress(done, total):
        seen.append(total)
        return False  # stop at the first report

    r = ep.run(
        slab(ep.Medium(mua=10, mus=90, g=0.75, n=1.0), 0.02),
        pencil(),
        photons=N,
        threads=2,
        record_escapes=False,
        progress=progress,
    )
    assert seen and seen[0] == N
    assert r.cancelled and 0 <= r.photons < N
    assert r.unit_size == 65536
    assert r.photons % 65536 == 0
    assert_no_nan(r)
    if r.photons:
        assert_energy_conserved(r, tol=1e-9)
