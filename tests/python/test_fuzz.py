"""Fuzzing SCENE.json and the CLI (issue 13): hypothesis mutates a valid scene document and
draws command-line option edges; every outcome must be a sound result (finite, energy
conserved) or a named error (ValueError / exit status 2) - never a crash, hang, traceback or
NaN. Deterministic (derandomize=True: the same cases on every run) and bounded (a fixed
number of examples, tiny runs), so it fits CI in well under 3 minutes."""
import copy
import json
import math

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import endophoton as ep
from endophoton.cli import main as cli_main
from endophoton.sources import source_from_dict
from physics_helpers import assert_energy_conserved, assert_no_nan

FUZZ = settings(
    max_examples=150, derandomize=True, deadline=None, database=None, suppress_health_check=list(HealthCheck)
)

BASE = {
    "unit": "cm",
    "ambient_n": 1.0,
    "regions": [
        {
            "name": "mucosa",
            "priority": 1,
            "medium": {"mua": 1.0, "mus": 50.0, "g": 0.9, "n": 1.4},
            "box": {"min": [-1, -1, -0.2], "max": [1, 1, 0]},
        },
        {
            "name": "polyp",
            "priority": 2,
            "medium": {"mua": 2.0, "mus": 30.0, "g": 0.8, "n": 1.37},
            "mesh": {
                "vertices": [
                    [-0.2, -0.2, -0.1],
                    [0.2, -0.2, -0.1],
                    [-0.2, 0.2, -0.1],
                    [0.2, 0.2, -0.1],
                    [-0.2, -0.2, 0.1],
                    [0.2, -0.2, 0.1],
                    [-0.2, 0.2, 0.1],
                    [0.2, 0.2, 0.1],
                ],
                "triangles": [
                    [0, 2, 3],
                    [0, 3, 1],
                    [4, 5, 7],
                    [4, 7, 6],
                    [0, 1, 5],
                    [0, 5, 4],
                    [2, 6, 7],
                    [2, 7, 3],
                    [0, 4, 6],
                    [0, 6, 2],
                    [1, 3, 7],
                    [1, 7, 5],
                ],
            },
            "fluorophores": [{"name": "photofrin", "d": 0.1, "c": 0.5}],
        },
    ],
    "source": {"type": "pencil", "position": [0.01, 0.02, 1.0], "direction": [0, 0, -1]},
    "run": {"photons": 64, "seed": 1},
}

# Values that broke the engine or the loader in the hostile-user trial, plus their neighbours.
EDGE_VALUES = [
    None,
    True,
    False,
    0,
    -1,
    1,
    2**31,
    2**32 + 1,
    2**63,
    2**64,
    -(2**64),
    10**30,
    0.5,
    -0.5,
    1e-300,
    1e19,
    1e30,
    1e155,
    1e308,
    -1e308,
    math.inf,
    -math.inf,
    math.nan,
    "",
    "abc",
    "1",
    "\ud800",
    [],
    [1],
    [1, 2],
    [0, 0, 0],
    [1e19, 0, 0],
    {},
    {"x": 1},
]


def _paths(node, prefix=()):
    """Every path (tuple of keys / indices) into a JSON document, the root excluded."""
    out = []
    items = node.items() if isinstance(node, dict) else enumerate(node) if isinstance(node, list) else ()
    for k, v in items:
        out.append(prefix + (k,))
        out.extend(_paths(v, prefix + (k,)))
    return out


ALL_PATHS = _paths(BASE)


def _get(doc, path):
    node = doc
    for k in path:
        node = node[k]
    return node


#: Paths to numbers: scaling them gives valid but extreme scenes, which exercise the engine.
NUMBER_PATHS = [p for p in ALL_PATHS if type(_get(BASE, p)) in (int, float)]
FACTORS = [0, 1e-9, 1e-3, 0.5, 2, 10, 1e3, 1e6, 1e9, -1]


def _set(doc, path, value):
    node = doc
    for k in path[:-1]:
        node = node[k]
    node[path[-1]] = value


