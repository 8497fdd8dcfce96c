# SPDX-License-Identifier: MIT
"""Engine results -> Blender: one collection per run (tagged with the run id and its
parameters), holding the point cloud (points.py), the Volume objects (volumes.py) and the
endoscope-view Images (endoscope_views.py); deleting a run removes exactly what it made.
"""


import bpy

from . import endoscope_views, node_utils, points, run_summary, volumes
from .keys import PARAMS_KEY, RESULT_KEY, RUN_KEY, SUMMARY_KEY, SWEEP_KEY


def result_collections(scene):
    return [c for c in scene.collection.children_recursive if c.get(RESULT_KEY)]


def run_files(collection):
    """Files the run wrote that only it uses: its .vdb (a fresh name per run)."""
    summary = collection.get(SUMMARY_KEY)
    path = summary.get("grid_path", "") if summary is not None else ""
    return [path, volumes.render_grid_path(path)] if path else []


def remove_run(collection):
    """Delete a run's collection, every datablock tagged with its run id and its .vdb file,
    and the points node group (points.POINTS_GROUP) once no object uses it."""
    import os

    run_id = collection.get(RUN_KEY)
    for path in run_files(collection):
        if os.path.isfile(path):
            os.remove(path)
    for obj in list(collection.all_objects):
        if obj.get(RUN_KEY) == run_id:
            bpy.data.objects.remove(obj)
    for datablocks in (bpy.data.meshes, bpy.data.volumes, bpy.data.materials, bpy.data.images):
        for block in list(datablocks):
            if run_id is not None and block.get(RUN_KEY) == run_id and block.users == int(block.use_fake_user):
                datablocks.remove(block)
    parents = [c for c in bpy.data.collections if c.get(SWEEP_KEY) and collection.name in c.children]
    bpy.data.collections.remove(collection)
    for parent in parents:  # a sweep's parent collection goes with its last β
        if not parent.children and not parent.objects:
            bpy.data.collections.remove(parent)
    # The shared points node group goes with the last point cloud that used it (never while used).
    for group in list(bpy.data.node_groups):
        if group.name.startswith(points.POINTS_GROUP) and "endophoton_version" in group and group.users == 0:
            bpy.data.node_groups.remove(group)


def remove_results(scene):
    for collection in result_collections(scene):
        remove_run(collection)


def _unique_run_id(inputs):
    base = f"{inputs.timestamp}-{inputs.rig_name}"
    taken = {c.get(RUN_KEY) for c in bpy.data.collections}
    run_id, i = base, 1
    while run_id in taken:
        i += 1
        run_id = f"{base}-{i}"
    return run_id


