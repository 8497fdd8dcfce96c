"""One word per concept (docs/design.md, "Words"): a point is a ``position``.
``DiskSource`` and the SCENE.json disk source take ``position``; the older
``center`` keeps working and means the same point."""
import numpy as np
import pytest

import endophoton as ep


def test_disk_source_position_and_center_are_one_point():
    a = ep.DiskSource(position=(0.1, 0.2, 1.0), direction=(0, 0, -1), radius=0.3)
    b = ep.DiskSource(center=(0.1, 0.2, 1.0), direction=(0, 0, -1), radius=0.3)
    c = ep.DiskSource((0.1, 0.2, 1.0), (0, 0, -1), 0.3)  # positional: position first
    for s in (a, b, c):
        assert np.array_equal(s.position, [0.1, 0.2, 1.0]) and np.array_equal(s.center, s.position)
        assert s.native_lights(1.0) == a.native_lights(1.0)
    assert a.native_lights(1.0)[0]["position"] == [0.1, 0.2, 1.0]
    with pytest.raises(ValueError, match="position or center"):
        ep.DiskSource(position=(0, 0, 1), center=(0, 0, 1))


@pytest.mark.parametrize("key", ["position", "center"])
def test_scene_json_disk_source_takes_either_key(key):
    src = ep.source_from_dict({"type": "disk", key: [0, 0, 2], "direction": [0, 0, -1], "radius": 0.1})
    assert np.array_equal(src.position, [0, 0, 2]) and src.radius == 0.1


@pytest.mark.parametrize(
    "body",
    [
        {"type": "disk", "direction": [0, 0, -1], "radius": 0.1},
        {"type": "disk", "position": [0, 0, 1], "center": [0, 0, 1], "direction": [0, 0, -1], "radius": 0.1},
    ],
)
def test_scene_json_disk_source_needs_exactly_one_point(body):
    with pytest.raises(ValueError, match="exactly one of 'position' or 'center'"):
        ep.source_from_dict(body)


def test_package_and_engine_name_the_same_fractions():
    """One list of fractions: the package's FRACTIONS (python/endophoton/tallies.py) are the engine's balance
    tallies (native/tally.cpp, exported read-only by the binding), in the same order; a run reports each with
    its standard error, and together they hold all the launched weight."""
    from endophoton import _core
    from physics_helpers import BALANCE_KEYS

    assert tuple(_core.BALANCE_TALLIES) == ep.FRACTIONS
    # FRACTIONS is read from the engine, so the check with teeth is against the tests' own
    # list of a packet's fates (physics_helpers.BALANCE_KEYS, written independently).
    assert set(_core.BALANCE_TALLIES) == set(BALANCE_KEYS)
    s = ep.Scene("cm")
    s.add_box("slab", (-1, -1, -0.1), (1, 1, 0), ep.Medium(mua=1.0, mus=10.0, g=0.0, n=1.0))
    r = ep.run(s, ep.PencilSource((0, 0, 1), (0, 0, -1)), photons=500, threads=1)
    raw = r.to_dict()
    assert all(k in raw and k + "_stderr" in raw for k in _core.BALANCE_TALLIES)
    assert sum(raw[k] for k in _core.BALANCE_TALLIES) == pytest.approx(1.0, abs=1e-12)  # the fates of all weight
