"""The float32 lanes (``run(lanes=True)``, native/lane_block.h; issue 39).

A lane run is another sample of the same physics, so it is checked as the double walk is: against
van de Hulst, Giovanelli, Chandrasekhar's H-function and MCML's three layers (oracles §1-§3), with
the suite's family-wise threshold, and its standard errors against the scatter of 64 seeds. Its
bits do not depend on the thread count, the lane kernel's instruction set (sse2, avx2, avx512:
4, 8, 16 lanes), or a Dask cluster. The lanes' sampling laws themselves are checked in
tests/cpp/test_lanes.cpp.
"""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest

import endophoton as ep
from endophoton import _core
from endophoton.view.camera import Camera
from bit_digest import cpu_flags
from isa_digest import digest  # every tally, stderr and record; not the kernel's name (NOT_ARITHMETIC)
from physics_helpers import (
    K_SIGMA,
    P_COMPARISON,
    assert_energy_conserved,
    assert_no_nan,
    assert_within,
    mc_reference_sigma,
    semi_infinite_isotropic_reflectance,
)

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))
PACKAGE_PARENT = os.path.dirname(os.path.dirname(os.path.abspath(ep.__file__)))  # the package under test
DOWN = ep.PencilSource(position=(0.0, 0.0, 1.0), direction=(0.0, 0.0, -1.0))
VDH_RD, VDH_TT, VDH_UNC = 0.09739, 0.66096, 0.5e-5  # van de Hulst (oracles §1), to 5 decimals
GIOVANELLI, GIOVANELLI_UNC = 0.2600, 0.5e-4  # Rsp + Rd, semi-infinite, n 1.5, albedo 0.9, g 0 (oracles §2)


def slab(g=0.75):
    scene = ep.Scene(unit="cm", ambient_n=1.0)
    scene.add_box("slab", min=(-100, -100, -0.02), max=(100, 100, 0.0), medium=ep.Medium(mua=10.0, mus=90.0, g=g))
    return scene


def semi_infinite(mua, mus, g, n, unit="cm", scale=1.0, offset=(0.0, 0.0, 0.0)):
    """A box 10 cm deep and 200 cm wide (in ``unit``, times ``scale``), its top face at z = 0 + offset."""
    scene = ep.Scene(unit=unit, ambient_n=1.0)
    o = np.asarray(offset)
    scene.add_box(
        "tissue",
        min=tuple(o + scale * np.array([-100, -100, -10])),
        max=tuple(o + scale * np.array([100, 100, 0])),
        medium=ep.Medium(mua=mua, mus=mus, g=g, n=n),
    )
    return scene


def down_from(offset=(0.0, 0.0, 0.0), height=1.0):
    return ep.PencilSource(position=(offset[0], offset[1], offset[2] + height), direction=(0.0, 0.0, -1.0))


def giovanelli(res):
    assert_energy_conserved(res)
    assert res.lanes is not None
    sigma = res.specular_reflectance_stderr + res.diffuse_reflectance_stderr
    total = res.specular_reflectance + res.diffuse_reflectance
    assert_within("Rsp + Rd (Giovanelli)", total, sigma, GIOVANELLI, GIOVANELLI_UNC)


def fluorescent(mua=20.0, mus=200.0, g=0.9, n=1.1, thickness=10.0):
    """The seed tissue (or another medium) with collagen and photofrin, the polyp's pair (seed §5), a
    box ``thickness`` cm deep under z = 0."""
    scene = ep.Scene(unit="cm", ambient_n=1.0)
    scene.add_box(
        "tissue",
        min=(-100, -100, -thickness),
        max=(100, 100, 0),
        medium=ep.Medium(mua=mua, mus=mus, g=g, n=n),
        fluorophores=[ep.Fluorophore("collagen", 0.2, 0.4), ep.Fluorophore("photofrin", 0.1, 0.33)],
    )
    return scene


