# SPDX-License-Identifier: MIT
"""Engine results -> Blender: one collection per run holding the surface
photon map as a point cloud and the voxel grids as Volume objects.

Point cloud: a mesh of vertices only, per-point data as named attributes
written with ``foreach_set``; a Geometry Nodes "Mesh to Points" modifier turns
it into a point cloud Cycles renders, with a material colouring the points by
wavelength (Wavelength node) or by energy.

Grids: the engine writes FOG_VOLUME grids to a .vdb; each grid becomes a
Volume object loading that file, with a volume material whose density is the
grid value normalised to its maximum times the scene's "Volume Density".

Everything the run creates is tagged with the run id (ID property
``endophoton_run``) so a re-run removes exactly that.
"""

import os

import bpy
import mathutils
import numpy as np

from . import colour_maps

RESULT_KEY = "endophoton_result"  # on the run's collection
RUN_KEY = "endophoton_run"  # on every datablock the run created
SUMMARY_KEY = "endophoton_summary"  # on the run's collection
PARAMS_KEY = "endophoton_params"  # on the run's collection: what the run was asked to do
SWEEP_KEY = "endophoton_sweep"  # on a sweep's parent collection (its sweep id): holds its β collections
POINTS_GROUP = "EP Photon Points"
DENSITY_NODE = "EP Density Scale"
EMISSION_NODE = "EP Point Emission"

TOTAL_NAMES = (
    "diffuse_reflectance",
    "specular_reflectance",
    "transmittance",
    "absorbed",
    "missed",
    "cut",
    "roulette",
    "fluorescent_escaped",
    "escaped_energy",
)

# Escape-record column -> (attribute name, Blender attribute type, numpy dtype, width)
POINT_ATTRIBUTES = (
    ("weight", "weight", "FLOAT", np.float32, 1),
    ("energy", "energy", "FLOAT", np.float32, 1),
    ("wavelength", "wavelength", "FLOAT", np.float32, 1),
    ("fluorescent", "fluorescent", "BOOLEAN", np.bool_, 1),
    ("fluorophore", "fluorophore", "INT", np.int32, 1),
    ("max_depth", "depth", "FLOAT", np.float32, 1),  # cm, as the engine reports it
    ("direction", "direction", "FLOAT_VECTOR", np.float32, 3),
    ("light", "light", "INT", np.int32, 1),
    ("kind", "kind", "INT", np.int32, 1),
    ("region", "region", "INT", np.int32, 1),
    ("scatterings", "scatterings", "INT", np.int32, 1),
    ("exit_order", "exit_order", "INT", np.int32, 1),  # 1st, 2nd, ... exit of its packet into the ambient
    ("next_hit", "next_hit", "INT", np.int32, 1),  # where its ray went: 0 away, 1 tissue, 2 head, 3 camera
)
COLOUR_ATTR = "ep_colour"  # linear RGB of the chosen mapping (colour_maps.colour_records)
SHOW_ATTR = "ep_show"  # False = hidden by the filters (Mesh to Points' selection)
STRENGTH_ATTR = "ep_strength"  # emission strength: the record's energy over the shown records' mean
NAMES_KEY = "endophoton_names"  # on the points object: {"fluorophore": [...], "region": [...]}
LEGEND_KEY = "endophoton_legend"  # on the points object: colour_maps.Legend.to_dict()


# --- pure numpy ----------------------------------------------------------------
def point_cloud_arrays(escapes, scale_length):
    """Validate escape records; return (positions in Blender units, {attr: (type, array)})."""
    if "position" not in escapes:
        raise ValueError("escape records have no 'position' column")
    position = np.asarray(escapes["position"], dtype=np.float64).reshape(-1, 3)
    count = len(position)
    attrs = {}
    for column, name, bl_type, dtype, width in POINT_ATTRIBUTES:
        if column not in escapes:
            continue
        values = np.asarray(escapes[column])
        if values.shape[0] != count or values.size != count * width:
            raise ValueError(f"escape column '{column}' has shape {values.shape}, expected ({count}, {width})")
        attrs[name] = (bl_type, np.ascontiguousarray(values.reshape(-1), dtype=dtype))
    return (position / scale_length).astype(np.float32), attrs


