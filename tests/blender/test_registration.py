# SPDX-License-Identifier: MIT
"""Acceptance 1: registration, plus install-from-zip, manifest and the panels."""

import os
import subprocess
import sys
import tomllib

import bpy
import pytest

import numpy as np
from types import SimpleNamespace

from conftest import ADDON, REPO, data_snapshot, ensure_addon, mesh_object

BOX = (
    np.array(
        [[-1, -1, -1], [1, -1, -1], [1, 1, -1], [-1, 1, -1], [-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]],
        dtype=float,
    )
    * 0.01,
    [np.array([[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]])],
)


def _addon_classes():
    import endophoton_addon
    from endophoton_addon import operators, panels, preferences, properties

    assert endophoton_addon  # the package itself is importable
    return (*properties.CLASSES, *operators.CLASSES, *panels.CLASSES, preferences.EndoPhotonPreferences)


def _registered():
    classes = _addon_classes()
    assert len(classes) >= 15
    types = {cls.__name__ for cls in classes if cls.is_registered}
    props = {
        "Scene.endophoton": hasattr(bpy.types.Scene, "endophoton"),
        "Object.endophoton": hasattr(bpy.types.Object, "endophoton"),
        "Object.endophoton_rig": hasattr(bpy.types.Object, "endophoton_rig"),
    }
    return types, props


def _all_names():
    return {cls.__name__ for cls in _addon_classes()}


def _operator_exists(idname):
    module, name = idname.split(".")
    try:
        getattr(getattr(bpy.ops, module), name).get_rna_type()
    except KeyError:
        return False
    return True


def test_register_unregister_twice():
    import endophoton_addon

    for _ in range(2):
        endophoton_addon.unregister()
        types, props = _registered()
        assert types == set(), f"still registered after unregister: {types}"
        assert not any(props.values()), props
        assert not _operator_exists("endophoton.run_simulation")
        endophoton_addon.register()
        types, props = _registered()
        assert types == _all_names()
        assert all(props.values()), props
        assert _operator_exists("endophoton.run_simulation")
        # The registered add-on works: the properties exist on a new object.
        obj = bpy.data.objects.new("probe", bpy.data.meshes.new("probe"))
        obj.endophoton.role = "TISSUE"
        assert obj.endophoton.fluorophores[0].species == "collagen"
        bpy.data.objects.remove(obj)


def test_register_rolls_back_when_a_class_fails(monkeypatch):
    """One registration loop for all modules: a failing class (here a panel
    without bl_space_type, which Blender refuses) leaves nothing registered."""
    import endophoton_addon
    from endophoton_addon import panels

    class ENDOPHOTON_PT_broken(bpy.types.Panel):
        bl_label = "Broken"

    endophoton_addon.unregister()
    monkeypatch.setattr(panels, "CLASSES", (*panels.CLASSES, ENDOPHOTON_PT_broken))
    with pytest.raises(Exception):
        endophoton_addon.register()
    types, props = _registered()
    assert types == set() and not any(props.values()), (types, props)
    monkeypatch.undo()
    endophoton_addon.register()
    assert _registered()[0] == _all_names()


def test_addon_utils_disable_enable_twice():
    import addon_utils

    for _ in range(2):
        addon_utils.disable(ADDON, default_set=True)
        assert _registered()[0] == set()
        assert addon_utils.enable(ADDON, default_set=True) is not None
        assert _registered()[0] == _all_names()
        assert ADDON in bpy.context.preferences.addons
    ensure_addon()


def test_bl_info_and_manifest():
    import endophoton_addon

    info = endophoton_addon.bl_info
    assert info["blender"] == (3, 4, 0)
    assert info["name"] == "EndoPhoton"
    path = os.path.join(REPO, "addon", ADDON, "blender_manifest.toml")
    with open(path, "rb") as f:
        manifest = tomllib.load(f)
    assert manifest["schema_version"] == "1.0.0"
    assert manifest["type"] == "add-on"
    assert manifest["blender_version_min"] >= "4.2.0"
    assert tuple(int(p) for p in manifest["version"].split(".")) == info["version"]
    for key in ("id", "name", "tagline", "maintainer", "license"):
        assert manifest[key], key
    # What the add-on does outside Blender: read the package, write grids, reach a Dask scheduler.
    assert set(manifest["permissions"]) == {"files", "network"}


