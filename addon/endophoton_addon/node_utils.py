# SPDX-License-Identifier: MIT
"""Node-tree helpers shared by the point cloud (points.py) and the grids (volumes.py):
group sockets in Blender 3.x and 4.x, and a material reading one geometry attribute."""

import bpy

from .keys import RUN_KEY


# --- datablocks ----------------------------------------------------------------
def new_socket(group, in_out, socket_type, name):
    """Group socket in 3.x (group.inputs/outputs) and 4.x (group.interface)."""
    if hasattr(group, "interface"):
        return group.interface.new_socket(name=name, in_out=in_out, socket_type=socket_type)
    sockets = group.inputs if in_out == "INPUT" else group.outputs
    return sockets.new(socket_type, name)


def group_input_identifiers(group):
    if hasattr(group, "interface"):
        return {
            item.name: item.identifier
            for item in group.interface.items_tree
            if getattr(item, "in_out", None) == "INPUT"
        }
    return {s.name: s.identifier for s in group.inputs}


def attribute_material(name, run_id, attribute_name):
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
