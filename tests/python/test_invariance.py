"""Invariances: the scene unit does not change the physics; a seed fixes the result
bit for bit, whatever the thread count and however often it is run."""
import math

import numpy as np
import pytest

import endophoton as ep
from physics_helpers import assert_energy_conserved, assert_same_within_stats, assert_within

# ----------------------------------------------------------------------------
# Units: the MCML Table 6.1 slab (d = 0.02 cm, n = 1) built in m, cm and mm
# ----------------------------------------------------------------------------
SCALE = {"m": 0.01, "cm": 1.0, "mm": 10.0}  # scene units per cm
THICK_CM = 0.02


def _slab_in(unit):
    k = SCALE[unit]
    s = ep.Scene(unit=unit, ambient_n=1.0)
    s.add_box(
        "slab",
        min=(-100 * k, -100 * k, -THICK_CM * k),
        max=(100 * k, 100 * k, 0.0),
        medium=ep.Medium(mua=10.0, mus=90.0, g=0.75, n=1.0),
    )  # coefficients always in cm^-1
    src = ep.PencilSource(position=(0.0, 0.0, 1.0 * k), direction=(0.0, 0.0, -1.0))
    return s, src


@pytest.fixture(scope="module")
def unit_results():
    out = {}
    for i, unit in enumerate(("m", "cm", "mm")):
        scene, src = _slab_in(unit)
        # independent seeds, so the comparison below is an honest two-sample test
        out[unit] = ep.run(scene, src, photons=200_000, seed=1000 + i, threads=0, record_escapes=True)
    return out


@pytest.mark.parametrize("a,b", [("m", "cm"), ("cm", "mm"), ("m", "mm")])
def test_units_give_the_same_physics(unit_results, a, b):
    ra, rb = unit_results[a], unit_results[b]
    assert_energy_conserved(ra)
    assert_energy_conserved(rb)
    for key in ("diffuse_reflectance", "transmittance", "absorbed"):
        assert_same_within_stats(
            f"{key} [{a} vs {b}]",
            getattr(ra, key),
            getattr(ra, key + "_stderr"),
            getattr(rb, key),
            getattr(rb, key + "_stderr"),
        )
    # Depths are reported in cm whatever the unit: mean max_depth of the reflected packets.
    da = ra.escapes["max_depth"][ra.escapes["kind"] == 0].astype(np.float64)
    db = rb.escapes["max_depth"][rb.escapes["kind"] == 0].astype(np.float64)
    assert_same_within_stats(
        f"mean max_depth (cm) [{a} vs {b}]",
        da.mean(),
        da.std(ddof=1) / math.sqrt(da.size),
        db.mean(),
        db.std(ddof=1) / math.sqrt(db.size),
    )
    # Lateral exit radius in cm (positions are in scene units): same distribution.
    ka, kb = SCALE[a], SCALE[b]
    xa = np.linalg.norm(ra.escapes["position"][:, :2].astype(np.float64), axis=1) / ka
    xb = np.linalg.norm(rb.escapes["position"][:, :2].astype(np.float64), axis=1) / kb
    assert_same_within_stats(
        f"mean exit radius (cm) [{a} vs {b}]",
        xa.mean(),
        xa.std(ddof=1) / math.sqrt(xa.size),
        xb.mean(),
        xb.std(ddof=1) / math.sqrt(xb.size),
    )


