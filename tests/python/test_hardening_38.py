"""Regression corpus of issue 38 (hardening, second pass): one case per class the second hostile-user
trial found. Contract as in test_hardening.py: a sound result or an error naming the field (or the
callback, the file) and the value; never an abort, a hang, a MemoryError or a traceback. No verdict
depends on timing: runs that would take long are requests that never end, stopped by the error."""
import os

import numpy as np
import pytest

import endophoton as ep
from endophoton import callbacks
from test_hardening import _subprocess  # noqa: E402  (one helper for subprocess cases)

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))
TISSUE = ep.Medium(mua=1.0, mus=10.0, g=0.9, n=1.4)
DOWN = ep.PencilSource((0, 0, 1), (0, 0, -1))
NEVER_ENDS = 2**40


def slab(thickness=0.02):
    s = ep.Scene("cm")
    s.add_box("slab", (-1, -1, -thickness), (1, 1, 0), TISSUE)
    return s


# ---------------------------------------------------------------- callbacks: no abort, a named TypeError
def test_progress_returning_a_string_is_a_named_type_error_not_an_abort():
    """Before: ``progress=lambda d, t: "continue"`` ended the process with SIGABRT (the binding cast the
    value to bool on the engine's watcher). Through ep.run and straight through the binding."""
    proc = _subprocess(
        """
        import endophoton as ep
        from endophoton import _core
        s = ep.Scene("cm"); s.add_box("slab", (-1, -1, -0.02), (1, 1, 0), ep.Medium(mua=1, mus=10, g=0.9, n=1.4))
        src = ep.PencilSource((0, 0, 1), (0, 0, -1))
        try:
            ep.run(s, src, photons=2**40, progress=lambda d, t: "continue", threads=1, record_escapes=False)
        except TypeError as e:
            print("API", e)
        native = s.to_native()
        source = _core.Source(src.native_lights(1.0), body=src.native_body(1.0))
        try:
            _core.run(native, source, _core.RunConfig(photons=2**40, threads=1), lambda d, t: [1])
        except TypeError as e:
            print("BINDING", e)
        """
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "API progress returned str 'continue'" in proc.stdout
    assert "BINDING progress returned list" in proc.stdout


@pytest.mark.parametrize("value,goes_on", [(None, True), (True, True), (False, False), (np.bool_(False), False)])
def test_progress_verdict_accepts_none_and_bools(value, goes_on):
    assert callbacks.progress_verdict("progress", value) is goes_on


@pytest.mark.parametrize("value", ["continue", 1, 0, 1.0, [], object()])
def test_progress_verdict_refuses_other_values_naming_the_callback(value):
    with pytest.raises(TypeError, match=r"^progress returned"):
        callbacks.progress_verdict("progress", value)


def test_progress_returning_false_still_stops_the_run():
    res = ep.run(slab(), DOWN, photons=NEVER_ENDS, threads=1, record_escapes=False, progress=lambda d, t: False)
    assert res.cancelled and res.photons < NEVER_ENDS


@pytest.mark.slow
def test_sweep_callbacks_are_checked_by_name(tmp_path):
    """The sweep's progress(i, n, done, total) answers like ep.run's; on_run/on_beta are told and
    answer nothing: their value is ignored, but False (read as "stop") is a TypeError naming them."""
    kw = dict(betas=[0.0], store=200, n_batches=10, threads=1, plots=False, report=False)
    with pytest.raises(TypeError, match=r"^on_run returned bool False"):
        ep.sweep(progress=False, on_run=lambda i, b, r: False, **kw)
    with pytest.raises(TypeError, match=r"^on_beta returned bool_ True"):
        ep.sweep(progress=False, on_beta=lambda i, n, row: np.bool_(True), **kw)
    kept = {}
    ep.sweep(progress=False, on_run=lambda i, b, r: kept.setdefault(i, r), **kw)  # a value: ignored
    assert list(kept) == [0]
    with pytest.raises(TypeError, match=r"^progress returned str"):
        ep.sweep(progress=lambda i, n, d, t: "go", **dict(kw, store=2**40))


# ---------------------------------------------------------------- special and huge files
FLAT_SCENE = {
    "unit": "cm",
    "ambient_n": 1.0,
    "regions": [{"name": "slab", "box": {"min": [-1, -1, -0.1], "max": [1, 1, 0]}, "medium": {"mua": 1, "mus": 10}}],
    "source": {"type": "pencil", "position": [0, 0, 1], "direction": [0, 0, -1]},
}


def _cli(argv):
    from endophoton.cli import main

    return main(argv)


@pytest.mark.parametrize("command", ["run", "render"])
def test_scene_fifo_is_refused_without_blocking(tmp_path, capsys, command):
    """Before: ``run``/``render`` opened a FIFO scene and waited forever for a writer."""
    fifo = tmp_path / "scene.json"
    os.mkfifo(fifo)
    argv = [command, str(fifo)] + (["--out", str(tmp_path / "o")] if command == "render" else [])
    assert _cli(argv) == 2
    assert f"scene file {str(fifo)!r} is not a regular file" in capsys.readouterr().err


def test_mesh_and_eem_fifos_are_refused_without_blocking(tmp_path):
    for name in ("m.obj", "e.csv"):
        os.mkfifo(tmp_path / name)
    with pytest.raises(ValueError, match="not a regular file"):
        ep.EEM.from_csv(tmp_path / "e.csv")
    with pytest.raises(ValueError, match="not a regular file"):
        region = {k: v for k, v in FLAT_SCENE["regions"][0].items() if k != "box"}
        ep.Scene.from_dict(dict(FLAT_SCENE, regions=[dict(region, mesh="m.obj")]), base_dir=str(tmp_path))


def _sparse(path, size=2 * 2**30):
    with open(path, "wb") as fh:
        fh.truncate(size)
    return path


@pytest.mark.parametrize("name", ["scene.json", "m.obj", "m.ply", "e.csv", "sweep.json"])
def test_huge_input_files_are_refused_by_name_before_reading(tmp_path, name):
    """Before: a 2 GB sparse scene.json, .obj or .ply ended in a MemoryError traceback after 14-33 s.
    Now each kind has a size limit (endophoton.io.MAX_INPUT_BYTES) checked before a byte is read."""
    from endophoton.io import MAX_INPUT_BYTES
    from endophoton.sweep.schema import SweepResult

    path = str(_sparse(tmp_path / name))
    kind, read = {
        "scene.json": ("scene file", lambda: ep.Scene.from_json(path)),
        "m.obj": ("mesh", lambda: ep.load_mesh(path)),
        "m.ply": ("mesh", lambda: ep.load_mesh(path)),
        "e.csv": ("eem file", lambda: ep.EEM.from_csv(path)),
        "sweep.json": ("sweep file", lambda: SweepResult.from_json(path)),
    }[name]
    with pytest.raises(ValueError) as ei:
        read()
    msg = str(ei.value)
    assert repr(path) in msg and f"more than the {MAX_INPUT_BYTES[kind]:,} bytes" in msg, msg


def test_huge_scene_file_at_the_cli_is_exit_2(tmp_path, capsys):
    path = str(_sparse(tmp_path / "scene.json"))
    assert _cli(["run", path]) == 2
    assert "more than the" in capsys.readouterr().err


def test_input_limits_are_in_numerics_doc():
    from endophoton.io import MAX_INPUT_BYTES

    text = open(os.path.join(ROOT, "docs", "numerics.md"), encoding="utf-8").read()
    for kind, limit in MAX_INPUT_BYTES.items():
        assert f"{kind} | {limit // 2**20} MiB" in text, kind


# ---------------------------------------------------------------- strict JSON: duplicate keys, long integers
def _write_json_text(tmp_path, text, name="scene.json"):
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return str(p)


def test_duplicate_keys_are_refused_naming_the_key_and_file(tmp_path, capsys):
    """Before: ``"mua": 10, "mua": 0`` ran with mua = 0 (the last key won)."""
    text = (
        '{"unit": "cm", "ambient_n": 1, "regions": [{"name": "slab", "box": {"min": [-1, -1, -1], "max": [1, 1, 0]},'
        ' "medium": {"mua": 10, "mus": 10, "mua": 0}}], "source": {"type": "pencil", "position": [0, 0, 1],'
        ' "direction": [0, 0, -1]}}'
    )
    path = _write_json_text(tmp_path, text)
    assert _cli(["run", path, "--photons", "10"]) == 2
    err = capsys.readouterr().err
    assert f"scene file {path!r}: key 'mua' appears twice in one object" in err, err
    with pytest.raises(ValueError, match="key 'mua' appears twice"):
        ep.Scene.from_json(path)


def test_a_5000_digit_integer_names_the_field_and_the_file(tmp_path, capsys):
    text = (
        '{"unit": "cm", "ambient_n": 1, "regions": [{"name": "slab", "box": {"min": [-1, -1, -1], "max": [1, 1, 0]},'
        ' "medium": {"mua": ' + "7" * 5000 + ', "mus": 10}}], "source": {"type": "pencil", "position": [0, 0, 1],'
        ' "direction": [0, 0, -1]}}'
    )
    path = _write_json_text(tmp_path, text)
    assert _cli(["run", path, "--photons", "10"]) == 2
    err = capsys.readouterr().err
    assert f"scene file {path!r}: regions[0].medium.mua is an integer of 5,000 digits" in err, err


# ---------------------------------------------------------------- one rule per input: schema and loader
def _schema_defaults():
    """(definition, field, default) of every field the schema gives a default, read from the schema file."""
    import json

    doc = json.load(open(os.path.join(ROOT, "docs", "scene.schema.json"), encoding="utf-8"))
    out = [("scene", k, v["default"]) for k, v in doc["properties"].items() if "default" in v]
    for name, d in doc["definitions"].items():
        out += [(name, k, v["default"]) for k, v in d.get("properties", {}).items() if "default" in v]
    return out


def test_every_schema_default_is_the_loaders_value_for_an_omitted_field():
    """Before: the schema gave unit and ambient_n defaults, and the loader refused a scene without them."""
    defaults = _schema_defaults()
    assert {(d, f) for d, f, _ in defaults} >= {("scene", "unit"), ("scene", "ambient_n"), ("region", "priority")}
    region = {"name": "slab", "box": {"min": [-1, -1, -1], "max": [1, 1, 0]}, "medium": {"mua": 1, "mus": 10}}
    scene = ep.Scene.from_dict({"regions": [region]})  # nothing but what the schema requires
    got = {
        ("scene", "unit"): scene.unit,
        ("scene", "ambient_n"): scene.ambient_n,
        ("region", "priority"): scene.regions[0].priority,
        ("medium_values", "g"): scene.regions[0].medium.g,
        ("medium_values", "n"): scene.regions[0].medium.n,
    }
    for definition, field, value in defaults:
        assert (definition, field) in got, f"schema default of {definition}.{field} has no loader check here"
        assert got[(definition, field)] == value, (definition, field)


def test_scene_file_with_only_the_required_keys_runs(tmp_path, capsys):
    import json

    doc = {k: v for k, v in FLAT_SCENE.items() if k not in ("unit", "ambient_n")}
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(doc))
    assert _cli(["run", str(path), "--photons", "100"]) == 0
    assert json.loads(capsys.readouterr().out)["unit"] == "cm"


