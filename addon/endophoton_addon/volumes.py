# SPDX-License-Identifier: MIT
"""The voxel grids as Volume objects: the engine writes FOG_VOLUME grids to a .vdb; each grid
becomes a Volume object loading (a Cycles copy of) that file, with a volume material whose
colour and density follow the grid value on the scene's Volume Scale."""

import os

import bpy
import mathutils
import numpy as np

from . import blend_paths, node_utils
from .keys import RUN_KEY

DENSITY_NODE = "EP Density Scale"


# Each grid's own colour ramp (dark -> bright, linear RGB); other names get the last one. The grids'
# names and quantities: endophoton.vdb.GRID_QUANTITIES (the fluorescence grids were renamed
# fluorescent_light*; the old names stay for files written before).
GRID_RAMPS = {
    "absorbed": ((0.5, 0.06, 0.0), (1.0, 0.4, 0.03), (1.0, 0.95, 0.6)),
    "fluorescent_light": ((0.05, 0.5, 0.05), (0.2, 1.0, 0.3), (0.85, 1.0, 0.75)),
    "fluorescent_light_collagen": ((0.03, 0.2, 0.6), (0.1, 0.55, 1.0), (0.75, 0.95, 1.0)),
    "fluorescent_light_photofrin": ((0.5, 0.0, 0.08), (1.0, 0.05, 0.2), (1.0, 0.75, 0.85)),
    "emission_collagen": ((0.03, 0.2, 0.6), (0.1, 0.55, 1.0), (0.75, 0.95, 1.0)),
    "emission_photofrin": ((0.5, 0.0, 0.08), (1.0, 0.05, 0.2), (1.0, 0.75, 0.85)),
}
# Files written before the rename hold the light grids under their old names: the same ramps.
LEGACY_RAMP_NAMES = {"fluorescence": "fluorescent_light", "fluorescence_collagen": "fluorescent_light_collagen",
                     "fluorescence_photofrin": "fluorescent_light_photofrin"}  # fmt: skip
GRID_RAMPS.update({old: GRID_RAMPS[new] for old, new in LEGACY_RAMP_NAMES.items()})


OTHER_RAMP = ((0.3, 0.05, 0.5), (0.7, 0.2, 1.0), (0.95, 0.85, 1.0))


INV_PEAK_NODE = "EP 1/peak"  # value: 1 / (the grid's or the run's maximum)


LOG_NODE = "EP log scale"  # value: 0 = linear, 1 = log


DECADES_NODE = "EP decades"  # value: decades shown by the log scale


def _math(nodes, links, operation, a, b=None, location=(0, 0), clamp=False):
    node = nodes.new("ShaderNodeMath")
    node.operation = operation
    node.use_clamp = clamp
    node.location = location
    for socket, value in ((node.inputs[0], a), (node.inputs[1], b)):
        if value is None:
            continue
        if isinstance(value, (int, float)):
            socket.default_value = value
        else:
            links.new(value, socket)
    return node.outputs[0]


def _value(nodes, name, value, location):
    node = nodes.new("ShaderNodeValue")
    node.name = node.label = name
    node.outputs[0].default_value = value
    node.location = location
    return node.outputs[0]


def _volume_material(name, grid_name, voxel_bu, run_id):
    """Grid value v -> t in [0, 1]: linear t = v/peak, or log t = 1 + log10(v/peak)/decades;
    colour = the grid's ramp at t, density = emission strength = t · Volume Density / voxel
    (Volume Density is then the optical depth of one voxel at t = 1)."""
    mat, nodes, links, out, attr = node_utils.attribute_material(name, run_id, grid_name)
    out.location = (900, 0)
    inv_peak = _value(nodes, INV_PEAK_NODE, 1.0, (-400, -200))
    use_log = _value(nodes, LOG_NODE, 0.0, (-400, -300))
    decades = _value(nodes, DECADES_NODE, 3.0, (-400, -400))
    scale = _value(nodes, DENSITY_NODE, 0.2, (300, -300))
    rel = _math(nodes, links, "MULTIPLY", attr.outputs["Fac"], inv_peak, (-200, 0))
    t_lin = _math(nodes, links, "MULTIPLY", rel, 1.0, (0, 100), clamp=True)
    log10 = _math(nodes, links, "LOGARITHM", _math(nodes, links, "MAXIMUM", rel, 1e-12, (-100, -100)), 10.0, (0, -100))
    t_log = _math(
        nodes, links, "ADD", _math(nodes, links, "DIVIDE", log10, decades, (100, -100)), 1.0, (200, -100), clamp=True
    )
    t = _math(
        nodes,
        links,
        "ADD",
        t_lin,
        _math(nodes, links, "MULTIPLY", use_log, _math(nodes, links, "SUBTRACT", t_log, t_lin, (300, -50)), (400, -50)),
        (500, 0),
    )
    ramp = nodes.new("ShaderNodeValToRGB")
    ramp.location = (550, 250)
    stops = GRID_RAMPS.get(grid_name, OTHER_RAMP)
    elements = ramp.color_ramp.elements
    elements.new(0.5)
    for element, colour in zip(elements, stops):
        element.color = (*colour, 1.0)
    links.new(t, ramp.inputs["Fac"])
    density = _math(
        nodes, links, "MULTIPLY", _math(nodes, links, "MULTIPLY", t, scale, (600, -200)), 1.0 / voxel_bu, (700, -200)
    )
    volume = nodes.new("ShaderNodeVolumePrincipled")
    # Density comes from the link below; the node's own "density" attribute
    # lookup would multiply it by a grid that does not exist (= 0).
    volume.inputs["Density Attribute"].default_value = ""
    volume.location = (750, 100)
    links.new(ramp.outputs["Color"], volume.inputs["Color"])
    links.new(ramp.outputs["Color"], volume.inputs["Emission Color"])
    links.new(density, volume.inputs["Density"])
    links.new(density, volume.inputs["Emission Strength"])
    links.new(volume.outputs["Volume"], out.inputs["Volume"])
    return mat