def test_lanes_serve_runs_without_grids_camera_or_path_cap(tmp_path):
    scene = semi_infinite(10.0, 90.0, 0.9, 1.4)
    assert ep.run(scene, DOWN, photons=2000, threads=1).lanes in ("sse2", "avx2", "avx512")  # the default
    assert ep.run(scene, DOWN, photons=2000, threads=1, lanes=False).lanes is None
    # Spectral runs too: fluorescence, or a forced wavelength.
    assert ep.run(fluorescent(), DOWN, photons=2000, threads=1).lanes is not None
    assert ep.run(scene, DOWN, photons=2000, threads=1, spectral=True).lanes is not None
    # Where they cannot serve, the double walk traces the run, and the result says so.
    assert ep.run(scene, DOWN, photons=2000, threads=1, lanes=True, max_path_cm=50.0).lanes is None
    assert ep.run(scene, DOWN, photons=2000, threads=1, lanes=True, safe_distance=False).lanes is None
    # Grids taking a deposit at every interaction go to the double walk; the emission grids alone
    # (deposits at fluorescence events, which the walk finishes) are served.
    for absorbed, light in ((True, False), (False, True), (True, True)):
        grids = ep.GridRequest(
            voxel_size=0.05, path=str(tmp_path / "g.vdb"), absorbed=absorbed, fluorescent_light=light
        )
        assert ep.run(fluorescent(), DOWN, photons=2000, threads=1, grids=grids).lanes is None
        assert ep.run(scene, DOWN, photons=2000, threads=1, grids=grids).lanes is None
    alone = ep.GridRequest(voxel_size=0.05, path=str(tmp_path / "e.vdb"), absorbed=False, fluorescent_light=False)
    assert ep.run(fluorescent(), DOWN, photons=2000, threads=1, grids=alone).lanes is not None
    cam = Camera.look_at((0, 0, 2.0), (0, 0, 0), up=(0, 1, 0), fov_deg=40)
    assert ep.run(fluorescent(), DOWN, photons=500, threads=1, view=dict(camera=cam, width=4, height=4)).lanes is None


def test_fluorescence_fires_with_chance_d_times_c():
    """Seed §4's trials, exactly: with no absorption and matched indices every weight stays 1, so the
    tallies count. Each interaction tries collagen (chance p1 = d c = 0.08), then, if it did not
    fire, photofrin (p2 = 0.033); under the paper's rule a packet stops trying after its event.
    The trials T = n1 + n2 with n2 = n1 - E1, so n1 = (T + E1) / 2, and by Wald's identity the
    events are E1 = p1 n1 and E2 = p2 n2 in expectation, binomial about it."""
    res = ep.run(fluorescent(mua=0.0, mus=100.0, n=1.0, thickness=0.2), DOWN, photons=20_000, seed=4,
                 threads=0, fluorescence_rule="paper", record_escapes=True)  # fmt: skip
    assert res.lanes is not None
    assert res.absorbed == 0.0 and res.roulette == 0.0 and res.stokes_loss > 0
    assert_energy_conserved(res)
    N = res.photons
    # Every packet leaves once (no reflection at n 1, no capture), and every interaction scatters
    # once, a fluorescent one too (the walk scatters it after the lanes).
    assert len(res.escapes["weight"]) == N
    assert int(np.sum(res.escapes["scatterings"])) == round(res.interactions * N)
    T = res.fluorescence_trials * N
    e1, e2 = (res.emitted_by_fluorophore[k] * N for k in ("collagen", "photofrin"))
    assert abs(e1 - round(e1)) < 1e-6 and abs(e2 - round(e2)) < 1e-6  # counts: every weight is 1
    assert abs(T - round(T)) < 1e-6 and res.fluorescence_events * N == pytest.approx(e1 + e2, abs=1e-6)
    T, e1, e2 = round(T), round(e1), round(e2)
    n1 = (T + e1) / 2
    for events, trials, p in ((e1, n1, 0.2 * 0.4), (e2, n1 - e1, 0.1 * 0.33)):
        assert trials > 10_000
        assert abs(events - p * trials) < K_SIGMA * math.sqrt(trials * p * (1 - p)), (events, trials, p)


