"""The view/ and sweep/ subpackages: the public names stay, and the old flat module paths keep
working for one release, as the moved modules themselves, with a DeprecationWarning."""
import importlib
import subprocess
import sys

import pytest

import endophoton as ep

OLD_TO_NEW = {
    "camera": "view.camera",
    "colour": "view.colour",
    "render": "view.render",
    "visibility": "view.visibility",
    "render_cli": "view.render_cli",
    "sweep_schema": "sweep.schema",
    "sweep_reduce": "sweep.reduce",
    "beta_sweep": "sweep.driver",
    "sweep_cli": "sweep.cli",
    "view_sweep": "sweep.view_sweep",
}


def test_public_names_unchanged():
    from endophoton.sweep import driver
    from endophoton.view import camera, render

    assert ep.sweep is driver.sweep and callable(ep.sweep)
    assert ep.render_view is render.render_view and ep.View is render.View and ep.Camera is camera.Camera
    assert ep.SweepResult is importlib.import_module("endophoton.sweep.schema").SweepResult


@pytest.mark.parametrize("old", sorted(OLD_TO_NEW))
def test_old_path_is_the_new_module_with_a_warning(old):
    # a fresh interpreter, so the warning is not swallowed by an earlier import in this session
    code = (
        "import warnings, importlib\n"
        "with warnings.catch_warnings(record=True) as w:\n"
        "    warnings.simplefilter('always')\n"
        f"    old = importlib.import_module('endophoton.{old}')\n"
        f"new = importlib.import_module('endophoton.{OLD_TO_NEW[old]}')\n"
        "assert old is new, (old, new)\n"
        "msgs = [str(x.message) for x in w if issubclass(x.category, DeprecationWarning)]\n"
        f"assert msgs == ['endophoton.{old} is deprecated: import endophoton.{OLD_TO_NEW[old]} instead'], msgs\n"
        "import endophoton as ep\n"
        "assert callable(ep.sweep)\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=_env())
    assert done.returncode == 0, done.stderr


def _env():
    import os

    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    return dict(os.environ, PYTHONPATH=os.path.join(root, "python"))