@pytest.mark.parametrize("unit", ["m", "cm", "mm"])
def test_each_unit_matches_van_de_hulst_and_reports_depth_in_cm(unit_results, unit):
    res = unit_results[unit]
    assert_energy_conserved(res)
    assert_within(f"Rd [{unit}]", res.diffuse_reflectance, res.diffuse_reflectance_stderr, 0.09739, 0.5e-5)
    assert_within(f"Tt [{unit}]", res.transmittance, res.transmittance_stderr, 0.66096, 0.5e-5)
    esc = res.escapes
    # No packet can get deeper than the slab, 0.02 cm, in any unit (float32 slack 1e-6 cm).
    # (A unit error would show as a factor 10 or 100; a few values slightly above mean a leak,
    # see test_extremes.test_no_packet_ever_deeper_than_the_slab.)
    deep = esc["max_depth"] > THICK_CM + 1e-6
    assert not deep.any(), (
        f"[{unit}] {int(deep.sum())} packets deeper than the 0.02 cm slab: max_depth "
        f"{esc['max_depth'][deep][:5].tolist()} cm, packets {esc['packet'][deep][:5].tolist()}"
    )
    assert float(esc["max_depth"].min()) >= 0.0
    # transmitted packets crossed the whole slab: max_depth is the thickness in cm
    tr = esc["kind"] == 1
    assert np.allclose(esc["max_depth"][tr], THICK_CM, atol=1e-6)
    # exit positions are in scene units: on the top (z = 0) or the bottom (z = -0.02 cm)
    k = SCALE[unit]
    z = esc["position"][:, 2].astype(np.float64) / k
    assert np.all(np.isclose(z, 0.0, atol=1e-6) | np.isclose(z, -THICK_CM, atol=1e-6))


# ----------------------------------------------------------------------------
# Determinism
# ----------------------------------------------------------------------------
ENV_KEYS = {"seconds", "threads"}  # describe the run environment, not the result


def _det_scene():
    s = ep.Scene(unit="mm", ambient_n=1.0)
    s.add_box("tissue", min=(-30, -30, -20), max=(30, 30, 0), medium=ep.Medium(20, 200, 0.9, 1.1))
    s.add_box("polyp", min=(-2, -2, -2), max=(2, 2, 1), medium=ep.Medium(5, 80, 0.8, 1.4), priority=1)
    return s


def _det_run(threads, seed=99):
    src = ep.ConeSource(position=(0.3, 0.1, 10.0), direction=(0.05, 0.0, -1.0), half_angle_deg=7.5, radius=1.0)
    return ep.run(_det_scene(), src, photons=30_000, seed=seed, threads=threads, record_escapes=True)


def _assert_identical(r1, r2):
    d1, d2 = r1.to_dict(), r2.to_dict()
    assert set(d1) == set(d2)
    for k in d1:
        if k in ENV_KEYS:
            continue
        assert d1[k] == d2[k], f"{k}: {d1[k]!r} != {d2[k]!r}"
    for k in ("specular_reflectance", "diffuse_reflectance", "transmittance", "absorbed", "missed", "cut", "roulette"):
        assert getattr(r1, k) == getattr(r2, k), k
        assert getattr(r1, k + "_stderr") == getattr(r2, k + "_stderr"), k
    assert r1.absorbed_by_region == r2.absorbed_by_region
    assert set(r1.escapes) == set(r2.escapes)
    for k in r1.escapes:
        a, b = np.asarray(r1.escapes[k]), np.asarray(r2.escapes[k])
        assert a.dtype == b.dtype and a.shape == b.shape, k
        assert np.array_equal(a, b), f"escapes[{k}] differ"


def test_same_seed_bit_identical_across_thread_counts():
    r1 = _det_run(threads=1)
    r2 = _det_run(threads=2)
    assert_energy_conserved(r1)
    assert_energy_conserved(r2)
    assert len(r1.escapes["weight"]) > 1000
    _assert_identical(r1, r2)


def test_same_seed_bit_identical_across_repeated_runs():
    runs = [_det_run(threads=2) for _ in range(3)]
    for r in runs:
        assert_energy_conserved(r)
    _assert_identical(runs[0], runs[1])
    _assert_identical(runs[0], runs[2])
    r0 = _det_run(threads=0)  # all cores
    assert_energy_conserved(r0)
    _assert_identical(runs[0], r0)


def test_different_seeds_differ():
    a, b = _det_run(threads=2, seed=1), _det_run(threads=2, seed=2)
    assert_energy_conserved(a)
    assert_energy_conserved(b)
    assert a.diffuse_reflectance != b.diffuse_reflectance
    assert not np.array_equal(a.escapes["weight"], b.escapes["weight"])
