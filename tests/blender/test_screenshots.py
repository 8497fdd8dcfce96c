# SPDX-License-Identifier: MIT
"""Issue 15, acceptance 6: a screenshot of each EndoPhoton panel, taken in a
windowed Blender under Xvfb, saved in out/blender/screenshots/.  Needs
xvfb-run (Debian package xvfb)."""

import json
import os
import shutil
import signal
import subprocess

import bpy
import pytest

from conftest import BLEND_DIR, ENGINE_FOLDER, HERE, OUT_DIR


def test_screenshot_of_each_panel(ep, tmp_path):
    xvfb = shutil.which("xvfb-run")
    if xvfb is None or shutil.which("xauth") is None:
        pytest.skip("xvfb-run/xauth not installed (apt-get install xvfb xauth): screenshots not taken")
    out = os.path.join(OUT_DIR, "screenshots")
    if os.path.isdir(out):
        shutil.rmtree(out)
    engine_folder = ENGINE_FOLDER or os.path.dirname(os.path.dirname(ep.__file__))
    cmd = [xvfb, "-a", "-s", "-screen 0 1280x900x24", bpy.app.binary_path, "--factory-startup",
           "--enable-event-simulate",
           os.path.join(BLEND_DIR, "colon_polyp.blend"),
           "--python", os.path.join(HERE, "gui_screenshot_driver.py"), "--", out, str(tmp_path), engine_folder]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    try:
        stdout, stderr = proc.communicate(timeout=300)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        stdout, stderr = proc.communicate()
    listing = os.path.join(out, "screenshots.json")
    assert os.path.exists(listing), f"no screenshots (rc {proc.returncode}):\n{stdout[-3000:]}\n{stderr[-3000:]}"
    with open(listing) as f:
        shots = json.load(f)
    assert [s["panel"] for s in shots] == ["ENDOPHOTON_PT_object", "ENDOPHOTON_PT_endoscope",
                                           "ENDOPHOTON_PT_simulation", "ENDOPHOTON_PT_results",
                                           "ENDOPHOTON_PT_sweep"]
    for shot in shots:
        assert os.path.getsize(shot["file"]) > 2000
        assert shot["size"][0] >= 150 and shot["size"][1] >= 300   # the sidebar, full height
        assert shot["std"] > 0.02, f"{shot['panel']}: the capture is one flat colour"
