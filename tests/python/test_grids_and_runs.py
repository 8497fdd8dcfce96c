"""OpenVDB grid output, "store N" determinism, emission reproducibility, progress and cancel."""
import threading

import numpy as np
import pytest

import endophoton as ep
from endophoton import _core, vdb
from physics_helpers import assert_energy_conserved, assert_no_nan, K_SIGMA


def _clear_absorber(unit="cm", scale=1.0):
    """A non-scattering absorbing box: a pencil beam deposits only along its own line."""
    s = ep.Scene(unit=unit)
    s.add_box(
        "absorber",
        np.array((-1, -1, -1)) * scale,
        np.array((1, 1, 0)) * scale,
        ep.Medium(mua=1.5, mus=0.0, g=0.0, n=1.0),
    )
    return s


def test_grid_lines_up_with_world_space_and_sums_to_the_absorbed_tally(tmp_path):
    x0, y0 = 0.3, -0.2
    voxel = 0.05
    path = tmp_path / "abs.vdb"
    res = ep.run(
        _clear_absorber(),
        ep.PencilSource((x0, y0, 1.0), (0, 0, -1)),
        photons=500,
        seed=1,
        grids=ep.GridRequest(voxel_size=voxel, path=str(path)),
    )
    assert_energy_conserved(res)
    assert res.grid_path == str(path) and path.exists()
    summary = vdb.read_grid_summary(str(path))
    g = summary["grids"]["absorbed"]
    assert g["grid_class"].lower().startswith("fog")
    assert g["voxel_size"] == pytest.approx((voxel,) * 3)
    # Every packet loses 1 - exp(-1.5 * 1 cm) in the box (Beer-Lambert, exact for mus = 0).
    expected_absorbed = 1 - np.exp(-1.5)
    assert res.absorbed == pytest.approx(expected_absorbed, rel=1e-12)
    assert g["sum"] == pytest.approx(res.absorbed, rel=1e-6)
    for key in ("packets", "seed", "unit_cm", "engine"):
        assert key in summary["metadata"] or key in g["metadata"], key
    # Voxel-to-world: the deposition line x = x0, y = y0, -1 < z < 0 (cell-centred voxels).
    arr, origin, h = vdb.grid_to_numpy(str(path), "absorbed")
    idx = np.argwhere(arr > 0)
    world = origin + idx * h
    assert np.all(np.abs(world[:, 0] - x0) <= 0.5 * h + 1e-9)
    assert np.all(np.abs(world[:, 1] - y0) <= 0.5 * h + 1e-9)
    assert world[:, 2].min() >= -1 - h and world[:, 2].max() <= 0 + h
    # Beer-Lambert shape: the voxel nearest the surface holds more than the deepest one.
    by_z = {round(float(z), 6): float(v) for z, v in zip(world[:, 2], arr[arr > 0])}
    zs = sorted(by_z)
    assert by_z[zs[-1]] > by_z[zs[0]]


def test_no_grid_file_unless_requested(tmp_path):
    res = ep.run(_clear_absorber(), ep.PencilSource((0, 0, 1), (0, 0, -1)), photons=200, seed=1)
    assert res.grid_path is None and res.grid_names == []


def test_grid_in_metres_lines_up_with_the_same_physical_point(tmp_path):
    path = tmp_path / "m.vdb"
    res = ep.run(
        _clear_absorber("m", 0.01),
        ep.PencilSource((0.003, -0.002, 0.01), (0, 0, -1)),
        photons=200,
        seed=1,
        grids=ep.GridRequest(voxel_size=0.0005, path=str(path)),
    )
    arr, origin, h = vdb.grid_to_numpy(str(path), "absorbed")
    world = origin + np.argwhere(arr > 0) * h
    assert np.all(np.abs(world[:, 0] - 0.003) <= 0.5 * h + 1e-12)
    # The box bottom is stored as float32(-0.01) m: the path is that thickness in cm.
    path_cm = -float(np.float32(-0.01)) * 100.0
    assert res.absorbed == pytest.approx(1 - np.exp(-1.5 * path_cm), rel=1e-12)


def _fluor_scene():
    s = ep.Scene(unit="cm")
    s.add_box(
        "tissue",
        (-5, -5, -5),
        (5, 5, 0),
        ep.Medium(20, 200, 0.9, 1.1),
        fluorophores=[ep.Fluorophore("collagen", 0.2, 0.4)],
    )
    return s


