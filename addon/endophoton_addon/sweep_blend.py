# SPDX-License-Identifier: MIT
"""The β sweep on a Blender scene, from scripts and the command line.

The package's ``python3 -m endophoton sweep --blend FILE`` starts
``blender -b FILE`` and calls :func:`main` here; scripts inside Blender call
:func:`sweep_blend` directly.  Both export the scene through :mod:`export`,
read the rig's sweep geometry from its properties and call the package's
``endophoton.sweep`` — the add-on depends on the package, never the reverse.

:func:`blender_regions_to_scene` is the one place that turns exported regions
into an engine scene; the Run and Sweep β operators use it too.

Lengths: Blender units × ``unit_settings.scale_length`` = metres, the engine
scene's unit here.
"""

import argparse
import os
import sys

from . import export, package_finder, rig

__all__ = ["blender_regions_to_scene", "rig_sweep_geometry", "enable_addon", "sweep_blend", "main"]


def _medium(ep, medium):
    """The engine medium of an exported medium dict: the named ep.media preset (spectral), else the numbers."""
    if medium.get("preset"):
        return ep.media.preset(medium["preset"])
    return ep.Medium(**medium)


def blender_regions_to_scene(ep, regions):
    """``ep.Scene(unit="m")`` holding the exported regions (a list of ``export.RegionExport``).

    Raises ValueError (the engine's own message, naming region and field) on bad input.
    """
    scene = ep.Scene(unit="m")
    for region in regions:
        fluorophores = [ep.Fluorophore(name, d, c) for name, d, c in region.fluorophores]
        scene.add_mesh(
            region.name,
            region.vertices,
            region.triangles,
            _medium(ep, region.medium),
            priority=region.priority,
            fluorophores=fluorophores,
        )
    return scene


def rig_sweep_geometry(rig_obj, scale_length):
    """What the sweep rebuilds the head from, for every β: ``distance_m``, ``point_m`` (target),
    ``normal``, ``tilt_axis`` and ``rig_params`` (head dimensions, ``EndoscopeRig`` keywords).

    Plain read of the rig's properties, in metres; validation is the caller's.
    """
    s = rig_obj.endophoton_rig
    return dict(
        distance_m=float(s.distance) * scale_length,
        point_m=tuple(float(x) * scale_length for x in s.target),
        normal=tuple(float(x) for x in s.normal),
        tilt_axis=tuple(float(x) for x in s.tilt_axis),
        rig_params=dict(rig.rig_parameters(rig_obj, scale_length)),
    )


def enable_addon():
    """Make sure the EndoPhoton add-on is registered (``scene.endophoton`` exists).

    Uses ``addon_utils.enable`` when Blender knows the add-on (installed), else
    registers this package directly (imported from a source tree on ``sys.path``).
    """
    import bpy

    if hasattr(bpy.types.Scene, "endophoton"):
        return
    import addon_utils

    package = __package__ or "endophoton_addon"
    if any(m.__name__ == package for m in addon_utils.modules()):
        addon_utils.enable(package, default_set=False)
        if hasattr(bpy.types.Scene, "endophoton"):
            return
    sys.modules[package].register()


def _open_scene(blend):
    import bpy

    if isinstance(blend, (str, os.PathLike)):
        bpy.ops.wm.open_mainfile(filepath=os.fspath(blend))
        return bpy.context.scene
    return bpy.context.scene if blend is None else blend


def _blend_rig_kwargs(bscene, kwargs):
    """``kwargs`` completed from the scene's rig (the chosen one, or its only one); kwargs win."""
    chosen = bscene.endophoton.rig
    rigs = [chosen] if chosen is not None else list(rig.find_rigs(bscene))
    if len(rigs) != 1:
        return kwargs
    geo = rig_sweep_geometry(rigs[0], float(bscene.unit_settings.scale_length))
    kw = dict(kwargs)
    kw.setdefault("distance", geo["distance_m"])
    kw.setdefault("point", geo["point_m"])
    kw.setdefault("normal", geo["normal"])
    kw.setdefault("tilt_axis", geo["tilt_axis"])
    kw["rig_kwargs"] = {**geo["rig_params"], **(kw.get("rig_kwargs") or {})}
    return kw


def sweep_blend(blend=None, use_blend_rig=True, **kwargs):
    """Run ``endophoton.sweep`` on a Blender scene; returns its ``SweepResult``.

    Must run inside Blender with the add-on registered (:func:`enable_addon`).
    ``blend`` is a ``bpy.types.Scene``, a path to a ``.blend`` file (opened with
    ``bpy.ops.wm.open_mainfile``) or ``None`` for the current scene.

    * regions: :func:`export.export_regions` (evaluated meshes, world space,
      metres) turned into an engine scene by :func:`blender_regions_to_scene`,
      exactly as the Run operator does;
    * rig: rebuilt for each β with ``EndoscopeRig.from_beta``.  With
      ``use_blend_rig`` and an endoscope rig in the scene (the scene's chosen
      rig, or its only one) its target, normal, tilt axis, distance and head
      dimensions are used (:func:`rig_sweep_geometry`); otherwise the defaults
      of ``endophoton.sweep`` (1 cm, origin, +z, tilt about y).  Keyword
      arguments given here win over both.

    The same regions, rig and seed give the same numbers as ``endophoton.sweep``
    on an ``ep.Scene`` built from the same arrays in plain Python.
    """
    import bpy

    ep = package_finder.require()
    bscene = _open_scene(blend)
    if not hasattr(bscene, "endophoton"):
        raise RuntimeError(
            "the EndoPhoton add-on is not registered (scene.endophoton is missing); " "call enable_addon() first"
        )
    current = bscene == bpy.context.scene
    view_layer = bpy.context.view_layer if current else bscene.view_layers[0]
    depsgraph = bpy.context.evaluated_depsgraph_get() if current else bscene.view_layers[0].depsgraph
    scene = blender_regions_to_scene(ep, export.export_regions(bscene, view_layer, depsgraph))
    kw = _blend_rig_kwargs(bscene, kwargs) if use_blend_rig else dict(kwargs)
    result = ep.sweep(scene, **kw)
    result.meta["scene"] = f"blender scene '{bscene.name}'" + (f" ({bpy.data.filepath})" if bpy.data.filepath else "")
    return result


def main(argv):
    """Inside ``blender -b FILE``: parse the ``sweep`` arguments forwarded by the package's CLI,
    register the add-on, sweep the open scene and write the outputs.  Returns the exit code."""
    enable_addon()
    package_finder.require()
    from endophoton import cli
    from endophoton.sweep import cli as sweep_cli

    parser = argparse.ArgumentParser(prog="endophoton sweep (blender)")
    sweep_cli.add_sweep_arguments(parser)
    # Bad input (e.g. a beta whose head enters the wall) exits 2 with the message, as the package's CLI.
    return cli.run_guarded(_sweep_and_write, parser.parse_args(argv))


def _sweep_and_write(args) -> int:
    """Sweep the open scene with the parsed ``sweep`` arguments and write the outputs; the exit code."""
    from endophoton.sweep import cli as sweep_cli
    from endophoton.sweep import driver as beta_sweep

    with sweep_cli.scheduler_client(args) as client:  # --scheduler: the angles run on that cluster
        res = sweep_blend(None, client=client, **sweep_cli.sweep_kwargs(args))
    beta_sweep.write_outputs(res, args.out)
    print(f"sweep: wrote {args.out}")
    return 130 if res.meta.get("cancelled") else 0
