"""Analytic boundary cases (oracles §4): Beer-Lambert, Fresnel at oblique incidence,
multiple internal reflections, total internal reflection.

Tolerance: |x - ref| < K_SIGMA sigma + ref_unc (sigma = engine stderr; the references
here are closed forms, ref_unc = 1e-12 for floating-point rounding).
"""
import math

import numpy as np
import pytest

import endophoton as ep
from physics_helpers import (
    K_SIGMA,
    assert_energy_conserved,
    assert_within,
    distance_to_box_surface,
    fresnel_unpolarized,
    slab_clear_totals,
)

DOWN = ep.PencilSource(position=(0.0, 0.0, 1.0), direction=(0.0, 0.0, -1.0))


def _slab(mua, mus, n, d, g=0.0, width=100.0):
    scene = ep.Scene(unit="cm", ambient_n=1.0)
    scene.add_box(
        "slab", min=(-width, -width, -d), max=(width, width, 0.0), medium=ep.Medium(mua=mua, mus=mus, g=g, n=n)
    )
    return scene


# ----------------------------------------------------------------------------
# Reference self-checks (the test's own Fresnel implementation)
# ----------------------------------------------------------------------------
def test_fresnel_reference_implementation():
    # normal incidence closed form and continuity of the oblique formula at 0
    assert fresnel_unpolarized(1.0, 1.5, 0.0) == pytest.approx(0.04, abs=1e-15)
    assert fresnel_unpolarized(1.0, 1.5, 1e-6) == pytest.approx(0.04, abs=1e-9)
    # Brewster angle: p-polarisation vanishes, R = Rs/2 = 0.5*((cos i - n cos t)/(cos i + n cos t))^2
    tb = math.atan(1.5)
    ci, ct = math.cos(tb), math.cos(math.asin(math.sin(tb) / 1.5))
    assert fresnel_unpolarized(1.0, 1.5, tb) == pytest.approx(0.5 * ((ci - 1.5 * ct) / (ci + 1.5 * ct)) ** 2, rel=1e-12)
    # reciprocity: R(n1 -> n2, i) = R(n2 -> n1, t)
    ti = math.radians(40)
    tt = math.asin(math.sin(ti) / 1.4)
    assert fresnel_unpolarized(1.0, 1.4, ti) == pytest.approx(fresnel_unpolarized(1.4, 1.0, tt), rel=1e-12)
    # total internal reflection beyond asin(1/1.4)
    assert fresnel_unpolarized(1.4, 1.0, math.asin(1 / 1.4) + 1e-9) == 1.0
    assert fresnel_unpolarized(1.0, 1.5, math.radians(89.999)) > 0.99


# ----------------------------------------------------------------------------
# Beer-Lambert (mus = 0)
# ----------------------------------------------------------------------------
def test_beer_lambert_matched_is_exact():
    """mus = 0, n = 1 everywhere: every packet follows the same straight line, nothing
    reflects, and the transmittance is exp(-mua d) with no randomness at all
    (acceptance criterion: exact to ~1e-12, i.e. absorption along a clear path must
    be applied as the deterministic weight factor exp(-mua s)). d = 0.125 cm is exact in
    float32 (mesh vertices are float32: a 0.1 cm slab would really be 0.1000000015 cm thick,
    which moves exp(-mua d) by 5e-9)."""
    mua, d = 8.0, 0.125
    res = ep.run(_slab(mua, 0.0, 1.0, d), DOWN, photons=2000, seed=5, threads=0, record_escapes=False)
    assert_energy_conserved(res)
    assert res.specular_reflectance == 0.0 and res.diffuse_reflectance == 0.0
    assert (
        abs(res.transmittance - math.exp(-mua * d)) < 1e-12
    ), f"Tt = {res.transmittance!r} +- {res.transmittance_stderr}, exp(-mua d) = {math.exp(-mua * d)!r}"
    assert abs(res.absorbed - (1 - math.exp(-mua * d))) < 1e-12, res.absorbed


