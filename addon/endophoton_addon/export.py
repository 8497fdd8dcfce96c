# SPDX-License-Identifier: MIT
"""Meshes -> numpy for the engine, and validation of per-object settings.

Meshes are taken from the evaluated depsgraph (modifiers applied), transformed
to world space and converted to metres (the engine unit) with the scene's
``unit_settings.scale_length`` (one Blender unit = scale_length metres).
``Object.to_mesh()`` makes a temporary mesh outside ``bpy.data``, so exporting
creates no datablock.

Every problem raises :class:`InputError` whose message names the object and
the field, e.g. ``Object 'Tissue': medium.mua = nan must be a finite number >= 0``.
"""

import math
from dataclasses import dataclass, field

import numpy as np

from . import presets
from .errors import InputError


@dataclass
class RegionExport:
    name: str
    vertices: np.ndarray  # float32 (N,3), metres, world space
    triangles: np.ndarray  # uint32 (M,3), outward CCW
    medium: dict  # mua, mus (cm^-1), g, n; "preset": an endophoton.media name for a spectral preset
    priority: int
    fluorophores: list = field(default_factory=list)  # [(species, d, c)]
    role: str = "TISSUE"


def _finite(value):
    return isinstance(value, (int, float)) and math.isfinite(value)


def validate_object_settings(obj):
    """Check role/medium/priority/fluorophores of a role object; return plain values."""
    s = obj.endophoton
    who = f"Object '{obj.name}'"
    m = s.medium
    checks = (
        ("mua", m.mua, lambda v: v >= 0.0, "a finite number >= 0 (cm⁻¹)"),
        ("mus", m.mus, lambda v: v >= 0.0, "a finite number >= 0 (cm⁻¹)"),
        ("g", m.g, lambda v: -1.0 <= v <= 1.0, "a finite number in [-1, 1]"),
        ("n", m.n, lambda v: v >= 1.0, "a finite number >= 1"),
    )
    medium = {}
    for name, value, ok, what in checks:
        if not _finite(value) or not ok(value):
            raise InputError(f"{who}: medium.{name} = {value:g} must be {what}")
        medium[name] = float(value)
    chosen = presets.TISSUE_PRESETS.get(s.tissue_preset)
    if chosen is not None and chosen.spectral:
        medium["preset"] = chosen.spectral  # the engine takes the spectra (sweep_blend.blender_regions_to_scene)
    fluorophores = []
    for i, f in enumerate(s.fluorophores):
        for name in ("d", "c"):
            value = getattr(f, name)
            if not _finite(value) or not 0.0 <= value <= 1.0:
                raise InputError(
                    f"{who}: fluorophores[{i}] ({f.species}).{name} = {value:g} " "must be a finite number in [0, 1]"
                )
        if f.species not in presets.FLUOROPHORE_NAMES:
            raise InputError(f"{who}: fluorophores[{i}].species = '{f.species}' is unknown")
        fluorophores.append((f.species, float(f.d), float(f.c)))
    return medium, int(s.priority), fluorophores


def mesh_arrays(obj, depsgraph, scale_length):
    """World-space triangles of the evaluated object in metres: (float32 (N,3), uint32 (M,3))."""
    who = f"Object '{obj.name}'"
    evaluated = obj.evaluated_get(depsgraph)
    mesh = evaluated.to_mesh()
    try:
        if mesh is None:
            raise InputError(f"{who}: has no mesh geometry")
        mesh.calc_loop_triangles()
        nv, nt = len(mesh.vertices), len(mesh.loop_triangles)
        co = np.empty(nv * 3, dtype=np.float64)
        mesh.vertices.foreach_get("co", co)
        tris = np.empty(nt * 3, dtype=np.int64)
        mesh.loop_triangles.foreach_get("vertices", tris)
        matrix = np.array(evaluated.matrix_world, dtype=np.float64)
    finally:
        evaluated.to_mesh_clear()
    co = co.reshape(-1, 3)
    tris = tris.reshape(-1, 3)
    if nt == 0:
        raise InputError(f"{who}: mesh has no faces (after modifiers)")
    world = co @ matrix[:3, :3].T + matrix[:3, 3]
    if np.linalg.det(matrix[:3, :3]) < 0.0:  # mirrored object: keep the winding outward
        tris = tris[:, ::-1]
    vertices = world * scale_length
    if not np.all(np.isfinite(vertices)):
        raise InputError(f"{who}: vertex coordinates are not finite")
    return vertices.astype(np.float32), np.ascontiguousarray(tris, dtype=np.uint32)