@pytest.mark.parametrize("rule", ["paper", "eem"])
def test_fluorescent_tissue_agrees_with_the_double_walk(rule):
    """The seed tissue with collagen and photofrin under both rules: every tally of the light and of
    the fluorescence agrees with the double walk's within their standard errors, and the energy
    balance closes."""
    scene = fluorescent()
    a = ep.run(scene, DOWN, photons=40_000, seed=31, threads=0, fluorescence_rule=rule)
    b = ep.run(scene, DOWN, photons=40_000, seed=32, threads=0, fluorescence_rule=rule, lanes=False)
    assert a.lanes is not None and b.lanes is None
    assert_energy_conserved(a)
    assert_no_nan(a)
    for key in ("diffuse_reflectance", "fluorescent_escaped", "absorbed_energy", "stokes_loss",
                "fluorescence_events", "fluorescence_trials", "escaped_energy"):  # fmt: skip
        va, vb = getattr(a, key), getattr(b, key)
        se = math.hypot(getattr(a, key + "_stderr"), getattr(b, key + "_stderr"))
        assert abs(va - vb) < K_SIGMA * se, (key, va, vb, se)
    for name in ("collagen", "photofrin"):
        se = math.hypot(a.emitted_by_fluorophore_stderr[name], b.emitted_by_fluorophore_stderr[name])
        assert abs(a.emitted_by_fluorophore[name] - b.emitted_by_fluorophore[name]) < K_SIGMA * se, name


@pytest.mark.parametrize("bad", ["yes", 1, None])
def test_lanes_must_be_a_bool(bad):
    with pytest.raises(ValueError, match="lanes"):
        ep.run(slab(), DOWN, photons=100, lanes=bad)


def test_slab_matches_van_de_hulst():
    res = ep.run(slab(), DOWN, photons=1_000_000, seed=20240602, threads=0, record_escapes=True, lanes=True)
    assert_energy_conserved(res)
    assert_no_nan(res)
    assert res.lanes is not None and res.missed == 0.0 and res.cut == 0.0
    assert_within("Rd (van de Hulst)", res.diffuse_reflectance, res.diffuse_reflectance_stderr, VDH_RD, VDH_UNC)
    assert_within("Tt (van de Hulst)", res.transmittance, res.transmittance_stderr, VDH_TT, VDH_UNC)
    # The unscattered packets (exp(-mu_t d) = exp(-2) of them) never enter the lanes: weight exactly 1.
    esc = res.escapes
    unscattered = (esc["scatterings"] == 0) & (esc["kind"] == 1)
    assert np.all(esc["weight"][unscattered] == 1.0)
    p = math.exp(-2.0)
    frac = esc["weight"][unscattered].sum() / res.photons
    assert_within("unscattered Tt", frac, math.sqrt(p * (1 - p) / res.photons), p)
    # The records add up to the tallies, and the lanes' deepest points lie inside the slab.
    assert esc["weight"][esc["kind"] == 0].sum() / res.photons == pytest.approx(res.diffuse_reflectance, abs=1e-9)
    assert np.all((esc["max_depth"] >= 0) & (esc["max_depth"] <= 0.02 + 1e-6))


def test_giovanelli_isotropic_n15():
    giovanelli(ep.run(semi_infinite(10.0, 90.0, 0.0, 1.5), DOWN, photons=500_000, seed=8, threads=0, lanes=True))


def test_chandrasekhar_matched_isotropic():
    res = ep.run(semi_infinite(10.0, 90.0, 0.0, 1.0), DOWN, photons=300_000, seed=12, threads=0, lanes=True)
    assert_energy_conserved(res)
    ref = semi_infinite_isotropic_reflectance(10.0, 90.0)
    assert_within("Rd (Chandrasekhar)", res.diffuse_reflectance, res.diffuse_reflectance_stderr, ref, 1e-6)


@pytest.mark.slow
def test_three_layers_match_mcml():
    """MCML's Table 6.7 sample (oracles §3): three touching regions, g 0.9, 0 and 0.7, n 1.37 -- the
    lanes' zones hold the layers' planes."""
    layers = [(1.0, 100.0, 0.9, 0.1), (1.0, 10.0, 0.0, 0.1), (2.0, 10.0, 0.7, 0.2)]
    scene = ep.layered_slab(
        [(ep.Medium(mua=a, mus=s, g=g, n=1.37), d) for a, s, g, d in layers], unit="cm", width=1e3, ambient_n=1.0
    )
    res = ep.run(scene, DOWN, photons=400_000, seed=5, threads=0, lanes=True)
    assert_energy_conserved(res)
    for name, ref in (("diffuse_reflectance", 0.237544), ("transmittance", 0.096490), ("absorbed", 0.641594)):
        sigma = math.hypot(getattr(res, name + "_stderr"), mc_reference_sigma(ref, 1_000_000))
        assert_within(name + " (MCML)", getattr(res, name), sigma, ref)