def summary_from_result(result, inputs, records):
    """Plain dict of what the panel shows (stored on the collection as ID properties)."""
    totals = {}
    for name in TOTAL_NAMES:
        value = getattr(result, name, None)
        if value is None:
            continue
        stderr = getattr(result, f"{name}_stderr", 0.0) or 0.0
        totals[name] = [float(value), float(stderr)]
    regions = {}
    by_region = getattr(result, "absorbed_by_region", None) or {}
    by_region_se = getattr(result, "absorbed_by_region_stderr", None) or {}
    for name, value in by_region.items():
        regions[str(name)] = [float(value), float(by_region_se.get(name, 0.0))]
    packets_traced = getattr(result, "packets_traced", None)
    if packets_traced is None:
        packets_traced = getattr(result, "photons", 0)
    return {
        "beta_deg": float(inputs.beta_deg),
        "timestamp": inputs.timestamp,
        "mode": inputs.kind,
        "requested": int(inputs.count),
        "photons": int(getattr(result, "photons", 0) or 0),
        "packets_traced": int(packets_traced or 0),
        "records": int(records),
        "seconds": float(getattr(result, "seconds", 0.0) or 0.0),
        "grid_path": str(getattr(result, "grid_path", None) or ""),
        "totals": totals,
        "absorbed_by_region": regions,
    }


# --- datablocks ----------------------------------------------------------------
def _new_socket(group, in_out, socket_type, name):
    """Group socket in 3.x (group.inputs/outputs) and 4.x (group.interface)."""
    if hasattr(group, "interface"):
        return group.interface.new_socket(name=name, in_out=in_out, socket_type=socket_type)
    sockets = group.inputs if in_out == "INPUT" else group.outputs
    return sockets.new(socket_type, name)


def _points_group():
    group = bpy.data.node_groups.get(POINTS_GROUP)
    if group is not None and group.bl_idname == "GeometryNodeTree" and group.get("endophoton_version") == 3:
        return group
    group = bpy.data.node_groups.new(POINTS_GROUP, "GeometryNodeTree")
    group["endophoton_version"] = 3
    _new_socket(group, "INPUT", "NodeSocketGeometry", "Geometry")
    radius = _new_socket(group, "INPUT", "NodeSocketFloat", "Radius")
    radius.default_value = 0.0001
    radius.min_value = 0.0
    _new_socket(group, "INPUT", "NodeSocketMaterial", "Material")
    _new_socket(group, "OUTPUT", "NodeSocketGeometry", "Geometry")
    nodes, links = group.nodes, group.links
    gin = nodes.new("NodeGroupInput")
    gin.location = (-400, 0)
    show = nodes.new("GeometryNodeInputNamedAttribute")
    show.data_type = "BOOLEAN"
    show.inputs["Name"].default_value = SHOW_ATTR
    show.location = (-400, -200)
    to_points = nodes.new("GeometryNodeMeshToPoints")
    to_points.mode = "VERTICES"
    to_points.location = (-150, 0)
    set_mat = nodes.new("GeometryNodeSetMaterial")
    set_mat.location = (100, 0)
    gout = nodes.new("NodeGroupOutput")
    gout.location = (320, 0)
    links.new(gin.outputs["Geometry"], to_points.inputs["Mesh"])
    # Named Attribute has one "Attribute" output per data type; only the BOOLEAN one is enabled.
    shown = next(o for o in show.outputs if o.name == "Attribute" and o.enabled)
    links.new(shown, to_points.inputs["Selection"])
    links.new(gin.outputs["Radius"], to_points.inputs["Radius"])
    links.new(to_points.outputs["Points"], set_mat.inputs["Geometry"])
    links.new(gin.outputs["Material"], set_mat.inputs["Material"])
    links.new(set_mat.outputs["Geometry"], gout.inputs["Geometry"])
    return group


def _group_input_identifiers(group):
    if hasattr(group, "interface"):
        return {
            item.name: item.identifier
            for item in group.interface.items_tree
            if getattr(item, "in_out", None) == "INPUT"
        }
    return {s.name: s.identifier for s in group.inputs}


