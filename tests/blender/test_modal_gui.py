# SPDX-License-Identifier: MIT
"""The modal Run and Sweep β operators in a real Blender window (Xvfb):
progress in the status bar, the UI keeps ticking while the engine runs, ESC
cancels and leaves nothing behind.  Needs xvfb-run (Debian package xvfb)."""

import json
import os


from conftest import ENGINE_FOLDER, run_windowed


def test_modal_operator_in_window(ep, tmp_path):
    out = tmp_path / "modal.json"
    grids = tmp_path / "grids"
    engine_folder = ENGINE_FOLDER or os.path.dirname(os.path.dirname(ep.__file__))
    returncode, stdout, stderr = run_windowed("flat_tissue.blend", "gui_modal_driver.py", [out, grids, engine_folder])
    assert out.exists(), f"driver wrote nothing (rc {returncode}):\n{stdout[-3000:]}\n{stderr[-3000:]}"
    report = json.loads(out.read_text())
    assert "error" not in report, report

    # Run 1: invoked as a modal operator, progress shown, finishes into a collection.
    assert report["invoke_1"] == ["RUNNING_MODAL"]
    # each status line says the tracing's progress, or, once the packets are traced, that the view renders
    # (which of the two the last lines caught depends on the timer, so either is accepted)
    assert report["run1_texts"] and all(
        ("packets/s" in t and "ETA" in t) or "packets traced · rendering the endoscope view" in t
        for t in report["run1_texts"]
    ), report["run1_texts"]
    assert report["run1_collection"].startswith("EP β=+0.0° ")
    # points + absorbed + fluorescent_light + an emission grid per fluorophore (collagen, photofrin)
    assert len(report["run1_objects"]) == 5, report["run1_objects"]
    # The UI kept running: timer ticks never stalled (software GL, 2 cores).
    assert report["run1_ticks"] >= 5
    # The UI stayed live: its timer kept ticking while the job ran. (Gap lengths
    # depend on machine load; they are in the report as figures, not verdicts.)

    # Run 2: ESC cancels; nothing new, the previous result stays, no grid file left over.
    assert report["invoke_2"] == ["RUNNING_MODAL"]
    assert report["run2_stopped_after"] >= report["esc_sent"] and report["run2_ticks"] >= 3
    assert report["run2_collection"] == report["run1_collection"]
    assert report["objects_after_run2"] == report["objects_after_run1"]
    # run 1's files only: its .vdb and the Cycles copy (volumes.RENDER_GRID_SUFFIX)
    assert len(report["grid_files"]) == 2 and report["grid_files"][0].endswith(".cycles.vdb")
    assert report["status_cleared"]

    # Sweep β, modal, to the end: β and position in the status text, the overall
    # fraction rising, the plots loaded as images with pixels, the files written.
    assert report["invoke_sweep_1"] == ["RUNNING_MODAL"]
    texts = report["sweep1_texts"]
    assert texts and texts[0].startswith("Sweep β=0° (1/2), ETA ")
    assert any(t.startswith("Sweep β=30° (2/2), ETA ") for t in texts), texts
    fractions = report["sweep1_fractions"]
    assert fractions == sorted(fractions) and 0.5 <= max(fractions) <= 1.0
    plots = [f for f in report["sweep1_files"] if f.endswith(".png")]
    assert len(plots) == 8 and {"sweep.csv", "sweep.json", "report.md"} <= set(report["sweep1_files"])
    assert report["sweep1_images"] == sorted(f"EndoPhoton Sweep: {f}" for f in plots)
    assert all(w > 0 and h > 0 for w, h in report["sweep1_image_sizes"])
    assert report["sweep1_summary"] == 2
    assert report["objects_after_sweep1"] == report["objects_after_run2"]
    assert report["sweep1_ticks"] >= 2

    # Sweep β cancelled with ESC: no new image, object or file; the status is cleared.
    assert report["invoke_sweep_2"] == ["RUNNING_MODAL"]
    assert report["sweep2_stopped_after"] >= report["sweep_esc_sent"]
    assert report["images_after_sweep2"] == report["images_after_sweep1"]
    assert report["objects_after_sweep2"] == report["objects_after_sweep1"]
    assert report["sweep2_files"] == report["sweep1_files"]
    assert report["sweep_status_cleared"]

    # The driver held each job's worker until the UI had ticked (run 1, run 2, and
    # each β of sweep 1): the UI ticked every time, none timed out.
    assert report["holds"] >= 4 and report["hold_timeouts"] == 0
    # Esc -> the operator ended: a figure for the record (docs/addon.md), never a verdict.
    print(f"cancel latency: run {report['run2_cancel_seconds']:.2f} s, sweep {report['sweep2_cancel_seconds']:.2f} s")
    print("cancel figures:", {k: v for k, v in report.items() if k.startswith("run2_") and "cancel" in k or "esc" in k})
    print("run2 texts:", report["run2_texts"], "gaps:", report["run2_gaps"])
