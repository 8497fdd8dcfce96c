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


# Registration order matters: preferences and properties first (operators and
# panels refer to them), panels last.  Each module lists its classes in
# CLASSES; properties.py also lists the PointerProperties it attaches to
# Blender's types in POINTERS, operators.py its app handlers in HANDLERS,
# rig_overlay.py its viewport draw handlers in DRAW_HANDLERS.
# This file holds the only registration loop.
_DRAW_HANDLES = {}  # (space type, callback) -> handle of draw_handler_add


def _add_draw_handler(key, region, draw_type):
    if key not in _DRAW_HANDLES:
        _DRAW_HANDLES[key] = key[0].draw_handler_add(key[1], (), region, draw_type)


def _modules():
    from . import operators, panels, preferences, properties, rig_overlay

    return [preferences, properties, operators, panels, rig_overlay]


def _steps():
    """(do, undo) pairs in registration order: every class, every pointer, every handler."""
    import bpy

    steps = []
    modules = _modules()
    for module in modules:
        for cls in module.CLASSES:
            steps.append((lambda c=cls: bpy.utils.register_class(c), lambda c=cls: bpy.utils.unregister_class(c)))
    for module in modules:
        for owner, name, group in getattr(module, "POINTERS", ()):
            steps.append(
                (
                    lambda o=owner, n=name, g=group: setattr(o, n, bpy.props.PointerProperty(type=g)),
                    lambda o=owner, n=name: delattr(o, n),
                )
            )
    for module in modules:
        for space, callback, region, draw_type in getattr(module, "DRAW_HANDLERS", ()):
            key = (space, callback)  # the handle lives in _DRAW_HANDLES between register and unregister
            steps.append(
                (
                    lambda k=key, r=region, d=draw_type: _add_draw_handler(k, r, d),
                    lambda k=key, r=region: k[0].draw_handler_remove(_DRAW_HANDLES.pop(k), r)
                    if k in _DRAW_HANDLES
                    else None,
                )
            )
    for module in modules:
        for list_name, function in getattr(module, "HANDLERS", ()):
            handlers = getattr(bpy.app.handlers, list_name)
            steps.append(
                (
                    lambda h=handlers, f=function: h.append(f) if f not in h else None,
                    lambda h=handlers, f=function: h.remove(f) if f in h else None,
                )
            )
    return steps


def register():
    done = []
    try:
        for do, undo in _steps():
            do()
            done.append(undo)
    except Exception:
        # Leave Blender as it was: undo what was registered so far.
        for undo in reversed(done):
            undo()
        raise


def unregister():
    from . import simulation

    simulation.cancel_all_jobs()
    simulation.forget_engine_scenes()
    for _do, undo in reversed(_steps()):
        undo()