def test_scale_free_and_far_away():
    """A semi-infinite medium's Rd depends on albedo, g and n only: the same Giovanelli value with mu
    scaled 100x (steps 100x shorter), in a scene in mm, and 1e4 cm from the origin (the lanes hold
    positions relative to their zone's centre)."""
    giovanelli(ep.run(semi_infinite(1000.0, 9000.0, 0.0, 1.5), DOWN, photons=200_000, seed=9, threads=0, lanes=True))
    mm = semi_infinite(1.0, 9.0, 0.0, 1.5, unit="mm", scale=10.0)
    giovanelli(ep.run(mm, down_from(height=10.0), photons=200_000, seed=10, threads=0, lanes=True))
    far = (1e4, -2e4, 5e3)
    giovanelli(ep.run(semi_infinite(10.0, 90.0, 0.0, 1.5, offset=far), down_from(far), photons=200_000, seed=13,
                      threads=0, lanes=True))  # fmt: skip


def test_no_absorption_captures_nothing():
    """mua = 0: the lanes capture exactly nothing, and every packet leaves (a slab of 20 mean free paths)."""
    scene = ep.Scene(unit="cm", ambient_n=1.0)
    scene.add_box(
        "slab", min=(-100, -100, -0.2), max=(100, 100, 0.0), medium=ep.Medium(mua=0.0, mus=100.0, g=0.9, n=1.4)
    )
    res = ep.run(scene, DOWN, photons=20_000, seed=3, threads=0, lanes=True)
    assert res.absorbed == 0.0 and res.roulette == 0.0 and res.cut == 0.0
    assert_energy_conserved(res)


@pytest.mark.parametrize("g", [0.9999, -0.9999, 1e-4])
def test_extreme_g_conserves_and_agrees_with_the_double_walk(g):
    """g -> +-1 and g -> 0 (both HG forms of the lanes): the balance closes and Rd agrees with the
    double walk's within their standard errors (the sampling law itself: tests/cpp/test_lanes.cpp)."""
    scene = semi_infinite(1.0, 100.0, g, 1.4)
    a = ep.run(scene, DOWN, photons=40_000, seed=21, threads=0, lanes=True)
    b = ep.run(scene, DOWN, photons=40_000, seed=22, threads=0, lanes=False)
    assert_energy_conserved(a)
    assert_no_nan(a)
    se = math.hypot(a.diffuse_reflectance_stderr, b.diffuse_reflectance_stderr)
    assert abs(a.diffuse_reflectance - b.diffuse_reflectance) < K_SIGMA * se


@pytest.mark.slow
def test_standard_errors_describe_the_scatter_over_seeds():
    """As test_mcml's check of the double walk: z = (Rd - van de Hulst) / stderr over 64 seeds of
    10k packets has mean 0 and the variance of Student's t49."""
    from scipy import stats

    z = []
    for seed in range(2000, 2064):
        r = ep.run(slab(), DOWN, photons=10_000, seed=seed, threads=0, record_escapes=False, lanes=True)
        z.append((r.diffuse_reflectance - VDH_RD) / r.diffuse_reflectance_stderr)
    z = np.asarray(z)
    var_t49, n = 49 / 47, len(z)
    assert abs(z.mean()) < K_SIGMA * math.sqrt(var_t49 / n), z.mean()
    lo = var_t49 * stats.chi2.ppf(P_COMPARISON / 2, n - 1) / (n - 1)
    hi = var_t49 * stats.chi2.isf(P_COMPARISON / 2, n - 1) / (n - 1)
    assert lo < z.var(ddof=1) < hi, z.var(ddof=1)


def _seed_tissue_run(threads, unit_size=0, fluorophores=False):
    scene = fluorescent() if fluorophores else semi_infinite(20.0, 200.0, 0.9, 1.1)
    return ep.run(scene, DOWN, photons=30_000, seed=5, threads=threads, unit_size=unit_size, lanes=True)


