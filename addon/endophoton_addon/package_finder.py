# SPDX-License-Identifier: MIT
"""Finding and importing the ``endophoton`` engine package.

Blender finds the package in one of two ways (docs/addon.md):

1. a normal ``import endophoton`` (the package is pip-installed into a
   site/dist-packages folder that Blender's Python sees), or
2. the folder set in the add-on preferences ("Package Folder"), which is put
   on ``sys.path`` before importing.  The environment variable
   ``ENDOPHOTON_PYTHONPATH`` does the same when no preference is set (handy for
   scripts and tests).

Nothing here raises into the UI: :func:`status` returns the module or a plain
message the panel shows instead of a traceback.
"""

import os
import sys

ENV_VAR = "ENDOPHOTON_PYTHONPATH"

# What the add-on uses from the package; an older package without these is
# reported as "too old" rather than failing later.
REQUIRED_NAMES = (
    "Scene",
    "Medium",
    "Fluorophore",
    "EndoscopeRig",
    "GridRequest",
    "CancelToken",
    "run",
)

_state = {"key": None, "module": None, "message": None, "added_path": None}


def _addon_package():
    return __package__ or "endophoton_addon"


def configured_path():
    """The folder set in the preferences, else $ENDOPHOTON_PYTHONPATH, else ''."""
    try:
        import bpy

        addon = bpy.context.preferences.addons.get(_addon_package())
        if addon is not None and addon.preferences is not None:
            path = addon.preferences.package_path.strip()
            if path:
                return bpy.path.abspath(path)
    except (ImportError, AttributeError):
        pass
    return os.environ.get(ENV_VAR, "").strip()


def _forget_partial_import():
    for name in list(sys.modules):
        if name == "endophoton" or name.startswith("endophoton."):
            del sys.modules[name]


HOW_TO_FIX = (
    "Install the package with /usr/bin/python3 -m pip into the dist-packages "
    "Blender sees, or set its folder in Preferences > Add-ons > EndoPhoton."
)


def _try_import(path):
    if path:
        if not os.path.isdir(os.path.join(path, "endophoton")):
            return None, (
                f"EndoPhoton engine not found: the package folder '{path}' has no "
                f"'endophoton' package in it. {HOW_TO_FIX}"
            )
        loaded = sys.modules.get("endophoton")
        if loaded is not None and not _is_inside(getattr(loaded, "__file__", "") or "", path):
            return None, (
                f"Another endophoton package is already imported from "
                f"'{os.path.dirname(loaded.__file__)}'; restart Blender to use '{path}'."
            )
        if path not in sys.path:
            sys.path.insert(0, path)
            _state["added_path"] = path
    try:
        import endophoton as module
    except Exception as exc:  # ImportError, or an ABI/linker error from the extension
        _forget_partial_import()
        where = f" from '{path}'" if path else ""
        return None, f"EndoPhoton engine not found{where} ({type(exc).__name__}: {exc}). {HOW_TO_FIX}"
    missing = [name for name in REQUIRED_NAMES if not hasattr(module, name)]
    if missing:
        return None, (
            f"EndoPhoton package at '{getattr(module, '__file__', '?')}' is too old: " f"it lacks {', '.join(missing)}."
        )
    return module, None


def _is_inside(file_path, folder):
    try:
        return os.path.commonpath([os.path.realpath(file_path), os.path.realpath(folder)]) == os.path.realpath(folder)
    except ValueError:
        return False


def status():
    """Return ``(module, None)`` or ``(None, message)``.  Never raises."""
    path = configured_path()
    if _state["key"] != path or (_state["module"] is None and _state["message"] is None):
        if _state["added_path"] and _state["added_path"] != path:
            if _state["added_path"] in sys.path:
                sys.path.remove(_state["added_path"])
            _state["added_path"] = None
        module, message = _try_import(path)
        _state.update(key=path, module=module, message=message)
    return _state["module"], _state["message"]


def get():
    """The engine module, or None when it cannot be imported."""
    return status()[0]


def loaded():
    """The engine module if an earlier lookup imported it, else None (never imports)."""
    return _state["module"]


def forget():
    """Drop the cached lookup so the next :func:`status` tries again."""
    _state.update(key=None, module=None, message=None)


class EngineMissing(RuntimeError):
    """The engine package cannot be imported; the message says why and what to do."""


def require():
    module, message = status()
    if module is None:
        raise EngineMissing(message)
    return module