def _attribute_material(name, run_id, attribute_name):
    """New node material reading the geometry attribute ``attribute_name``:
    returns (material, nodes, links, output node, attribute node)."""
    mat = bpy.data.materials.new(name)
    mat[RUN_KEY] = run_id
    mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    nodes.clear()
    out = nodes.new("ShaderNodeOutputMaterial")
    out.location = (600, 0)
    attr = nodes.new("ShaderNodeAttribute")
    attr.attribute_type = "GEOMETRY"
    attr.attribute_name = attribute_name
    attr.location = (-400, 0)
    return mat, nodes, links, out, attr


def _points_material(name, run_id):
    """Emission coloured by the point attribute ``ep_colour`` and as bright as the
    record's energy (``ep_strength``, written by :func:`recolour`): a packet that
    landed on tissue across the lumen and left again carries little weight and
    glows accordingly, as the light it stands for does.  The points are otherwise
    transparent (emission + Transparent BSDF), so overlapping points add up like
    the light they stand for: a pixel shows the sum of its records' colours times
    energies (up to Cycles' transparent bounces), not the front point's."""
    mat, nodes, links, out, colour = _attribute_material(name, run_id, COLOUR_ATTR)
    strength = nodes.new("ShaderNodeAttribute")
    strength.attribute_type = "GEOMETRY"
    strength.attribute_name = STRENGTH_ATTR
    strength.location = (-400, -200)
    scale = nodes.new("ShaderNodeMath")
    scale.operation = "MULTIPLY"
    scale.inputs[1].default_value = 1.0
    scale.location = (-150, -200)
    emit = nodes.new("ShaderNodeEmission")
    emit.name = emit.label = EMISSION_NODE
    emit.location = (100, 0)
    links.new(colour.outputs["Color"], emit.inputs["Color"])
    links.new(strength.outputs["Fac"], scale.inputs[0])
    links.new(scale.outputs["Value"], emit.inputs["Strength"])
    clear = nodes.new("ShaderNodeBsdfTransparent")
    clear.location = (100, -150)
    add = nodes.new("ShaderNodeAddShader")
    add.location = (350, 0)
    links.new(emit.outputs["Emission"], add.inputs[0])
    links.new(clear.outputs["BSDF"], add.inputs[1])
    links.new(add.outputs["Shader"], out.inputs["Surface"])
    mat.blend_method = "BLEND"  # Eevee / Material Preview: the same see-through glow
    return mat


def read_point_columns(mesh):
    """The record attributes of a points mesh as numpy arrays (foreach_get)."""
    columns = {}
    for _column, name, bl_type, dtype, width in POINT_ATTRIBUTES:
        attribute = mesh.attributes.get(name)
        if attribute is None:
            continue
        values = np.empty(len(attribute.data) * width, dtype=dtype)
        attribute.data.foreach_get("vector" if width == 3 else "value", values)
        columns[name] = values.reshape(-1, 3) if width == 3 else values
    return columns


def _set_attribute(mesh, name, bl_type, values):
    attribute = mesh.attributes.get(name)
    if attribute is not None and attribute.data_type != bl_type:
        mesh.attributes.remove(attribute)
        attribute = None
    if attribute is None:
        attribute = mesh.attributes.new(name, bl_type, "POINT")
    key = "color" if bl_type == "FLOAT_COLOR" else ("vector" if bl_type == "FLOAT_VECTOR" else "value")
    attribute.data.foreach_set(key, values.ravel())


def display_filters(settings, names):
    """colour_maps.Filters from the scene's filter settings and the run's names."""
    fluorophores = list(names.get("fluorophore", ()))
    regions = list(names.get("region", ()))
    pick = settings.filter_fluorophore
    reg = settings.filter_region
    camera = settings.id_data.camera if settings.filter_toward_camera else None
    return colour_maps.Filters(
        fluorescent_only=bool(settings.filter_fluorescent),
        fluorophore=fluorophores.index(pick) if pick in fluorophores else (-2 if pick == "ANY" else -3),
        region=regions.index(reg) if reg in regions else (-2 if reg == "ANY" else -3),
        toward=None if camera is None else (tuple(camera.matrix_world.translation), settings.camera_cone_deg),
    )


def point_names(obj):
    names = obj.get(NAMES_KEY)
    if names is None:
        return {}
    return {k: list(v) for k, v in (names.to_dict() if hasattr(names, "to_dict") else dict(names)).items()}


