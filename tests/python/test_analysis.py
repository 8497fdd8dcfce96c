"""Tests of endophoton.analysis on synthetic escape records with known answers."""

import math
import types

import numpy as np
import pytest

from endophoton import analysis as an

import _synth as sy


LIGHTS = np.array([[0.35, 0.0, 1.0], [-0.35, 0.0, 1.0]])


def ring_fractions_uniform(n_elev=10):
    e = np.radians(np.linspace(0, 90, n_elev + 1))
    return np.diff(np.sin(e))  # solid angle of ring / 2 pi


def ring_fractions_lambert(n_elev=10):
    e = np.radians(np.linspace(0, 90, n_elev + 1))
    return np.diff(np.sin(e) ** 2)  # cos(theta)-weighted solid angle / pi


def gof_p(observed, expected):
    x2 = float(np.sum((observed - expected) ** 2 / expected))
    return an.chi2_sf(x2, observed.size - 1)


# ---------------------------------------------------------------- chi-square


@pytest.mark.parametrize("dof", [1, 2, 9, 35, 100])
def test_chi2_sf_matches_scipy(dof):
    stats = pytest.importorskip("scipy.stats")
    for x in [0.01, 0.5, dof * 0.5, dof, dof + 1.0, 2.0 * dof + 5, 5.0 * dof + 30]:
        ref = stats.chi2.sf(x, dof)
        got = an.chi2_sf(x, dof)
        assert got == pytest.approx(ref, rel=1e-9, abs=1e-300), (x, dof)


def test_uniformity_test_on_exact_and_skewed_counts():
    flat = np.full((3, 36), 50.0)
    assert np.allclose(an.azimuthal_uniformity_test(flat), 1.0)
    skew = flat.copy()
    skew[1, 18] += 300.0
    p = an.azimuthal_uniformity_test(skew)
    assert p[1] < 1e-20 and p[0] == pytest.approx(1.0)
    empty = np.zeros((2, 36))
    assert np.all(np.isnan(an.azimuthal_uniformity_test(empty)))


# ---------------------------------------------------------------- histogram geometry


@pytest.mark.parametrize(
    "sampler,fractions",
    [(sy.sample_uniform_hemisphere, ring_fractions_uniform), (sy.sample_lambertian, ring_fractions_lambert)],
)
def test_hemisphere_rings_and_uniform_azimuth(sampler, fractions):
    rng = np.random.default_rng(12345)
    k = 200_000
    el, az = sampler(rng, k)
    esc = sy.make_records(el, az, rng, LIGHTS)
    counts, stderr = an.exit_direction_histogram(esc, LIGHTS)
    assert counts.shape == (10, 36) and stderr.shape == (10, 36)
    assert counts.sum() == k
    expected = k * fractions()
    assert gof_p(counts.sum(axis=1), expected) > 1e-3
    p = an.azimuthal_uniformity_test(counts)
    assert np.all(np.isfinite(p))
    assert min(1.0, 10 * p.min()) > 1e-3  # Bonferroni over 10 rings
    # multinomial counts with small cell probabilities: var(count) ~ count
    ratio = np.mean(stderr**2 / counts)
    assert 0.85 < ratio < 1.15


def test_hand_placed_bins_and_azimuth_convention():
    rng = np.random.default_rng(1)
    # light straight +x of the exit point (and above): azimuth 0 is +x, 90 is +y (CCW seen from outside)
    cases = [(4.5, 5.0, 0, 0), (49.5, 95.0, 5, 9), (85.5, 185.0, 9, 18), (13.5, 355.0, 1, 35), (0.5, 275.0, 0, 27)]
    el = np.array([c[0] for c in cases])
    az = np.array([c[1] for c in cases])
    lights = np.array([[1.0, 0.0, 0.5]])
    esc = sy.make_records(el, az, rng, lights, spot_sd=0.0)
    esc["position"][:] = 0.0
    esc["direction"] = sy.direction_from_angles(
        el, az, np.array([1.0, 0, 0]), np.array([0, 1.0, 0]), np.array([0, 0, 1.0])
    ).astype(np.float32)
    e, a = an.exit_angles(esc, lights)
    assert np.allclose(e, el, atol=1e-4) and np.allclose(a, az, atol=1e-4)
    counts, _ = an.exit_direction_histogram(esc, lights, n_batches=2)
    for _, _, i, j in cases:
        assert counts[i, j] == 1
    assert counts.sum() == len(cases)
    # +y direction at the horizon: azimuth 90 exactly
    esc2 = sy.make_records([0.0], [0.0], rng, lights, spot_sd=0.0)
    esc2["position"][:] = 0.0
    esc2["direction"][:] = [0.0, 1.0, 0.0]
    assert an.exit_angles(esc2, lights)[1][0] == pytest.approx(90.0, abs=1e-6)