def test_beer_lambert_matched_statistical():
    """Same physics, checked only in expectation: |Tt - exp(-mua d)| < K_SIGMA sigma + 1e-12
    (d = 0.125 cm, exact in float32)."""
    mua, d = 8.0, 0.125
    res = ep.run(_slab(mua, 0.0, 1.0, d), DOWN, photons=100_000, seed=6, threads=0, record_escapes=False)
    assert_energy_conserved(res)
    assert res.specular_reflectance == 0.0
    assert res.diffuse_reflectance == 0.0  # no scattering, no index step: nothing can come back
    assert res.missed == 0.0 and res.cut == 0.0
    assert_within("Tt", res.transmittance, res.transmittance_stderr, math.exp(-mua * d), 1e-12)
    assert_within("A", res.absorbed, res.absorbed_stderr, 1 - math.exp(-mua * d), 1e-12)


@pytest.mark.parametrize("n", [1.5, 1.4])
def test_beer_lambert_mismatched_with_internal_reflections(n):
    """mus = 0, slab index n in air: Fresnel R = ((n-1)/(n+1))^2 at both faces and all
    internal reflections: Tt = (1-R)^2 q / (1 - R^2 q^2), Rd = (1-R)^2 R q^2 / (1 - R^2 q^2),
    q = exp(-mua d), Rsp = R."""
    mua, d = 2.0, 0.5
    res = ep.run(_slab(mua, 0.0, n, d), DOWN, photons=200_000, seed=8, threads=0, record_escapes=False)
    assert_energy_conserved(res)
    R = fresnel_unpolarized(1.0, n, 0.0)
    rsp, rd, tt = slab_clear_totals(R, mua, d)
    assert_within("Rsp", res.specular_reflectance, res.specular_reflectance_stderr, rsp, 1e-12)
    assert_within("Rd", res.diffuse_reflectance, res.diffuse_reflectance_stderr, rd, 1e-12)
    assert_within("Tt", res.transmittance, res.transmittance_stderr, tt, 1e-12)
    assert_within("A", res.absorbed, res.absorbed_stderr, 1 - rsp - rd - tt, 1e-12)


# ----------------------------------------------------------------------------
# Oblique pencil beam on a clear slab: Fresnel R(theta) and multiple reflections
# ----------------------------------------------------------------------------
@pytest.mark.parametrize("theta_deg", [0.0, 30.0, 60.0, 85.0])
def test_oblique_incidence_clear_slab(theta_deg):
    """mua = mus = 0, n = 1.5, d = 0.1 cm, air around. Rsp = R(theta) (Fresnel, oracles §4).
    Inside, the refracted ray meets both faces at theta_t, where R is the same R(theta)
    (reciprocity), so summing the internal bounces: Rsp + Rd = 2R/(1+R), Tt = (1-R)/(1+R)."""
    n, d = 1.5, 0.1
    th = math.radians(theta_deg)
    hit = np.array([0.3, 0.1, 0.0])  # a generic point of the top face
    direction = np.array([math.sin(th), 0.0, -math.cos(th)])
    src = ep.PencilSource(position=tuple(hit - direction / math.cos(th)), direction=tuple(direction))
    res = ep.run(_slab(0.0, 0.0, n, d), src, photons=100_000, seed=9, threads=0, record_escapes=True)
    assert_energy_conserved(res)
    R = fresnel_unpolarized(1.0, n, th)
    assert res.absorbed == 0.0 and res.missed == 0.0 and res.cut == 0.0
    assert_within(f"Rsp({theta_deg})", res.specular_reflectance, res.specular_reflectance_stderr, R, 1e-12)
    total_r = 2 * R / (1 + R)
    assert_within(
        f"Rsp+Rd({theta_deg})",
        res.specular_reflectance + res.diffuse_reflectance,
        res.specular_reflectance_stderr + res.diffuse_reflectance_stderr,
        total_r,
        1e-12,
    )
    assert_within(f"Tt({theta_deg})", res.transmittance, res.transmittance_stderr, 1 - total_r, 1e-12)

    # Geometry of the escapes: Snell's law makes every transmitted ray parallel to the
    # incident one and every reflected ray its mirror image; the k-th crossing of the slab
    # moves the ray by d tan(theta_t) along x.
    esc = res.escapes
    assert np.all(esc["scatterings"] == 0)
    tr, rf = esc["kind"] == 1, esc["kind"] == 0
    assert tr.any()
    assert np.allclose(esc["direction"][tr], direction, atol=2e-6)
    assert np.allclose(esc["direction"][rf], direction * [1, 1, -1], atol=2e-6)
    assert np.allclose(esc["position"][tr][:, 2], -d, atol=1e-6)
    assert np.allclose(esc["position"][rf][:, 2], 0.0, atol=1e-6)
    assert np.allclose(esc["position"][:, 1], hit[1], atol=1e-6)
    if theta_deg > 0:
        tt_ = math.asin(math.sin(th) / n)
        k = (esc["position"][:, 0] - hit[0]) / (d * math.tan(tt_))  # crossings of the slab
        assert np.allclose(k, np.round(k), atol=1e-3)
        k = np.round(k).astype(int)
        assert np.all(k[tr] % 2 == 1) and np.all(k[rf] % 2 == 0) and np.all(k[rf] >= 2)


