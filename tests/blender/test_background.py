# SPDX-License-Identifier: MIT
"""Issue 15, scripting: a background run prints progress, and one Ctrl-C
cancels it cleanly, keeping the previous result (Blender exits normally)."""

import os
import signal
import subprocess

import bpy

from conftest import BLEND_DIR, ENGINE_FOLDER, HERE


def test_background_progress_and_one_ctrl_c(ep, tmp_path):
    env = dict(os.environ, ENDOPHOTON_PYTHONPATH=ENGINE_FOLDER or os.path.dirname(os.path.dirname(ep.__file__)))
    cmd = [
        bpy.app.binary_path,
        "-b",
        "--factory-startup",
        os.path.join(BLEND_DIR, "flat_tissue.blend"),
        "--python-exit-code",
        "1",
        "--python",
        os.path.join(HERE, "background_driver.py"),
        "--",
        str(tmp_path),
    ]
    proc = subprocess.Popen(
        cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True, env=env
    )
    lines = []
    try:
        for line in proc.stdout:
            lines.append(line)
            # the huge run's line: the small one may print progress too (it renders the view after its packets)
            if "Ctrl-C to cancel" in line and "/200,000,000 packets" in line:
                proc.send_signal(signal.SIGINT)  # once
                break
        rest, _ = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    out = "".join(lines) + rest
    assert "FIRST {'FINISHED'}" in out, out[-3000:]
    progress = [ln for ln in lines if ln.startswith("EndoPhoton: ") and "/200,000,000 packets" in ln]
    assert progress, out[-3000:]
    assert "Ctrl-C -> cancelling the run" in out
    assert "SECOND {'CANCELLED'}" in out, out[-3000:]
    kept = [ln for ln in out.splitlines() if ln.startswith("RESULTS")]
    assert len(kept) == 1 and kept[0].count("EP β=") == 1, out[-3000:]  # the first run, still there
    assert proc.returncode == 0, out[-3000:]