def emission_strength(energy, show, count):
    """Per-point emission strength: energy / mean energy of the shown points
    (1 where the energy column is missing or no shown point has energy)."""
    if energy is None or len(energy) != count:
        return np.ones(count, dtype=np.float32)
    w = np.asarray(energy, dtype=np.float64)
    shown = w[np.asarray(show, dtype=bool)] if count else w
    mean = shown.mean() if shown.size else 0.0
    if not (mean > 0 and np.isfinite(mean)):
        return np.ones(count, dtype=np.float32)
    return (w / mean).astype(np.float32)


def recolour(obj, settings):
    """Write ``ep_colour`` / ``ep_show`` of a points object for the scene's
    Colour By and filters; store and return its legend (colour_maps.Legend)."""
    from . import package_finder

    mesh = obj.data
    columns = read_point_columns(mesh)
    position = np.empty(len(mesh.vertices) * 3, np.float32)
    mesh.vertices.foreach_get("co", position)
    columns["position"] = position.reshape(-1, 3) @ np.asarray(obj.matrix_world.to_3x3(), np.float32).T + np.asarray(
        obj.matrix_world.translation, np.float32
    )
    names = point_names(obj)
    key = settings.color_by
    if colour_maps.COLOUR_MAPS[key].column not in columns:
        key = "WAVELENGTH"  # e.g. "Exit Order" on a result without that column
    try:
        rgb, show, legend = colour_maps.colour_records(
            key, columns, display_filters(settings, names), names, count=len(mesh.vertices)
        )
    except package_finder.EngineMissing as exc:  # wavelength colour needs endophoton.view.colour
        settings.legend.clear()
        settings.legend_header = f"Cannot colour the points: {exc}"
        return None
    rgba = np.ones((len(rgb), 4), dtype=np.float32)
    rgba[:, :3] = rgb
    _set_attribute(mesh, COLOUR_ATTR, "FLOAT_COLOR", rgba)
    _set_attribute(mesh, SHOW_ATTR, "BOOLEAN", show)
    _set_attribute(mesh, STRENGTH_ATTR, "FLOAT", emission_strength(columns.get("energy"), show, len(rgb)))
    mesh.update()
    obj[LEGEND_KEY] = legend.to_dict()
    obj.update_tag()
    if settings.result_collection is not None and obj.name in settings.result_collection.all_objects:
        show_legend(settings, legend)
    return legend


def show_legend(settings, legend):
    """Copy a legend into the scene's panel rows (colour swatch + label)."""
    settings.legend.clear()
    settings.legend_header = legend.caption()
    for colour, label in legend.entries:
        entry = settings.legend.add()
        entry.name = label
        entry.colour = tuple(float(c) for c in colour)


def render_with_legend(scene, collection, path):
    """Render the scene's camera (its render settings) and write ``path``: the
    render (linear, exposed by the endoscope-view images' rule, colour_maps.exposed_srgb)
    with the colour bar of ``collection``'s points beside it, loaded as an Image
    tagged with the run (removed with it).  Returns the Image."""
    import os

    points = points_objects(collection)
    legend = legend_of(points[0]) if points else None
    if legend is None:
        raise RuntimeError(f"Collection '{collection.name}' has no coloured point cloud to make a legend of")
    if scene.camera is None:
        raise RuntimeError(f"Scene '{scene.name}' has no camera to render from")
    import tempfile

    images_before = set(bpy.data.images)
    try:
        with tempfile.TemporaryDirectory(prefix="endophoton_legend_") as tmp:
            raw = os.path.join(tmp, "raw.exr")  # linear scene values, no view transform; removed with tmp
            saved = scene.render.filepath, scene.render.image_settings.file_format
            try:
                scene.render.filepath = raw
                scene.render.image_settings.file_format = "OPEN_EXR"
                bpy.ops.render.render(write_still=True, scene=scene.name)
            finally:
                scene.render.filepath, scene.render.image_settings.file_format = saved
            rendered = bpy.data.images.load(raw)
            try:
                w, h = rendered.size
                pixels = np.empty(w * h * 4, np.float32)
                rendered.pixels.foreach_get(pixels)
            finally:
                bpy.data.images.remove(rendered)
        # Blender's rows run bottom-up; exposed like the endoscope-view images.
        picture, exposure = colour_maps.exposed_srgb(pixels.reshape(h, w, 4)[::-1, :, :3])
        os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
        colour_maps.legend_figure(legend, path, image=picture, title=f"{collection.name} (exposure ×{exposure:.3g})")
    except BaseException:  # no image of ours left behind (Blender's own "Render Result" slot stays, as after F12)
        for image in set(bpy.data.images) - images_before:
            if image.type != "RENDER_RESULT":
                bpy.data.images.remove(image)
        raise
    image = bpy.data.images.load(path, check_existing=True)
    image.reload()
    image[RUN_KEY] = collection.get(RUN_KEY)
    return image