# ----------------------------------------------------------------------------
# Total internal reflection
# ----------------------------------------------------------------------------
TIR_LO, TIR_HI = (-1.0, -0.7, -1.3), (1.0, 0.7, 0.0)
TIR_START = (0.13, -0.21, -0.57)
# every |component| < cos(asin(1/1.4)) = 0.69985: each face (axis-aligned normal) is met
# beyond the critical angle, and mirror reflections only flip signs, so this stays true.
TIR_DIR = np.array([0.6, 0.5, 0.6245]) / np.linalg.norm([0.6, 0.5, 0.6245])


def _tir_scene(mua):
    scene = ep.Scene(unit="cm", ambient_n=1.0)
    scene.add_box("crystal", min=TIR_LO, max=TIR_HI, medium=ep.Medium(mua=mua, mus=0.0, g=0.0, n=1.4))
    return scene


def _billiard_path_lengths(p, d, lo, hi, total):
    """Cumulative path lengths at the successive wall hits of a ray in the box (specular walls)."""
    p, d = np.array(p, float), np.array(d, float)
    lo, hi = np.array(lo, float), np.array(hi, float)
    out, L = [], 0.0
    while L < total:
        t = np.where(d > 0, (hi - p) / d, np.where(d < 0, (lo - p) / d, np.inf))
        k = int(np.argmin(t))
        p = p + d * t[k]
        d[k] = -d[k]
        L += t[k]
        out.append(L)
    return np.array(out)


def test_tir_reference_direction_is_beyond_critical_angle():
    cos_c = math.sqrt(1 - (1 / 1.4) ** 2)
    assert np.all(np.abs(TIR_DIR) < cos_c)
    for i in range(3):
        theta = math.acos(abs(TIR_DIR[i]))
        assert fresnel_unpolarized(1.4, 1.0, theta) == 1.0


def test_total_internal_reflection_never_escapes():
    """Start inside an n = 1.4 box (mua = 3, mus = 0) on a ray that meets every face beyond
    the critical angle: nothing can ever leave, so Rsp = Rd = Tt = missed = 0 exactly and
    all weight is absorbed (|A - 1| < K_SIGMA sigma_A + 1e-9; A + roulette = 1 exactly)."""
    src = ep.PencilSource(position=TIR_START, direction=tuple(TIR_DIR))
    res = ep.run(_tir_scene(3.0), src, photons=20_000, seed=12, threads=0, record_escapes=True)
    assert_energy_conserved(res)
    assert res.specular_reflectance == 0.0
    assert res.diffuse_reflectance == 0.0
    assert res.transmittance == 0.0
    assert res.missed == 0.0 and res.cut == 0.0
    assert len(res.escapes["weight"]) == 0
    assert_within("A", res.absorbed, res.absorbed_stderr, 1.0, 1e-9)
    assert res.absorbed_by_region["crystal"] == pytest.approx(res.absorbed, abs=1e-12)


