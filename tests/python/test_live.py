"""ep.run_live (issue 36, the live endoscope view): a local run through the unit path that hands
snapshots of the units merged so far to a callback. The final result is the same bits as ep.run's
(1 and 2 threads; fixed count, "store N", target, grids); snapshots are partial runs whose packets
never decrease and whose records are a prefix of the final ones; a cancel returns the merged prefix.
Snapshots are forced after the first chunks (snapshot_after_chunks, fixed chunk_units): no verdict
depends on timing."""
import threading

import numpy as np
import pytest

import endophoton as ep
from endophoton.sweep.driver import default_flat_scene
from endophoton.vdb import grid_to_numpy

HOW = ("seconds", "threads", "grid_path")  # how a run ran, not what it found


def fluorescent_endoscope():
    scene = default_flat_scene(polyp="dome", half_width_cm=2.0, thickness_cm=1.0, mesh_resolution=(8, 16))
    return scene, ep.EndoscopeRig.from_beta(20, 1.0)


def assert_same_result(a, b):
    ra, rb = a.to_dict(), b.to_dict()
    for k in HOW:
        ra.pop(k, None), rb.pop(k, None)
    assert ra == rb
    assert set(a.escapes) == set(b.escapes)
    for k in a.escapes:
        assert a.escapes[k].dtype == b.escapes[k].dtype, k
        assert np.array_equal(a.escapes[k], b.escapes[k]), k


@pytest.mark.slow
@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize(
    "budget",
    [dict(photons=20000), dict(store=3000), dict(target=ep.Target("diffuse_reflectance", 0.05), max_photons=200000)],
    ids=["photons", "store", "target"],
)
def test_final_result_is_the_bits_of_ep_run(threads, budget):
    scene, rig = fluorescent_endoscope()
    local = ep.run(scene, rig, seed=5, threads=threads, **budget)
    snaps = []
    live = ep.run_live(
        scene, rig, seed=5, threads=threads, on_snapshot=snaps.append, snapshot_after_chunks=3, chunk_units=2, **budget
    )
    assert not live.cancelled
    assert_same_result(local, live)
    assert snaps, "the first merged chunks make snapshots"


@pytest.mark.slow
def test_grids_and_records_are_the_bits_of_ep_run(tmp_path):
    scene, rig = fluorescent_endoscope()
    grid = lambda name: ep.GridRequest(voxel_size=0.1, path=str(tmp_path / name), per_fluorophore=True)  # noqa: E731
    local = ep.run(scene, rig, photons=5000, seed=2, threads=2, grids=grid("a.vdb"))
    snaps = []
    live = ep.run_live(
        scene,
        rig,
        photons=5000,
        seed=2,
        threads=2,
        grids=grid("b.vdb"),
        on_snapshot=snaps.append,
        snapshot_after_chunks=2,
        chunk_units=20,
    )
    assert_same_result(local, live)
    assert local.grid_names == live.grid_names and len(live.grid_names) > 2
    for name in local.grid_names:
        a, oa, ha = grid_to_numpy(local.grid_path, name)
        b, ob, hb = grid_to_numpy(live.grid_path, name)
        assert a.shape == b.shape and oa == ob and ha == hb and np.array_equal(a, b), name
    assert len(snaps) == 2 and sorted(p.name for p in tmp_path.iterdir()) == ["a.vdb", "b.vdb"]  # no scratch left