@pytest.mark.parametrize("scale", [1e-13, 1e-300])
def test_tiny_nonzero_direction_is_accepted_as_the_schema_says(scale):
    """The schema's "direction": any non-zero length. Before: an up vector of length 1e-13 was refused."""
    cam = ep.Camera.look_at((0, 0, 5), (0, 0, 0), up=(0, scale, 0))
    assert np.allclose(cam.up, (0, 1, 0))
    src = ep.PencilSource((0, 0, 1), (0, 0, -scale))
    assert np.allclose(src.native_lights(1.0)[0]["direction"], (0, 0, -1))
    with pytest.raises(ValueError, match="has zero length"):
        ep.PencilSource((0, 0, 1), (0, 0, 0))


# ---------------------------------------------------------------- scheduler addresses and local:N memory
@pytest.mark.parametrize(
    "address,text",
    [
        ("tls://127.0.0.1:8786", "tls:// needs TLS certificates"),
        ("inproc://10.0.0.1/1/2", "inproc:// names a scheduler inside this process"),
        ("garbage", "must be tcp://host:port or local:N"),
        ("tcp://", "must be tcp://host:port or local:N"),
        ("udp://h:1", "must be tcp://host:port or local:N"),
        ("", "must be tcp://host:port or local:N"),
    ],
)
def test_every_scheduler_scheme_is_accepted_or_refused_by_name(address, text):
    """Before: ``--scheduler tls://...`` ended in a TypeError traceback (Client without a Security)."""
    from endophoton import distributed

    with pytest.raises(ValueError, match="^scheduler = ") as ei:
        distributed.check_address(address)
    assert text in str(ei.value)