def test_store_n_is_deterministic_across_thread_counts():
    rig = ep.EndoscopeRig.from_beta(15, 1.0)
    a = ep.run(_fluor_scene(), rig, store=3000, fluorescent_only=True, seed=4, threads=1)
    b = ep.run(_fluor_scene(), rig, store=3000, fluorescent_only=True, seed=4, threads=2)
    assert a.stop_reason == "store" and len(a.escapes["weight"]) == 3000
    assert a.packets_traced == b.packets_traced
    assert a.packets_traced == int(a.escapes["packet"][-1]) + 1
    for k in a.escapes:
        assert np.array_equal(a.escapes[k], b.escapes[k]), k
    assert np.all(a.escapes["fluorescent"] == 1)
    assert np.all(np.diff(a.escapes["packet"].astype(np.int64)) > 0)


def test_halton_emission_is_reproducible():
    rig = ep.EndoscopeRig.from_beta(20, 1.0)
    src = ep._core.Source(rig.native_lights(1.0))
    p1, d1, w1, l1 = ep._core._testing.emit(src, 9, 0, 4096, True)
    p2, d2, w2, l2 = ep._core._testing.emit(src, 9, 0, 4096, True)
    assert np.array_equal(p1, p2) and np.array_equal(d1, d2) and np.array_equal(w1, w2)
    assert np.array_equal(l1, np.arange(4096) % 2)
    # Directions are inside each light's cone (half angle 7.5 deg about the head axis).
    cosang = d1 @ rig.forward
    assert np.all(cosang >= np.cos(np.radians(7.5)) - 1e-12)
    # Flat white 400-700 nm by default: uniform, checked by the first two moments.
    assert w1.min() >= 400 and w1.max() <= 700
    assert abs(w1.mean() - 550) < K_SIGMA * 300 / np.sqrt(12 * len(w1))


NEVER_ENDS = 2**40  # packets: no run in a test can finish this, so a stop is always the cancel


def test_progress_is_reported_and_cancel_returns_a_marked_partial_result():
    """No verdict depends on timing: the run cannot finish, so whatever the load it is still
    running when the first progress report arrives and when the token is cancelled. Meanwhile
    this thread runs Python (the GIL is released). How many units were merged before the
    cancel depends on timing; every assertion holds for any count, 0 included."""
    scene = _fluor_scene()
    token = ep.CancelToken()
    calls = []
    reported = threading.Event()

    def progress(done, total):
        calls.append((done, total))
        reported.set()

    out = {}

    def work():
        out["res"] = ep.run(
            scene,
            ep.PencilSource((0, 0, 1), (0, 0, -1)),
            photons=NEVER_ENDS,
            seed=1,
            threads=2,
            record_escapes=False,
            progress=progress,
            cancel=token,
        )

    th = threading.Thread(target=work)
    th.start()
    reported.wait()
    ticks = sum(1 for _ in range(100000))
    token.cancel()
    th.join()
    res = out["res"]
    assert ticks == 100000
    assert res.cancelled is True and res.stop_reason == "cancelled"
    assert 0 <= res.photons < NEVER_ENDS and res.photons % res.unit_size == 0
    assert calls and all(t == NEVER_ENDS for _, t in calls)
    assert_no_nan(res)
    if res.photons:
        assert_energy_conserved(res)


def test_cancel_after_three_units_is_an_exact_partial_result(tmp_path):
    """The engine's test hook cancels right after the 3rd merged unit: the partial result holds
    exactly 3 units, is marked cancelled, conserves energy and writes no grid file."""
    scene = _fluor_scene()
    src = ep.PencilSource((0, 0, 1), (0, 0, -1))
    path = tmp_path / "never.vdb"
    raw = _core.run(
        scene.to_native(),
        _core.Source(src.native_lights(scene.unit_cm)),
        _core.RunConfig(
            photons=1_000_000,
            unit_size=500,
            seed=3,
            threads=2,
            record_escapes=False,
            grid_voxel_size=0.1,
            grid_path=str(path),
            test_cancel_after_units=3,
        ),
    )
    assert raw["cancelled"] is True and raw["stop_reason"] == "cancelled"
    assert raw["photons"] == 1500
    assert raw["grid_path"] is None and not path.exists() and list(tmp_path.iterdir()) == []
    assert_no_nan(raw)
    assert_energy_conserved(raw)


def test_progress_returning_false_stops_the_run():
    res = ep.run(
        _fluor_scene(),
        ep.PencilSource((0, 0, 1), (0, 0, -1)),
        photons=NEVER_ENDS,
        seed=1,
        record_escapes=False,
        progress=lambda done, total: False,
    )
    assert res.cancelled and res.photons < NEVER_ENDS
    assert_no_nan(res)


