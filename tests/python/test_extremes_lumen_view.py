"""Extremes of the features that came after the core transport's extremes suite (test_extremes.py,
test_numerics.py, test_invariance.py): light crossing the lumen, the endoscope rig, the endoscope's
view and the beta sweep with visibility. Every case has an expected value from an analytic result,
an invariance or an independent numpy recomputation (docs/numerics.md, "Lumen, view and rig at the
extremes"), or must be a ValueError naming the field and the value.

Tolerance: |x - ref| < K_SIGMA sigma + ref_unc (physics_helpers), sigma the engine's batch-means
standard error, or the batch-means error of a sum over escape records recomputed here.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

import endophoton as ep
from endophoton import analysis, placement
from endophoton.view import colour
from endophoton.view.camera import Camera
from endophoton.mesh_io import box_mesh
from endophoton.units import unit_cm
from endophoton.sweep.view_sweep import add_visibility, plot_visibility, visibility_columns, visibility_report
from endophoton.view.visibility import fit_peak
from physics_helpers import (
    K_SIGMA,
    assert_energy_conserved,
    assert_no_nan,
    assert_same_within_stats,
    assert_within,
    fresnel_unpolarized,
    semi_infinite_isotropic_reflectance,
    slab_clear_totals,
)

from _synth import RecordsResult, hollow_box, lambertian_records, polyp_box_scene, random_rotation

AWAY = 0  # next_hit of a record whose ray leaves the scene (native/records.h)


def _records_fraction(res, mask, n_batches=50):
    """Weight of the records in ``mask`` per launched packet, and its batch-means standard error
    (contiguous packet-index batches, as the engine's tallies), recomputed with numpy."""
    e = res.escapes
    batch, per_batch = analysis.batch_index(e["packet"], n_batches, int(res.photons))
    sums = np.bincount(batch[mask], weights=e["weight"][mask], minlength=n_batches)
    means = sums / per_batch
    return float(sums.sum() / res.photons), float(np.std(means, ddof=1) / math.sqrt(n_batches))


# ----------------------------------------------------------------------------
# The lumen between two clear slabs: the incoherent bounce series
# ----------------------------------------------------------------------------
def _bounce_series(n, mua, d_cm, theta):
    """Two identical clear slabs (index n in an n = 1 ambient, absorption mua cm^-1, thickness d_cm cm)
    face each other across a gap; a collimated beam in the gap meets the first at incidence theta (rad).
    Each slab reflects Rs and transmits Ts (its internal reflections summed, slab_clear_totals with the
    refracted path d / cos theta_t; Fresnel's R is the same on both sides of a face), and the beam keeps
    its angle from bounce to bounce, so the light that leaves through the first slab is
    Ts (1 + Rs^2 + Rs^4 + ...) = Ts / (1 - Rs^2) and through the second Ts Rs / (1 - Rs^2)."""
    R = fresnel_unpolarized(1.0, n, theta)
    cos_t = math.sqrt(1.0 - (math.sin(theta) / n) ** 2)
    rsp, rd, ts = slab_clear_totals(R, mua, d_cm / cos_t)
    rs = rsp + rd
    return {"first": ts / (1.0 - rs * rs), "second": ts * rs / (1.0 - rs * rs)}


GAP_DEFAULTS = dict(unit="cm", gap=0.5, d=0.1, n=1.5, mua=1.0, mus=0.0, g=0.0, theta=0.0, offset=(0, 0, 0), rot=None)
GAP_CASES = {
    "n1.5": {},
    "narrow_gap_1e-3cm": dict(gap=1e-3),
    "wide_gap_30cm": dict(gap=30.0),
    # 89 deg: the beam walks 0.57 cm along the wall per crossing; about 15 crossings stay well inside the 200 cm slabs.
    "grazing_89deg": dict(gap=0.01, theta=89.0),
    "n100_near_total_reflection": dict(n=100.0),  # R = 0.96 at each face: up to ~20 crossings
    "forward_delta_g1": dict(mus=10.0, g=1.0),  # g = 1 scatters nothing away: the clear slab's series
    "mm": dict(unit="mm"),
    "m": dict(unit="m"),
    "m_30m_away": dict(unit="m", offset=(1e3, -2e3, 2e3), d=0.2),
    "cm_1e4cm_away": dict(offset=(1e4, 1e4, -1e4), d=0.5),
    "rotated": dict(rot=7, theta=40.0),
}


def _gap_scene(c):
    """Two clear slabs (200 cm wide, ``d`` cm thick) across a ``gap`` cm lumen, built in ``unit``, turned by a
    random rotation (seed ``rot``) and moved by ``offset`` cm; a pencil beam at the gap's mid-plane aimed at
    the lower slab at ``theta`` deg. Returns (scene, source, world normal of the lower slab, thickness in cm
    of the float32 lower slab along z when not rotated)."""
    k = 1.0 / unit_cm(c["unit"])
    R = np.eye(3) if c["rot"] is None else random_rotation(np.random.default_rng(c["rot"]))
    off = np.asarray(c["offset"], dtype=np.float64)
    medium = ep.Medium(mua=c["mua"], mus=c["mus"], g=c["g"], n=c["n"])
    scene = ep.Scene(unit=c["unit"])
    d, gap, w = c["d"], c["gap"], 100.0
    thickness = d
    for name, z0 in (("lower", -d), ("upper", gap)):
        v, t = box_mesh((-w, -w, z0), (w, w, z0 + d))
        v32 = (((v.astype(np.float64) @ R.T) + off) * k).astype(np.float32)
        scene.add_mesh(name, v32, t, medium)
        if name == "lower" and c["rot"] is None:
            thickness = float(v32[:, 2].max() - v32[:, 2].min()) / k  # what the engine's float32 geometry holds
    th = math.radians(c["theta"])
    src = ep.PencilSource(
        position=(R @ np.array([0.0, 0.0, 0.5 * gap]) + off) * k,
        direction=R @ np.array([math.sin(th), 0, -math.cos(th)]),
    )
    return scene, src, R @ np.array([0.0, 0.0, 1.0]), thickness


# n = 100 bounces near total reflection for a second or more: the one slow case
@pytest.mark.parametrize(
    "case", [pytest.param(c, marks=pytest.mark.slow) if c.startswith("n100") else c for c in sorted(GAP_CASES)]
)
def test_light_bouncing_across_the_lumen_between_clear_slabs(case):
    """Narrow and wide lumens, grazing incidence, n = 100, g = 1, mm/cm/m, 30 m and 1.7e4 cm from the
    origin, rotated: the escaping weight and the share through the first slab follow the bounce series.
    Roulette is off, so escaped = 1 - absorbed packet by packet and sigma(escaped) = sigma(absorbed)."""
    c = {**GAP_DEFAULTS, **GAP_CASES[case]}
    scene, src, normal, d_cm = _gap_scene(c)
    res = ep.run(scene, src, photons=20_000, seed=11, threads=2, roulette_threshold=0.0)
    assert_energy_conserved(res, tol=1e-12)
    assert_no_nan(res)
    assert res.missed == 0.0 and res.cut == 0.0 and res.roulette == 0.0
    ref = _bounce_series(c["n"], c["mua"], d_cm, math.radians(c["theta"]))
    escaped = res.specular_reflectance + res.diffuse_reflectance + res.transmittance
    assert_within(f"escaped [{case}]", escaped, res.absorbed_stderr, ref["first"] + ref["second"])
    e = res.escapes
    away = e["next_hit"] == AWAY
    # The escaping weight is the weight of the records whose rays leave the scene, but for packets that
    # land, reflect off the landing face (no exit, no record) and then leave: at 89 deg (R = 0.9 at each
    # landing) a few such chains carry ~1e-11 of the weight (roulette is off, so their weight is tiny).
    assert escaped * res.photons == pytest.approx(e["weight"][away].sum(), rel=1e-9)
    first = away & (e["direction"].astype(np.float64) @ normal < 0)
    v, s = _records_fraction(res, first)
    assert_within(f"through the first slab [{case}]", v, s, ref["first"])
    assert e["exit_order"].max() >= 3  # the light did cross the lumen, several times


@pytest.mark.parametrize("unit", ["mm", "cm", "m"])
def test_matched_clear_wall_is_beer_lambert_exactly_across_the_lumen(unit):
    """Wall n = 1 (matched): no Fresnel anywhere, so the beam crosses the lower slab once and
    escaped = exp(-mua d32) with no statistical error (d32: the float32 thickness), in every unit."""
    c = {**GAP_DEFAULTS, "unit": unit, "n": 1.0}
    scene, src, _, d_cm = _gap_scene(c)
    res = ep.run(scene, src, photons=5_000, seed=12, threads=2)
    assert_energy_conserved(res, tol=1e-12)
    ref = math.exp(-c["mua"] * d_cm)
    assert res.transmittance == pytest.approx(ref, rel=1e-12)
    assert res.transmittance_stderr < 1e-12 and res.diffuse_reflectance == 0.0
    assert res.absorbed == pytest.approx(1.0 - ref, rel=1e-12)


def test_non_absorbing_clear_walls_let_everything_out():
    """mua = 0: the walls absorb nothing, so A = roulette = 0 exactly and all weight escapes (to 1e-12);
    the share through the first slab is (1 + R) / (1 + 3 R) (the bounce series at q = 1)."""
    c = {**GAP_DEFAULTS, "mua": 0.0}
    scene, src, normal, d_cm = _gap_scene(c)
    res = ep.run(scene, src, photons=20_000, seed=13, threads=2)
    assert_energy_conserved(res, tol=1e-12)
    assert res.absorbed == 0.0 and res.roulette == 0.0 and res.cut == 0.0
    assert res.diffuse_reflectance + res.transmittance + res.specular_reflectance == pytest.approx(1.0, abs=1e-12)
    R = fresnel_unpolarized(1.0, c["n"], 0.0)
    ref = (1 + R) / (1 + 3 * R)
    assert _bounce_series(c["n"], 0.0, d_cm, 0.0)["first"] == pytest.approx(ref, rel=1e-12)
    e = res.escapes
    v, s = _records_fraction(res, (e["next_hit"] == AWAY) & (e["direction"].astype(np.float64) @ normal < 0))
    assert_within("through the first slab (mua = 0)", v, s, ref)


# ----------------------------------------------------------------------------
# Closed cavities: nothing reaches infinity from inside
# ----------------------------------------------------------------------------
def test_non_absorbing_cavity_wall_sends_everything_out_through_the_outer_wall():
    """A cavity in a scattering wall with mua = 0: no weight is ever lost, none can come back to the light
    (a closed pocket), so Rsp = Rd = A = roulette = 0 exactly and Tt + cut = 1 to 1e-12; Tt is exactly
    the weight of the records that leave the outer wall."""
    scene = ep.Scene(unit="cm")
    scene.add_mesh("shell", *hollow_box(1.05, 1.0), ep.Medium(mua=0.0, mus=100.0, g=0.9, n=1.4))
    src = ep.PencilSource(position=(0.0, 0.0, 0.0), direction=(0.3, 0.2, -1.0))
    res = ep.run(scene, src, photons=5_000, seed=14, threads=2)
    assert_energy_conserved(res, tol=1e-12)
    assert res.specular_reflectance == 0.0 and res.diffuse_reflectance == 0.0
    assert res.absorbed == 0.0 and res.roulette == 0.0 and res.missed == 0.0
    assert res.transmittance + res.cut == pytest.approx(1.0, abs=1e-12)
    e = res.escapes
    away = e["next_hit"] == AWAY
    assert res.transmittance * res.photons == pytest.approx(e["weight"][away].sum(), rel=1e-12)
    assert np.all(np.max(np.abs(e["position"][away]), axis=1) > 1.05 - 1e-5)  # outer-wall exits only
    assert e["exit_order"].max() >= 5


def test_huge_mus_cavity_first_landing_reflects_like_chandrasekhar():
    """mua = 100, mus = 1e5 cm^-1 (albedo 0.999), g = 0, n = 1, 1 cm walls: the beam's first landing is a
    semi-infinite medium at normal incidence (penetration ~1e-3 cm), so the weight of the first exits is
    R = 1 - H(1) sqrt(1 - albedo) (Chandrasekhar); the walls are ~1000 transport lengths thick, so nothing
    leaves the cavity: Rsp = Rd = Tt = 0 exactly and A = 1 to within the net roulette weight."""
    mua, mus = 100.0, 1e5
    scene = ep.Scene(unit="cm")
    scene.add_mesh("shell", *hollow_box(2.0, 1.0), ep.Medium(mua=mua, mus=mus, g=0.0, n=1.0))
    src = ep.PencilSource(position=(0.0, 0.0, 0.0), direction=(0.0, 0.0, -1.0))
    res = ep.run(scene, src, photons=3_000, seed=15, threads=2)
    assert_energy_conserved(res)
    assert res.specular_reflectance == 0.0 and res.diffuse_reflectance == 0.0 and res.transmittance == 0.0
    assert res.absorbed + res.roulette == pytest.approx(1.0, abs=1e-12)
    e = res.escapes
    v, s = _records_fraction(res, e["exit_order"] == 1)
    assert_within("first landing R (mus = 1e5)", v, s, semi_infinite_isotropic_reflectance(mua, mus), 1e-6)
    assert np.all(e["next_hit"] != AWAY)


# ----------------------------------------------------------------------------
# The endoscope rig at the extremes
# ----------------------------------------------------------------------------
def _flat_wall(unit="cm"):
    """The paper's flat tissue without a polyp (100 cm wide, n = 1.1; beta_sweep.default_flat_scene)."""
    return ep.default_flat_scene(unit=unit, polyp=None)


@pytest.mark.parametrize("unit", ["mm", "cm", "m"])
def test_front_face_meets_the_wall_where_geometry_says(unit):
    """from_beta orbits the head at d = 1 cm from the surface point, tilted by beta about y; a face point u
    from the centre along the tilt lies at height d cos(beta) - u sin(beta). A 12 mm or 10 um head's rim
    (u = r) reaches the wall at tan(beta) = d / r (59.04 deg; 89.97 deg); a 10 m head first meets the 1 m
    wall's edge (x = 50 cm), at sin(beta) = d / 50 cm (1.146 deg). Just inside: no complaint; just beyond:
    a ValueError naming the region and rig.beta_deg, in every unit."""
    k = 1.0 / unit_cm(unit)
    scene = _flat_wall(unit)
    for head_mm, beta_max in (
        (12.0, math.degrees(math.atan(1.0 / 0.6))),
        (0.01, math.degrees(math.atan(1.0 / 5e-4))),
        (1e4, math.degrees(math.asin(1.0 / 50.0))),
    ):
        kw = dict(head_diameter_mm=head_mm, light_offset_mm=0.25 * head_mm, light_diameter_mm=0.25 * head_mm)
        kw["camera_aperture_mm"] = 0.1 * head_mm
        delta = 0.01 * min(1.0, 90.0 - beta_max, beta_max)
        assert placement.check_rig(scene, ep.EndoscopeRig.from_beta(beta_max - delta, 1.0 * k, **kw)) == []
        beyond = ep.EndoscopeRig.from_beta(beta_max + delta, 1.0 * k, **kw)
        with pytest.raises(ValueError, match=r"front face .* region 'tissue' \(rig.beta_deg = "):
            ep.run(scene, beyond, photons=10)
    res = ep.run(scene, ep.EndoscopeRig.from_beta(59.0, 1.0 * k), photons=2_000, seed=16, threads=2)
    assert_energy_conserved(res)
    assert res.warnings == []


def test_rig_face_touching_the_wall_is_refused_and_a_hair_above_it_runs():
    """A head (transform) whose face lies exactly on the wall would launch its light on the surface and let
    the light leaving the wall under it pass through the (opaque) head: refused by name. 1e-4 cm above the
    wall (50 times the contact tolerance) it runs and conserves energy."""
    scene = _flat_wall()
    M = np.eye(4)  # looks along -z: the face lies in the plane z = height
    for height, ok in ((0.0, False), (1e-4, True)):
        M[2, 3] = height
        rig = ep.EndoscopeRig(transform=M.copy())
        if ok:
            assert_energy_conserved(ep.run(scene, rig, photons=2_000, seed=17, threads=2))
        else:
            with pytest.raises(ValueError, match="crosses or touches region 'tissue'"):
                ep.run(scene, rig, photons=10)


def test_placement_messages_quote_the_numbers_as_given():
    """β = 89.99999 deg is not 90 and a 12.000001 mm head is not 12 mm: the front-face error and the
    body warning quote β, head_diameter_mm and head_length_mm as given (shortest round-trip text), never
    rounded as ``:g`` would."""
    rig = ep.EndoscopeRig.from_beta(89.99999, 1.0, head_diameter_mm=12.000001)
    with pytest.raises(ValueError) as err:
        placement.check_rig(_flat_wall(), rig)
    assert "rig.beta_deg = 89.99999," in str(err.value)
    assert "head_diameter_mm = 12.000001)" in str(err.value)
    scene = ep.Scene(unit="cm")
    scene.add_box("floor", (-5.0, -1.6, -1.6), (5.0, 1.6, -1.5), ep.Medium(mua=5.0, mus=100.0, g=0.9, n=1.4))
    scene.add_box("ceiling", (-5.0, -1.6, 1.5), (5.0, 1.6, 1.6), ep.Medium(mua=5.0, mus=100.0, g=0.9, n=1.4))
    rig = ep.EndoscopeRig.from_beta(20.0, 1.0, point=(0.0, 0.0, -1.5), head_length_mm=49.9999999)
    (warning,) = placement.check_rig(scene, rig)
    assert "head_length_mm = 49.9999999 behind" in warning and "region 'ceiling'" in warning


def test_rig_body_through_the_opposite_wall_is_a_warning():
    """A head 1 cm over a floor, tilted 20 deg, under a ceiling 3 cm above the floor: a 50 mm body's back
    reaches z = -1.5 + (1 + 5) cos 20 = 4.1 cm, through the ceiling (1.5-1.6 cm): the run goes on (the engine stops
    light on the body only in the ambient) and says so in Result.warnings, naming the region. A 5 mm body
    (back at z = -1.5 + 1.5 cos 20 = -0.09 cm) has no warning."""
    scene = ep.Scene(unit="cm")
    scene.add_box("floor", (-5.0, -1.6, -1.6), (5.0, 1.6, -1.5), ep.Medium(mua=5.0, mus=100.0, g=0.9, n=1.4))
    scene.add_box("ceiling", (-5.0, -1.6, 1.5), (5.0, 1.6, 1.6), ep.Medium(mua=5.0, mus=100.0, g=0.9, n=1.4))
    for length, warned in ((50.0, True), (5.0, False)):
        rig = ep.EndoscopeRig.from_beta(20.0, 1.0, point=(0.0, 0.0, -1.5), head_length_mm=length)
        res = ep.run(scene, rig, photons=2_000, seed=18, threads=2)
        assert_energy_conserved(res)
        assert any("body" in w and "region 'ceiling'" in w for w in res.warnings) == warned, res.warnings


def test_collimated_rig_at_89_degrees_reflects_fresnel_exactly():
    """beta = 89 deg, 50 cm from the wall (the face clears it: tan 89 = 57 < 50 / 0.6), collimated light:
    every packet meets the n = 1.1 wall at 89 deg and its mirror ray leaves the scene, so the specular part
    is MCML's deterministic split, Rsp = R_Fresnel(89 deg) to rounding."""
    rig = ep.EndoscopeRig.from_beta(89.0, 50.0, cone_angle_deg=0.0)
    res = ep.run(_flat_wall(), rig, photons=5_000, seed=19, threads=2)
    assert_energy_conserved(res)
    ref = fresnel_unpolarized(1.0, 1.1, math.radians(89.0))
    assert res.specular_reflectance == pytest.approx(ref, rel=1e-9)
    assert res.specular_reflectance_stderr < 1e-9 and res.missed == 0.0


def test_huge_head_over_the_wall_stops_all_light_that_leaves_it():
    """A 10 m head 1 cm above the 1 m wide wall at beta = 0: every exit ray that rises more than
    atan(1 cm / 450 cm) = 0.13 deg above the wall meets the face, so Rd is bounded by the share of exits
    flatter than that (< (0.13 deg in rad)^2 for a cosine-law exit, ~5e-6 of the exits); the specular part
    returns onto the head. Everything else is absorbed, occluded or collected: the balance to 1e-12."""
    rig = ep.EndoscopeRig.from_beta(0.0, 1.0, head_diameter_mm=1e4)
    res = ep.run(_flat_wall(), rig, photons=20_000, seed=20, threads=2)
    assert_energy_conserved(res, tol=1e-12)
    assert res.specular_reflectance == 0.0 and res.transmittance == 0.0
    assert res.diffuse_reflectance <= K_SIGMA * res.diffuse_reflectance_stderr + 1e-5
    assert res.occluded + res.camera_collected > 0.03


@pytest.mark.parametrize("unit", ["mm", "cm", "m"])
def test_tiny_rig_returns_the_walls_mirror_light_onto_its_guides(unit):
    """A 10 um head (guides 2.5 um across) 1 cm over a clear glass block (n = 1.5, strongly absorbing) at
    beta = 0, collimated: the only light that comes back is the face's Fresnel reflection R = 0.04, straight
    back onto the guides: occluded = R within the binomial error, nothing collected, in every unit."""
    k = 1.0 / unit_cm(unit)
    scene = ep.Scene(unit=unit)
    scene.add_box("glass", (-5 * k, -5 * k, -5 * k), (5 * k, 5 * k, 0.0), ep.Medium(mua=50.0, mus=0.0, n=1.5))
    rig = ep.EndoscopeRig.from_beta(
        0.0,
        1.0 * k,
        cone_angle_deg=0.0,
        head_diameter_mm=0.01,
        light_diameter_mm=0.0025,
        light_offset_mm=0.0025,
        camera_aperture_mm=0.001,
    )
    n = 20_000
    res = ep.run(scene, rig, photons=n, seed=21, threads=2)
    assert_energy_conserved(res, tol=1e-12)
    R = 0.04
    assert_within(f"occluded [{unit}]", res.occluded, math.sqrt(R * (1 - R) / n), R)
    assert res.camera_collected == 0.0 and res.specular_reflectance == 0.0


def test_from_beta_near_90_degrees_keeps_the_head_on_its_orbit():
    """beta = +-89.999 deg at d = 50 cm: the head sits at point + d (sin b, 0, cos b), looks back at the point,
    and its lights (in the plane of tilt) at heights d cos b -+ 0.35 sin b cm; beta = 90 is a named error."""
    for beta in (89.999, -89.999, 0.0):
        b = math.radians(beta)
        rig = ep.EndoscopeRig.from_beta(beta, 50.0, point=(1.0, 2.0, 0.0))
        expected = np.array([1.0 + 50 * math.sin(b), 2.0, 50 * math.cos(b)])
        assert np.allclose(rig.position, expected, rtol=0, atol=1e-12)
        assert np.allclose(rig.forward, -(expected - [1.0, 2.0, 0.0]) / 50.0, atol=1e-14)
        heights = sorted(rig.light_positions("cm")[:, 2])
        ref = sorted([50 * math.cos(b) - 0.35 * math.sin(b), 50 * math.cos(b) + 0.35 * math.sin(b)])
        assert np.allclose(heights, ref, atol=1e-12)
    for bad in (90.0, -90.0, float("nan")):
        with pytest.raises(ValueError, match="rig.beta_deg"):
            ep.EndoscopeRig.from_beta(bad, 50.0)
    with pytest.raises(ValueError, match=r"rig.camera_fov_deg = 0 must be a finite number \(0, 179"):
        ep.EndoscopeRig.from_beta(0.0, 1.0, camera_fov_deg=0)  # was accepted, then refused as camera.fov_deg


# ----------------------------------------------------------------------------
# The endoscope's view at the extremes (synthetic Lambertian records: L = 1 / (4 pi) per packet)
# ----------------------------------------------------------------------------
L_LAMBERT = 1.0 / (4.0 * math.pi)  # lambertian_records(n) on [-1, 1]^2 cm: n / (P * 4 cm^2 * pi)


def _plane_records(n=200_000, scene=None):
    if scene is None:
        scene = ep.Scene(unit="cm")
        scene.add_box("tissue", (-5, -5, -1), (5, 5, 0), ep.Medium(mua=1.0, mus=10.0))
    return RecordsResult(scene, lambertian_records(n), n)


def _assert_image_defined(img):
    for key, v in img.items():
        assert np.all(np.isfinite(np.asarray(v, dtype=np.float64))), key
    assert np.all(img["radiance_stderr"] >= 0)


def test_camera_looking_away_from_all_tissue_gives_a_defined_black_view(tmp_path):
    """Nothing in view: every pixel and every image is exactly 0 with stderr 0 (no NaN), the auto exposure
    is 1 (its rule for a 0 percentile), no region is seen, a contrast is a named error, and the PNGs are black."""
    cam = Camera.look_at((0, 0, 2), (0, 0, 5), up=(0, 1, 0), aperture_radius=0.1)
    view = ep.render_view(_plane_records(1000), cam, 5, 3)
    assert np.all(view.region_map == -1) and view.regions() == {} and view.kernel_summary()["bias"] == {}
    for images in (view.images, view.aperture):
        for img in images.values():
            _assert_image_defined(img)
            assert not img["radiance"].any() and not img["radiance_stderr"].any() and not img["srgb8"].any()
            assert float(img["exposure"]) == 1.0
    with pytest.raises(ValueError, match="target = 'tissue': the camera sees no pixel"):
        view.contrast("tissue", "tissue")
    import matplotlib.image as mpimg

    png = mpimg.imread(view.save(tmp_path)["white"])
    assert png.shape[:2] == (3, 5) and not png[..., :3].any()


@pytest.mark.parametrize("fov,size", [(30.0, (1, 1)), (179.0, (3, 3)), (1e-4, (3, 3))])
def test_extreme_fields_of_view_see_the_lambertian_radiance(fov, size):
    """One pixel; the widest field the camera accepts (179 deg: the centre pixel looks straight down, the
    corner pixels graze past the records' patch and see nothing); a 1e-4 deg field (all pixels see the same
    point). Every pixel that sees the records estimates L = 1/(4 pi) within K sigma + the kernel's 0.5 %
    cone bias (test_render); the others are exactly 0 with stderr 0; a 1 x 1 image's largest channel is
    exposed to 0.5, i.e. 8-bit round(255 (1.055 0.5^(1/2.4) - 0.055)) = 188."""
    W, H = size
    cam = Camera.look_at((0, 0, 2), (0, 0, 0), up=(0, 1, 0), fov_deg=fov)
    view = ep.render_view(_plane_records(400_000), cam, W, H, kernel_radius=0.3)
    img = view.images["white"]
    _assert_image_defined(img)
    L, se = img["radiance"], img["radiance_stderr"]
    seen = L > 0
    assert seen[H // 2, W // 2]
    for y, x in zip(*np.nonzero(seen)):
        assert_within(f"L pixel ({y},{x}) at fov {fov}", L[y, x], se[y, x], L_LAMBERT, 0.005 * L_LAMBERT)
    assert not se[~seen].any()
    if fov == 179.0:
        assert seen.sum() == 1  # the corner rays meet the plane ~90 cm out, far from the 2 x 2 cm records
    if W * H == 1:
        encoded = 1.055 * 0.5 ** (1 / 2.4) - 0.055
        assert int(img["srgb8"].max()) == round(255 * encoded) == 188


@pytest.mark.parametrize("size", [(7, 3), (3, 7), (1, 5)])
def test_non_square_images_follow_the_larger_side_field_of_view(size):
    """fov is the full angle across the larger image side, the other side gets tan(fov/2) x smaller/larger
    (Blender's AUTO fit). A hand projection of the pixel centres onto the polyp box's top (z = 0.3) and the
    wall (z = 0) from 2 cm gives each pixel's region and depth."""
    W, H = size
    scene = ep.Scene(unit="cm")
    scene.add_box("wall", (-5, -5, -1), (5, 5, 0), ep.Medium(mua=1.0, mus=10.0))
    scene.add_box("polyp", (-0.3, -0.3, -0.2), (0.3, 0.3, 0.3), ep.Medium(mua=1.0, mus=10.0), priority=1)
    view = ep.render_view(
        _plane_records(1000, scene), Camera.look_at((0, 0, 2), (0, 0, 0), up=(0, 1, 0), fov_deg=40), W, H
    )
    t = math.tan(math.radians(20.0))
    tx, ty = (t, t * H / W) if W >= H else (t * W / H, t)
    X, Y = np.meshgrid(((np.arange(W) + 0.5) / W * 2 - 1) * tx, (1 - (np.arange(H) + 0.5) / H * 2) * ty)
    on_polyp = (np.abs(X * 1.7) < 0.3) & (np.abs(Y * 1.7) < 0.3)
    assert view.region_map.shape == (H, W)
    assert np.array_equal(view.region_map, np.where(on_polyp, 1, 0))
    assert np.allclose(view.depth, np.where(on_polyp, 1.7, 2.0), rtol=1e-6)
    for img in view.images.values():
        _assert_image_defined(img)


def test_field_of_view_limits_are_named_errors():
    """fov 0, 180, negative, NaN: ValueError naming camera.fov_deg; a 1e-300 deg field whose default kernel
    (2 pixel footprints) is 0 in double precision names camera.fov_deg too (it used to name the derived
    kernel_radius, which the caller never gave)."""
    for bad in (0.0, 180.0, -1.0, float("nan")):
        with pytest.raises(ValueError, match="camera.fov_deg"):
            Camera.look_at((0, 0, 2), (0, 0, 0), up=(0, 1, 0), fov_deg=bad)
    cam = Camera.look_at((0, 0, 2), (0, 0, 0), up=(0, 1, 0), fov_deg=1e-300)
    with pytest.raises(ValueError, match=r"camera.fov_deg = 1e-300 with width = 3: the default kernel_radius"):
        ep.render_view(_plane_records(1000), cam, 3, 3)


def test_target_out_of_view_gives_undefined_visibility_not_an_error():
    """The camera looks at wall only: the polyp has no pixel, so every contrast is undefined (None, also in a
    sweep row) and target_pixels = 0, background_pixels = W x H; a region the scene lacks is still a named
    error, and view.contrast still names the unseen target."""
    scene = polyp_box_scene()
    res = RecordsResult(scene, lambertian_records(5000), 5000)
    cam = dict(camera=Camera.look_at((2.0, 2.0, 1.0), (2.0, 2.0, 0.0), up=(0, 1, 0), fov_deg=20), width=6, height=4)
    cols = visibility_columns(res, "polyp", "wall", **cam)
    assert cols["target_pixels"] == 0 and cols["background_pixels"] == 24
    counts = ("target_pixels", "background_pixels", "view_packets", "white_packets")  # defined out of view too
    assert cols["view_packets"] == cols["white_packets"] == 5000
    assert all(v is None for k, v in cols.items() if k not in counts)
    row = add_visibility({}, res, 10.0, {"target": "polyp", "background": "wall", **cam})
    assert all(v is None for k, v in row.items() if k not in counts)
    with pytest.raises(ValueError, match="target = 'tumour' is not a region"):
        visibility_columns(res, "tumour", "wall", **cam)
    with pytest.raises(ValueError, match="target = 'polyp': the camera sees no pixel"):
        ep.render_view(res, **cam).contrast("polyp", "wall")


@pytest.mark.filterwarnings("error")
def test_colour_and_legend_of_empty_and_one_pixel_views(tmp_path):
    """All-zero image: exposure 1, black 8-bit image; one pixel (0.2, 0.1, 0.05): exposure 0.5 / 0.2 = 2.5
    and the IEC sRGB encoding of (0.5, 0.25, 0.125); a negative channel clips to 0. A sweep whose contrasts
    are all undefined still plots (a PNG, no series and no warning: it used to draw masked NaN points) and
    reports that no maximum can be located."""
    assert colour.auto_exposure(np.zeros((4, 4)), np.ones((4, 4), bool)) == 1.0
    assert not colour.to_srgb8(np.zeros((4, 4, 3)), 1.0).any()
    px = np.array([[[0.2, 0.1, 0.05]]])
    k = colour.auto_exposure(px.max(axis=-1))
    assert k == pytest.approx(2.5, rel=1e-15)
    lin = np.array([0.5, 0.25, 0.125])
    iec = np.where(lin <= 0.0031308, 12.92 * lin, 1.055 * lin ** (1 / 2.4) - 0.055)
    assert colour.to_srgb8(px, k)[0, 0].tolist() == np.round(255 * iec).astype(int).tolist()
    assert colour.to_srgb8(np.array([[[-0.1, 0.2, 0.0]]]), 2.5)[0, 0, 0] == 0
    rows = [{k: None for k in ("red_green_contrast", "fluorescence_contrast", "white_contrast")} for _ in range(3)]
    for r in rows:
        r.update({k + "_stderr": None for k in list(r)})
    assert fit_peak([0, 10, 20], [math.nan] * 3, [math.nan] * 3)["x_peak"] is None
    path = plot_visibility([0, 10, 20], rows, tmp_path / "visibility.png")
    with open(path, "rb") as fh:
        assert fh.read(8) == b"\x89PNG\r\n\x1a\n"
    assert "Too few β values" in visibility_report([0, 10, 20], rows)


# ----------------------------------------------------------------------------
# The beta sweep with visibility at its extremes
# ----------------------------------------------------------------------------
def test_sweep_refuses_an_angle_whose_head_enters_the_wall_before_any_run():
    """At d = 1 cm the 12 mm head's face reaches the wall at 59.04 deg: a sweep over 0, 70 and 80 deg names
    both refused angles and the region before it traces a single packet."""
    runs = []
    with pytest.raises(ValueError, match=r"betas: at rig.beta_deg = 70, 80 .* region 'tissue'"):
        ep.sweep(
            ep.default_flat_scene(), betas=[0, 70, 80], store=100, progress=False, on_run=lambda *a: runs.append(a)
        )
    assert runs == []


@pytest.mark.slow
def test_sweep_with_visibility_at_beta_0_and_the_steepest_accepted_beta(tmp_path):
    """beta = 0 and 58.5 deg (0.5 deg short of the face touching the wall): both runs conserve energy, the
    head looks at the polyp's top so the polyp is in view (target_pixels > 0: the image centre sees it),
    every column is finite or nan (never an error), and the views, plot and report are written."""
    out = []
    res = ep.sweep(
        ep.default_flat_scene(),
        betas=[0.0, 58.5],
        store=1000,
        progress=False,
        threads=2,
        out_dir=tmp_path,
        visibility={"target": "polyp", "background": "tissue", "width": 16, "height": 16},
        on_run=lambda i, beta, r: out.append(r),
    )
    for r in out:
        assert_energy_conserved(r)
        assert r.warnings == []
    for row in res.rows:
        assert row["target_pixels"] > 0 and row["target_pixels"] + row["background_pixels"] <= 256
        for key in ("fluorescence_contrast", "white_contrast", "red_green_contrast"):
            assert row[key] is None or math.isfinite(row[key])
    assert (tmp_path / "visibility.png").exists() and (tmp_path / "views" / "beta58.5_fluorescence.png").exists()


# ----------------------------------------------------------------------------
# Units, placement and rotation of the rig's scene: fractions and the camera image
# ----------------------------------------------------------------------------
def _rig_scene(unit, offset_cm=(0.0, 0.0, 0.0), rot=None):
    """A wall (20 x 20 x 5 cm, the paper's tissue) with a box polyp (0.8 x 0.8 x 0.4 cm above the wall),
    and a rig 1 cm above the polyp's top at beta = 30 deg, 32 x 32 camera: in ``unit``, moved by
    ``offset_cm``, turned by the random rotation of seed ``rot`` (rig included)."""
    k = 1.0 / unit_cm(unit)
    R = np.eye(3) if rot is None else random_rotation(np.random.default_rng(rot))
    off = np.asarray(offset_cm, dtype=np.float64)
    tissue = ep.Medium(mua=20.0, mus=200.0, g=0.9, n=1.1)
    scene = ep.Scene(unit=unit)
    for name, lo, hi, prio in (
        ("wall", (-10, -10, -5), (10, 10, 0), 0),
        ("polyp", (-0.4, -0.4, -0.2), (0.4, 0.4, 0.4), 1),
    ):
        v, t = box_mesh(lo, hi)
        scene.add_mesh(name, (((v.astype(np.float64) @ R.T) + off) * k).astype(np.float32), t, tissue, priority=prio)
    rig = ep.EndoscopeRig.from_beta(
        30.0,
        1.0 * k,
        point=(R @ np.array([0.0, 0.0, 0.4]) + off) * k,
        normal=R @ np.array([0.0, 0.0, 1.0]),
        tilt_axis=R @ np.array([0.0, 1.0, 0.0]),
        camera_resolution=(32, 32),
    )
    return scene, rig


RIG_VARIANTS = {
    "mm": dict(unit="mm"),
    "m": dict(unit="m"),
    "m_20m_away": dict(unit="m", offset_cm=(2e3, -1e3, 1e3)),
    "cm_5000cm_away": dict(unit="cm", offset_cm=(-5e3, 3e3, 2e3)),
    "rotated": dict(unit="cm", rot=3),
}


@pytest.fixture(scope="module")
def rig_reference():
    scene, rig = _rig_scene("cm")
    res = ep.run(scene, rig, photons=60_000, seed=30, threads=2, spectral=True)
    return res, ep.render_view(res, kernel_angle_deg=30.0, threads=2)


@pytest.mark.parametrize("variant", sorted(RIG_VARIANTS))
def test_rig_scene_gives_the_same_fractions_and_image_in_any_unit_place_and_orientation(rig_reference, variant):
    """The same physical scene and rig in mm and m, 20 m and 5000 cm from the origin, and turned as a
    whole: Rd, occluded, camera_collected, absorbed and each region's mean radiance (per cm^2 per sr) in the
    rig camera's image agree with the cm scene at the origin within K sigma of the two independent runs;
    each region covers the same pixels up to its outline (float32 vertices)."""
    ref, ref_view = rig_reference
    scene, rig = _rig_scene(**RIG_VARIANTS[variant])
    res = ep.run(scene, rig, photons=60_000, seed=31, threads=2, spectral=True)
    assert_energy_conserved(res)
    # Far from the origin the edges are resolved more coarsely, and the run says so for both boxes
    # (scale_check.h, kEdgeResolutionMfp); the fractions and image below still agree.
    far = "away" in variant
    assert [w.split("'")[1] for w in res.warnings] == (["wall", "polyp"] if far else [])
    assert all("are one crossing" in w for w in res.warnings)
    for key in ("diffuse_reflectance", "occluded", "camera_collected", "absorbed"):
        a, sa = getattr(res, key), getattr(res, key + "_stderr")
        b, sb = getattr(ref, key), getattr(ref, key + "_stderr")
        assert_same_within_stats(f"{key} [{variant}]", a, sa, b, sb)
    view = ep.render_view(res, kernel_angle_deg=30.0, threads=2)
    got, want = view.regions(), ref_view.regions()
    for name in ("wall", "polyp"):
        assert abs(got[name]["pixels"] - want[name]["pixels"]) <= 4
        a, sa = got[name]["white_radiance"], got[name]["white_radiance_stderr"]
        b, sb = want[name]["white_radiance"], want[name]["white_radiance_stderr"]
        assert_same_within_stats(f"{name} radiance [{variant}]", a, sa, b, sb)
