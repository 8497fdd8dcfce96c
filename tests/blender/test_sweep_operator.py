# SPDX-License-Identifier: MIT
"""The Sweep β operator: the same job the modal operator runs (worker thread,
polled progress, finish on the main thread), cancelling, and bad input.

The numbers must equal those of ``endophoton.sweep`` on the same exported
scene and of ``endophoton_addon.sweep_blend`` for the same seed."""

import csv
import math
import importlib
import os
import re
import sys
import threading
import time

import bpy
import numpy as np
import pytest

from endophoton_addon import points, results, rig, sweep_blend, sweep_job
from conftest import REPO, data_snapshot, open_blend

BETAS, STORE, SEED = "0,30", 2_000, 5
LINE_PLOTS = ("packets_traced.png", "energy.png", "camera_fraction.png", "max_depth.png")


def _setup(tmp_path, betas=BETAS, store=STORE, keep_runs="OFF"):
    """flat_tissue.blend with the sweep's settings; ``keep_runs`` OFF (plots and summary only)
    unless a test is about the per-β collections (test_sweep_results.py)."""
    scene = open_blend("flat_tissue.blend", tmp_path / "grids")
    s = scene.endophoton.sweep
    s.betas, s.store, s.seed, s.threads, s.keep_runs = betas, store, SEED, 1, keep_runs
    s.visibility = False  # the energy sweep of sweep_blend (test_sweep_answer.py runs the visibility sweep)
    s.output_dir = str(tmp_path / "sweep")
    return scene


def _run_job(context):
    """Start, poll like the modal timer, finish.  Returns (job, images, progress seen).

    The progress seen holds, besides the polls, the job's progress as each β ends, taken
    in the worker just before the job counts that β as done: a β that ends between two
    polls (a fast machine) is still seen while it is the current one, so no verdict
    depends on timing."""
    job = sweep_job.prepare_job(context)
    seen, lock = [], threading.Lock()
    on_beta = job._on_beta

    def seen_on_beta(index, n, row):
        with lock:
            seen.append(job.progress())
        on_beta(index, n, row)

    job._on_beta = seen_on_beta  # read by the worker's sweep call, after start()
    job.start()
    while not job.wait(0.05):
        with lock:
            seen.append(job.progress())
    return job, sweep_job.finish_sweep(context, job), seen


def _documented_columns():
    with open(os.path.join(REPO, "docs", "sweep.md"), encoding="utf-8") as f:
        text = f.read()
    block = text.split("<!-- csv-columns:begin -->")[1].split("<!-- csv-columns:end -->")[0]
    return re.findall(r"^\| `([a-z0-9_]+)` \|", block, flags=re.M)


def _same(a, b):
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return a == b


def _assert_same_rows(got, ref):
    assert len(got.rows) == len(ref.rows)
    for row, ref_row in zip(got.rows, ref.rows):
        assert set(row) == set(ref_row)
        for key in row:
            if key != "seconds":
                assert _same(row[key], ref_row[key]), (row["beta_deg"], key, row[key], ref_row[key])
    for h, ref_h in zip(got.histograms, ref.histograms):
        for key in ("counts", "counts_fixed", "chi2_p"):
            np.testing.assert_array_equal(np.asarray(h[key]), np.asarray(ref_h[key]))