def test_total_internal_reflection_with_path_cap():
    """Same ray, mua = 1, max_path_cm = 1: weights stay >= exp(-mua (1 + diagonal)) >> the
    roulette threshold, so roulette = 0 exactly and A = 1 - cut (to 1e-9). The cut weight is
    the probability of reaching the cap without absorption: exp(-mua L), with L between the cap
    and the first wall hit beyond it (the engine may stop exactly at the cap or at the next event)."""
    mua, cap = 1.0, 1.0
    src = ep.PencilSource(position=TIR_START, direction=tuple(TIR_DIR))
    res = ep.run(_tir_scene(mua), src, photons=20_000, seed=13, threads=0, record_escapes=True, max_path_cm=cap)
    assert_energy_conserved(res)
    assert res.roulette == 0.0
    assert res.diffuse_reflectance == 0.0 and res.transmittance == 0.0 and res.specular_reflectance == 0.0
    assert res.missed == 0.0
    assert len(res.escapes["weight"]) == 0
    assert 0.0 < res.cut < 1.0
    assert abs(res.absorbed - (1.0 - res.cut)) < 1e-9
    hits = _billiard_path_lengths(TIR_START, TIR_DIR, TIR_LO, TIR_HI, cap)
    l_star = hits[hits >= cap][0]
    lo_ref, hi_ref = math.exp(-mua * l_star), math.exp(-mua * cap)
    s = res.cut_stderr
    assert lo_ref - K_SIGMA * s - 1e-12 < res.cut < hi_ref + K_SIGMA * s + 1e-12, (res.cut, s, lo_ref, hi_ref)


def test_internal_incidence_below_critical_angle_escapes_with_fresnel():
    """Start inside the n = 1.4 box (mua = mus = 0) going up at 30 deg from the normal of the
    top face (below the critical angle 45.6 deg): the fraction that leaves at the first hit is
    1 - R(30 deg; 1.4 -> 1), leaving at theta_t = asin(1.4 sin 30 deg) (Snell)."""
    th = math.radians(30.0)
    d = np.array([math.sin(th), 0.0, math.cos(th)])
    start = np.array([0.1, 0.05, -0.6])
    first_hit = start + d * (0.0 - start[2]) / d[2]
    src = ep.PencilSource(position=tuple(start), direction=tuple(d))
    res = ep.run(_tir_scene(0.0), src, photons=50_000, seed=14, threads=0, record_escapes=True)
    assert_energy_conserved(res)
    assert res.absorbed == 0.0 and res.missed == 0.0 and res.specular_reflectance == 0.0
    esc = res.escapes
    # every packet eventually leaves the clear box somewhere on its surface
    assert esc["weight"].sum() / res.photons == pytest.approx(1.0 - res.cut, abs=1e-9)
    assert np.all(distance_to_box_surface(esc["position"], TIR_LO, TIR_HI) < 1e-5)
    direct = np.linalg.norm(esc["position"] - first_hit, axis=1) < 1e-5
    frac = esc["weight"][direct].sum() / res.photons
    T = 1.0 - fresnel_unpolarized(1.4, 1.0, th)
    assert_within("direct escape", frac, math.sqrt(T * (1 - T) / res.photons), T, 1e-12)
    st = 1.4 * math.sin(th)
    assert np.allclose(esc["direction"][direct], [st, 0.0, math.sqrt(1 - st * st)], atol=2e-6)