def _delete(doc, path):
    node = doc
    for k in path[:-1]:
        node = node[k]
    del node[path[-1]]


@st.composite
def mutated_documents(draw):
    doc = copy.deepcopy(BASE)
    for _ in range(draw(st.integers(1, 2))):
        kind = draw(st.sampled_from(["scale", "scale", "scale", "edge", "number", "delete", "unknown_key"]))
        path = draw(st.sampled_from(NUMBER_PATHS if kind == "scale" else ALL_PATHS))
        try:
            if kind == "scale":
                v = _get(doc, path)
                if type(v) in (int, float):
                    w = v * draw(st.sampled_from(FACTORS))
                    _set(doc, path, int(w) if type(v) is int and abs(w) < 2**63 else w)
            elif kind == "edge":
                _set(doc, path, copy.deepcopy(draw(st.sampled_from(EDGE_VALUES))))
            elif kind == "number":
                _set(
                    doc,
                    path,
                    draw(st.one_of(st.integers(-(2**70), 2**70), st.floats(allow_nan=True, allow_infinity=True))),
                )
            elif kind == "delete":
                _delete(doc, path)
            else:
                _set(doc, path[:-1] + ("bogus_key",), 1)
        except (KeyError, IndexError, TypeError):
            pass  # an earlier mutation removed or replaced the parent: keep the document as is
    return doc


def _sound(res):
    assert_no_nan(res)
    if res.photons:
        assert_energy_conserved(res)
    json.dumps(res.to_dict(), allow_nan=False)


@pytest.mark.slow
@FUZZ
@given(mutated_documents())
def test_mutated_scene_documents_give_a_sound_result_or_a_named_error(doc):
    try:
        scene = ep.Scene.from_dict(doc)
        source = source_from_dict(doc.get("source"))
        kw = {k: v for k, v in doc.get("run", {}).items() if k != "photons"} if isinstance(doc.get("run"), dict) else {}
        res = ep.run(scene, source, photons=64, threads=2, **kw)
    except ValueError as e:
        msg = str(e)
        assert msg and "Traceback" not in msg
        assert " = " in msg or ":" in msg, f"error does not name a field: {msg}"
        return
    _sound(res)


def _cli_outcome(argv, capsys):
    """(exit code, stdout, stderr) of the command line on ``argv`` (argparse's own refusals included);
    never a traceback."""
    try:
        code = cli_main(argv)
    except SystemExit as e:  # argparse: a bad option value
        code = e.code
    out, err = capsys.readouterr()
    assert "Traceback" not in err
    return code, out, err


CLI_OPTIONS = ["--photons", "--seed", "--threads", "--time-budget", "--target-rel-error", "--max-photons"]
CLI_VALUES = [
    "0",
    "1",
    "-1",
    "64",
    "2147483648",
    "18446744073709551615",
    "18446744073709551616",
    "4611686018427387905",
    "nan",
    "inf",
    "-inf",
    "1e309",
    "abc",
    "",
    " 5",
    "1.5",
    "0x10",
    "1e3",
    "0.5",
]


@pytest.mark.slow
@FUZZ
@given(st.lists(st.tuples(st.sampled_from(CLI_OPTIONS), st.sampled_from(CLI_VALUES)), min_size=1, max_size=3))
def test_cli_option_edges_give_json_or_exit_2(tmp_path_factory, capsys, options):
    path = tmp_path_factory.mktemp("fuzz") / "scene.json"
    path.write_text(json.dumps(BASE))
    argv = ["run", str(path)]
    for opt, val in options:
        if opt == "--photons" and val not in ("0", "-1") and val.strip().isdigit() and int(val) > 64:
            val = "64"  # keep valid runs tiny; the huge values are covered by the named cases below
        argv += [opt, val]
    code, out, err = _cli_outcome(argv, capsys)
    assert code in (0, 2), (argv, code, err)
    if code == 0:
        data = json.loads(out)
        for k, v in data.items():
            if isinstance(v, float):
                assert math.isfinite(v), (k, v)
    else:
        assert "error" in err, err