EXPORT_FORMATS = ("CSV", "NPZ", "JSON")


def _plain(value):
    return value.to_dict() if hasattr(value, "to_dict") else value


def _atomic_writer(ep):
    """The package's atomic writes: endophoton.io."""
    import importlib

    return importlib.import_module(f"{ep.__name__}.io")


def export_result(ep, collection, path, fmt):
    """Write the run's photon map and summary: CSV (one row per record, header
    names the columns; summary in ``<path>.json`` beside it), NPZ (record
    columns + ``summary_json``) or JSON (summary, parameters and legend only).
    Atomic writes through the package.  Returns the paths written."""
    import io
    import json

    if fmt not in EXPORT_FORMATS:
        raise ValueError(f"export format = '{fmt}' must be one of {', '.join(EXPORT_FORMATS)}")
    points = points_objects(collection)
    columns = read_point_columns(points[0].data) if points else {}
    info = {
        "name": collection.name,
        "summary": _plain(collection.get(SUMMARY_KEY, {})),
        "parameters": _plain(collection.get(PARAMS_KEY, {})),
        "names": point_names(points[0]) if points else {},
    }
    summary_text = json.dumps(info, indent=1, sort_keys=True)
    writer = _atomic_writer(ep)
    if fmt == "JSON":
        return [writer.atomic_write_text(path, summary_text)]
    if fmt == "NPZ":
        buffer = io.BytesIO()
        np.savez(buffer, summary_json=np.array(summary_text), **columns)
        return [writer.atomic_write_bytes(path, buffer.getvalue())]
    flat = {}
    for name, values in columns.items():
        if values.ndim == 2:
            for j, axis in enumerate("xyz"):
                flat[f"{name}_{axis}"] = values[:, j]
        else:
            flat[name] = values
    table = np.column_stack([v.astype(np.float64) for v in flat.values()]) if flat else np.zeros((0, 0))
    buffer = io.StringIO()
    np.savetxt(buffer, table, delimiter=",", header=",".join(flat), comments="", fmt="%.9g")
    return [writer.atomic_write_text(path, buffer.getvalue()), writer.atomic_write_text(path + ".json", summary_text)]


def legend_of(obj):
    data = obj.get(LEGEND_KEY)
    if data is None:
        return None
    return colour_maps.Legend.from_dict(data.to_dict() if hasattr(data, "to_dict") else dict(data))


def create_point_cloud(name, positions, attrs, radius, material, run_id, names=None):
    """Vertices-only mesh with named attributes + Mesh to Points modifier.
    ``names``: {"fluorophore": [...], "region": [...]} for legends and filters."""
    mesh = bpy.data.meshes.new(name)
    mesh[RUN_KEY] = run_id
    mesh.vertices.add(len(positions))
    mesh.vertices.foreach_set("co", positions.ravel())
    for attr_name, (bl_type, values) in attrs.items():
        attribute = mesh.attributes.new(attr_name, bl_type, "POINT")
        key = "vector" if bl_type == "FLOAT_VECTOR" else "value"
        attribute.data.foreach_set(key, values)
    _set_attribute(mesh, SHOW_ATTR, "BOOLEAN", np.ones(len(positions), dtype=bool))  # until recolour()
    mesh.update()
    obj = bpy.data.objects.new(name, mesh)
    obj[RUN_KEY] = run_id
    obj[NAMES_KEY] = {k: list(v) for k, v in (names or {}).items()}
    group = _points_group()
    modifier = obj.modifiers.new("EP Mesh to Points", "NODES")
    modifier.node_group = group
    ids = _group_input_identifiers(group)
    modifier[ids["Radius"]] = float(radius)
    modifier[ids["Material"]] = material
    obj.data.materials.append(material)
    return obj


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
    "fluorescence": ((0.05, 0.5, 0.05), (0.2, 1.0, 0.3), (0.85, 1.0, 0.75)),
    "fluorescence_collagen": ((0.03, 0.2, 0.6), (0.1, 0.55, 1.0), (0.75, 0.95, 1.0)),
    "fluorescence_photofrin": ((0.5, 0.0, 0.08), (1.0, 0.05, 0.2), (1.0, 0.75, 0.85)),
}
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
    mat, nodes, links, out, attr = _attribute_material(name, run_id, grid_name)
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
    volume.filepath = path
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


