# SPDX-License-Identifier: MIT
"""EndoPhoton Blender add-on.

Sets up tissue/polyp meshes and an endoscope rig in Blender, runs the
EndoPhoton Monte Carlo engine (the ``endophoton`` Python package) in a worker
thread and brings the surface photon map and the voxel grids back as a point
cloud and Volume objects.

The engine package is not bundled: Blender finds it either on its normal
``sys.path`` (pip-installed into the dist-packages Blender sees) or through the
folder set in the add-on preferences.  See docs/addon.md.
"""

bl_info = {
    "name": "EndoPhoton",
    "author": "EndoPhoton developers",
    "version": (0, 1, 0),
    "blender": (3, 4, 0),
    "location": "3D Viewport > Sidebar > EndoPhoton",
    "description": "Monte Carlo endoscope light transport and fluorescence in colon tissue",
    "doc_url": "",
    "category": "Render",
}

import importlib

# Registration order matters: preferences and properties first (operators and
# panels refer to them), panels last.
_MODULE_NAMES = ("preferences", "properties", "operators", "panels")


def _modules():
    return [importlib.import_module(f"{__name__}.{name}") for name in _MODULE_NAMES]


def register():
    registered = []
    try:
        for module in _modules():
            module.register()
            registered.append(module)
    except Exception:
        # Leave Blender as it was: undo what was registered so far.
        for module in reversed(registered):
            module.unregister()
        raise


def unregister():
    from . import simulation

    simulation.cancel_all_jobs()
    for module in reversed(_modules()):
        module.unregister()
