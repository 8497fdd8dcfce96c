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
from endophoton import analysis, colour, placement
from endophoton.camera import Camera
from endophoton.mesh_io import box_mesh
from endophoton.units import unit_cm
from endophoton.view_sweep import add_visibility, plot_visibility, visibility_columns, visibility_report
from endophoton.visibility import fit_peak
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
        position=(R @ np.array([0.0, 0.0, 0.5 * gap]) + off) * k, direction=R @ np.array([math.sin(th), 0, -math.cos(th)])
    )
    return scene, src, R @ np.array([0.0, 0.0, 1.0]), thickness


@pytest.mark.parametrize("case", sorted(GAP_CASES))
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
