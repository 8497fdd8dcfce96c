"""The local triangle caches and the interior steps (issue 11) are speed only.

With ``safe_distance=False`` every step of every packet goes through the general
loop and Embree's ray queries; with it on (the default) most steps run in the
interior-step loop over the per-cube triangle caches, which draws the same
random numbers in the same order -- fluorescence trials included -- and finds
the same crossings. So the two must agree bit for bit: every tally, every
standard error and every escape record, under both fluorescence rules, on the
colon benchmark (curved walls, a polyp of higher priority with two
fluorophores, the lumen rule, the rig head). (Up to a crossing within float
rounding of a shared triangle edge, where the two may name different triangles:
docs/numerics.md, "Vertices and edges"; none occurs in these runs.)
"""
from __future__ import annotations


import numpy as np
import pytest

import endophoton as ep
from physics_helpers import run_physics

from cli_helpers import bench_scene

ENV_KEYS = {"seconds", "threads", "peak_record_bytes", "grid_path"}


@pytest.fixture(scope="module")
def colon():
    return bench_scene("colon")


@pytest.mark.parametrize("rule", ["paper", "eem"])
def test_interior_steps_change_nothing_on_the_colon(colon, rule):
    scene, rig = colon
    runs = [
        ep.run(
            scene,
            rig,
            photons=3000,
            threads=1,
            seed=5,
            record_escapes=True,
            fluorescence_rule=rule,
            safe_distance=safe,
            lanes=False,  # the double walk, where this rule is made (the lanes: docs/numerics.md)
        )
        for safe in (True, False)
    ]
    fast, slow = (r.to_dict() for r in runs)
    assert set(fast) == set(slow)
    for k in fast:
        if k in ENV_KEYS or "time" in k or "second" in k:
            continue
        assert fast[k] == slow[k], f"{k}: {fast[k]!r} != {slow[k]!r}"
    assert runs[0].fluorescence_events > 0 and runs[0].fluorescence_trials > runs[0].fluorescence_events
    esc_fast, esc_slow = runs[0].escapes, runs[1].escapes
    assert set(esc_fast) == set(esc_slow) and len(esc_fast["weight"]) > 100
    for k in esc_fast:
        assert np.array_equal(np.asarray(esc_fast[k]), np.asarray(esc_slow[k])), f"escapes[{k}] differ"


def test_interior_steps_deposit_the_grids_of_the_general_loop(colon, tmp_path):
    """Grid runs take the interior steps too (they deposit as interact() does): every voxel of
    every grid -- absorbed, fluorescence and one per fluorophore -- and every tally equal the
    general loop's bit for bit."""
    from endophoton import vdb

    scene, rig = colon
    runs, grids = [], []
    for safe in (True, False):
        path = str(tmp_path / f"g{int(safe)}.vdb")
        request = ep.GridRequest(voxel_size=5e-4, path=path, per_fluorophore=True)
        runs.append(ep.run(scene, rig, photons=2000, threads=1, seed=9, grids=request, safe_distance=safe))
        names = list(vdb.read_grid_summary(path)["grids"])
        grids.append({name: vdb.grid_to_numpy(path, name) for name in names})
    fast, slow = (r.to_dict() for r in runs)
    for k in fast:
        if k in ENV_KEYS or "time" in k or "second" in k:
            continue
        assert fast[k] == slow[k], f"{k}: {fast[k]!r} != {slow[k]!r}"
    assert set(grids[0]) == set(grids[1]) and len(grids[0]) >= 4, sorted(grids[0])
    for name, (values, origin, size) in grids[0].items():
        other_values, other_origin, other_size = grids[1][name]
        assert np.array_equal(origin, other_origin) and size == other_size, name
        assert np.array_equal(values, other_values), f"grid {name} differs"
        assert np.count_nonzero(values) > 50, name


@pytest.mark.parametrize("lanes", [False, True])
def test_a_full_cache_store_changes_nothing_on_the_colon(lanes):
    """The cube store's budget (``cache_store_cap_bytes``) bounds its memory: once the store
    holds it, cubes not cached yet take the full ray query (the double walk) or are gathered
    into the lane slot's own caches (a packet enters the float32 lanes only where a cube's
    cache gives it a zone). Same answers, so a run on a store capped at 256 kB, at 2 threads,
    equals a run on an uncapped store at 1 thread bit for bit, and the capped store stays
    within its budget plus one chunk a thread."""
    kwargs = dict(photons=3000, seed=5, record_escapes=True, lanes=lanes)
    ep.forget_native_scenes()
    scene, rig = bench_scene("colon")
    free = ep.run(scene, rig, threads=1, **kwargs)
    free_bytes = scene.to_native().cache_store_bytes
    assert scene.cache_store_mb is None  # the engine's default
    assert scene.to_native().cache_store_cap_bytes == ep._core.DEFAULT_CACHE_STORE_BYTES == 512 << 20
    ep.forget_native_scenes()
    scene, rig = bench_scene("colon")  # the same content, a new engine scene and store
    scene.cache_store_mb = 0.25
    native = scene.to_native()
    cap = 256 * 1024
    assert native.cache_store_bytes == 0 and native.cache_store_cap_bytes == cap
    capped = ep.run(scene, rig, threads=2, **kwargs)
    # The test has teeth: the free store grew far past the budget.
    assert free_bytes > 8 * cap, free_bytes
    # A build is refused once the store holds the budget; each thread may have just taken a
    # chunk before it saw the store full (64 kB: chunks are huge pages only past 2 MiB).
    assert cap <= native.cache_store_bytes <= cap + 2 * 65536, native.cache_store_bytes
    assert len(free.escapes["weight"]) > 100
    assert (free.lanes is not None) == lanes and (capped.lanes is not None) == lanes
    assert run_physics(free) == run_physics(capped)
    ep.forget_native_scenes()