@pytest.mark.slow
def test_clear_region_deposits_are_exact_per_voxel(tmp_path):
    """mus = 0: the absorbed weight of every voxel equals the Beer-Lambert loss along the part
    of the ray inside that voxel (reference: fine numerical integration along the ray,
    binned by cell-centred voxel index), for an oblique ray that crosses voxel faces."""
    h, mua = 0.07, 1.5
    s = ep.Scene(unit="cm")
    s.add_box("a", (-1, -1, -1), (1, 1, 0), ep.Medium(mua, 0.0, 0.0, 1.0))
    d = np.array([0.3, 0.1, -1.0])
    d /= np.linalg.norm(d)
    p0 = np.array([0.013, 0.02, 1.0])
    path = tmp_path / "clear.vdb"
    res = ep.run(s, ep.PencilSource(tuple(p0), tuple(d)), photons=64, grids=ep.GridRequest(h, str(path)))
    arr, origin, hh = vdb.grid_to_numpy(str(path), "absorbed")
    entry = p0 + d * (-p0[2] / d[2])
    length = -1.0 / d[2]
    t = np.linspace(0.0, length, 2_000_001)
    w = np.exp(-mua * t)
    mid = entry + np.outer(0.5 * (t[1:] + t[:-1]), d)
    ref = {}
    for key, v in zip(map(tuple, np.round(mid / h).astype(int)), w[:-1] - w[1:]):
        ref[key] = ref.get(key, 0.0) + v
    got = {tuple(np.round((origin + ijk * hh) / h).astype(int)): float(arr[tuple(ijk)]) for ijk in np.argwhere(arr > 0)}
    assert set(got) == set(ref)
    for key, v in ref.items():
        assert got[key] == pytest.approx(v, rel=1e-4, abs=1e-7), key
    assert res.absorbed == pytest.approx(1 - np.exp(-mua * length), rel=1e-6)


def test_time_budget_stops_a_fixed_count_run():
    """The count can never be reached, so the stop is the budget whatever the load; the rule
    runs after a merge, so at least one whole unit is in the result (its stderrs finite even
    when it is the only one). The timing of the rule itself is tested with a fake clock in
    tests/cpp (StopRule)."""
    res = ep.run(
        _fluor_scene(),
        ep.PencilSource((0, 0, 1), (0, 0, -1)),
        photons=NEVER_ENDS,
        seed=1,
        record_escapes=False,
        time_budget_s=0.5,
        unit_size=2000,
    )
    assert res.stop_reason == "time" and 2000 <= res.photons < NEVER_ENDS and res.photons % 2000 == 0
    assert not res.cancelled and res.seconds >= 0.5
    assert_no_nan(res)
    assert_energy_conserved(res)


def _all_grids(path):
    return {name: vdb.grid_to_numpy(str(path), name) for name in vdb.read_grid_summary(str(path))["grids"]}


def test_grids_are_the_same_bits_on_any_thread_count_and_either_grid_path(tmp_path):
    """Voxels are exact fixed-point sums (docs/numerics.md, "Grid sums"): one thread, two
    threads (each with its own grids for the whole run) and the per-unit grids that runs with a
    stop rule keep (a time budget that never fires) give every voxel of every grid bit for bit,
    and the absorbed grid sums to the absorbed tally. Workers stage several units before they
    add them to the run's grids (engine.cpp, kStagedPackets) and add what is left when they end:
    64-packet units (the last one short) give the same bits too."""
    rig = ep.PencilSource((0, 0, 1), (0, 0, -1))
    kw = dict(photons=4000, unit_size=250, seed=6, record_escapes=False)
    runs = {}
    for label, extra in (
        ("t1", dict(threads=1)),
        ("t2", dict(threads=2)),
        ("t2-budget", dict(threads=2, time_budget_s=1e6)),
        ("t1-units64", dict(threads=1, unit_size=64)),
        ("t2-units64", dict(threads=2, unit_size=64)),
    ):
        path = tmp_path / f"{label}.vdb"
        res = ep.run(
            _fluor_scene(), rig, grids=ep.GridRequest(0.05, str(path), per_fluorophore=True), **{**kw, **extra}
        )
        assert res.photons == 4000 and res.stop_reason == "photons"
        runs[label] = (res, _all_grids(path))
    ref_res, ref = runs["t1"]
    assert sorted(ref) == ["absorbed", "emission_collagen", "fluorescent_light", "fluorescent_light_collagen"]
    assert ref_res.grid_absorbed_sum == pytest.approx(ref_res.absorbed_energy, rel=1e-12)
    for label, (res, grids) in runs.items():
        assert res.grid_absorbed_sum == ref_res.grid_absorbed_sum, label
        for name, (arr, origin, h) in ref.items():
            got, got_origin, got_h = grids[name]
            assert got_origin == origin and got_h == h, (label, name)
            assert np.array_equal(got, arr), (label, name)