@pytest.mark.parametrize("value", ["18446744073709551615", "18446744073709551616", "4611686018427387905"])
def test_cli_huge_photon_counts_are_named_errors(tmp_path, capsys, value):
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(BASE))
    with pytest.raises(SystemExit) as ei:
        cli_main(["run", str(path), "--photons", value])
    assert ei.value.code == 2 and "argument --photons" in capsys.readouterr().err


# ---------------------------------------------------------------- issue 38: the second pass's classes
def _fuzz(n):
    """Deterministic settings with ``n`` examples (each class below is bounded by its count)."""
    return settings(
        max_examples=n, derandomize=True, deadline=None, database=None, suppress_health_check=list(HealthCheck)
    )


CALLBACK_VALUES = [None, True, False, 0, 1, 1.0, "", "continue", [], [1], {}, object(), b"x", 2**70]


@_fuzz(12)
@given(st.sampled_from(CALLBACK_VALUES))
def test_progress_callback_return_values_give_a_result_or_a_named_type_error(value):
    """The first tick answers ``value``, the next stops the run: None/True/False give a result (cancelled),
    anything else a TypeError naming the callback (it used to abort the process on a string)."""
    import numpy as np

    calls = []

    def progress(done, total):
        calls.append(done)
        return value if len(calls) == 1 else False

    scene = ep.Scene.from_dict(BASE)
    source = source_from_dict(BASE["source"])
    try:
        res = ep.run(scene, source, photons=2**40, threads=1, record_escapes=False, progress=progress)
    except TypeError as e:
        assert not isinstance(value, (bool, type(None), np.bool_)), value
        assert str(e).startswith("progress returned"), e
        return
    assert isinstance(value, (bool, type(None))) and res.cancelled
    _sound(res)


def _special(tmp, kind):
    """A path of ``kind`` at ``tmp/x``: a FIFO, a folder, or a symlink to a FIFO."""
    import os

    p = tmp / "x"
    if kind == "fifo":
        os.mkfifo(p)
    elif kind == "dir":
        p.mkdir()
    else:
        os.mkfifo(tmp / "fifo")
        os.symlink(tmp / "fifo", p)
    return p


