# SPDX-License-Identifier: MIT
"""Issue 15, acceptance 6: a screenshot of each EndoPhoton panel, taken in a
windowed Blender under Xvfb, saved in out/blender/screenshots/.  Issue 36's
acceptance pictures follow: the Sweep β panel with a visibility sweep's answer
(target Polyp, background Colon), *Render with Legend* from the endoscope camera
and the live view mid-run (an Image Editor showing the live image while the run's
merge waits).  Needs xvfb-run (Debian package xvfb)."""

import json
import os
import shutil


from conftest import ENGINE_FOLDER, OUT_DIR, run_windowed


def test_screenshot_of_each_panel(ep, tmp_path):
    out = os.path.join(OUT_DIR, "screenshots")
    if os.path.isdir(out):
        shutil.rmtree(out)
    engine_folder = ENGINE_FOLDER or os.path.dirname(os.path.dirname(ep.__file__))
    returncode, stdout, stderr = run_windowed(
        "colon_polyp.blend", "gui_screenshot_driver.py", [out, tmp_path, engine_folder], screen="1280x1400", timeout=900
    )
    listing = os.path.join(out, "screenshots.json")
    assert os.path.exists(listing), f"no screenshots (rc {returncode}):\n{stdout[-3000:]}\n{stderr[-3000:]}"
    with open(listing) as f:
        shots = json.load(f)
    assert [s["panel"] for s in shots] == [
        "ENDOPHOTON_PT_object",
        "ENDOPHOTON_PT_endoscope",
        "ENDOPHOTON_PT_simulation",
        "ENDOPHOTON_PT_results",
        "ENDOPHOTON_PT_sweep",
        "ENDOPHOTON_PT_sweep_answer",
        "render_with_legend",
        "live_view_mid_run",
    ], shots[-1].get("error", shots)
    for shot in shots:
        assert os.path.getsize(shot["file"]) > 2000
        assert shot["size"][0] >= 150 and shot["size"][1] >= 300  # the sidebar, full height
        assert shot["std"] > 0.02, f"{shot['panel']}: the capture is one flat colour"
    names = {s["panel"]: s for s in shots}
    assert os.path.basename(names["ENDOPHOTON_PT_sweep_answer"]["file"]) == "sweep_answer.png"
    assert names["render_with_legend"]["size"][0] > 300  # the render with its colour bar beside it
    shot = names["live_view_mid_run"]
    assert shot["image"] == "EP View white (live)"  # the Image Editor switched to the live image
    assert shot["live_packets"] and 0 < shot["live_packets"][-1] <= shot["merged_packets"] < shot["run_packets"]
