# SPDX-License-Identifier: MIT
"""Fixtures for tests that run inside ``blender -b`` (see run_blender_tests.py).

Outside Blender (plain pytest from the repository root) this folder is ignored.
"""

import importlib.util
import os
import sys

try:
    import bpy  # noqa: F401
except ImportError:  # not inside Blender
    collect_ignore_glob = ["*"]
    bpy = None

import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(os.path.dirname(HERE))
ADDON = "endophoton_addon"
BLEND_DIR = os.path.join(REPO, "blend_scenes")
OUT_DIR = os.path.join(REPO, "out", "blender")

if os.path.join(REPO, "addon") not in sys.path:
    sys.path.insert(0, os.path.join(REPO, "addon"))


def engine_folder():
    """Folder for the add-on's "Package Folder" preference ('' = normal import)."""
    env = os.environ.get("ENDOPHOTON_PYTHONPATH", "").strip()
    if env:
        return env
    if importlib.util.find_spec("endophoton") is not None:
        return ""
    return os.path.join(REPO, "python")


ENGINE_FOLDER = engine_folder()


def ensure_addon(package_path=None):
    """Enable the add-on (if a factory reset disabled it) and set its preference."""
    import addon_utils

    if not hasattr(bpy.types.Scene, "endophoton"):
        if addon_utils.enable(ADDON, default_set=True) is None:
            raise RuntimeError("could not enable the add-on")
    addons = bpy.context.preferences.addons
    if ADDON not in addons:
        addons.new().module = ADDON
    prefs = addons[ADDON].preferences
    prefs.package_path = ENGINE_FOLDER if package_path is None else package_path
    return prefs


def reset_blender():
    from endophoton_addon import simulation

    simulation.cancel_all_jobs()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    ensure_addon()


@pytest.fixture(autouse=True)
def fresh_blender():
    """Factory-reset Blender (empty scene) around every test."""
    reset_blender()
    yield
    reset_blender()


@pytest.fixture
def ep():
    """The real engine; the test fails (not skips) when it cannot be imported."""
    from endophoton_addon import package_finder

    module, message = package_finder.status()
    if module is None:
        pytest.fail(f"engine required: {message}")
    return module


@pytest.fixture
def out_dir():
    os.makedirs(OUT_DIR, exist_ok=True)
    return OUT_DIR


def open_blend(name, grid_dir):
    """Open blend_scenes/<name> (never saved back) with grids written to grid_dir."""
    bpy.ops.wm.open_mainfile(filepath=os.path.join(BLEND_DIR, name))
    ensure_addon()
    bpy.context.scene.endophoton.grid_dir = str(grid_dir)
    return bpy.context.scene


DATA_KINDS = (
    "objects",
    "collections",
    "meshes",
    "materials",
    "volumes",
    "node_groups",
    "lights",
    "cameras",
    "images",
    "scenes",
)


def data_snapshot():
    """Everything a run could add or change, as comparable plain values."""
    snap = {kind: sorted(block.name for block in getattr(bpy.data, kind)) for kind in DATA_KINDS}
    scene = bpy.context.scene
    snap["tree"] = sorted(
        (c.name, tuple(sorted(o.name for o in c.objects)))
        for c in [scene.collection, *scene.collection.children_recursive]
    )
    snap["result_collection"] = getattr(scene.endophoton.result_collection, "name", None)
    return snap


def mesh_object(name, verts, faces, collection=None):
    from endophoton_addon import meshutil

    obj = bpy.data.objects.new(name, meshutil.mesh_from_arrays(name, verts, faces))
    (collection or bpy.context.scene.collection).objects.link(obj)
    return obj


def run_windowed(blend, driver, args, screen="1280x800", timeout=360):
    """Run ``driver`` in a windowed Blender under xvfb-run (skips the test when
    xvfb-run/xauth are missing).  Returns (returncode, stdout, stderr); on a
    timeout the whole process group (Xvfb and Blender) is killed."""
    import shutil
    import signal
    import subprocess

    xvfb = shutil.which("xvfb-run")
    if xvfb is None or shutil.which("xauth") is None:
        pytest.skip("xvfb-run/xauth not installed (apt-get install xvfb xauth): windowed test not run")
    cmd = [
        xvfb,
        "-a",
        "-s",
        f"-screen 0 {screen}x24",
        bpy.app.binary_path,
        "--factory-startup",
        "--enable-event-simulate",
        os.path.join(BLEND_DIR, blend),
        "--python",
        os.path.join(HERE, driver),
        "--",
        *map(str, args),
    ]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        stdout, stderr = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        stdout, stderr = proc.communicate()
    return proc.returncode, stdout, stderr