@_fuzz(15)
@given(st.sampled_from(["fifo", "dir", "link_to_fifo"]), st.sampled_from(["scene", "mesh", "eem"]))
def test_special_files_are_refused_by_name_without_blocking(tmp_path_factory, capsys, kind, where):
    import os

    tmp = tmp_path_factory.mktemp("special")
    path = _special(tmp, kind)
    doc = copy.deepcopy(BASE)
    if where == "mesh":
        os.rename(path, tmp / "m.obj")
        doc["regions"][1]["mesh"], path = "m.obj", tmp / "m.obj"
    elif where == "eem":
        os.rename(path, tmp / "e.csv")
        doc["regions"][1]["fluorophores"][0]["eem"], path = "e.csv", tmp / "e.csv"
    scene = tmp / "scene.json" if where != "scene" else path
    if where != "scene":
        scene.write_text(json.dumps(doc))
    assert cli_main(["run", str(scene), "--photons", "10"]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and os.path.basename(path) in err, err


@pytest.mark.slow
@_fuzz(8)
@given(st.sampled_from(["scene file", "mesh", "eem file"]), st.sampled_from([1, 2**31]))
def test_huge_files_are_refused_by_size_before_reading(tmp_path_factory, capsys, kind, beyond):
    """Sparse files a byte beyond their kind's limit, and of 2 GB: a named refusal, never a MemoryError."""
    from endophoton.io import MAX_INPUT_BYTES

    tmp = tmp_path_factory.mktemp("huge")
    size = MAX_INPUT_BYTES[kind] + 1 if beyond == 1 else beyond
    name = {"scene file": "scene.json", "mesh": "m.ply", "eem file": "e.csv"}[kind]
    with open(tmp / name, "wb") as fh:
        fh.truncate(size)
    doc = copy.deepcopy(BASE)
    if kind == "mesh":
        doc["regions"][1]["mesh"] = name
    elif kind == "eem file":
        doc["regions"][1]["fluorophores"][0]["eem"] = name
    scene = tmp / "scene.json"
    if kind != "scene file":
        scene.write_text(json.dumps(doc))
    assert cli_main(["run", str(scene), "--photons", "10"]) == 2
    err = capsys.readouterr().err
    assert f"{size:,} bytes, more than the {MAX_INPUT_BYTES[kind]:,}" in err, err


def _dumps_twice(node, path, value):
    """JSON text of ``node`` in which the object at ``path`` holds its first key twice (the copy first,
    with ``value``)."""
    if isinstance(node, dict):
        parts = [f"{json.dumps(k)}: {_dumps_twice(v, path[1:] if path and path[0] == k else None, value)}"
                 for k, v in node.items()]  # fmt: skip
        if path is not None and len(path) == 0 and node:
            parts.insert(0, f"{json.dumps(next(iter(node)))}: {json.dumps(value)}")
        return "{" + ", ".join(parts) + "}"
    if isinstance(node, list):
        return "[" + ", ".join(_dumps_twice(v, path[1:] if path and path[0] == i else None, value)
                               for i, v in enumerate(node)) + "]"  # fmt: skip
    return json.dumps(node)


OBJECT_PATHS = [()] + [p for p in ALL_PATHS if isinstance(_get(BASE, p), dict) and _get(BASE, p)]


@_fuzz(25)
@given(st.sampled_from(OBJECT_PATHS), st.sampled_from([0, 1, -1, 0.5, "x", None, [], {}]))
def test_duplicate_keys_anywhere_are_refused_naming_the_key(tmp_path_factory, capsys, path, value):
    tmp = tmp_path_factory.mktemp("dup")
    (tmp / "scene.json").write_text(_dumps_twice(BASE, path, value))
    assert cli_main(["run", str(tmp / "scene.json"), "--photons", "10"]) == 2
    key = next(iter(_get(BASE, path)))
    assert f"key {key!r} appears twice in one object" in capsys.readouterr().err


@_fuzz(40)
@given(
    st.lists(st.tuples(st.integers(-3, 3), st.integers(1, 3)), min_size=3, max_size=3),
    st.lists(st.tuples(st.integers(-3, 3), st.integers(1, 3)), min_size=3, max_size=3),
    st.sampled_from([(0, 0), (0, 1), (2, 2)]),
)
def test_overlapping_boxes_of_equal_priority_are_refused_exactly_when_they_share_volume(a, b, priorities):
    """The oracle is independent of the mesh test: two boxes share volume iff their intervals
    overlap with positive length on all three axes."""
    boxes = [([lo for lo, _ in box], [lo + w for lo, w in box]) for box in (a, b)]
    scene = ep.Scene("cm")
    for (lo, hi), name, p in zip(boxes, ("A", "B"), priorities):
        scene.add_box(name, lo, hi, ep.Medium(mua=1.0, mus=10.0), priority=p)
    share = all(max(boxes[0][0][k], boxes[1][0][k]) < min(boxes[0][1][k], boxes[1][1][k]) for k in range(3))
    refused = priorities[0] == priorities[1] and share
    try:
        scene.to_native()
    except ValueError as e:
        assert refused and "regions 'A' and 'B' overlap with the same priority" in str(e), e
        return
    assert not refused


RENDER_SIZES = ["0", "-1", "1", "2", "7", "8192", "8193", "100000", "1.5", "abc", ""]


@pytest.mark.slow
@_fuzz(20)
@given(
    st.sampled_from(["--width", "--height"]), st.sampled_from(RENDER_SIZES), st.sampled_from([None, "mucosa", "nope"])
)
def test_render_cli_sizes_and_targets_give_json_or_exit_2_before_the_run(
    tmp_path_factory, capsys, option, size, target
):
    """Render sizes beyond [1, 8192], sizes beyond the memory budget (view.budget) and unknown --target
    regions are refused before the run (exit 2); other sizes that would cost more than a tiny render are
    not run here. Valid tiny ones give JSON."""
    tmp = tmp_path_factory.mktemp("render")
    doc = dict(
        copy.deepcopy(BASE), camera={"position": [0, 0, 1], "look_at": [0, 0, 0], "up": [0, 1, 0], "fov_deg": 40}
    )
    (tmp / "scene.json").write_text(json.dumps(doc))
    argv = ["render", str(tmp / "scene.json"), "--out", str(tmp / "o"), "--photons", "200", option, size]
    if target is not None:
        argv += ["--target", target, "--background", "polyp"]
    valid = size.lstrip("-").isdigit() and 1 <= int(size) <= 8192 and target != "nope"
    if valid and int(size) == 8192:  # 8192 x 128: beyond the 4 GiB budget (view.budget)
        code, out, err = _cli_outcome(argv, capsys)
        assert code == 2 and "more than the memory budget" in err, (argv, code, err)
        return
    if valid and int(size) > 16:
        return  # a larger render within the budget: a run this test need not pay for
    code, out, err = _cli_outcome(argv, capsys)
    if valid:
        assert code in (0, 2), err  # 2: e.g. the camera sees no pixel of the target
        if code == 0:
            json.loads(out)
    else:
        assert code == 2, (argv, code, err)


SWEEP_OPTIONS = ["--betas", "--store", "--seed", "--threads", "--batches", "--distance", "--view-size"]
SWEEP_VALUES = ["0", "1", "-1", "5", "0,10", "0:20:10", "nan", "inf", "1e309", "abc", "", "2147483648", "0.5"]


@pytest.mark.slow
@_fuzz(15)
@given(st.lists(st.tuples(st.sampled_from(SWEEP_OPTIONS), st.sampled_from(SWEEP_VALUES)), min_size=1, max_size=2))
def test_sweep_cli_option_edges_give_outputs_or_exit_2(tmp_path_factory, capsys, options):
    """The sweep CLI's options at their edges: outputs and exit 0, or exit 2 naming the option; never a
    traceback. Stores are kept tiny (the store's own edges: a named error before any run)."""
    tmp = tmp_path_factory.mktemp("sweep")
    argv = ["sweep", "--no-progress", "--all-photons", "--threads", "1", "--out", str(tmp / "o"), "--betas", "0"]
    argv += ["--store", "200", "--batches", "10"]
    for opt, val in options:
        if opt == "--store" and val.isdigit() and int(val) > 200:
            val = "200"
        argv += [opt, val]
    code, out, err = _cli_outcome(argv, capsys)
    assert code in (0, 2), (argv, code, err)
    if code == 0:
        assert (tmp / "o" / "sweep.csv").exists()
    else:
        assert "error" in err, err


@pytest.mark.slow
@_fuzz(3)
@given(st.integers(0, 1))
def test_ctrl_c_in_a_sweep_at_any_angle_keeps_the_finished_ones(tmp_path_factory, monkeypatch, at):
    """SIGINT after angle ``at`` of three: exit 130, the angles up to it written, marked cancelled."""
    import signal

    from endophoton.sweep import driver

    accept = driver._Rows.accept

    def accept_then_interrupt(self, i, one):
        ok = accept(self, i, one)
        if i == at:
            signal.raise_signal(signal.SIGINT)
        return ok

    with monkeypatch.context() as m:
        m.setattr(driver._Rows, "accept", accept_then_interrupt)
        tmp = tmp_path_factory.mktemp("ctrlc")
        argv = ["sweep", "--betas", "0,10,20", "--store", "200", "--batches", "10", "--all-photons", "--threads", "1"]
        assert cli_main(argv + ["--no-progress", "--out", str(tmp)]) == 130
    data = json.loads((tmp / "sweep.json").read_text())
    assert data["meta"]["cancelled"] is True and [r["beta_deg"] for r in data["rows"]] == [0.0, 10.0][: at + 1]