VIEW_KEY = "endophoton_view"  # on an endoscope-view Image: which image of the View it holds
VIEWS_KEY = "endophoton_views"  # on the run's collection: the names of its view Images
VIEW_IMAGES = ("white", "fluorescence")


def view_pixels(view, name):
    """RGBA float32 rows bottom-up (Blender's order) of ``view.images[name]``: the linear
    sRGB radiance times the image's exposure, unclipped (NaN -> 0), so the Image shows
    what ``srgb8`` encodes and pixel / exposure is the radiance."""
    image = view.images[name]
    rgba = np.ones((view.height, view.width, 4), dtype=np.float32)
    rgba[..., :3] = np.nan_to_num(np.asarray(image["rgb"], dtype=np.float64) * float(image["exposure"]))
    return rgba[::-1]


def view_info(view, name):
    """What the view Image carries as ID properties besides its pixels."""
    return {
        "exposure": float(view.images[name]["exposure"]),
        "width": int(view.width),
        "height": int(view.height),
        "packets": int(view.packets),
        "kernel_radius_m": float(view.kernel["radius"]),
        "kernel_angle_deg": float(view.kernel["angle_deg"]),
        "emission_filter": str(view.emission_filter),
        "white_balance": str(view.white_balance),
    }


def create_view_images(collection, view, label):
    """The rig camera's images (``ep.View``) as float Images tagged with the run:
    packed and kept with a fake user (saved with the .blend), removed by remove_run."""
    names = []
    for name in VIEW_IMAGES:
        image = bpy.data.images.new(f"EP View {name} {label}", view.width, view.height, alpha=True, float_buffer=True)
        image.colorspace_settings.name = "Linear"
        image.pixels.foreach_set(view_pixels(view, name).ravel())
        image.pack()
        image.use_fake_user = True
        image[RUN_KEY] = collection[RUN_KEY]
        image[VIEW_KEY] = name
        image["endophoton_collection"] = collection.name
        image[PARAMS_KEY] = collection[PARAMS_KEY]
        image["endophoton_view_info"] = view_info(view, name)
        names.append(image.name)
    collection[VIEWS_KEY] = names
    return [bpy.data.images[n] for n in names]


def view_images(collection):
    """The run's endoscope-view Images, by VIEW_KEY."""
    run_id = collection.get(RUN_KEY)
    return {
        im[VIEW_KEY]: im
        for im in bpy.data.images
        if run_id is not None and im.get(RUN_KEY) == run_id and VIEW_KEY in im
    }


def result_collections(scene):
    return [c for c in scene.collection.children_recursive if c.get(RESULT_KEY)]


def run_files(collection):
    """Files the run wrote that only it uses: its .vdb (a fresh name per run)."""
    summary = collection.get(SUMMARY_KEY)
    path = summary.get("grid_path", "") if summary is not None else ""
    return [path, render_grid_path(path)] if path else []


