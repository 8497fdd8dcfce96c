"""Tests that start Blender from the shell (the system Python's pytest runs them; each starts
``blender -b`` as a subprocess): the sweep on a .blend file, through the add-on's module and on a
local Dask cluster. They take tens of seconds each, so they live apart from tests/python's fast tier
(``bash scripts/test.sh`` runs them; ``--fast`` does not). Skipped where Blender (with Python 3.11 and
numpy) or the engine is missing.
"""

import csv
import json
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))
sys.path[:0] = [os.path.join(ROOT, "python"), os.path.join(ROOT, "tests", "python")]

from cli_helpers import run_cli  # noqa: E402
from endophoton.sweep import driver as sw  # noqa: E402


def _blender_ready():
    """Blender runs Python 3.11 with numpy, and the engine is built."""
    exe = shutil.which("blender")
    try:
        from endophoton import _core  # noqa: F401
    except ImportError:
        return False
    if exe is None:
        return False
    try:
        out = subprocess.run(
            [exe, "-b", "--factory-startup", "--python-expr", "import numpy, sys; print('PYOK', sys.version_info[:2])"],
            capture_output=True,
            text=True,
            timeout=120,
        )
    except (OSError, subprocess.TimeoutExpired):
        return False
    return "PYOK (3, 11)" in out.stdout


pytestmark = [
    pytest.mark.slow,
    pytest.mark.blender,
    pytest.mark.skipif(not _blender_ready(), reason="blender with python 3.11 + numpy, or the engine, missing"),
]


def _csv_rows(path):
    """The sweep CSV's rows as text, without the wall-clock ``seconds``."""
    with open(path, newline="") as fh:
        return [{k: v for k, v in r.items() if k != "seconds"} for r in csv.DictReader(fh)]


BLENDER_SCRIPT = r'''
import json, sys
import numpy as np
import bpy
sys.path[:0] = [PKG, ADDON]
from endophoton.sweep import driver as sw
from endophoton_addon import sweep_blend as sb
sb.enable_addon()
for obj in list(bpy.data.objects):
    bpy.data.objects.remove(obj, do_unlink=True)
bscene = bpy.context.scene
bscene.unit_settings.scale_length = 1.0          # 1 Blender unit = 1 m, the engine's unit here
src = sw.default_flat_scene(unit="m", polyp="dome")
for region in src.regions:
    mesh = bpy.data.meshes.new(region.name)
    mesh.from_pydata(region.vertices.astype(float).tolist(), [], region.triangles.astype(int).tolist())
    mesh.update()
    obj = bpy.data.objects.new(region.name, mesh)
    bscene.collection.objects.link(obj)
    s = obj.endophoton
    s.role = "TISSUE" if region.name == "tissue" else "POLYP"
    m = region.medium
    s.medium.mua, s.medium.mus, s.medium.g, s.medium.n = m.mua, m.mus, m.g, m.n
    s.priority = region.priority
    s.fluorophores.clear()
    for f in region.fluorophores:
        item = s.fluorophores.add()
        item.species, item.d, item.c = f.name, f.d, f.c
bpy.ops.wm.save_as_mainfile(filepath=BLEND)
res = sb.sweep_blend(BLEND, betas=BETAS, store=STORE, seed=SEED, progress=False)
with open(OUT, "w") as fh:
    json.dump({"rows": res.rows, "counts": [np.asarray(h["counts"]).tolist() for h in res.histograms]}, fh)
'''