def test_sweep_job_matches_python_api(ep, tmp_path):
    scene = _setup(tmp_path)
    out = tmp_path / "sweep"
    before = data_snapshot()
    job, images, seen = _run_job(bpy.context)
    assert job.error is None and not job.cancelled, job.error_traceback

    # Progress: fraction over the whole sweep, β and position in the status text.
    assert seen and all(0.0 <= p.fraction <= 1.0 for p in seen)
    assert [p.fraction for p in seen] == sorted(p.fraction for p in seen)
    assert any(p.text().startswith("Sweep β=0° (1/2), ETA ") for p in seen)
    assert any(p.text().startswith("Sweep β=30° (2/2), ETA ") for p in seen)

    # The CSV: the documented columns, one row per β, store-N records.
    with open(out / "sweep.csv", newline="", encoding="utf-8") as f:
        reader = csv.DictReader(f)
        header, rows = reader.fieldnames, list(reader)
    fixed = list(importlib.import_module('endophoton.sweep.schema').CSV_COLUMNS)
    assert header[: len(fixed)] == _documented_columns() == fixed
    assert header[len(fixed) :] and all(h.startswith("absorbed_by_region.") for h in header[len(fixed) :])
    assert [float(r["beta_deg"]) for r in rows] == [0.0, 30.0]
    assert all(int(r["records"]) == STORE and int(r["packets_traced"]) > STORE for r in rows)
    beta_seed = importlib.import_module("endophoton.sweep.schema").beta_seed  # a seed per β by default
    assert [int(r["seed"]) for r in rows] == [beta_seed(SEED, k, True) for k in range(len(rows))]
    assert all(r["cancelled"] == "0" for r in rows)
    for name in ("sweep.json", "report.md"):
        assert (out / name).stat().st_size > 0

    # The plots, loaded as images named after their files, with pixels.
    files = sorted(p.name for p in out.glob("*.png"))
    assert files == sorted(
        [*LINE_PLOTS, "polar_beta_00.png", "polar_beta_30.png", "polar_fixed_beta_00.png", "polar_fixed_beta_30.png"]
    )
    assert sorted(img.name for img in images) == sorted(f"EndoPhoton Sweep: {f}" for f in files)
    for img in images:
        assert bpy.data.images[img.name] == img
        assert img.size[0] > 100 and img.size[1] > 100
        assert os.path.samefile(bpy.path.abspath(img.filepath), out / img.name.split(": ", 1)[1])
    after = data_snapshot()
    assert {k: v for k, v in after.items() if k != "images"} == {k: v for k, v in before.items() if k != "images"}
    assert set(after["images"]) - set(before["images"]) == {img.name for img in images}

    # Summary for the panel.
    summary = scene[sweep_job.SUMMARY_KEY].to_dict()
    packets = [int(r["packets_traced"]) for r in rows]
    assert summary["n_betas"] == 2 and summary["images"] == len(files)
    assert (summary["packets_min"], summary["packets_max"]) == (min(packets), max(packets))
    # 2 angles: no degree-6 fit; undefined is None in memory (never NaN), absent from the ID property
    assert job.summary["best_beta_energy_total"] is None and job.summary["best_beta_energy_total_se"] is None
    assert "best_beta_energy_total" not in summary and summary["fit_degree"] == 0
    assert not [k for k, v in job.summary.items() if isinstance(v, float) and not math.isfinite(v)]
    assert sweep_job.summary_rows(scene)[2][1].startswith(f"– (needs ≥ {sweep_job.min_fit_points(ep)} β values)")
    assert summary["out_dir"] == str(out)
    labels = dict(sweep_job.summary_rows(scene))
    assert labels["Packets"] == f"{min(packets):,} – {max(packets):,}"

    # Same numbers as ep.sweep on the exported scene with the rig's geometry ...
    rig_obj = scene.objects["EP Endoscope"]
    rs, scale = rig_obj.endophoton_rig, scene.unit_settings.scale_length
    ref = ep.sweep(
        job.engine_scene,
        betas=[0, 30],
        store=STORE,
        seed=SEED,
        threads=1,
        distance=rs.distance * scale,
        point=tuple(x * scale for x in rs.target),
        normal=tuple(rs.normal),
        tilt_axis=tuple(rs.tilt_axis),
        rig_kwargs=rig.rig_parameters(rig_obj, scale),
        progress=False,
    )
    _assert_same_rows(job.result, ref)
    for row, ref_row in zip(rows, ref.rows):  # ... and in the file
        assert float(row["energy_total"]) == ref_row["energy_total"]
        assert int(row["packets_traced"]) == ref_row["packets_traced"]
    # ... and as sweep_blend, which exports the scene and reads the rig itself.
    _assert_same_rows(
        job.result, sweep_blend.sweep_blend(scene, betas=[0, 30], store=STORE, seed=SEED, threads=1, progress=False)
    )

    # A second sweep into the same folder reuses the images of the same name and
    # drops those of β values it does not have.
    pointers = {img.name: img.as_pointer() for img in images}
    scene.endophoton.sweep.betas = "0"
    scene.endophoton.sweep.store = 500
    _job, images2, _seen = _run_job(bpy.context)
    names2 = sorted(img.name for img in images2)
    assert names2 == sorted(
        f"EndoPhoton Sweep: {f}" for f in (*LINE_PLOTS, "polar_beta_00.png", "polar_fixed_beta_00.png")
    )
    assert sorted(img.name for img in sweep_job.sweep_images()) == names2
    assert all(img.as_pointer() == pointers[img.name] and img.size[0] > 0 for img in images2)
    assert scene[sweep_job.SUMMARY_KEY]["n_betas"] == 1