@pytest.mark.slow
def test_snapshots_grow_and_hold_a_prefix_of_the_final_records():
    scene, rig = fluorescent_endoscope()
    snaps = []
    final = ep.run_live(
        scene,
        rig,
        photons=20000,
        seed=9,
        threads=2,
        on_snapshot=snaps.append,
        chunk_units=40,
        snapshot_after_chunks=100,
    )
    photons = [s.photons for s in snaps]
    assert len(snaps) == 7  # 313 units of 64 packets in 8 chunks: a snapshot after each but the last
    assert photons == sorted(photons) and len(set(photons)) == len(photons) and photons[-1] < final.photons
    assert photons == [64 * 40 * (i + 1) for i in range(7)]
    for s in snaps:
        assert s.cancelled  # a partial run
        n = len(s.escapes["weight"])
        for k in final.escapes:
            assert np.array_equal(s.escapes[k], final.escapes[k][:n]), k
    # A snapshot's records render like a finished run's (the kernel estimator).
    view = ep.render_view(snaps[-1], width=16, height=16)
    assert np.all(np.isfinite(view.images["white"]["rgb"]))


@pytest.mark.slow
def test_cancel_mid_way_returns_the_merged_prefix():
    scene, rig = fluorescent_endoscope()
    token, snaps = ep.CancelToken(), []

    def on_snapshot(result):
        snaps.append(result)
        if len(snaps) == 2:
            token.cancel()

    part = ep.run_live(
        scene,
        rig,
        photons=20000,
        seed=9,
        threads=1,
        on_snapshot=on_snapshot,
        chunk_units=40,
        snapshot_after_chunks=100,
        cancel=token,
    )
    assert part.cancelled and part.photons == 2 * 40 * 64 == snaps[-1].photons
    full = ep.run(scene, rig, photons=20000, seed=9, threads=1)
    n = len(part.escapes["weight"])
    assert 0 < n < len(full.escapes["weight"])
    assert np.array_equal(part.escapes["weight"], full.escapes["weight"][:n])


@pytest.mark.slow
def test_clock_snapshots_are_made_in_their_own_thread_while_the_run_goes_on():
    scene, rig = fluorescent_endoscope()
    made, caller = threading.Event(), threading.get_ident()
    snaps = []

    def on_snapshot(result):
        snaps.append((threading.get_ident(), result.photons))
        made.set()

    def progress(done, total):  # the merging thread waits, after its second chunk, for the first snapshot
        if done == 2 * 5 * 64:
            assert made.wait(60.0)

    final = ep.run_live(
        scene,
        rig,
        photons=3000,
        seed=4,
        threads=1,
        on_snapshot=on_snapshot,
        every_s=1e-6,
        chunk_units=5,
        progress=progress,
    )
    assert snaps[0] == (snaps[0][0], 5 * 64) and snaps[0][0] != caller
    assert_same_result(ep.run(scene, rig, photons=3000, seed=4, threads=1), final)


def test_progress_false_stops_and_progress_counts_packets():
    scene, rig = fluorescent_endoscope()
    seen = []

    def progress(done, total):
        seen.append((done, total))
        return len(seen) < 2

    part = ep.run_live(
        scene, rig, photons=3000, seed=1, threads=1, on_snapshot=lambda r: None, chunk_units=5, progress=progress
    )
    assert seen == [(5 * 64, 3000), (10 * 64, 3000)] and part.cancelled and part.photons == 640


@pytest.mark.parametrize(
    "kwargs, text",
    [
        (dict(every_s=0), "every_s = 0"),
        (dict(every_s=float("nan")), "every_s = nan"),
        (dict(overhead_share=1.5), "overhead_share = 1.5"),
        (dict(snapshot_after_chunks=-1), "snapshot_after_chunks = -1"),
        (dict(chunk_units="4"), "chunk_units = '4'"),
        (dict(on_snapshot=None), "on_snapshot = None"),
        (dict(on_snapshot=3), "on_snapshot"),
        (dict(view=True), "view = True"),
        (dict(client=object()), "client"),
        (dict(photons=0), "photons = 0"),
    ],
)
def test_bad_input_is_named(kwargs, text):
    scene, rig = fluorescent_endoscope()
    args = dict(photons=1000, on_snapshot=lambda r: None)
    args.update(kwargs)
    with pytest.raises((ValueError, TypeError), match=None) as info:
        ep.run_live(scene, rig, **args)
    assert text in str(info.value)
