"""Energy conservation: Rsp + Rd + Tt + A + missed + cut + roulette == 1 (to 1e-9) in
every run, and Russian roulette is unbiased (its net weight is 0 within 3 sigma, and an
aggressive roulette does not move the MCML slab off van de Hulst's values).

Every test of the physics suite also calls assert_energy_conserved on its own runs;
this file adds scenes chosen to exercise each term of the balance.
"""
import math

import numpy as np
import pytest

import endophoton as ep
from physics_helpers import assert_energy_conserved, assert_within

DOWN = ep.PencilSource(position=(0.0, 0.0, 1.0), direction=(0.0, 0.0, -1.0))
TISSUE = ep.Medium(**ep.paper.TISSUE)  # the seed paper's colon tissue


def _scene_overlapping():
    """A polyp-like box (higher priority) overlapping a tissue block, both mismatched."""
    s = ep.Scene(unit="mm", ambient_n=1.0)
    s.add_box("tissue", min=(-50, -50, -50), max=(50, 50, 0), medium=TISSUE, priority=0)
    s.add_box("polyp", min=(-2, -2, -3), max=(2, 2, 1.5), medium=ep.Medium(mua=5, mus=100, g=0.8, n=1.4), priority=5)
    return s


def _scene_stack():
    return ep.layered_slab(
        [(ep.Medium(1, 100, 0.9, 1.37), 0.1), (ep.Medium(1, 10, 0.0, 1.5), 0.1), (ep.Medium(2, 10, 0.7, 1.2), 0.2)],
        unit="cm",
        width=20.0,
    )


def _scene_small_cube():
    # small, strongly scattering cube: lots of side escapes and internal reflections
    s = ep.Scene(unit="cm", ambient_n=1.33)
    s.add_box("cube", min=(-0.1, -0.1, -0.2), max=(0.1, 0.1, 0.0), medium=ep.Medium(0.5, 50, 0.0, 1.45))
    return s


CASES = {
    "overlap_pencil": (_scene_overlapping, ep.PencilSource((0.5, 0.3, 10.0), (0.0, 0.0, -1.0)), {}),
    "overlap_cone": (
        _scene_overlapping,
        ep.ConeSource(position=(0, 0, 10.0), direction=(0.1, 0.0, -1.0), half_angle_deg=20.0, radius=1.0),
        {},
    ),
    "stack_disk": (_scene_stack, ep.DiskSource(center=(0, 0, 1), direction=(0, 0, -1), radius=0.5), {}),
    "stack_oblique_max_steps": (_scene_stack, ep.PencilSource((-1.0, 0, 1.0), (1.0, 0.0, -1.0)), dict(max_steps=30)),
    "stack_max_path": (_scene_stack, DOWN, dict(max_path_cm=0.5)),
    "cube_heavy_roulette": (_scene_small_cube, DOWN, dict(roulette_threshold=0.2, roulette_chance=0.3)),
    "cube_cone_partly_missing": (
        _scene_small_cube,
        ep.ConeSource(position=(0, 0, 0.5), direction=(0, 0, -1), half_angle_deg=60.0),
        {},
    ),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_energy_balance(case):
    build, src, opts = CASES[case]
    res = ep.run(build(), src, photons=20_000, seed=31, threads=0, record_escapes=True, **opts)
    assert_energy_conserved(res)
    # the records of exits whose ray went away (next_hit 0) carry the escaped weight, exactly
    # when no exit landed on tissue again; a landing (next_hit 1) can also reflect off the
    # surface it meets and escape without a record of its own (light crosses the lumen)
    esc = res.escapes
    n = res.photons
    escaped = res.diffuse_reflectance + res.transmittance
    away = esc["weight"][esc["next_hit"] == 0].sum() / n
    landed = esc["weight"][esc["next_hit"] == 1].sum() / n
    if landed == 0:
        assert away == pytest.approx(escaped, abs=1e-9)
    else:
        assert away - 1e-9 <= escaped <= away + landed + 1e-9
    assert np.all(esc["weight"] > 0)
    if "max_steps" in opts or "max_path_cm" in opts:
        assert res.cut > 0
    else:
        assert res.cut == 0.0
    if case == "cube_cone_partly_missing":
        # Point source 0.5 cm above the centre of the cube's 0.2 x 0.2 cm top face, directions
        # uniform in the 60 deg cone (solid angle 2 pi (1 - cos 60) = pi). A ray that crosses the
        # plane z = 0 outside the top face moves away from the axis and cannot reach a side, so
        # it hits iff it crosses the top face, whose solid angle is 4 asin(a^2 / (a^2 + h^2))
        # (a = 0.1, h = 0.5; the face lies well inside the cone).
        a, h = 0.1, 0.5
        missed_ref = 1.0 - 4 * math.asin(a * a / (a * a + h * h)) / math.pi
        assert_within("missed (solid angle)", res.missed, res.missed_stderr, missed_ref, 1e-12)


def test_source_pointing_away_misses_everything():
    s = _scene_small_cube()
    res = ep.run(s, ep.PencilSource((0, 0, 1), (0, 0, 1)), photons=1000, seed=1, threads=0)
    assert_energy_conserved(res)
    assert res.missed == 1.0
    assert res.absorbed == 0.0 and res.diffuse_reflectance == 0.0 and res.transmittance == 0.0


@pytest.mark.parametrize("threshold,chance", [(0.05, 0.1), (0.3, 0.5)])
def test_roulette_is_unbiased_on_mcml_slab(threshold, chance):
    """With a roulette far more aggressive than MCML's (threshold 0.05-0.3 instead of 1e-4),
    the MCML Table 6.1 slab still matches van de Hulst (Rd 0.09739, Tt 0.66096, +-0.5e-5) within
    3 sigma, and the roulette's net weight is 0 within 3 sigma."""
    scene = ep.Scene(unit="cm")
    scene.add_box("slab", min=(-100, -100, -0.02), max=(100, 100, 0), medium=ep.Medium(10, 90, 0.75, 1.0))
    res = ep.run(
        scene,
        DOWN,
        photons=300_000,
        seed=77,
        threads=0,
        record_escapes=False,
        roulette_threshold=threshold,
        roulette_chance=chance,
    )
    assert_energy_conserved(res)
    assert res.roulette != 0.0 and res.roulette_stderr > 0  # the roulette did act
    assert_within("Rd", res.diffuse_reflectance, res.diffuse_reflectance_stderr, 0.09739, 0.5e-5)
    assert_within("Tt", res.transmittance, res.transmittance_stderr, 0.66096, 0.5e-5)


def test_fluorescent_scene_conserves_weight():
    """Fluorescence changes wavelengths, not weights: the balance still holds."""
    s = ep.Scene(unit="cm")
    s.add_box(
        "tissue", min=(-5, -5, -5), max=(5, 5, 0), medium=TISSUE, fluorophores=[ep.Fluorophore("collagen", 0.2, 0.4)]
    )
    res = ep.run(s, DOWN, photons=20_000, seed=4, threads=0)
    assert_energy_conserved(res)
    assert res.fluorescent_escaped > 0