# A closed mesh whose |signed volume| is at most this fraction of its largest extent cubed
# encloses nothing: flat, or scaled to 0 along an axis (float32 round-off is ~1e-7 per axis).
ZERO_VOLUME = 1e-9


def check_closed(name, vertices, triangles):
    """Raise InputError unless the triangle mesh is closed, consistently oriented, outward
    and encloses a volume (not flat)."""
    who = f"Object '{name}'"
    tris = triangles.astype(np.int64)
    degenerate = (tris[:, 0] == tris[:, 1]) | (tris[:, 1] == tris[:, 2]) | (tris[:, 0] == tris[:, 2])
    tris = tris[~degenerate]
    directed = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
    undirected = np.sort(directed, axis=1)
    n = int(max(int(tris.max()) + 1, 1))
    key_u = undirected[:, 0] * n + undirected[:, 1]
    _, counts = np.unique(key_u, return_counts=True)
    open_edges = int(np.count_nonzero(counts == 1))
    non_manifold = int(np.count_nonzero(counts > 2))
    if open_edges:
        raise InputError(
            f"{who}: mesh is open ({open_edges} boundary edges after modifiers); "
            "tissue and polyps must be closed (watertight) meshes"
        )
    if non_manifold:
        raise InputError(f"{who}: mesh has {non_manifold} non-manifold edges (shared by more than two faces)")
    key_d = directed[:, 0] * n + directed[:, 1]
    _, dcounts = np.unique(key_d, return_counts=True)
    if np.any(dcounts > 1):
        raise InputError(f"{who}: face winding is inconsistent; recalculate normals (Mesh > Normals)")
    v = vertices.astype(np.float64)
    a, b, c = v[tris[:, 0]], v[tris[:, 1]], v[tris[:, 2]]
    volume = float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum()) / 6.0
    extent = float(np.max(v.max(axis=0) - v.min(axis=0)))
    if abs(volume) <= ZERO_VOLUME * extent**3:  # round-off of a flat mesh, not a winding
        raise InputError(
            f"{who}: mesh has zero volume (signed volume {volume:.3g} m³ over an extent of {extent:.3g} m): "
            "it is flat or scaled to 0 along an axis; tissue and polyps must enclose a volume "
            "(check the object's scale and the mesh)"
        )
    if not volume > 0.0:
        raise InputError(f"{who}: normals point inward (signed volume {volume:.3g} m³); " "recalculate normals outside")


def export_regions(scene, view_layer, depsgraph):
    """All role objects of the view layer as RegionExport, validated; raises InputError."""
    scale = scene.unit_settings.scale_length
    if not _finite(scale) or scale <= 0.0:
        raise InputError(f"Scene '{scene.name}': unit_settings.scale_length = {scale:g} must be > 0")
    regions = []
    for obj in view_layer.objects:
        role = obj.endophoton.role
        if role == "NONE":
            continue
        if obj.type != "MESH":
            raise InputError(
                f"Object '{obj.name}': role is {role.lower()} but the object is a {obj.type.lower()}; "
                "only meshes can be tissue or polyps"
            )
        medium, priority, fluorophores = validate_object_settings(obj)
        vertices, triangles = mesh_arrays(obj, depsgraph, scale)
        check_closed(obj.name, vertices, triangles)
        regions.append(RegionExport(obj.name, vertices, triangles, medium, priority, fluorophores, role))
    if not any(r.role == "TISSUE" for r in regions):
        raise InputError(f"Scene '{scene.name}': no object has role 'tissue'; set Object > EndoPhoton > Role")
    return regions
