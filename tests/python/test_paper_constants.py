"""The seed paper's constants are written once, in endophoton.paper.

The Blender add-on registers before it knows where the package is (the package
may be missing; the add-on then says so in its panel), so its role defaults
(addon/endophoton_addon/presets.py, plain data, no bpy) cannot import them.
This test holds that copy to the package's: any drift fails here.
"""
import importlib.util
import os

import endophoton as ep
from endophoton import paper

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _addon_presets():
    path = os.path.join(ROOT, "addon", "endophoton_addon", "presets.py")
    spec = importlib.util.spec_from_file_location("_presets_under_test", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_values_are_the_papers():
    # Zacher 2009 §3: n = 1.1, mua = 20 /cm, mus = 200 /cm, g = 0.9; collagen d = 0.2, c = 0.4;
    # photofrin d = 0.1, c = 0.33; §5: 15 deg camera criterion, 1 cm head distance.
    assert paper.TISSUE == {"mua": 20.0, "mus": 200.0, "g": 0.9, "n": 1.1}
    assert paper.COLLAGEN == {"d": 0.2, "c": 0.4} and paper.PHOTOFRIN == {"d": 0.1, "c": 0.33}
    assert paper.IMPORTANT_ANGLE_DEG == 15.0 and paper.DISTANCE_CM == 1.0


def test_package_uses_them():
    assert {k: list(v) for k, v in paper.FLUOROPHORES.items()} == ep.FLUOROPHORE_DEFAULTS
    scene = ep.default_flat_scene(polyp="dome")
    for region in scene.regions:
        m = region.medium
        assert {"mua": m.mua, "mus": m.mus, "g": m.g, "n": m.n} == paper.TISSUE
        kind = "polyp" if region.name == "polyp" else "tissue"
        assert tuple((f.name, f.d, f.c) for f in region.fluorophores) == paper.FLUOROPHORES[kind]


def test_addon_role_defaults_equal_the_papers():
    roles = _addon_presets().ROLE_DEFAULTS
    for role, kind in (("TISSUE", "tissue"), ("POLYP", "polyp")):
        assert roles[role]["medium"] == paper.TISSUE
        assert tuple(roles[role]["fluorophores"]) == paper.FLUOROPHORES[kind]
