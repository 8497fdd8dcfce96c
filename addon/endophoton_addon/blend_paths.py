# SPDX-License-Identifier: MIT
"""The files a run or a sweep refers to from the .blend (a run's .vdb on its Volume datablocks, the
sweep's plot images, the legend PNG) are stored ``//``-relative to the saved .blend, so a project
folder moved or shared as a whole keeps working.

A path made while the .blend is saved is stored relative at once (:func:`stored_path`); paths made
in an unsaved file (they live in the temporary folder) are made relative when the file is saved:
:func:`relative_on_save` (a ``save_post`` handler) rewrites them and saves once more, so the file
on disk holds the relative paths.
"""

import os

import bpy

from .keys import RUN_KEY, SWEEP_PLOT_KEY

_busy = {"saving": False}


def stored_path(path):
    """``path`` as the .blend should hold it: ``//``-relative when the .blend is saved, else as is."""
    if not path or path.startswith("//") or not bpy.data.filepath:
        return path
    # A .blend opened by a relative path (``open_mainfile(filepath="scenes/a.blend")``)
    # has a relative bpy.data.filepath; Blender resolves "//" against it without the
    # working directory and misses the file, so such paths stay absolute.
    if not os.path.isabs(bpy.data.filepath):
        return path
    try:
        return bpy.path.relpath(os.path.abspath(path))
    except ValueError:  # another drive (Windows): keep it absolute
        return path


def _ours():
    for datablocks in (bpy.data.volumes, bpy.data.images):
        for block in datablocks:
            if (block.get(RUN_KEY) is not None or block.get(SWEEP_PLOT_KEY)) and block.filepath:
                yield block


def make_relative():
    """Rewrite the add-on's absolute file paths as ``//``-relative ones; returns how many changed."""
    changed = 0
    for block in _ours():
        relative = stored_path(block.filepath)
        if relative != block.filepath:
            block.filepath = relative
            changed += 1
    return changed


@bpy.app.handlers.persistent
def relative_on_save(*_args):
    """save_post: when the saved file still held absolute paths of ours, store them relative and
    save again (once; the nested save does not recurse)."""
    if _busy["saving"] or not bpy.data.filepath or not make_relative():
        return
    _busy["saving"] = True
    try:
        bpy.ops.wm.save_mainfile()
    finally:
        _busy["saving"] = False