def test_degenerate_light_falls_back_to_world_x():
    rng = np.random.default_rng(2)
    lights = np.array([[0.0, 0.0, 1.0]])
    esc = sy.make_records([30.0, 30.0], [0.0, 0.0], rng, lights, spot_sd=0.0)
    esc["position"][:] = 0.0
    s, c = math.sin(math.radians(30)), math.cos(math.radians(30))
    esc["direction"] = np.array([[c, 0, s], [0, c, s]], np.float32)
    _, az = an.exit_angles(esc, lights)
    assert az == pytest.approx([0.0, 90.0], abs=1e-4)
    # normal along world x: reference falls back to world y
    esc["normal"][:] = [1.0, 0.0, 0.0]
    esc["direction"] = np.array([[s, c, 0], [s, 0, c]], np.float32)
    lights_x = np.array([[1.0, 0.0, 0.0]])
    _, az = an.exit_angles(esc, lights_x)
    assert az == pytest.approx([0.0, 90.0], abs=1e-4)


def test_fixed_reference_frame():
    rng = np.random.default_rng(12)
    el = np.array([4.5, 4.5, 4.5, 40.5])
    az = np.zeros(4)
    esc = sy.make_records(el, az, rng, LIGHTS)
    s, c = math.sin(math.radians(4.5)), math.cos(math.radians(4.5))
    s4, c4 = math.sin(math.radians(40.5)), math.cos(math.radians(40.5))
    esc["direction"] = np.array([[c, 0, s], [0, c, s], [-c, 0, s], [0, -c4, s4]], np.float32)
    # reference with a normal component: only its tangent projection matters
    _, a = an.exit_angles(esc, None, reference=(2.0, 0.0, 5.0))
    assert a == pytest.approx([0.0, 90.0, 180.0, 270.0], abs=1e-4)
    # reference along the normal: falls back to world x
    _, a2 = an.exit_angles(esc, None, reference=(0.0, 0.0, 1.0))
    assert a2 == pytest.approx(a, abs=1e-4)
    counts, _ = an.exit_direction_histogram(esc, None, n_batches=2, reference=(0.0, 1.0, 0.0))
    assert counts[0, 27] == 1 and counts[0, 0] == 1 and counts[0, 9] == 1 and counts[4, 18] == 1
    with pytest.raises(ValueError, match="reference"):
        an.exit_angles(esc, None, reference=(0.0, 0.0))


def test_histogram_is_invariant_under_rigid_motion():
    rng = np.random.default_rng(3)
    el, az = sy.sample_uniform_hemisphere(rng, 20_000)
    esc = sy.make_records(el, az, rng, LIGHTS)
    c0, s0 = an.exit_direction_histogram(esc, LIGHTS)
    R = sy.random_rotation(rng)
    t = np.array([3.0, -2.0, 7.0])
    moved = dict(esc)
    for key in ("direction", "normal"):
        moved[key] = esc[key].astype(np.float64) @ R.T
    moved["position"] = esc["position"].astype(np.float64) @ R.T + t
    lights = LIGHTS @ R.T + t
    el2, az2 = an.exit_angles(moved, lights)
    el1, az1 = an.exit_angles(esc, LIGHTS)
    dphi = np.abs((az2 - az1 + 180.0) % 360.0 - 180.0)
    assert np.max(np.abs(el2 - el1)) < 1e-3 and np.max(dphi) < 1e-3
    c1, _ = an.exit_direction_histogram(moved, lights)
    # float32 inputs: only records within ~1e-3 deg of a bin edge may move
    assert np.abs(c1 - c0).sum() <= 20
    assert c1.sum() == c0.sum()


