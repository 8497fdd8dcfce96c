# SPDX-License-Identifier: MIT
"""Add-on preferences: where to find the ``endophoton`` package, and an optional
Dask scheduler that runs trace on (docs/distributed.md)."""

import bpy
from bpy.props import StringProperty

from . import package_finder
from .utils import wrap_text


def _package_path_changed(_self, _context):
    package_finder.forget()


class EndoPhotonPreferences(bpy.types.AddonPreferences):
    bl_idname = __package__

    package_path: StringProperty(
        name="Package Folder",
        description=(
            "Folder that contains the 'endophoton' package (the folder holding "
            "endophoton/__init__.py). Leave empty when the package is pip-installed "
            "into a dist-packages folder Blender's Python sees"
        ),
        subtype="DIR_PATH",
        default="",
        update=_package_path_changed,
    )

    scheduler_address: StringProperty(
        name="Dask Scheduler",
        description=(
            "tcp://host:port of a Dask scheduler whose workers trace the runs (same results as a "
            "local run, bit for bit). Leave empty to run on this machine"
        ),
        default="",
    )

    def draw(self, _context):
        layout = self.layout
        layout.prop(self, "package_path")
        layout.prop(self, "scheduler_address")
        module, message = package_finder.status()
        if module is None:
            box = layout.box()
            box.label(text="EndoPhoton engine not available", icon="ERROR")
            for line in wrap_text(message, 90):
                box.label(text=line)
        else:
            layout.label(text=f"Engine: {getattr(module, '__file__', 'endophoton')}", icon="CHECKMARK")
        layout.operator("endophoton.retry_engine_import", icon="FILE_REFRESH")


CLASSES = (EndoPhotonPreferences,)


def scheduler_address(context=None):
    """The preferences' Dask scheduler address ('' = run locally); main thread only."""
    addon = (context or bpy.context).preferences.addons.get(__package__)
    return addon.preferences.scheduler_address.strip() if addon is not None else ""