def test_scheduler_tls_at_the_cli_is_exit_2(tmp_path, capsys):
    import json

    path = tmp_path / "scene.json"
    path.write_text(json.dumps(FLAT_SCENE))
    assert _cli(["run", str(path), "--photons", "10", "--scheduler", "tls://127.0.0.1:8786"]) == 2
    assert "scheduler = 'tls://127.0.0.1:8786': tls:// needs TLS certificates" in capsys.readouterr().err


def test_local_workers_are_checked_against_the_memory_before_starting():
    """Before: local:256 started 256 processes of ~100 MB each with no memory check."""
    from endophoton import distributed

    assert distributed.check_address("tcp://127.0.0.1:8786") is None
    each = distributed.LOCAL_WORKER_BYTES
    distributed.check_local_memory("local:4", 4, available=8 * each)  # fits in 3/4 of it
    with pytest.raises(ValueError, match=r"scheduler = 'local:7': 7 local worker processes need about .* give local:6"):
        distributed.check_local_memory("local:7", 7, available=8 * each)


# ---------------------------------------------------------------- Ctrl-C in a sweep keeps the finished work
def _interrupt_after_first_angle(monkeypatch):
    """SIGINT raised in this process as soon as the first angle's row is accepted (deterministic: the
    handler runs before the next bytecode of the main thread)."""
    import signal

    from endophoton.sweep import driver

    accept = driver._Rows.accept

    def accept_then_interrupt(self, i, one):
        ok = accept(self, i, one)
        if i == 0:
            signal.raise_signal(signal.SIGINT)
        return ok

    monkeypatch.setattr(driver._Rows, "accept", accept_then_interrupt)