def test_tilted_normals_recover_local_angles():
    rng = np.random.default_rng(4)
    k = 2000
    nrm = rng.standard_normal((k, 3))
    nrm[:, 2] = np.abs(nrm[:, 2]) + 0.2
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    el = rng.uniform(0.5, 89.5, k)
    az = rng.uniform(0.0, 360.0, k)
    esc = sy.make_records(el, az, rng, LIGHTS)
    esc["normal"] = nrm.astype(np.float32)
    light = esc["light"].astype(int)
    u, v, n = sy.local_frame(esc["normal"].astype(float), LIGHTS[light] - esc["position"])
    esc["direction"] = sy.direction_from_angles(el, az, u, v, n).astype(np.float32)
    e, a = an.exit_angles(esc, LIGHTS)
    assert np.max(np.abs(e - el)) < 5e-3
    assert np.max(np.abs((a - az + 180) % 360 - 180)) < 5e-3


def test_forward_shift_gives_negative_low_ring_asymmetry():
    special = pytest.importorskip("scipy.special")
    rng = np.random.default_rng(5)
    k, kappa = 100_000, 1.5
    el = np.degrees(np.arcsin(rng.random(k)))
    az = np.where(el < 45.0, np.degrees(rng.vonmises(np.pi, kappa, k)) % 360.0, 360.0 * rng.random(k))
    esc = sy.make_records(el, az, rng, LIGHTS)
    counts, _, batches = an.exit_direction_histogram(esc, LIGHTS, return_batches=True)
    low, high = list(range(5)), list(range(5, 10))
    a_low = an.azimuth_asymmetry(counts, low)
    se_low = an.batch_se(an.azimuth_asymmetry(batches, low))
    # E[cos phi] of a von Mises about pi, times the 10-degree binning factor sinc(5 deg)
    d = math.radians(5.0)
    exact = -special.i1(kappa) / special.i0(kappa) * math.sin(d) / d
    assert abs(a_low - exact) < 4 * se_low
    assert abs(an.azimuth_asymmetry(counts, high)) < 4 * an.batch_se(an.azimuth_asymmetry(batches, high))
    p = an.azimuthal_uniformity_test(counts)
    assert np.all(p[:5] < 1e-10) and min(1.0, 5 * p[5:].min()) > 1e-3


# ---------------------------------------------------------------- camera


def _camera():
    return dict(
        position=(0.0, 0.0, 1.0), forward=(0.0, 0.0, -1.0), up=(0.0, 1.0, 0.0), fov_deg=90.0, resolution=(200, 100)
    )


def test_important_mask_hand_placed():
    # fov 90 across the width 200 -> |x/z| <= 1; height 100 -> |y/z| <= 0.5
    t14, t20 = math.radians(14.0), math.radians(20.0)
    pos = np.array(
        [[0, 0, 0], [0, 0, 0], [0, 0, 0], [0.9, 0, 0], [0, 0.6, 0], [0, 0.4, 0], [0, 0, 2.0], [1.2, 0, 0]], float
    )
    to_cam = np.array([0, 0, 1.0]) - pos
    to_cam /= np.linalg.norm(to_cam, axis=1, keepdims=True)
    d = to_cam.copy()
    d[1] = [math.sin(t14), 0, math.cos(t14)]  # 14 deg off: important
    d[2] = [0, math.sin(t20), math.cos(t20)]  # 20 deg off: not
    d[6] = [0, 0, -1.0]  # behind the camera
    expect = np.array([True, True, False, True, False, True, False, False])
    rng = np.random.default_rng(6)
    esc = sy.make_records(np.full(8, 45.0), np.zeros(8), rng, LIGHTS)
    esc["position"] = pos.astype(np.float32)
    esc["direction"] = d.astype(np.float32)
    assert np.array_equal(an.important_mask(esc, _camera()), expect)
    obj = types.SimpleNamespace(**_camera())
    assert np.array_equal(an.important_mask(esc, obj), expect)
    v, se = an.important_fraction(esc, obj, n_batches=2)
    assert v == expect.mean()
    assert np.isfinite(se)
    # the angle criterion itself
    assert an.important_mask(esc, _camera(), max_angle_deg=25.0)[2]
    assert not an.important_mask(esc, _camera(), max_angle_deg=10.0)[1]