@pytest.mark.parametrize("fluorophores", [False, True])
def test_same_bits_on_any_thread_count_and_unit_size(fluorophores):
    ref = digest(_seed_tissue_run(1, fluorophores=fluorophores))
    assert digest(_seed_tissue_run(2, fluorophores=fluorophores)) == ref
    assert digest(_seed_tissue_run(0, fluorophores=fluorophores)) == ref
    # A unit is traced by one thread from its first packet; units of another size are other units,
    # so only their packets' sums may regroup -- the packets themselves are the same.
    a, b = _seed_tissue_run(1, unit_size=1000), _seed_tissue_run(2, unit_size=333)
    assert a.interactions == pytest.approx(b.interactions, rel=1e-12)
    assert np.array_equal(np.sort(a.escapes["weight"]), np.sort(b.escapes["weight"]))


CASE = """
import json, sys
sys.path.insert(0, {tests!r})
from isa_digest import digest
from test_lanes import _seed_tissue_run
r, f = _seed_tissue_run(2), _seed_tissue_run(2, fluorophores=True)
print(json.dumps({{"lanes": r.lanes, "digest": [digest(r), digest(f)]}}))
"""


def _in_process(isa: str | None) -> dict:
    env = dict(os.environ, PYTHONPATH=PACKAGE_PARENT)
    env.pop("ENDOPHOTON_LANE_ISA", None)
    if isa:
        env["ENDOPHOTON_LANE_ISA"] = isa
    code = CASE.format(tests=os.path.dirname(os.path.abspath(__file__)))
    p = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    return json.loads(p.stdout)


@pytest.mark.slow
def test_same_bits_from_every_instruction_set():
    flags = cpu_flags()
    isas = (
        ["sse2"]
        + (["avx2"] if "avx2" in flags else [])
        + (["avx512"] if {"avx512f", "avx512vl", "avx512dq"} <= flags else [])
    )
    runs = {isa: _in_process(isa) for isa in isas}
    for isa, r in runs.items():
        assert r["lanes"] == isa
    assert len({tuple(r["digest"]) for r in runs.values()}) == 1, runs
    assert _in_process(None)["digest"] == runs["sse2"]["digest"]  # the default: the widest


@pytest.mark.parametrize("value", ["avx1024", "SSE2", ""])
def test_unknown_instruction_set_is_named(tmp_path, value):
    """The CLI names the variable and its value, no traceback."""
    with open(os.path.join(ROOT, "examples", "seed_tissue.json"), encoding="utf-8") as f:
        doc = json.load(f)
    doc["run"].update(lanes=True, photons=100)
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(doc))
    env = dict(os.environ, ENDOPHOTON_LANE_ISA=value, PYTHONPATH=PACKAGE_PARENT)
    p = subprocess.run([sys.executable, "-m", "endophoton", "run", str(path)], env=env, capture_output=True,
                       text=True, timeout=120)  # fmt: skip
    assert p.returncode != 0, (p.returncode, p.stderr)
    assert f"ENDOPHOTON_LANE_ISA = '{value}'" in p.stderr and "Traceback" not in p.stderr, p.stderr


@pytest.mark.slow
def test_same_bits_on_a_dask_cluster():
    pytest.importorskip("distributed")
    from endophoton import distributed

    scene = semi_infinite(20.0, 200.0, 0.9, 1.1)
    local = ep.run(scene, DOWN, photons=20_000, seed=6, threads=1, lanes=True, unit_size=500)
    with distributed.connect("local:2") as c:
        dist = ep.run(scene, DOWN, photons=20_000, seed=6, client=c, chunk_units=7, lanes=True, unit_size=500)
    assert dist.lanes is not None
    assert digest(dist) == digest(local)


def test_a_cancel_mid_unit_keeps_the_whole_units_before_it():
    """The engine's cancel reaches the lanes before each packet starts (RunConfig.test_cancel_at_packet,
    deterministic): the result is that of a run cancelled after the units before it, bit for bit."""
    scene = semi_infinite(20.0, 200.0, 0.9, 1.1)
    src = _core.Source(DOWN.native_lights(scene.unit_cm))

    def raw(**hook):
        config = _core.RunConfig(photons=20_000, unit_size=400, seed=5, threads=1, lanes=True, **hook)
        return _core.run(scene.to_native(), src, config)

    mid, after = raw(test_cancel_at_packet=3 * 400 + 200), raw(test_cancel_after_units=3)
    assert mid["cancelled"] and mid["photons"] == 3 * 400 and mid["lanes"] is not None
    for k in mid:
        if k not in ("seconds", "escapes"):
            assert mid[k] == after[k], k