def test_time_budget_with_grids_keeps_only_the_merged_units_deposits(tmp_path):
    """A time budget stops after some unit while the other thread may have traced later units:
    their deposits must be dropped with them, so the absorbed grid still sums to the absorbed
    tally of the merged packets (whatever unit the budget stops at)."""
    path = tmp_path / "budget.vdb"
    res = ep.run(
        _fluor_scene(),
        ep.PencilSource((0, 0, 1), (0, 0, -1)),
        photons=NEVER_ENDS,
        seed=2,
        threads=2,
        record_escapes=False,
        time_budget_s=0.3,
        unit_size=500,
        grids=ep.GridRequest(0.05, str(path)),
    )
    assert res.stop_reason == "time" and res.photons % 500 == 0 and res.photons >= 500
    assert res.grid_absorbed_sum == pytest.approx(res.absorbed_energy, rel=1e-12)
    summary = vdb.read_grid_summary(str(path))
    assert summary["grids"]["absorbed"]["metadata"]["packets"] == str(res.photons)


def test_target_on_a_tally_that_stays_zero_stops_and_says_so():
    """Transmittance of a 10 cm deep absorbing box is exactly 0: its relative error is
    undefined, so the run stops after its minimum and reports 'target_zero'."""
    s = ep.Scene(unit="cm")
    s.add_box("t", (-5, -5, -10), (5, 5, 0), ep.Medium(20, 200, 0.9, 1.1))
    res = ep.run(
        s, ep.PencilSource((0, 0, 1), (0, 0, -1)), target=ep.Target("transmittance", 0.01), record_escapes=False
    )
    assert res.stop_reason == "target_zero" and not res.target_reached
    assert res.transmittance == 0.0


# The .vdb writer's limits (native/vdb_writer.h). A tree node costs far more
# than a voxel, so deposits scattered at a tiny voxel size once took gigabytes
# of OpenVDB nodes for a few thousand voxels and aborted the process.
def _scattering_slab():
    return ep.layered_slab([(ep.Medium(mua=1, mus=100, g=0.9, n=1.4), 0.5)])


_DOWN = ep.PencilSource(position=(0, 0, 1), direction=(0, 0, -1))


def test_a_voxel_below_openvdbs_scale_is_refused_before_the_run(tmp_path):
    out = tmp_path / "tiny.vdb"
    with pytest.raises(ValueError, match=r"grids\.voxel_size = 1(\.0+1)?e-05 is below the smallest voxel OpenVDB"):
        ep.run(_scattering_slab(), _DOWN, photons=10, threads=1, grids=ep.GridRequest(1e-5, str(out)))
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    "photons, stage",
    [
        # 20 packets at 1 um voxels: ~5,000 voxels, nearly each in its own leaf
        # and internal node (~36 kB a voxel): the writer's trees pass 1 MiB.
        (20, r"their OpenVDB tree nodes would need more than the 1 MiB"),
        # 2,000 packets: ~500,000 voxels a grid, tens of MB of the run's tables.
        (2000, r"the run's voxel tables took \d+ MiB, more than the 1 MiB"),
    ],
)
def test_scattered_deposits_stop_at_the_memory_limit_and_leave_no_file(tmp_path, photons, stage):
    grids = ep.GridRequest(voxel_size=1e-4, path=str(tmp_path / "scattered.vdb"), max_memory_mb=1)
    with pytest.raises(RuntimeError, match=r"grids\.voxel_size = 0\.0001: .*" + stage):
        ep.run(_scattering_slab(), _DOWN, photons=photons, threads=2, grids=grids)
    assert list(tmp_path.iterdir()) == []


def test_scattered_deposits_with_room_are_written_whole(tmp_path):
    out = tmp_path / "scattered.vdb"
    grids = ep.GridRequest(voxel_size=1e-4, path=str(out), max_memory_mb=4096)
    res = ep.run(_scattering_slab(), _DOWN, photons=20, threads=2, grids=grids)
    assert out.exists() and res.grid_absorbed_sum == pytest.approx(res.absorbed, rel=1e-9)


@pytest.mark.parametrize("bad", [0, 0.5, -1, float("nan"), float("inf"), True, "1"])
def test_bad_writer_memory_limits_are_refused_by_name(tmp_path, bad):
    with pytest.raises(ValueError, match=r"grids\.max_memory_mb = "):
        ep.GridRequest(voxel_size=0.01, path=str(tmp_path / "g.vdb"), max_memory_mb=bad)