def _bernoulli_records(rng, k, p):
    imp = rng.random(k) < p
    esc = sy.make_records(np.full(k, 45.0), np.zeros(k), rng, LIGHTS)
    pos = np.zeros((k, 3))
    pos[~imp, 0] = 5.0  # outside the image
    d = np.zeros((k, 3))
    d[:, 2] = 1.0  # straight up, toward the camera at (0,0,1)
    esc["position"] = pos.astype(np.float32)
    esc["direction"] = d.astype(np.float32)
    return esc, imp


def test_important_fraction_stderr_matches_binomial():
    rng = np.random.default_rng(7)
    k, p, reps = 20_000, 0.3, 30
    ses, vals = [], []
    for _ in range(reps):
        esc, imp = _bernoulli_records(rng, k, p)
        v, se = an.important_fraction(esc, _camera())
        assert v == imp.mean()
        vals.append(v)
        ses.append(se)
    analytic = math.sqrt(p * (1 - p) / k)
    # mean of 30 batch-means estimates (each ~16 % relative scatter for B = 20)
    assert np.mean(ses) == pytest.approx(analytic, rel=0.10)
    assert abs(np.mean(vals) - p) < 4 * analytic / math.sqrt(reps)


# ---------------------------------------------------------------- energy, rate, depth


def test_total_energy_per_packet_and_stderr():
    rng = np.random.default_rng(8)
    P, q, reps = 40_000, 0.4, 25
    ses = []
    for _ in range(reps):
        has = rng.random(P) < q
        packets = np.flatnonzero(has)
        k = packets.size
        e = rng.random(k)
        esc = sy.make_records(np.full(k, 45.0), np.zeros(k), rng, LIGHTS, packets=packets, energy=e)
        v, se = an.total_energy(esc, n_packets=P, per_packet=True)
        assert v == pytest.approx(e.sum() / P, rel=1e-12)
        tot, tse = an.total_energy(esc, n_packets=P)
        assert tot == pytest.approx(e.sum(), rel=1e-12) and tse == pytest.approx(P * se, rel=1e-12)
        ses.append(se)
    var_x = q / 3.0 - (q / 2.0) ** 2  # X = energy of a packet's record, 0 if none; U(0,1) energies
    assert np.mean(ses) == pytest.approx(math.sqrt(var_x / P), rel=0.10)


def test_record_rate_and_mean_energy():
    rng = np.random.default_rng(9)
    P = 10_000
    packets = np.flatnonzero(rng.random(P) < 0.25)
    e = np.full(packets.size, 2.0)
    esc = sy.make_records(np.full(packets.size, 45.0), np.zeros(packets.size), rng, LIGHTS, packets=packets, energy=e)
    rate, rse = an.record_rate(esc, P)
    assert rate == packets.size / P and 0 < rse < 0.01
    m, mse = an.mean_energy_per_record(esc, P)
    assert m == 2.0 and mse == pytest.approx(0.0, abs=1e-12)  # constant energy: no batch scatter


def test_batch_index_is_contiguous_by_packet():
    packet = np.arange(103)
    batch, ppb = an.batch_index(packet, 20)
    assert ppb.sum() == 103 and set(ppb.tolist()) <= {5, 6}
    assert np.all(np.diff(batch) >= 0) and batch[0] == 0 and batch[-1] == 19
    edges = np.concatenate([[0], np.cumsum(ppb)])
    for p_, b_ in zip(packet, batch):
        assert edges[b_] <= p_ < edges[b_ + 1]
    with pytest.raises(ValueError, match="n_packets"):
        an.batch_index(np.arange(5), 20)


