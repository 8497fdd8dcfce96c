"""The β sweep's live view (issue 36): ``sweep(..., live={...})`` runs each β through ep.run_live and
hands its snapshots to ``on_snapshot(i_beta, beta_deg, result)``. The sweep's result is the same bits as
without the live view (its ``seconds`` aside: how long a run took, not what it found); the snapshots of a
β grow; a Dask client is refused. Snapshots are forced after the first merged chunks
(``snapshot_after_chunks``): no verdict depends on timing."""
import types

import numpy as np
import pytest

from endophoton.sweep import driver as sw

BETAS = [0, 25]


def small_scene():
    return sw.default_flat_scene(polyp="dome", half_width_cm=2.0, thickness_cm=1.0, mesh_resolution=(8, 16))


def assert_same_sweep(a, b):
    """Every row (but ``seconds``), histogram, batch array and meta entry (but the clock times) alike."""
    assert len(a.rows) == len(b.rows) == len(BETAS)
    for ra, rb in zip(a.rows, b.rows):
        ra, rb = dict(ra), dict(rb)
        ra.pop("seconds"), rb.pop("seconds")
        assert ra == rb
    for ha, hb in zip(a.histograms, b.histograms):
        assert set(ha) == set(hb)
        for k in ha:
            assert np.array_equal(ha[k], hb[k], equal_nan=True), k
    for ba, bb in zip(a.batches, b.batches):
        assert set(ba) == set(bb)
        for k in ba:
            assert np.array_equal(ba[k], bb[k], equal_nan=True), k
    when = ("started", "finished")  # the clock's, not the runs'
    assert {k: v for k, v in a.meta.items() if k not in when} == {k: v for k, v in b.meta.items() if k not in when}


@pytest.mark.parametrize("threads", [1, 2])
def test_live_sweep_is_the_bits_of_a_plain_sweep_and_its_snapshots_grow_within_a_beta(threads):
    scene = small_scene()
    common = dict(betas=BETAS, store=3000, n_batches=4, seed=3, threads=threads, progress=False, plots=False)
    plain = sw.sweep(scene, **common)
    snaps = []

    def on_snapshot(i, beta, result):
        snaps.append((i, beta, int(result.packets_traced), bool(result.cancelled)))

    # chunks of 2 units (the run's own choice would be one chunk of ~0.25 s: the whole of this small run)
    live = sw.sweep(scene, live={"on_snapshot": on_snapshot, "snapshot_after_chunks": 3}, chunk_units=2, **common)
    assert_same_sweep(plain, live)
    assert not live.meta.get("cancelled")
    assert sorted({(i, beta) for i, beta, _, _ in snaps}) == list(enumerate(BETAS))  # every β shows, labelled
    assert [i for i, *_ in snaps] == sorted(i for i, *_ in snaps)  # β after β
    for k, beta in enumerate(BETAS):
        packets = [p for i, _, p, _ in snaps if i == k]
        assert len(packets) >= 2 and packets == sorted(set(packets)) and packets[0] > 0, packets  # noise falls
        assert packets[-1] <= live.rows[k]["packets_traced"]
    assert all(partial for *_, partial in snaps)  # a snapshot is a partial run


class _FakeClient:
    def submit(self, *a, **k):  # never called: the sweep is refused before anything runs
        raise AssertionError("no task may be submitted")


@pytest.mark.parametrize(
    "kwargs, text",
    [
        (dict(client=_FakeClient()), "live with client = <"),
        (dict(run_kwargs={"client": _FakeClient()}), "live with run_kwargs['client'] = "),
        (dict(run_kwargs={"view": True}), "live with run_kwargs['view'] = True"),
    ],
    ids=["client", "run_kwargs-client", "view"],
)
def test_live_sweep_refuses_a_client_or_the_camera_tally_by_name(kwargs, text):
    calls = []
    with pytest.raises(ValueError) as err:
        sw.sweep(small_scene(), betas=[0], store=100, progress=False, live={"on_snapshot": calls.append}, **kwargs)
    assert text in str(err.value)
    assert calls == []


@pytest.mark.parametrize(
    "live, text",
    [
        ({"every_s": 1.0}, "live['on_snapshot'] = None must be a callable"),
        ({"on_snapshot": 3}, "live['on_snapshot'] = 3 must be a callable"),
        ({"on_snapshot": print, "photons": 5}, "live: 'photons' is not a keyword argument of ep.run_live"),
        ([1], "live = [1] must be None or a dict"),
    ],
)
def test_live_sweep_bad_live_names_the_field(live, text):
    with pytest.raises(ValueError) as err:
        sw.sweep(small_scene(), betas=[0], store=100, progress=False, live=live)
    assert text in str(err.value)


class _Stop(Exception):
    pass


def test_live_sweep_hands_each_betas_snapshots_with_its_index(monkeypatch):
    """Without the engine: each β's ep.run_live call gets the sweep's run keywords and an on_snapshot that
    passes the β's index and angle on."""
    seen, calls = [], []

    def fake_run_live(scene, rig, **kw):
        calls.append(kw)
        kw["on_snapshot"](types.SimpleNamespace(packets_traced=len(calls)))
        raise _Stop  # ends the sweep at its first β: only the call matters here

    monkeypatch.setattr(sw, "run_live", fake_run_live)
    with pytest.raises(_Stop):
        sw.sweep(
            small_scene(),
            betas=[10, 20],
            store=100,
            seed=4,
            progress=False,
            live={"on_snapshot": lambda i, beta, r: seen.append((i, beta, r.packets_traced)), "every_s": 2.0},
        )
    assert seen == [(0, 10.0, 1)]
    assert calls[0]["every_s"] == 2.0 and calls[0]["store"] == 100 and calls[0]["seed"] == sw.beta_seed(4, 0, True)