@pytest.mark.slow
def test_ctrl_c_in_a_sweep_writes_the_finished_angles_then_exits_130(tmp_path, monkeypatch):
    """Before: Ctrl-C in ``sweep`` wrote nothing, not even the angles that had finished. (With
    --scheduler the same CancelToken reaches distributed.run_many, whose cancel test_distributed
    covers; which angles have finished there when Ctrl-C lands is not deterministic.)"""
    import json

    _interrupt_after_first_angle(monkeypatch)
    out = tmp_path / "out"
    argv = ["sweep", "--betas", "0,10,20", "--store", "300", "--all-photons", "--threads", "1", "--no-progress"]
    argv += ["--out", str(out)]
    assert _cli(argv) == 130
    data = json.loads((out / "sweep.json").read_text())
    assert data["meta"]["cancelled"] is True
    rows = data["rows"]
    assert rows and rows[0]["beta_deg"] == 0.0 and rows[0]["cancelled"] == 0  # the finished angle, whole
    assert len(rows) < 3 or any(r["cancelled"] for r in rows)
    csv = (out / "sweep.csv").read_text().splitlines()
    assert len(csv) == 1 + len(rows)
    assert "cancelled" in (out / "report.md").read_text()
    assert (out / "polar_beta_00.png").stat().st_size > 0  # the finished angle's images
    assert not list(out.glob(".*.tmp"))  # every file written atomically: no temporary left


# ---------------------------------------------------------------- unreachable targets
def test_unreachable_target_stops_early_with_a_named_warning():
    """Before: a target of 1e-12 without max_photons ran toward 2^62 packets without a word (the time
    budget here only bounds the test on the old code). Now the packets it needs are projected after
    the first units and the run stops as "target_unreachable", naming them and the default cap."""
    from endophoton.run import DEFAULT_TARGET_MAX_PHOTONS

    r = ep.run(slab(), DOWN, target=ep.Target("diffuse_reflectance", 1e-12), threads=1, time_budget_s=120.0)
    assert r.stop_reason == "target_unreachable" and not r.target_reached
    assert 0 < r.photons < DEFAULT_TARGET_MAX_PHOTONS
    (w,) = [w for w in r.warnings if w.startswith("target not reached")]
    assert "would need about" in w and f"the default cap of {DEFAULT_TARGET_MAX_PHOTONS}" in w, w


def test_a_cap_the_user_gives_is_run_to_and_named():
    r = ep.run(slab(), DOWN, target=ep.Target("diffuse_reflectance", 1e-12), max_photons=30_000, threads=1)
    assert r.stop_reason == "max_photons" and r.photons == 30_000
    assert any(w.startswith("target not reached") and "max_photons = 30000" in w for w in r.warnings)


# ---------------------------------------------------------------- per-region tallies carry standard errors
def two_layers():
    s = ep.Scene("cm")
    s.add_box("top", (-1, -1, -0.05), (1, 1, 0), TISSUE)
    s.add_box("deep", (-1, -1, -0.3), (1, 1, -0.05), ep.Medium(mua=2.0, mus=20.0, g=0.8, n=1.4))
    return s