def remove_run(collection):
    """Delete a run's collection, every datablock tagged with its run id and its .vdb file,
    and the points node group (POINTS_GROUP) once no object uses it."""
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
        if group.name.startswith(POINTS_GROUP) and "endophoton_version" in group and group.users == 0:
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

    ``render_grids``: what :func:`write_render_grids` returned for the run's .vdb;
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
        positions, attrs = point_cloud_arrays(escapes, inputs.scale_length)
    grid_path = getattr(result, "grid_path", None)
    grids = list(grid_info)
    if grid_path and not grids:
        # No pyopenvdb: names from the result (or the file), densities not normalised.
        names = list(getattr(result, "grid_names", None) or []) or [None]
        grids = [(name, None, 0.0) for name in names]
    records = 0 if positions is None else len(positions)
    summary = summary_from_result(result, inputs, records)

    run_id = _unique_run_id(inputs)
    beta = f"β={inputs.beta_deg:+.1f}°"
    collection = bpy.data.collections.new(f"EP {beta} {inputs.timestamp}")
    collection[RESULT_KEY] = True
    collection[RUN_KEY] = run_id
    (parent or scene.collection).children.link(collection)
    try:
        if positions is not None:
            material = _points_material(f"EP Photons {beta}", run_id)
            obj = create_point_cloud(
                f"EP Photons {beta}",
                positions,
                attrs,
                settings.point_radius,
                material,
                run_id,
                names=record_names(result, inputs),
            )
            recolour(obj, settings)
            collection.objects.link(obj)
        for grid_name, _active, vmax in grids:
            if grid_name is None:
                grid_name = _first_grid_name(grid_path)
            index_matrix = (render_grids or {}).get(grid_name)
            obj = create_volume(
                f"EP Grid {grid_name} {beta}",
                grid_path if index_matrix is None else render_grid_path(grid_path),
                grid_name,
                vmax,
                inputs.grid_voxel_m,
                inputs.scale_length,
                run_id,
                index_matrix=index_matrix,
            )
            collection.objects.link(obj)
        set_volume_scale(collection, settings)
        collection[SUMMARY_KEY] = summary
        collection[PARAMS_KEY] = {**run_parameters(inputs), **(tags or {})}
        if view is not None:
            create_view_images(collection, view, f"{beta} {inputs.timestamp}")
    except Exception:
        remove_run(collection)
        raise
    settings.result_collection = collection
    return collection


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


def record_names(result, inputs):
    """Names behind the integer record columns: fluorophore ids and region indices."""
    fluorophores = list(getattr(result, "fluorophore_names", None) or [])
    return {"fluorophore": [str(n) for n in fluorophores], "region": [str(r.name) for r in inputs.regions]}


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


def points_objects(collection):
    return [obj for obj in collection.all_objects if obj.type == "MESH" and obj.get(NAMES_KEY) is not None]


def update_display(scene):
    """Apply point radius, colour mapping, filters and volume density to the scene's results.

    A display setting that is not a finite number within its limits (guards.check_display)
    changes no result: its message becomes the legend's header and is returned (else None)."""
    from . import guards
    from .export import InputError

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
                    and modifier.node_group.name.startswith(POINTS_GROUP)
                ):
                    ids = _group_input_identifiers(modifier.node_group)
                    modifier[ids["Radius"]] = float(settings.point_radius)
                    obj.update_tag()
            if obj.get(NAMES_KEY) is not None:
                recolour(obj, settings)
        set_volume_scale(collection, settings)


# Short labels: the sidebar is narrow (Rsp + Rd + Tt + A + missed + cut + roulette = 1).
SUMMARY_LABELS = {
    "diffuse_reflectance": "Rd",
    "specular_reflectance": "Rsp",
    "transmittance": "Tt",
    "absorbed": "A",
    "missed": "Missed",
    "cut": "Cut",
    "roulette": "Roulette",
    "fluorescent_escaped": "Fluor. out",
    "escaped_energy": "Energy out",
}


def summary_rows(collection):
    """(label, value) rows of a run's summary for the panel; totals as value ± standard error."""
    summary = collection.get(SUMMARY_KEY)
    if summary is None:
        return []
    s = summary.to_dict() if hasattr(summary, "to_dict") else dict(summary)
    rows = [
        ("β", f"{s['beta_deg']:+.2f}°"),
        ("Traced", f"{s['packets_traced']:,}"),
        ("Launched", f"{s['photons']:,}"),
        ("Records", f"{s['records']:,}"),
        ("Time", f"{s['seconds']:.2f} s"),
    ]
    for name, (value, stderr) in s.get("totals", {}).items():
        rows.append((SUMMARY_LABELS.get(name, name), f"{value:.4g}±{stderr:.1g}"))
    for name, (value, stderr) in s.get("absorbed_by_region", {}).items():
        rows.append((f"A {name}", f"{value:.4g}±{stderr:.1g}"))
    return rows


def summary_lines(collection):
    """The summary as 'label: value' lines (scripts, reports)."""
    return [f"{label}: {value}" for label, value in summary_rows(collection)]
