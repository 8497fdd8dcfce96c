# SPDX-License-Identifier: MIT
"""Building meshes from numpy arrays (foreach_set, no per-element Python loops)."""

import bpy
import numpy as np


def mesh_from_arrays(name, vertices, faces):
    """New mesh from float (N,3) vertices and an (F,k) int array of k-gon faces
    (or a list of such arrays for mixed face sizes)."""
    vertices = np.ascontiguousarray(vertices, dtype=np.float32).reshape(-1, 3)
    blocks = faces if isinstance(faces, (list, tuple)) else [faces]
    blocks = [np.asarray(b, dtype=np.int32) for b in blocks if len(b)]
    loops = np.concatenate([b.reshape(-1) for b in blocks]) if blocks else np.zeros(0, np.int32)
    totals = (
        np.concatenate([np.full(len(b), b.shape[1], np.int32) for b in blocks]) if blocks else np.zeros(0, np.int32)
    )
    starts = np.zeros(len(totals), np.int32)
    if len(totals):
        starts[1:] = np.cumsum(totals)[:-1]
    mesh = bpy.data.meshes.new(name)
    mesh.vertices.add(len(vertices))
    mesh.vertices.foreach_set("co", vertices.ravel())
    mesh.loops.add(len(loops))
    mesh.loops.foreach_set("vertex_index", loops)
    mesh.polygons.add(len(totals))
    mesh.polygons.foreach_set("loop_start", starts)
    mesh.polygons.foreach_set("loop_total", totals)
    mesh.update(calc_edges=True)
    mesh.validate()
    return mesh


def cylinder_arrays(segments, length):
    """Closed unit-radius cylinder from z=0 to z=length: (vertices, [quads, caps])."""
    angles = np.linspace(0.0, 2.0 * np.pi, segments, endpoint=False)
    ring = np.stack([np.cos(angles), np.sin(angles), np.zeros(segments)], axis=1)
    verts = np.concatenate([ring, ring + np.array([0.0, 0.0, length])])
    i = np.arange(segments)
    j = (i + 1) % segments
    sides = np.stack([i, j, j + segments, i + segments], axis=1)
    front = np.arange(segments)[::-1].reshape(1, -1)  # faces -Z
    back = (np.arange(segments) + segments).reshape(1, -1)  # faces +Z
    return verts, [sides, front, back]
