"""Bad input: one test per class. Contract (docs/design.md): a ValueError whose message
names the region, the field and the offending value, e.g.
``region 'tissue': medium.mus = -1 must be >= 0``.

Mesh classes are built with add_mesh (the error may come from add_mesh or from the
run, which builds the native scene); medium classes go through Scene.from_dict (the
SCENE.json path, where the region is known) and through the Python API (where the
error may come from ep.Medium itself, before any region exists: there the message
must still name the field and the value).
"""
import copy
import math
import re

import numpy as np
import pytest

import endophoton as ep
from physics_helpers import cube_mesh, mesh_signed_volume

REGION = "polyp_7"  # distinctive, so a match cannot be accidental
MEDIUM = dict(mua=1.0, mus=10.0, g=0.9, n=1.4)
DOWN = ep.PencilSource(position=(0.0, 0.0, 1.0), direction=(0.0, 0.0, -1.0))


def _word(token):
    return re.compile(r"(?<![A-Za-z0-9_.])" + re.escape(token) + r"(?![A-Za-z0-9_])")


def _assert_message(msg, region, fields, values):
    """The message names the region, one of the accepted spellings of the field and one of
    the accepted spellings of the offending value."""
    low = msg.lower()
    if region is not None:
        assert f"'{region}'" in msg or f'"{region}"' in msg or region in msg, f"region {region!r} not named: {msg}"
    assert any(f.lower() in low for f in fields), f"none of the fields {fields} named: {msg}"
    assert any(_word(v.lower()).search(low) for v in values), f"none of the values {values} named: {msg}"


def _run_mesh(v, t, name=REGION):
    scene = ep.Scene(unit="cm", ambient_n=1.0)
    scene.add_mesh(name, v, t, ep.Medium(**MEDIUM))
    ep.run(scene, DOWN, photons=10, seed=1, threads=1)


def _good_mesh():
    v, t = cube_mesh((-1, -1, -1), (1, 1, 0))
    assert mesh_signed_volume(v, t) == pytest.approx(4.0)  # closed, outward: volume 2 x 2 x 1 cm^3
    return v, t


def test_good_mesh_runs():
    """Control: the unmodified test mesh is accepted and conserves energy."""
    from physics_helpers import assert_energy_conserved

    v, t = _good_mesh()
    scene = ep.Scene(unit="cm")
    scene.add_mesh(REGION, v, t, ep.Medium(**MEDIUM))
    res = ep.run(scene, DOWN, photons=1000, seed=1, threads=1)
    assert_energy_conserved(res)
    assert res.absorbed > 0


# ----------------------------------------------------------------------------
# Mesh classes
# ----------------------------------------------------------------------------
def test_open_mesh():
    v, t = _good_mesh()
    removed = t[7].tolist()
    t = np.delete(t, 7, axis=0)
    with pytest.raises(ValueError) as ei:
        _run_mesh(v, t)
    msg = str(ei.value)
    _assert_message(
        msg,
        REGION,
        ["watertight", "open", "boundary edge", "not closed"],
        [f"({a}, {b})" for a in removed for b in removed if a != b] + [f"{a}" for a in removed],
    )


def test_inconsistent_orientation():
    v, t = _good_mesh()
    k = 5
    t[k] = t[k][::-1]
    with pytest.raises(ValueError) as ei:
        _run_mesh(v, t)
    msg = str(ei.value)
    tri = t[k].tolist()
    _assert_message(
        msg,
        REGION,
        ["orientation", "winding", "inconsistent"],
        [str(k)] + [f"({a}, {b})" for a in tri for b in tri if a != b],
    )


def test_inside_out_mesh():
    """Consistently but inward oriented (every triangle flipped): negative volume."""
    v, t = _good_mesh()
    t = t[:, ::-1].copy()
    with pytest.raises(ValueError) as ei:
        _run_mesh(v, t)
    _assert_message(str(ei.value), REGION, ["orientation", "inward", "winding", "volume"], ["-4", "inward"])


def test_degenerate_triangle():
    """A zero-area sliver that keeps the mesh watertight and consistently oriented: split the
    top triangle (4, 5, 6) at the midpoint m of its edge 6 -> 4 into (4, 5, m) and (m, 5, 6);
    the directed edges (6, m), (m, 4) and the neighbour's (4, 6) then find their twins in the
    collinear triangle (4, m, 6), whose area is exactly 0."""
    v, t = _good_mesh()
    m = len(v)
    v = np.vstack([v, 0.5 * (v[4] + v[6])]).astype(np.float32)  # exactly (0, 0, 0)
    assert np.array_equal(v[m], [0.0, 0.0, 0.0])
    tris = [tr for tr in t.tolist() if tr != [4, 5, 6]]
    tris += [[4, 5, m], [m, 5, 6], [4, m, 6]]
    t2 = np.array(tris, dtype=np.uint32)
    k = len(t2) - 1
    # the mesh is closed and consistently oriented: each directed edge once, with its twin
    edges = {}
    for tr in t2.tolist():
        for a, b in ((tr[0], tr[1]), (tr[1], tr[2]), (tr[2], tr[0])):
            edges[(a, b)] = edges.get((a, b), 0) + 1
    assert all(c == 1 for c in edges.values()) and all((b, a) in edges for (a, b) in edges)
    assert mesh_signed_volume(v, t2) == pytest.approx(4.0)
    with pytest.raises(ValueError) as ei:
        _run_mesh(v, t2)
    _assert_message(str(ei.value), REGION, ["degenerate", "zero area", "zero-area"], [str(k), f"(4, {m}, 6)"])