def apply_result(context, inputs, result, grid_info=(), render_grids=None, view=None, tags=None, parent=None):
    """Build the run's collection from an engine Result (main thread only).

    ``render_grids``: what :func:`volumes.write_render_grids` returned for the run's .vdb;
    ``view``: the rig camera's ``ep.View`` (simulation.endoscope_view), made into Images;
    ``tags``: plain values added to the run's parameters (PARAMS_KEY), e.g. its sweep;
    ``parent``: the collection to put the run's collection in (a sweep's), else the scene's.

    Everything is checked first; the previous run's collection is replaced
    only once the new one can be built.
    """
    scene = bpy.data.scenes.get(inputs.scene_name) or context.scene
    settings = scene.endophoton

    escapes = getattr(result, "escapes", None) if inputs.output_points else None
    positions = attrs = None
    if inputs.output_points:
        if escapes is None:
            raise RuntimeError("the engine returned no escape records for the point cloud")
        positions, attrs = points.point_cloud_arrays(escapes, inputs.scale_length)
    grid_path = getattr(result, "grid_path", None)
    grids = list(grid_info)
    if grid_path and not grids:
        # No pyopenvdb: names from the result (or the file), densities not normalised.
        names = list(getattr(result, "grid_names", None) or []) or [None]
        grids = [(name, None, 0.0) for name in names]
    records = 0 if positions is None else len(positions)
    summary = run_summary.summary_from_result(result, inputs, records)

    run_id = _unique_run_id(inputs)
    beta = f"β={inputs.beta_deg:+.1f}°"
    collection = bpy.data.collections.new(f"EP {beta} {inputs.timestamp}")
    collection[RESULT_KEY] = True
    collection[RUN_KEY] = run_id
    (parent or scene.collection).children.link(collection)
    try:
        if positions is not None:
            material = points._points_material(f"EP Photons {beta}", run_id)
            obj = points.create_point_cloud(
                f"EP Photons {beta}",
                positions,
                attrs,
                settings.point_radius,
                material,
                run_id,
                names=points.record_names(result, inputs),
            )
            points.recolour(obj, settings)
            collection.objects.link(obj)
        for grid_name, _active, vmax in grids:
            if grid_name is None:
                grid_name = volumes._first_grid_name(grid_path)
            index_matrix = (render_grids or {}).get(grid_name)
            obj = volumes.create_volume(
                f"EP Grid {grid_name} {beta}",
                grid_path if index_matrix is None else volumes.render_grid_path(grid_path),
                grid_name,
                vmax,
                inputs.grid_voxel_m,
                inputs.scale_length,
                run_id,
                index_matrix=index_matrix,
            )
            collection.objects.link(obj)
        volumes.set_volume_scale(collection, settings)
        collection[SUMMARY_KEY] = summary
        collection[PARAMS_KEY] = {**run_parameters(inputs), **(tags or {})}
        if view is not None:
            endoscope_views.create_view_images(collection, view, f"{beta} {inputs.timestamp}")
    except Exception:
        remove_run(collection)
        raise
    settings.result_collection = collection
    show_run_legend(settings, collection)
    return collection


def show_run_legend(settings, collection):
    """Show the legend of ``collection``'s point cloud in the panel (right after its run, so the
    legend and Render with Legend are there at once); a run without points clears it."""
    legend = next((points.legend_of(obj) for obj in points.points_objects(collection)), None)
    if legend is None:
        settings.legend.clear()
        settings.legend_header = ""
    else:
        points.show_legend(settings, legend)


def id_int(value):
    """``value`` as an ID property holds it: an int within Blender's 32-bit range, else its
    decimal string (a β's own seed in a sweep with a seed per β reaches 2^64 - 1)."""
    value = int(value)
    return value if -(2**31) <= value < 2**31 else str(value)


def run_parameters(inputs):
    """The run's parameters as plain values (the tag that tells runs apart)."""
    return {
        "beta_deg": float(inputs.beta_deg),
        "rig": inputs.rig_name,
        "kind": inputs.kind,
        "count": int(inputs.count),
        "target_error": float(inputs.target_error or 0.0),
        "seed": id_int(inputs.seed),
        "fluorescent_only": bool(inputs.fluorescent_only),
        "fluorescence_rule": inputs.fluorescence_rule,
        "scale_length_m": float(inputs.scale_length),
        "voxel_size_m": float(inputs.grid_voxel_m or 0.0),
        "regions": [r.name for r in inputs.regions],
    }


def update_display(scene):
    """Apply point radius, colour mapping, filters and volume density to the scene's results.

    A display setting that is not a finite number within its limits (guards.check_display)
    changes no result: its message becomes the legend's header and is returned (else None)."""
    from . import guards
    from .errors import InputError

    settings = scene.endophoton
    try:
        guards.check_display(settings, f"Scene '{scene.name}'")
    except InputError as exc:
        settings.legend_header = str(exc)
        return str(exc)
    for collection in result_collections(scene):
        for obj in collection.all_objects:
            for modifier in obj.modifiers:
                if (
                    modifier.type == "NODES"
                    and modifier.node_group is not None
                    and modifier.node_group.name.startswith(points.POINTS_GROUP)
                ):
                    ids = node_utils.group_input_identifiers(modifier.node_group)
                    modifier[ids["Radius"]] = float(settings.point_radius)
                    obj.update_tag()
            if obj.get(points.NAMES_KEY) is not None:
                points.recolour(obj, settings)
        volumes.set_volume_scale(collection, settings)
