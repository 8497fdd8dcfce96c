"""ep.check_run: every check ep.run makes before tracing, without tracing (errors named, no file
written), and ep.run, which makes its checks through it, gives the same results as before."""
import os
import time

import numpy as np
import pytest

import endophoton as ep
from physics_helpers import cube_mesh

MEDIUM = dict(mua=1.0, mus=10.0, g=0.9, n=1.4)
DOWN = ep.PencilSource(position=(0.0, 0.0, 1.0), direction=(0.0, 0.0, -1.0))


def _slab(name="tissue_3"):
    scene = ep.Scene(unit="cm", ambient_n=1.0)
    v, t = cube_mesh((-1, -1, -1), (1, 1, 0))
    scene.add_mesh(name, v, t, ep.Medium(**MEDIUM))
    return scene


def _self_intersecting(name="knot_5"):
    """A box and a half-size copy of it shifted up to cut through its top face, in one mesh."""
    scene = ep.Scene(unit="cm", ambient_n=1.0)
    v, t = cube_mesh((-1, -1, -1), (1, 1, 0))
    v2 = v * 0.5 + np.array([0.0, 0.0, 0.2], dtype=v.dtype)
    scene.add_mesh(name, np.concatenate([v, v2]), np.concatenate([t, t + len(v)]), ep.Medium(**MEDIUM))
    return scene


def test_valid_request_returns_the_runs_notes_and_traces_nothing(tmp_path):
    grid = tmp_path / "g.vdb"
    progress = []
    t0 = time.perf_counter()
    notes = ep.check_run(
        _slab(),
        DOWN,
        photons=10**15,
        seed=3,
        grids=ep.GridRequest(0.1, str(grid)),
        progress=lambda done, total: progress.append(done),
    )
    assert time.perf_counter() - t0 < 5.0  # 10^15 packets would take years: nothing was traced
    assert notes == []
    assert progress == [] and not grid.exists() and os.listdir(tmp_path) == []


def test_engine_validation_error_is_named_without_tracing():
    with pytest.raises(ep._core.InvalidArgument, match=r"store = 10 with fluorescent_only = True needs a fluorophore"):
        ep.check_run(_slab(), DOWN, store=10, fluorescent_only=True)
    assert issubclass(ep._core.InvalidArgument, ValueError)


def test_mesh_error_names_the_region():
    with pytest.raises(ValueError, match=r"region 'knot_5': mesh intersects itself"):
        ep.check_run(_self_intersecting(), DOWN, photons=10)


def test_argument_errors_name_the_field():
    with pytest.raises(ValueError, match=r"seed = -1"):
        ep.check_run(_slab(), DOWN, photons=10, seed=-1)
    with pytest.raises(ValueError, match=r"photons and store are exclusive"):
        ep.check_run(_slab(), DOWN, photons=10, store=10)
    with pytest.raises(TypeError):
        ep.check_run(_slab(), DOWN, photons=10, no_such_option=1)


def test_rig_placement_is_checked():
    rig = ep.EndoscopeRig(transform=np.eye(4))  # head at the origin, inside the tissue (z <= 0)
    with pytest.raises(ValueError):
        ep.check_run(_slab(), rig, photons=10)


def test_run_after_check_gives_identical_results():
    """The engine scene check_run builds (kept on the Scene) gives the bits of a fresh one."""
    scene = _slab()
    ep.check_run(scene, DOWN, photons=2000, seed=7, threads=2)
    kept = ep.run(scene, DOWN, photons=2000, seed=7, threads=2)
    ep.forget_native_scenes()
    fresh = ep.run(_slab(), DOWN, photons=2000, seed=7, threads=2)
    timing = ("seconds", "packets_per_second")
    assert {k: v for k, v in kept.to_dict().items() if k not in timing} == {
        k: v for k, v in fresh.to_dict().items() if k not in timing
    }
    for k in kept.escapes:
        np.testing.assert_array_equal(kept.escapes[k], fresh.escapes[k])


def test_a_local_run_crosses_into_the_engine_once(monkeypatch):
    """ep.run leaves the engine's validation to _core.run, which validates before it traces:
    neither the validate-only call nor the Dask planning call is made, and a bad request still
    gets the engine's named error (from _core.run)."""
    from endophoton import _core

    calls = []

    def refuse(name):
        def call(*args, **kwargs):
            calls.append(name)
            raise AssertionError(f"_core.{name} called by a local run")

        return call

    monkeypatch.setattr(_core, "check_run", refuse("check_run"))
    monkeypatch.setattr(_core, "unit_plan", refuse("unit_plan"))
    res = ep.run(_slab(), DOWN, photons=200, seed=1, threads=1)
    assert res.photons == 200 and calls == []
    with pytest.raises(ep._core.InvalidArgument, match=r"store = 10 with fluorescent_only = True needs a fluorophore"):
        ep.run(_slab(), DOWN, store=10, fluorescent_only=True)
    assert calls == []