@pytest.mark.slow
def test_absorbed_by_region_stderr_matches_the_spread_of_independent_seeds():
    """The reported batch-means stderr of each region's absorbed fraction against the spread of K
    independent seeds' estimates (numpy, no engine error bar involved): (K-1) s^2 / mean(se^2) is
    chi-square with K-1 degrees of freedom; two-sided at the family-wise 1e-4 level."""
    from scipy import stats

    K = 16
    runs = [ep.run(two_layers(), DOWN, photons=20_000, seed=s, threads=1, record_escapes=False) for s in range(K)]
    for name in ("top", "deep"):
        v = np.array([r.absorbed_by_region[name] for r in runs])
        se = np.array([r.absorbed_by_region_stderr[name] for r in runs])
        assert np.all(se > 0)
        chi2 = (K - 1) * v.var(ddof=1) / np.mean(se**2)
        lo, hi = stats.chi2.ppf([0.5e-4 / 2, 1 - 0.5e-4 / 2], K - 1)
        assert lo < chi2 < hi, (name, chi2, lo, hi)


@pytest.mark.slow
def test_sweep_rows_and_csv_carry_the_per_region_tallies_with_stderr(tmp_path):
    """Before: the sweep CSV had no per-region tally at all (eight runs for an error bar)."""
    import csv

    from endophoton.sweep.schema import REGION_COLUMN

    seen = []
    res = ep.sweep(
        betas=[0.0], store=300, n_batches=10, threads=1, plots=False, report=False, progress=False,
        fluorescent_only=False, out_dir=str(tmp_path), on_run=lambda i, b, r: seen.append(r) and None,
    )  # fmt: skip
    (run,) = seen
    with open(tmp_path / "sweep.csv", newline="", encoding="utf-8") as fh:
        (row,) = list(csv.DictReader(fh))
    assert run.absorbed_by_region
    for name, value in run.absorbed_by_region.items():
        assert float(row[REGION_COLUMN + name]) == value == res.rows[0][REGION_COLUMN + name]
        assert float(row[REGION_COLUMN + name + "_stderr"]) == run.absorbed_by_region_stderr[name] > 0


# ---------------------------------------------------------------- small ones
CAMERA = {"position": [0, 0, 1], "look_at": [0, 0, 0], "up": [0, 1, 0], "fov_deg": 40}


@pytest.mark.parametrize("kind", ["fifo", "symlink"])
@pytest.mark.parametrize("name", ["view.npz", "white.png"])
def test_render_refuses_a_fifo_or_symlink_at_an_output_before_the_run(tmp_path, capsys, kind, name):
    """Before: ``render`` replaced a FIFO or a symlink at view.npz/white.png (the grid writer refuses
    them); now io.check_output_files, the one check of every writer, has the grid writer's rule."""
    import json

    out = tmp_path / "out"
    out.mkdir()
    elsewhere = tmp_path / "elsewhere.txt"
    elsewhere.write_text("keep me")
    os.mkfifo(out / name) if kind == "fifo" else os.symlink(elsewhere, out / name)
    scene = tmp_path / "scene.json"
    scene.write_text(json.dumps(dict(FLAT_SCENE, camera=CAMERA)))
    assert _cli(["render", str(scene), "--out", str(out), "--photons", "100"]) == 2
    err = capsys.readouterr().err
    assert repr(str(out / name)) in err and ("symbolic link" if kind == "symlink" else "not a regular file") in err
    assert elsewhere.read_text() == "keep me" and os.path.lexists(out / name)
    assert sorted(os.listdir(out)) == [name]  # nothing written


def test_a_contrast_is_defined_only_with_its_stderr():
    """Before: red_green could be defined while its stderr was None (a batch held all of the
    background's green). The jackknife now gives a value only with its error."""
    from endophoton.view.visibility import jackknife

    sums = np.array([[1.0, 1.0, 1.0, 1.0], [0.0, 0.0, 2.0, 0.0]])  # the second row: one batch only
    value, se = jackknife(sums, np.full(4, 10.0), lambda m: m[0] / m[1] if m[1] > 0 else None)
    assert value is None and se is None
    value, se = jackknife(sums + 1.0, np.full(4, 10.0), lambda m: m[0] / m[1])
    assert value is not None and se is not None and se > 0


