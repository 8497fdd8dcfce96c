"""A cancel in the middle of a work unit (issue 36: Cancel ends within 1 s of Esc, whatever the unit size).

The engine checks its cancel token before every packet and abandons the unit it is tracing; an
abandoned unit is never merged. The partial result then holds whole merged units only, in unit order,
so it is bit-identical to a run cancelled at that unit boundary (RunConfig.test_cancel_after_units).
RunConfig.test_cancel_at_packet sets the cancel as a worker is about to trace a given packet index:
deterministic, no timing involved.
"""

import numpy as np
import pytest

import endophoton as ep
from endophoton import _core, vdb
from physics_helpers import assert_energy_conserved, assert_no_nan
from test_grids_and_runs import _fluor_scene  # one scene for the cancel tests

UNIT = 400
ENV_KEYS = {"seconds", "threads"}  # describe the run environment, not the result


def _run(tmp_path, name, threads, photons=100_000, grids=True, **hooks):
    scene = _fluor_scene()
    src = ep.PencilSource((0, 0, 1), (0, 0, -1))
    path = tmp_path / f"{name}.vdb"
    config = _core.RunConfig(
        photons=photons, unit_size=UNIT, seed=5, threads=threads, record_escapes=True, **hooks
    )  # fmt: skip
    if grids:
        config.grid_voxel_size, config.grid_path = 0.1, str(path)
    return _core.run(scene.to_native(), _core.Source(src.native_lights(scene.unit_cm)), config), path


def _assert_same_bits(a, b, where="result"):
    """Every field of two raw results (nested dicts, lists, arrays) equal bit for bit, but the run's
    environment (seconds, threads)."""
    if isinstance(a, dict):
        assert set(a) == set(b), where
        for k in a:
            if k not in ENV_KEYS:
                _assert_same_bits(a[k], b[k], f"{where}.{k}")
    elif isinstance(a, np.ndarray):
        assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes(), where
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            _assert_same_bits(x, y, f"{where}[{i}]")
    else:
        assert a == b, f"{where}: {a!r} != {b!r}"


def test_a_cancel_mid_unit_keeps_only_the_whole_units_before_it(tmp_path):
    """One thread: a cancel before packet 3.5 units in keeps units 0-2, exactly as a cancel right
    after the 3rd merged unit does (1 and 2 threads), with no grid file."""
    mid, mid_path = _run(tmp_path, "mid", threads=1, test_cancel_at_packet=3 * UNIT + UNIT // 2)
    assert mid["cancelled"] is True and mid["stop_reason"] == "cancelled"
    assert mid["photons"] == 3 * UNIT and len(mid["escapes"]["weight"]) > 0
    assert mid["grid_path"] is None and not mid_path.exists()
    assert_no_nan(mid)
    assert_energy_conserved(mid)
    for threads in (1, 2):
        boundary, _ = _run(tmp_path, f"boundary{threads}", threads=threads, test_cancel_after_units=3)
        _assert_same_bits(mid, boundary)


@pytest.mark.parametrize("at_packet", [UNIT // 3, 5 * UNIT + 1, 9 * UNIT - 1])
def test_a_cancel_mid_unit_on_two_threads_gives_a_prefix_of_whole_units(tmp_path, at_packet):
    """Two threads: which units were merged depends on the threads' pace, but the result is the
    first k whole units, bit for bit the run cancelled after its k-th merged unit."""
    mid, _ = _run(tmp_path, "mid", threads=2, test_cancel_at_packet=at_packet)
    assert mid["cancelled"] is True and mid["photons"] % UNIT == 0 and mid["photons"] <= at_packet
    units = mid["photons"] // UNIT
    if units == 0:
        assert mid["escapes"]["weight"].size == 0
        return
    boundary, _ = _run(tmp_path, "boundary", threads=1, test_cancel_after_units=units)
    _assert_same_bits(mid, boundary)


def test_the_hook_past_the_last_packet_leaves_the_run_unchanged(tmp_path):
    """The per-packet check costs nothing in bits: an uncancelled run with the hook set past its
    last packet equals the plain run on 1 and 2 threads, grid file included."""
    plain, plain_path = _run(tmp_path, "plain", threads=1, photons=6 * UNIT)
    assert plain["cancelled"] is False and plain["stop_reason"] == "photons"
    for threads in (1, 2):
        hooked, path = _run(
            tmp_path, f"hooked{threads}", threads=threads, photons=6 * UNIT, test_cancel_at_packet=10**9
        )
        for name in plain["grid_names"]:  # the voxels (the file's bytes hold OpenVDB's random UUID)
            a, b = vdb.grid_to_numpy(str(path), name), vdb.grid_to_numpy(str(plain_path), name)
            assert a[0].tobytes() == b[0].tobytes() and a[1:] == b[1:], name
        hooked["grid_path"] = plain["grid_path"]
        _assert_same_bits(hooked, plain)