@pytest.mark.parametrize("bad,token", [(float("nan"), "nan"), (float("inf"), "inf"), (-float("inf"), "-inf")])
def test_non_finite_coordinate(bad, token):
    v, t = _good_mesh()
    v = v.copy()
    v[3, 1] = bad
    with pytest.raises(ValueError) as ei:
        _run_mesh(v, t)
    _assert_message(str(ei.value), REGION, ["vertices", "vertex", "coordinate"], [token])


# ----------------------------------------------------------------------------
# Medium classes: SCENE.json (Scene.from_dict) and the Python API
# ----------------------------------------------------------------------------
BASE = {
    "unit": "cm",
    "ambient_n": 1.0,
    "regions": [
        {"name": REGION, "priority": 1, "medium": dict(MEDIUM), "box": {"min": [-5, -5, -10], "max": [5, 5, 0]}}
    ],
    "source": {"type": "pencil", "position": [0, 0, 1], "direction": [0, 0, -1]},
}

MEDIUM_CASES = [  # field, value, accepted spellings of the value
    ("mua", -1.0, ["-1", "-1.0"]),
    ("mus", -2.5, ["-2.5"]),
    ("g", 1.5, ["1.5"]),
    ("g", -1.01, ["-1.01"]),
    ("n", 0.8, ["0.8"]),
]


def test_scene_dict_control_is_valid():
    scene = ep.Scene.from_dict(copy.deepcopy(BASE))
    assert [r.name for r in scene.regions] == [REGION]


@pytest.mark.parametrize("field,value,spellings", MEDIUM_CASES, ids=[f"{f}={v}" for f, v, _ in MEDIUM_CASES])
def test_bad_medium_from_dict(field, value, spellings):
    d = copy.deepcopy(BASE)
    d["regions"][0]["medium"][field] = value
    with pytest.raises(ValueError) as ei:
        ep.Scene.from_dict(d)
    msg = str(ei.value)
    _assert_message(msg, REGION, [f"medium.{field}", f"{field} ="], spellings)


@pytest.mark.parametrize("field,value,spellings", MEDIUM_CASES, ids=[f"{f}={v}" for f, v, _ in MEDIUM_CASES])
def test_bad_medium_python_api(field, value, spellings):
    kw = dict(MEDIUM)
    kw[field] = value
    region_named = False
    with pytest.raises(ValueError) as ei:
        m = ep.Medium(**kw)  # may raise here, before any region exists
        region_named = True
        scene = ep.Scene(unit="cm")
        scene.add_box(REGION, min=(-1, -1, -1), max=(1, 1, 0), medium=m)
        ep.run(scene, DOWN, photons=10, seed=1)
    _assert_message(str(ei.value), REGION if region_named else None, [f"{field} ="], spellings)


def test_unknown_key_in_medium():
    d = copy.deepcopy(BASE)
    d["regions"][0]["medium"]["musp"] = 3.0
    with pytest.raises(ValueError) as ei:
        ep.Scene.from_dict(d)
    _assert_message(str(ei.value), REGION, ["unknown"], ["musp", "'musp'"])


def test_unknown_key_in_region():
    d = copy.deepcopy(BASE)
    d["regions"][0]["colour"] = "red"
    with pytest.raises(ValueError) as ei:
        ep.Scene.from_dict(d)
    _assert_message(str(ei.value), REGION, ["unknown"], ["colour", "'colour'"])


def test_unknown_top_level_key():
    d = copy.deepcopy(BASE)
    d["ambiant_n"] = 1.0  # misspelt
    with pytest.raises(ValueError) as ei:
        ep.Scene.from_dict(d)
    _assert_message(str(ei.value), None, ["unknown"], ["ambiant_n", "'ambiant_n'"])


def test_nan_in_medium_from_dict():
    d = copy.deepcopy(BASE)
    d["regions"][0]["medium"]["mus"] = float("nan")
    with pytest.raises(ValueError) as ei:
        ep.Scene.from_dict(d)
    _assert_message(str(ei.value), REGION, ["medium.mus"], ["nan"])