def test_plot_images_survive_save_and_reopen(ep, tmp_path):
    """The plots are kept with the .blend (a fake user; the files stay in the output folder):
    after save and reopen they are there, pointing at the sweep's files; the next sweep
    replaces them in place, no copies pile up."""
    from conftest import ensure_addon

    _setup(tmp_path, betas="0", store=500)
    assert bpy.ops.endophoton.sweep_beta() == {"FINISHED"}
    names = sorted(img.name for img in sweep_job.sweep_images())
    assert len(names) == 6
    blend = str(tmp_path / "saved.blend")
    bpy.ops.wm.save_as_mainfile(filepath=blend)
    bpy.ops.wm.open_mainfile(filepath=blend)
    ensure_addon()
    images = sweep_job.sweep_images()
    assert sorted(img.name for img in images) == names
    for img in images:
        path = bpy.path.abspath(img.filepath)
        assert os.path.dirname(path) == str(tmp_path / "sweep") and os.path.isfile(path)
        assert img.use_fake_user and img.size[0] > 0
    assert bpy.context.scene[sweep_job.SUMMARY_KEY]["images"] == 6

    pointers = {img.name: img.as_pointer() for img in images}
    assert bpy.ops.endophoton.sweep_beta() == {"FINISHED"}
    again = sweep_job.sweep_images()
    assert {img.name: img.as_pointer() for img in again} == pointers
    assert len([img for img in bpy.data.images if img.name.startswith(sweep_job.IMAGE_PREFIX)]) == 6


def test_cancel_adds_nothing(ep, tmp_path):
    scene = _setup(tmp_path, betas="0", store=500)
    # An earlier sweep's images and summary, made by the operator's blocking path.
    assert bpy.ops.endophoton.sweep_beta() == {"FINISHED"}
    assert len(sweep_job.sweep_images()) == 6 and scene[sweep_job.SUMMARY_KEY]["n_betas"] == 1
    out = tmp_path / "sweep"
    files = {p.name: p.stat().st_mtime_ns for p in out.iterdir()}
    summary = scene[sweep_job.SUMMARY_KEY].to_dict()
    before = data_snapshot()

    s = scene.endophoton.sweep
    s.betas, s.store, s.keep_runs = "0:60:5", 2_000_000, "ON"  # records would be kept: still nothing added
    job = sweep_job.prepare_job(bpy.context)
    job.start()
    deadline = time.monotonic() + 600.0  # a hang guard, not a verdict on speed (issue 13)
    while job.progress().done == 0 and not job.done and time.monotonic() < deadline:
        time.sleep(0.02)
    assert job.progress().done > 0 and not job.done  # the engine is running
    labels = _sidebar_labels_while_running(job)
    assert labels[0].startswith("Sweep β=0° (1/12)") and "packets · ETA --" in labels[1]
    job.cancel()  # what Esc does
    assert job.wait(600.0)
    assert sweep_job.finish_sweep(bpy.context, job) is None
    assert job.cancelled and job.error is None and job.paths is None
    assert data_snapshot() == before
    assert repr(scene[sweep_job.SUMMARY_KEY].to_dict()) == repr(summary)  # nan-aware
    assert {p.name: p.stat().st_mtime_ns for p in out.iterdir()} == files


def _sidebar_labels_while_running(job):
    """The main panel's progress box while ``job`` is the running job, as the modal operator sets it."""
    from types import SimpleNamespace

    from endophoton_addon import operators
    from test_registration import FakeLayout

    saved = dict(operators._running)
    operators._running.update(job=job, modal=True)
    try:
        log = []
        bpy.types.ENDOPHOTON_PT_main.draw(SimpleNamespace(layout=FakeLayout(log)), bpy.context)
    finally:
        operators._running.clear()
        operators._running.update(saved)
    assert ("operator", "endophoton.cancel_run") in log
    return [text for kind, text in log if kind == "label" and not text.startswith("Engine")]


def _assert_rejected(pattern, out_dir, invoke=False):
    scene = bpy.context.scene
    before = data_snapshot()
    args = ("INVOKE_DEFAULT",) if invoke else ()
    with pytest.raises(RuntimeError, match=pattern):
        bpy.ops.endophoton.sweep_beta(*args)
    assert data_snapshot() == before
    assert sweep_job.SUMMARY_KEY not in scene
    assert not os.path.exists(out_dir)


