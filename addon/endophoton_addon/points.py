# SPDX-License-Identifier: MIT
"""The surface photon map as a point cloud: a mesh of vertices only, per-point record columns
as named attributes written with ``foreach_set``; a Geometry Nodes "Mesh to Points" modifier turns
it into a point cloud Cycles renders, with a material colouring the points by the chosen
mapping (``ep_colour``, colour_maps.py) and as bright as each record's energy.  Also the
legend the mapping shows (on the object and in the scene's panel rows)."""

import bpy
import numpy as np

from . import colour_maps, node_utils
from .keys import RUN_KEY

POINTS_GROUP = "EP Photon Points"


EMISSION_NODE = "EP Point Emission"


# Escape-record column -> (attribute name, Blender attribute type, numpy dtype, width), in the
# engine's column order: the point cloud holds every column of the engine's records (the vertex
# coordinates hold "position"); record_columns() reads them back under the engine's names.
POINT_ATTRIBUTES = (
    ("direction", "direction", "FLOAT_VECTOR", np.float32, 3),
    ("normal", "surface_normal", "FLOAT_VECTOR", np.float32, 3),  # "normal" is Blender's own field
    ("entry", "entry", "FLOAT_VECTOR", np.float32, 3),  # metres (the engine scene's unit)
    ("weight", "weight", "FLOAT", np.float32, 1),
    ("energy", "energy", "FLOAT", np.float32, 1),
    ("wavelength", "wavelength", "FLOAT", np.float32, 1),
    ("max_depth", "depth", "FLOAT", np.float32, 1),  # cm, as the engine reports it
    ("fluorescent", "fluorescent", "BOOLEAN", np.bool_, 1),
    ("light", "light", "INT", np.int32, 1),
    ("kind", "kind", "INT", np.int32, 1),
    ("fluorophore", "fluorophore", "INT", np.int32, 1),
    ("region", "region", "INT", np.int32, 1),
    ("scatterings", "scatterings", "INT", np.int32, 1),
    ("packet", "packet", "INT", np.int32, 1),  # uint64: low 32 bits here, high 32 bits in PACKET_HI_ATTR
    ("exit_order", "exit_order", "INT", np.int32, 1),  # 1st, 2nd, ... exit of its packet into the ambient
    ("next_hit", "next_hit", "INT", np.int32, 1),  # where its ray went: 0 away, 1 tissue, 2 head, 3 camera
)
PACKET_HI_ATTR = "packet_hi"  # Blender's INT attribute is 32-bit: the packet index's high word


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
        if column == "packet":  # split the uint64 index into two 32-bit words (bit patterns)
            words = np.ascontiguousarray(values.reshape(-1), dtype=np.uint64)
            attrs[name] = (bl_type, (words & 0xFFFFFFFF).astype(np.uint32).view(np.int32))
            attrs[PACKET_HI_ATTR] = (bl_type, (words >> np.uint64(32)).astype(np.uint32).view(np.int32))
            continue
        attrs[name] = (bl_type, np.ascontiguousarray(values.reshape(-1), dtype=dtype))
    return (position / scale_length).astype(np.float32), attrs


def record_columns(obj, scale_length):
    """The records of a points object under the engine's column names, ``position`` first (world
    space, metres: Blender units × ``scale_length``), then every record column in the engine's
    order (``packet`` as uint64 again).  What Export Result writes."""
    mesh = obj.data
    co = np.empty(len(mesh.vertices) * 3, np.float64)
    mesh.vertices.foreach_get("co", co)
    matrix = np.asarray(obj.matrix_world, np.float64)
    world = co.reshape(-1, 3) @ matrix[:3, :3].T + matrix[:3, 3]
    columns = {"position": world * float(scale_length)}
    stored = read_point_columns(mesh)
    for column, name, _bl_type, _dtype, _width in POINT_ATTRIBUTES:
        if name not in stored:
            continue
        values = stored[name]
        if column == "packet":
            hi = stored.get(PACKET_HI_ATTR, np.zeros_like(values))
            values = (hi.view(np.uint32).astype(np.uint64) << np.uint64(32)) | values.view(np.uint32).astype(np.uint64)
        columns[column] = values
    return columns


def _points_group():
    group = bpy.data.node_groups.get(POINTS_GROUP)
    if group is not None and group.bl_idname == "GeometryNodeTree" and group.get("endophoton_version") == 3:
        return group
    group = bpy.data.node_groups.new(POINTS_GROUP, "GeometryNodeTree")
    group["endophoton_version"] = 3
    node_utils.new_socket(group, "INPUT", "NodeSocketGeometry", "Geometry")
    radius = node_utils.new_socket(group, "INPUT", "NodeSocketFloat", "Radius")
    radius.default_value = 0.0001
    radius.min_value = 0.0
    node_utils.new_socket(group, "INPUT", "NodeSocketMaterial", "Material")
    node_utils.new_socket(group, "OUTPUT", "NodeSocketGeometry", "Geometry")
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


def _points_material(name, run_id):
    """Emission coloured by the point attribute ``ep_colour`` and as bright as the
    record's energy (``ep_strength``, written by :func:`recolour`): a packet that
    landed on tissue across the lumen and left again carries little weight and
    glows accordingly, as the light it stands for does.  The points are otherwise
    transparent (emission + Transparent BSDF), so overlapping points add up like
    the light they stand for: a pixel shows the sum of its records' colours times
    energies (up to Cycles' transparent bounces), not the front point's."""
    mat, nodes, links, out, colour = node_utils.attribute_material(name, run_id, COLOUR_ATTR)
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
    """The record attributes of a points mesh as numpy arrays (foreach_get), by attribute name."""
    columns = {}
    specs = [(name, dtype, width) for _column, name, _type, dtype, width in POINT_ATTRIBUTES]
    for name, dtype, width in specs + [(PACKET_HI_ATTR, np.int32, 1)]:
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
    ids = node_utils.group_input_identifiers(group)
    modifier[ids["Radius"]] = float(radius)
    modifier[ids["Material"]] = material
    obj.data.materials.append(material)
    return obj


def points_objects(collection):
    return [obj for obj in collection.all_objects if obj.type == "MESH" and obj.get(NAMES_KEY) is not None]


def record_names(result, inputs):
    """Names behind the integer record columns: fluorophore ids and region indices."""
    fluorophores = list(getattr(result, "fluorophore_names", None) or [])
    return {"fluorophore": [str(n) for n in fluorophores], "region": [str(r.name) for r in inputs.regions]}