# ---------------------------------------------------------------- equal-priority overlaps: one rule, every path
def test_equal_priority_overlaps_are_refused_on_the_json_and_python_paths(tmp_path, capsys):
    """Before: two overlapping regions of one priority passed through JSON and the API (the later one
    won); the add-on refused them. Now endophoton.overlaps refuses them on every path (the add-on
    asks the same function)."""
    import json

    doc = dict(FLAT_SCENE)
    doc["regions"] = [
        FLAT_SCENE["regions"][0],
        {"name": "polyp", "box": {"min": [-0.2, -0.2, -0.05], "max": [0.2, 0.2, 0.05]}, "medium": {"mua": 2, "mus": 5}},
    ]
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(doc))
    assert _cli(["run", str(path), "--photons", "10"]) == 2
    assert "regions 'slab' and 'polyp' overlap with the same priority = 0" in capsys.readouterr().err
    scene = ep.Scene.from_dict(doc)
    with pytest.raises(ValueError, match="regions 'slab' and 'polyp' overlap with the same priority = 0"):
        ep.run(scene, DOWN, photons=10)
    doc["regions"][1]["priority"] = 1  # the polyp owns the overlap: accepted
    assert ep.run(ep.Scene.from_dict(doc), DOWN, photons=10, threads=1).photons == 10


def test_touching_layers_and_nested_meshes_of_distinct_priority_are_accepted():
    from endophoton.overlaps import equal_priority_overlaps

    s = ep.Scene("cm")
    s.add_box("top", (-1, -1, -0.1), (1, 1, 0), TISSUE)
    s.add_box("middle", (-1, -1, -0.2), (1, 1, -0.1), TISSUE)
    s.add_box("side", (1, -1, -0.2), (2, 1, 0), TISSUE)
    assert equal_priority_overlaps(s.regions) == []
    s.add_box("inside", (-0.5, -0.5, -0.15), (0.5, 0.5, -0.05), TISSUE)  # inside top and middle, priority 0
    assert equal_priority_overlaps(s.regions) == [("top", "inside", 0), ("middle", "inside", 0)]


def test_render_refuses_an_unknown_target_or_size_before_the_run(tmp_path, capsys):
    """Before: an unknown --target was refused after the whole run (9 s). Checked first now (the
    render CLI's own options; the render's scaling is the view branch's)."""
    import json

    scene = tmp_path / "scene.json"
    scene.write_text(json.dumps(dict(FLAT_SCENE, camera=CAMERA)))
    base = ["render", str(scene), "--out", str(tmp_path / "o"), "--photons", str(NEVER_ENDS)]
    assert _cli(base + ["--target", "nope", "--background", "slab"]) == 2
    assert "--target = 'nope' is not a region of the scene (regions: slab)" in capsys.readouterr().err
    assert _cli(base + ["--width", "8193"]) == 2
    assert "--width = 8193 must be an integer in [1, 8192] (pixels)" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


@pytest.mark.slow
def test_ctrl_c_during_an_angles_run_keeps_its_partial_row_marked_cancelled(tmp_path, monkeypatch):
    """SIGINT while the second angle's run is tracing (its store made unreachable, so only the cancel
    ends it): the first angle's whole row and the second's partial row, marked cancelled, exit 130."""
    import json
    import signal

    from endophoton.sweep import driver

    run, calls = driver.run, []

    def second_run_interrupted(scene, rig, **kw):
        calls.append(1)
        if len(calls) == 2:
            engine_progress = kw["progress"]
            kw["store"] = NEVER_ENDS

            def progress(done, total):
                signal.raise_signal(signal.SIGINT)  # the CLI's handler cancels the run's token
                return engine_progress(done, total)

            kw["progress"] = progress
        return run(scene, rig, **kw)

    monkeypatch.setattr(driver, "run", second_run_interrupted)
    out = tmp_path / "out"
    argv = ["sweep", "--betas", "0,10,20", "--store", "300", "--all-photons", "--threads", "1", "--no-progress"]
    assert _cli(argv + ["--out", str(out)]) == 130
    data = json.loads((out / "sweep.json").read_text())
    assert data["meta"]["cancelled"] is True and len(calls) == 2
    assert [(r["beta_deg"], r["cancelled"]) for r in data["rows"]] in ([(0.0, 0), (10.0, 1)], [(0.0, 0)])
    assert "cancelled" in (out / "report.md").read_text()