@pytest.mark.parametrize(
    "field, value, pattern",
    [
        ("betas", "", r"Scene '[^']+': sweep.betas = '' is empty"),
        ("betas", "  ", r"sweep.betas = '  ' is empty"),
        ("betas", "0,90", r"sweep.betas = '0,90': β = 90° must be a finite angle in \(-90, 90\)"),
        ("betas", "-95,0", r"β = -95° must be a finite angle"),
        ("betas", "0,10,0", r"sweep.betas = '0,10,0': β = 0 is given twice"),
        # closer than the package's resolution (1e-6 degrees): these used to end Blender in LAPACK mid-sweep
        ("betas", "0,1e-200", r"sweep.betas = '0,1e-200': β = 0 and β = 1e-200 are closer than 1e-06 degrees"),
        ("betas", "0,1e-300", r"sweep.betas = '0,1e-300': β = 0 and β = 1e-300 are closer than 1e-06 degrees"),
        ("betas", "20,10,20.0000005", r"β = 20 and β = 20.0000005 are closer than 1e-06 degrees"),
        ("betas", "10:0:5", r"sweep.betas = '10:0:5' must be a list '0,10,20' or a range"),
        ("betas", "ten", r"sweep.betas = 'ten' must be a list"),
        ("betas", "0:1e9:1e-9", r"sweep.betas = '0:1e9:1e-9' must be a list .* gives 1e18 angles, more than 10000"),
        ("store", 0, r"Scene '[^']+': sweep.store = 0 must be > 0"),
        ("store", 10, r"sweep.store = 10 must be >= sweep.batches = 20"),
        ("batches", 1, r"sweep.batches = 1 must be >= 2"),
    ],
)
def test_bad_settings_rejected(ep, tmp_path, field, value, pattern):
    _setup(tmp_path)
    setattr(bpy.context.scene.endophoton.sweep, field, value)
    _assert_rejected(pattern, tmp_path / "sweep")


@pytest.mark.parametrize(
    "betas, refused", [("0,80", "80"), ("0,89.99999", "89.99999"), ("0,80,89.99999", "80, 89.99999")]
)
def test_head_entering_the_tissue_rejected_before_the_sweep_starts(ep, tmp_path, capfd, monkeypatch, betas, refused):
    """A β inside (-90, 90) whose head enters the tissue (flat_tissue.blend: from about 59°) is the
    package's placement check (endophoton.sweep.driver.check_placements), made on the main thread before the
    worker starts: the operator's error names the field and the β as typed (89.99999, not 90),
    no traceback is printed, no folder is made and the scene is untouched."""
    _setup(tmp_path, betas=betas)

    def no_start(self):
        raise AssertionError("the sweep's worker started")

    monkeypatch.setattr(sweep_job.SweepJob, "start", no_start)
    capfd.readouterr()
    pattern = (
        rf"sweep.betas = '{re.escape(betas)}' with rig 'EP Endoscope': betas: at rig.beta_deg = {re.escape(refused)} "
        r"the endoscope head enters the tissue; drop them\. .*region '"
    )
    _assert_rejected(pattern, tmp_path / "sweep")
    out, err = capfd.readouterr()
    assert "Traceback" not in out + err, out + err


def test_bad_input_through_invoke(ep, tmp_path):
    _setup(tmp_path, betas="")
    _assert_rejected(r"sweep.betas = '' is empty", tmp_path / "sweep", invoke=True)


def test_output_folder_is_a_file(ep, tmp_path):
    scene = _setup(tmp_path)
    path = tmp_path / "taken"
    path.write_text("not a folder")
    scene.endophoton.sweep.output_dir = str(path)
    with pytest.raises(RuntimeError, match=r"sweep.output_dir = '.*taken' is a file, not a folder"):
        bpy.ops.endophoton.sweep_beta()
    assert path.read_text() == "not a folder"


def test_bad_rig_rejected(ep, tmp_path):
    scene = _setup(tmp_path)
    rs = scene.objects["EP Endoscope"].endophoton_rig
    normal = tuple(rs.normal)
    rs.tilt_axis = normal
    _assert_rejected(
        r"Object 'EP Endoscope': endophoton_rig.tilt_axis is parallel to endophoton_rig.normal", tmp_path / "sweep"
    )
    rs.tilt_axis = (0.0, 1.0, 0.0)
    rs.distance = 0.0
    _assert_rejected(r"Object 'EP Endoscope': endophoton_rig.distance = 0 must be > 0", tmp_path / "sweep")


def test_no_tissue_rejected(ep, tmp_path):
    scene = _setup(tmp_path)
    for obj in scene.objects:
        if obj.type == "MESH":
            obj.endophoton.role = "NONE"
    _assert_rejected(r"Scene '[^']+': no object has role 'tissue'", tmp_path / "sweep")