def test_install_from_zip_in_fresh_blender(tmp_path):
    """Build the zip the way users install it and install + enable it from the
    preferences operator in a separate Blender with its own user-scripts folder."""
    sys.path.insert(0, os.path.join(REPO, "addon"))
    import build_zip

    archive = build_zip.build(str(tmp_path / f"{ADDON}.zip"))
    import zipfile

    names = zipfile.ZipFile(archive).namelist()
    assert f"{ADDON}/__init__.py" in names and f"{ADDON}/blender_manifest.toml" in names
    assert not any("__pycache__" in n for n in names)
    user_scripts = tmp_path / "user_scripts"
    user_scripts.mkdir()
    script = tmp_path / "install.py"
    script.write_text(
        "import bpy, addon_utils, sys\n"
        f"bpy.ops.preferences.addon_install(filepath={archive!r})\n"
        f"mod = addon_utils.enable({ADDON!r}, default_set=True)\n"
        "assert mod is not None, 'enable failed'\n"
        "assert hasattr(bpy.types, 'ENDOPHOTON_PT_main')\n"
        "print('INSTALLED_FROM', mod.__file__)\n"
        f"addon_utils.disable({ADDON!r}, default_set=True)\n"
        "assert not hasattr(bpy.types, 'ENDOPHOTON_PT_main')\n"
        "print('ZIP_INSTALL_OK')\n"
        "sys.exit(0)\n"
    )
    env = dict(os.environ, BLENDER_USER_SCRIPTS=str(user_scripts))
    proc = subprocess.run(
        [bpy.app.binary_path, "-b", "--factory-startup", "--python-exit-code", "1", "--python", str(script)],
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert "ZIP_INSTALL_OK" in proc.stdout
    installed = [line for line in proc.stdout.splitlines() if line.startswith("INSTALLED_FROM")]
    assert installed and str(user_scripts) in installed[0], installed


class FakeLayout:
    """Records what a panel draws; checks every prop() names a real property."""

    def __init__(self, log):
        self.log = log
        self.active = self.enabled = True
        self.scale_y = 1.0

    def _child(self, *_args, **_kwargs):
        return FakeLayout(self.log)

    row = column = box = split = grid_flow = _child

    def label(self, text="", icon="NONE"):
        self.log.append(("label", text))

    def prop(self, data, name, **_kwargs):
        assert name in data.bl_rna.properties, f"{data} has no property {name}"
        self.log.append(("prop", name))

    def operator(self, idname, **_kwargs):
        module, name = idname.split(".")
        getattr(getattr(bpy.ops, module), name).get_rna_type()  # KeyError if not registered
        self.log.append(("operator", idname))
        return SimpleNamespace()  # operator properties the panel sets

    def template_list(self, *args, **_kwargs):
        assert args[3] in args[2].bl_rna.properties
        self.log.append(("template_list", args[3]))


def _draw_all_panels():
    from types import SimpleNamespace

    log = []
    for name in (
        "ENDOPHOTON_PT_main",
        "ENDOPHOTON_PT_object",
        "ENDOPHOTON_PT_endoscope",
        "ENDOPHOTON_PT_simulation",
        "ENDOPHOTON_PT_results",
        "ENDOPHOTON_PT_sweep",
    ):
        panel = getattr(bpy.types, name)
        panel.draw(SimpleNamespace(layout=FakeLayout(log)), bpy.context)
    return log


def test_panel_says_plainly_when_package_missing(tmp_path):
    from endophoton_addon import package_finder

    saved = {k: v for k, v in sys.modules.items() if k == "endophoton" or k.startswith("endophoton.")}
    for k in saved:
        del sys.modules[k]
    try:
        ensure_addon(package_path=str(tmp_path))  # an existing folder without the package
        package_finder.forget()
        module, message = package_finder.status()
        assert module is None
        assert "EndoPhoton engine not found" in message and str(tmp_path) in message
        log = _draw_all_panels()
        labels = " ".join(text for kind, text in log if kind == "label")
        assert "Engine package not found" in labels
        assert "Preferences" in labels
        # With a valid scene the run operator reports the same message (an
        # operator error, not a traceback) and adds nothing.
        from endophoton_addon import rig

        tissue = mesh_object("Tissue", *BOX)
        tissue.endophoton.role = "TISSUE"
        rig.create_rig(bpy.context, target=(0, 0, 0))
        before = data_snapshot()
        with pytest.raises(RuntimeError, match="EndoPhoton engine not found"):
            bpy.ops.endophoton.run_simulation()
        assert data_snapshot() == before
    finally:
        sys.modules.update(saved)
        ensure_addon()
        package_finder.forget()


def test_panels_draw_with_objects_and_rig():
    from endophoton_addon import rig

    obj = bpy.data.objects.new("Tissue", bpy.data.meshes.new("Tissue"))
    bpy.context.scene.collection.objects.link(obj)
    obj.endophoton.role = "POLYP"
    bpy.context.view_layer.objects.active = obj
    rig.create_rig(bpy.context)
    log = _draw_all_panels()
    props = {name for kind, name in log if kind == "prop"}
    assert {
        "role",
        "mua",
        "mus",
        "g",
        "n",
        "priority",
        "beta",
        "distance",
        "quality",
        "seed",
        "threads",
        "voxel_size",
        "output_points",
        "output_grids",
        "color_by",
    } <= props
    assert ("template_list", "fluorophores") in log
    assert ("operator", "endophoton.run_simulation") in log
    assert ("operator", "endophoton.add_endoscope") in log
    # The Sweep β sub-panel: the command line's options and the operator.
    assert {"betas", "store", "batches", "fluorescent_only", "fluorescence_rule", "output_dir"} <= props
    assert ("operator", "endophoton.sweep_beta") in log


def test_tissue_presets_load_published_media_with_their_source():
    from endophoton_addon import presets

    obj = bpy.data.objects.new("Tissue", bpy.data.meshes.new("Tissue"))
    bpy.context.scene.collection.objects.link(obj)
    obj.endophoton.role = "TISSUE"
    obj.endophoton.tissue_preset = "COLON_800"
    m = obj.endophoton.medium
    # Marchesini et al. 1994 at 800 nm: μa = 1.0, μs' = 6.2 cm⁻¹; μs = μs'/(1 − g) with the assumed g = 0.9.
    assert (m.mua, m.g, m.n) == pytest.approx((1.0, 0.9, 1.4))
    assert m.mus * (1 - m.g) == pytest.approx(6.2, rel=1e-5)
    assert "Marchesini" in presets.TISSUE_PRESETS["COLON_800"].source
    obj.endophoton.tissue_preset = "PAPER"
    assert (m.mua, m.mus, m.g, m.n) == pytest.approx((20.0, 200.0, 0.9, 1.1))


def test_fluorophore_rows_fit_the_default_sidebar():
    """Each row of the fluorophore list is one short label (no truncated fields);
    the active row is edited with full-width fields below the list."""
    obj = bpy.data.objects.new("Polyp", bpy.data.meshes.new("Polyp"))
    bpy.context.scene.collection.objects.link(obj)
    obj.endophoton.role = "POLYP"
    log = []
    ui_list = bpy.types.ENDOPHOTON_UL_fluorophores
    for item in obj.endophoton.fluorophores:
        ui_list.draw_item(None, None, FakeLayout(log), None, item, None, None, None)
    labels = [text for kind, text in log if kind == "label"]
    assert labels == ["Collagen  d 0.20  c 0.40", "Photofrin  d 0.10  c 0.33"]
    assert max(len(t) for t in labels) <= 26  # the default sidebar shows ~30 characters


def test_loading_a_file_frees_the_kept_engine_scene(ep, tmp_path):
    """The package keeps the last engine scene built for the next run of the same content
    (~100 MB on colon_polyp); loading another file must not keep it alive, and neither must
    unregistering the add-on.  Checked by behaviour: the same file's scene, exported again
    after a load, gets a newly built engine scene."""
    import endophoton_addon
    from conftest import open_blend
    from endophoton_addon import operators, simulation

    assert operators._forget_engine_scenes in bpy.app.handlers.load_post
    open_blend("flat_tissue.blend", tmp_path)
    native = simulation.prepare_job(bpy.context).engine_scene.to_native()
    assert simulation.prepare_job(bpy.context).engine_scene.to_native() is native  # kept across exports
    open_blend("flat_tissue.blend", tmp_path)  # load_post
    reloaded = simulation.prepare_job(bpy.context).engine_scene.to_native()
    assert reloaded is not native
    endophoton_addon.unregister()
    try:
        assert operators._forget_engine_scenes not in bpy.app.handlers.load_post
    finally:
        endophoton_addon.register()
    assert simulation.prepare_job(bpy.context).engine_scene.to_native() is not reloaded