def test_blender_path_gives_identical_numbers(tmp_path):
    """sweep_blend on a .blend holding the paper's scene == sweep() on the same arrays and values."""
    import subprocess
    import endophoton as ep_mod

    betas, store, seed = [0.0, 30.0], 3000, 7
    pkg = os.path.join(ROOT, "python")
    script = tmp_path / "run_in_blender.py"
    out = tmp_path / "blender.json"
    blend = tmp_path / "paper.blend"
    addon = os.path.join(ROOT, "addon")
    script.write_text(
        f"PKG={pkg!r}\nADDON={addon!r}\nBLEND={str(blend)!r}\nOUT={str(out)!r}\nBETAS={betas!r}\n"
        f"STORE={store}\nSEED={seed}\n" + BLENDER_SCRIPT
    )
    proc = subprocess.run(
        ["blender", "-b", "--factory-startup", "--python-exit-code", "1", "--python", str(script)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    got = json.loads(out.read_text())
    # the same scene in plain Python: Blender keeps vertex coordinates and the
    # add-on's float properties in single precision, so round the same way
    f32 = lambda x: float(np.float32(x))
    src = sw.default_flat_scene(unit="m", polyp="dome")
    scene = ep_mod.Scene(unit="m")
    for r in src.regions:
        m = r.medium
        scene.add_mesh(
            r.name,
            r.vertices,
            r.triangles,
            ep_mod.Medium(mua=f32(m.mua), mus=f32(m.mus), g=f32(m.g), n=f32(m.n)),
            priority=r.priority,
            fluorophores=[ep_mod.Fluorophore(f.name, f32(f.d), f32(f.c)) for f in r.fluorophores],
        )
    ref = sw.sweep(scene, betas=betas, store=store, seed=seed, progress=False)
    for a, b in zip(ref.rows, got["rows"]):
        for k in (
            "packets_traced",
            "records",
            "energy_total",
            "energy_per_packet",
            "important_fraction",
            "max_depth_cm",
            "azimuth_asym_low",
        ):
            assert a[k] == b[k], (k, a[k], b[k])
    for h, c in zip(ref.histograms, got["counts"]):
        assert np.array_equal(np.asarray(h["counts"]), np.asarray(c))


def test_cli_blend_runs_the_addon_module_in_blender(tmp_path):
    """``python3 -m endophoton sweep --blend FILE`` starts Blender, which runs the add-on's
    sweep_blend on the file's scene and rig (the package itself never imports bpy)."""
    out = tmp_path / "out"
    blend = os.path.join(ROOT, "blend_scenes", "flat_tissue.blend")
    proc = run_cli(
        "sweep", "--blend", blend, "--betas", "0,20", "--store", "400", "--batches", "4", "--threads", "1",
        "--seed", "3", "--no-progress", "--out", out, timeout=900, cwd=str(tmp_path),
    )  # fmt: skip
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    res = sw.SweepResult.from_json(str(out / "sweep.json"))
    assert res.meta["scene"].startswith("blender scene") and "flat_tissue.blend" in res.meta["scene"]
    assert list(res.betas) == [0.0, 20.0] and all(r["records"] == 400 for r in res.rows)
    assert res.meta["seed"] == 3 and res.meta["n_batches"] == 4 and res.meta["unit"] == "m"
    # the rig of the .blend (its head dimensions reach from_beta), at its distance (10 mm) in metres
    assert "head_diameter_mm" in res.meta["rig_kwargs"] and res.meta["distance"] == pytest.approx(0.01)
    assert (out / "report.md").exists() and (out / "sweep.csv").exists()


def test_cli_sweep_blend_on_local2_runs_on_the_cluster(tmp_path):
    """``sweep --blend FILE --scheduler local:2``: the cluster is started here and Blender's
    sweep connects to it (the chunk bar shows on stderr); the angles' rows are complete."""
    blend = os.path.join(ROOT, "blend_scenes", "flat_tissue.blend")
    out = run_cli(
        "sweep", "--blend", blend, "--betas", "0,20", "--store", "400", "--batches", "4", "--seed", "3",
        "--scheduler", "local:2", "--out", str(tmp_path / "o"),
    )  # fmt: skip
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-3000:]
    assert "chunk" in out.stderr
    rows = _csv_rows(tmp_path / "o" / "sweep.csv")
    assert [float(r["beta_deg"]) for r in rows] == [0.0, 20.0] and all(r["records"] == "400" for r in rows)
    assert all(r["cancelled"] == "0" for r in rows)