def test_summary_best_beta_is_the_reports_fit(ep, tmp_path):
    """With enough angles for the paper's degree-6 fit, the panel's best β and its error are the
    written report's (ep.report.compute_trends: the fit's maximum refitted per batch of packets,
    one rule in one place), the same numbers report.md prints, with or without "at range edge"."""
    n = sweep_job.min_fit_points(ep)
    betas = [5.0 * k for k in range(n)]
    scene = _setup(tmp_path, betas=",".join(f"{b:g}" for b in betas), store=500)
    job, _, _ = _run_job(bpy.context)
    assert job.error is None and not job.cancelled, job.error_traceback
    assert list(job.result.betas) == betas
    trends = ep.report.compute_trends(job.result)
    summary = scene[sweep_job.SUMMARY_KEY].to_dict()
    report = (tmp_path / "sweep" / "report.md").read_text(encoding="utf-8")
    rows = dict(sweep_job.summary_rows(scene))
    for key, label in (("energy_total", "Energy max β (sum)"), ("energy_per_packet", "Energy max β (/packet)")):
        peak, se, fit = trends[key + "_peak"], trends[key + "_peak_se"], trends[key + "_fit"]
        assert fit["deg"] == ep.paper.PAPER_TRENDS["energy_fit_degree"] == summary["fit_degree"]
        assert min(betas) <= peak <= max(betas) and se is not None and se > 0
        assert (summary[f"best_beta_{key}"], summary[f"best_beta_{key}_se"]) == (peak, se)
        assert summary[f"best_beta_{key}_interior"] == fit["interior"]
        assert f"fit maximum at β = {peak:.3g} ± {se:.2g}°" in report
        shown = f"{peak:.1f} ± {se:.1f}°" + ("" if fit["interior"] else " at range edge")
        assert rows[label].startswith(shown), (rows[label], shown)
    assert not [k for k, v in job.summary.items() if isinstance(v, float) and not math.isfinite(v)]


def test_sweep_on_a_dask_scheduler_matches_the_local_sweep(ep, tmp_path):
    """With the preferences' Dask Scheduler set, the sweep's runs trace on that
    cluster (2 single-threaded worker processes started outside Blender, importing
    the same package) and give the local sweep's rows and histograms."""
    import subprocess
    import sys

    from conftest import engine_folder

    scene = _setup(tmp_path)
    local, _, _ = _run_job(bpy.context)
    assert local.error is None, local.error_traceback
    starter = (
        "import sys; from distributed import LocalCluster; "
        "c = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=':0', "
        "env={'PYTHONPATH': sys.argv[1]}); print(c.scheduler_address, flush=True); sys.stdin.read(); c.close()"
    )
    folder = engine_folder() or ""
    cluster = subprocess.Popen(
        ["/usr/bin/python3", "-c", starter, folder],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
        env=dict(os.environ, PYTHONPATH=folder),
    )
    prefs = bpy.context.preferences.addons["endophoton_addon"].preferences
    try:
        address = cluster.stdout.readline().strip()
        assert address.startswith("tcp://"), address
        prefs.scheduler_address = address
        scene.endophoton.sweep.output_dir = str(tmp_path / "sweep_cluster")
        scene.endophoton.sweep.keep_runs = "ON"  # the records come back from the workers too
        remote, _, seen = _run_job(bpy.context)
    finally:
        prefs.scheduler_address = ""
        cluster.stdin.close()
        cluster.wait(timeout=120)
    assert remote.scheduler == address and local.scheduler == ""  # the runs really went there
    assert remote.error is None and not remote.cancelled, remote.error_traceback
    _assert_same_rows(remote.result, local.result)
    kept = sweep_job.sweep_collections(scene, sweep_job.sweep_id(remote.inputs))
    assert [c[results.PARAMS_KEY]["beta_deg"] for c in kept] == [0.0, 30.0]
    for collection, row in zip(kept, remote.result.rows):
        (cloud,) = points.points_objects(collection)
        assert len(cloud.data.vertices) == row["records"] == STORE
    # The bar followed the chunks merged over all angles, and they all came in.
    merged, total = remote._chunks
    assert merged == total > 0
    fractions = [p.fraction for p in seen]
    assert all(0.0 <= f <= 1.0 for f in fractions)


@pytest.mark.parametrize("owner", ["run", "sweep"])
def test_threads_bounded_within_the_packages_limit(ep, owner):
    """Threads (Run and Sweep β) cannot exceed what ep.run accepts (endophoton.run.MAX_THREADS):
    100000 is held at the property's maximum, 1024."""
    settings = bpy.context.scene.endophoton
    settings = settings if owner == "run" else settings.sweep
    settings.threads = 100_000
    assert (
        settings.threads
        == settings.bl_rna.properties["threads"].hard_max
        == 1024
        <= sys.modules["endophoton.run"].MAX_THREADS
    )