def test_max_depth_and_batch_spread():
    rng = np.random.default_rng(10)
    k = 40
    md = np.linspace(0.01, 0.4, k)[rng.permutation(k)]
    esc = sy.make_records(np.full(k, 45.0), np.zeros(k), rng, LIGHTS, max_depth=md)
    assert an.max_depth(esc) == pytest.approx(float(np.float32(md.max())))
    mean, sd, per = an.max_depth_spread(esc, n_batches=4, return_batches=True)
    expect = [md.astype(np.float32)[i * 10 : (i + 1) * 10].max() for i in range(4)]
    assert np.allclose(per, expect)
    assert mean == pytest.approx(np.mean(expect)) and sd == pytest.approx(np.std(expect, ddof=1))


# ---------------------------------------------------------------- trends


def test_poly_peak_and_linear_fit():
    x = np.arange(0, 60, 5.0)
    y = 1.0 - (x - 34.0) ** 2 / 2000.0
    pk = an.poly_peak(x, y, 6)
    assert pk["deg"] == 6 and abs(pk["x_peak"] - 34.0) < 0.05 and pk["interior"]
    assert any(abs(m - 34.0) < 1e-3 for m in pk["local_maxima"])
    lf = an.linear_fit(x, 3.0 - 0.5 * x)
    assert lf["slope"] == pytest.approx(-0.5) and lf["intercept"] == pytest.approx(3.0)
    assert lf["r2"] == pytest.approx(1.0)
    assert an.pearson_r(x, -x) == pytest.approx(-1.0)
    assert an.poly_peak(x[:3], y[:3], 6)["deg"] == 2


# ---------------------------------------------------------------- validation


def test_malformed_input_names_the_key():
    rng = np.random.default_rng(11)
    esc = sy.make_records(np.full(50, 45.0), np.zeros(50), rng, LIGHTS)
    for key in ("position", "direction", "normal", "light", "packet"):
        bad = {k: v for k, v in esc.items() if k != key}
        with pytest.raises(ValueError, match=key):
            an.exit_direction_histogram(bad, LIGHTS, n_batches=2)
    bad = dict(esc, direction=esc["direction"][:, :2])
    with pytest.raises(ValueError, match="direction"):
        an.exit_angles(bad, LIGHTS)
    bad = dict(esc, normal=esc["normal"][:10])
    with pytest.raises(ValueError, match="normal"):
        an.exit_angles(bad, LIGHTS)
    nanpos = esc["position"].copy()
    nanpos[3, 0] = np.nan
    with pytest.raises(ValueError, match="position"):
        an.exit_angles(dict(esc, position=nanpos), LIGHTS)
    inward = esc["direction"].copy()
    inward[0] = [0, 0, -1]
    with pytest.raises(ValueError, match="direction"):
        an.exit_angles(dict(esc, direction=inward), LIGHTS)
    with pytest.raises(ValueError, match="light"):
        an.exit_angles(esc, LIGHTS[:1])
    with pytest.raises(ValueError, match="energy"):
        an.total_energy({k: v for k, v in esc.items() if k != "energy"}, n_batches=2)
    with pytest.raises(ValueError, match="max_depth"):
        an.max_depth({k: v for k, v in esc.items() if k != "max_depth"})
    with pytest.raises(ValueError, match="packet"):
        an.important_fraction(dict(esc, packet=esc["packet"].astype(float)), _camera(), n_batches=2)
    cam = _camera()
    del cam["fov_deg"]
    with pytest.raises(ValueError, match="fov_deg"):
        an.important_mask(esc, cam)
    with pytest.raises(ValueError, match="up"):
        an.important_mask(esc, dict(_camera(), up=(0, 0, 1)))
    with pytest.raises(ValueError, match="escapes"):
        an.total_energy([1, 2, 3])
    with pytest.raises(ValueError, match="n_batches"):
        an.total_energy(esc, n_batches=1)