def set_volume_scale(collection, settings):
    """Apply Volume Scale (own maximum, the run's shared maximum, log), decades and density."""
    volumes = [o for o in collection.all_objects if o.type == "VOLUME" and "endophoton_grid_max" in o]
    shared = max([o["endophoton_grid_max"] for o in volumes] or [0.0])
    for obj in volumes:
        peak = shared if settings.volume_scale == "SHARED" else obj["endophoton_grid_max"]
        values = {
            INV_PEAK_NODE: 1.0 / peak if peak > 0 else 1.0,
            LOG_NODE: float(settings.volume_scale == "LOG"),
            DECADES_NODE: float(settings.volume_decades),
            DENSITY_NODE: float(settings.volume_density),
        }
        for slot in obj.material_slots:
            if slot.material is None or not slot.material.use_nodes:
                continue
            for node_name, value in values.items():
                node = slot.material.node_tree.nodes.get(node_name)
                if node is not None:
                    node.outputs[0].default_value = value


# Why Cycles needs its own copy of the grids (Blender 3.4, intern/cycles/scene/volume.cpp):
# Cycles bounds a volume by a mesh around its active leaf nodes, and shifts every vertex of
# that mesh by 0.1 * hash(datablock name) / (active voxels along the axis) *in the grid's
# own units*, "to avoid overlapping faces".  The offset is meant to be a tiny fraction of a
# voxel, which it is only when a voxel is about one unit.  The engine's grids are in metres
# (0.5 mm voxels), so the shift is up to 0.1 / 14 m = 7 mm = 14 voxels for a grid 14 voxels
# deep: the bounding mesh misses the data, and which grids render empty follows the
# datablock's name (renaming one changes it), never the data.  The copy below keeps the
# values and uses voxel index space (voxel size 1) as grid space; the Volume object's
# matrix carries the index -> metres -> Blender units transform instead, so the shift is
# at most 0.1 / dim of a voxel.
RENDER_GRID_SUFFIX = ".cycles.vdb"


def render_grid_path(path):
    """The Cycles copy of the run's .vdb ``path`` (see RENDER_GRID_SUFFIX)."""
    return os.path.splitext(path)[0] + RENDER_GRID_SUFFIX


def write_render_grids(path):
    """Write :func:`render_grid_path` of ``path`` (no bpy: the worker thread calls it).

    Returns {grid name: its index -> metres matrix (4x4 rows)}, or {} without pyopenvdb
    (the Volume objects then load ``path`` itself)."""
    try:
        import pyopenvdb
    except ImportError:
        return {}
    grids, metadata = pyopenvdb.readAll(path)
    matrices = {}
    for grid in grids:
        origin = np.array(grid.transform.indexToWorld((0, 0, 0)), dtype=np.float64)
        matrix = np.eye(4)
        for axis in range(3):
            unit = [0, 0, 0]
            unit[axis] = 1
            matrix[:3, axis] = np.array(grid.transform.indexToWorld(unit)) - origin
        matrix[:3, 3] = origin
        matrices[grid.name] = matrix.tolist()
        grid.transform = pyopenvdb.createLinearTransform(voxelSize=1.0)
    target = render_grid_path(path)
    partial = f"{target}.{os.getpid()}.partial.vdb"
    pyopenvdb.write(partial, grids=grids, metadata=metadata)
    os.replace(partial, target)
    return matrices


def create_volume(name, path, grid_name, vmax, voxel_m, scale_length, run_id, index_matrix=None):
    """Volume object loading ``path`` and rendering ``grid_name`` (metres -> Blender units).

    ``index_matrix``: the grid's index -> metres matrix when ``path`` is the Cycles copy
    written by :func:`write_render_grids` (grid space = voxel index space)."""
    volume = bpy.data.volumes.new(name)
    volume[RUN_KEY] = run_id
    volume.filepath = blend_paths.stored_path(path)
    # Load up front: a missing or unreadable file is reported here, not at render time.
    if not volume.grids.load():
        raise RuntimeError(f"grid file '{path}' could not be read: {volume.grids.error_message}")
    if volume.grids.find(grid_name) < 0:
        raise RuntimeError(f"grid file '{path}' has no grid '{grid_name}'")
    volume.grids.active_index = volume.grids.find(grid_name)
    # Cycles treats voxels below render.clipping (default 1e-3) as empty, and
    # tallies per launched packet are far smaller: clip relative to the peak.
    volume.render.clipping = 1e-4 * vmax if vmax > 0 else 0.0
    voxel_bu = voxel_m / scale_length
    volume.materials.append(_volume_material(name, grid_name, voxel_bu, run_id))
    obj = bpy.data.objects.new(name, volume)
    obj[RUN_KEY] = run_id
    obj["endophoton_grid"] = grid_name
    obj["endophoton_grid_max"] = float(vmax)
    inv = 1.0 / scale_length
    if index_matrix is None:
        obj.scale = (inv, inv, inv)
    else:
        obj.matrix_world = mathutils.Matrix(np.diag([inv, inv, inv, 1.0]) @ np.asarray(index_matrix))
    return obj


def _first_grid_name(path):
    probe = bpy.data.volumes.new("EP probe")
    try:
        probe.filepath = path
        probe.grids.load()
        if not len(probe.grids):
            raise RuntimeError(f"grid file '{path}' holds no grids")
        return probe.grids[0].name
    finally:
        bpy.data.volumes.remove(probe)
