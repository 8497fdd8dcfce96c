"""Read EndoPhoton voxel tallies (.vdb files) back into Python.

The engine writes one float fog-volume grid per tally with a pure linear
transform: voxel (i, j, k) is centred at world (i, j, k) * voxel_size, in scene
units. These helpers summarise such files and turn a grid into a dense numpy
array for analysis.

pyopenvdb is imported only when a helper is called, so ``import endophoton``
works on machines without OpenVDB's Python module.
"""

from __future__ import annotations

import importlib
import math
import os
from typing import Any, Dict, Tuple

import numpy as np

__all__ = [
    "read_grid_summary",
    "grid_to_numpy",
    "GRID_QUANTITIES",
    "LEGACY_GRID_NAMES",
    "grid_quantity",
    "current_grid_name",
]

#: What each grid of a run's .vdb file holds, with its unit (docs/design.md, "Grids"). ``<fluorophore>``
#: stands for a fluorophore's name. Every value is a sum over the voxel (not a density: divide by
#: voxel_size**3 for one) divided by the run's launched packets, so a grid's sum is a fraction of the
#: launched packets' weight (or energy), dimensionless. The engine writes the same words into each
#: grid's ``meaning`` metadata.
GRID_QUANTITIES = {
    "absorbed": (
        "Energy absorbed in the voxel, per launched packet (energy = packet weight × 500 nm / wavelength; "
        "the weight itself when the run is not spectral). Dimensionless; sums to the run's absorbed "
        "energy fraction."
    ),
    "fluorescent_light": (
        "Weight of fluorescent packets summed over their interaction sites in the voxel (collision "
        "density of fluorescence light), per launched packet. Dimensionless; where the fluorescence "
        "light travels, not where it is made."
    ),
    "fluorescent_light_<fluorophore>": (
        "Weight of packets that <fluorophore> turned fluorescent, summed over their interaction sites in "
        "the voxel, per launched packet. Dimensionless; where that fluorophore's light travels (the "
        "whole lit wall), not where the fluorophore is."
    ),
    "emission_<fluorophore>": (
        "Packet weight <fluorophore> converted into fluorescence in the voxel, at the conversion points, "
        "per launched packet (fluorescence photons emitted per launched photon). Dimensionless; nonzero "
        "only where the fluorophore is; sums to Result.emitted_by_fluorophore['<fluorophore>']."
    ),
}

#: Grid names of files written before the grids were renamed (kept readable for one release):
#: old name -> current name. ``grid_to_numpy`` and ``grid_quantity`` accept both.
LEGACY_GRID_NAMES = {
    "fluorescence": "fluorescent_light",
    "fluorescence_<fluorophore>": "fluorescent_light_<fluorophore>",
}


def _pattern_of(name: str) -> tuple[str, str | None]:
    """(GRID_QUANTITIES or LEGACY_GRID_NAMES key, fluorophore name or None) of a grid ``name``."""
    for table in (GRID_QUANTITIES, LEGACY_GRID_NAMES):
        if name in table:
            return name, None
    for table in (GRID_QUANTITIES, LEGACY_GRID_NAMES):
        for key in table:
            prefix = key.replace("<fluorophore>", "")
            if key.endswith("<fluorophore>") and name.startswith(prefix) and len(name) > len(prefix):
                return key, name[len(prefix) :]
    raise KeyError(f"grid name '{name}' is not one the engine writes (known: {', '.join(GRID_QUANTITIES)})")


def current_grid_name(name: str) -> str:
    """The current name of grid ``name`` (itself, or the new name of a legacy one, e.g.
    ``fluorescence_photofrin`` -> ``fluorescent_light_photofrin``). KeyError for a name the engine
    never wrote."""
    key, fluorophore = _pattern_of(name)
    key = LEGACY_GRID_NAMES.get(key, key)
    return key if fluorophore is None else key.replace("<fluorophore>", fluorophore)


def grid_quantity(name: str) -> str:
    """What grid ``name`` holds and its unit (GRID_QUANTITIES, the fluorophore's name filled in);
    legacy names are read as their current ones. KeyError for a name the engine never wrote."""
    key, fluorophore = _pattern_of(current_grid_name(name))
    text = GRID_QUANTITIES[key]
    return text if fluorophore is None else text.replace("<fluorophore>", fluorophore)


# A dense copy larger than this (float32, 1 GiB) is almost always a mistake,
# e.g. two stray deposits far apart spanning a huge bounding box.
DEFAULT_MAX_VOXELS = 1 << 28


def _openvdb():
    try:
        return importlib.import_module("pyopenvdb")
    except ImportError as exc:
        raise ImportError(
            "endophoton.vdb needs OpenVDB's Python module 'pyopenvdb', which could not be "
            "imported (Debian/Ubuntu: apt install python3-openvdb; it must match this "
            "Python's version). Blender's Volume objects can still load the .vdb files."
        ) from exc


def _check_file(path: str) -> str:
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise FileNotFoundError(f"vdb file '{path}' does not exist")
    return path


def _active_index_bbox(grid) -> Tuple[Tuple[int, int, int], Tuple[int, int, int]] | None:
    if grid.activeVoxelCount() == 0:
        return None  # OpenVDB reports an inverted (MAX, MIN) box for empty grids
    lo, hi = grid.evalActiveVoxelBoundingBox()
    return tuple(int(v) for v in lo), tuple(int(v) for v in hi)


def _world_bbox(transform, index_bbox):
    """World box covering the active voxels' cells (faces, not centres).

    Voxels are cell-centred, so voxel i spans index [i - 0.5, i + 0.5]. All
    eight corners are mapped so the box is right for any affine transform.
    """
    (i0, j0, k0), (i1, j1, k1) = index_bbox
    corners = [
        transform.indexToWorld((x, y, z))
        for x in (i0 - 0.5, i1 + 0.5)
        for y in (j0 - 0.5, j1 + 0.5)
        for z in (k0 - 0.5, k1 + 0.5)
    ]
    lo = tuple(min(c[a] for c in corners) for a in range(3))
    hi = tuple(max(c[a] for c in corners) for a in range(3))
    return lo, hi


def _active_sum(grid) -> float:
    # Tiles stand for `count` voxels of one value; math.fsum makes the total
    # exact to double rounding however many float32 voxels there are.
    return math.fsum(item["value"] * item["count"] for item in grid.citerOnValues())


def read_grid_summary(path) -> Dict[str, Any]:
    """Summarise every grid in a .vdb file.

    Returns ``{"path": str, "metadata": {file-level metadata},
    "grids": {name: summary}}`` with grids in file order. Each summary has:

    - ``name``, ``value_type`` (e.g. ``"float"``), ``grid_class`` (``"fog volume"``)
    - ``voxel_size``: (x, y, z) in world (scene) units
    - ``active_voxel_count``: int
    - ``sum``: sum of active values (tiles counted once per voxel they cover)
    - ``index_bbox``: ((imin, jmin, kmin), (imax, jmax, kmax)) of active voxels, or None
    - ``world_bbox``: ((xmin, ymin, zmin), (xmax, ymax, zmax)) covering the
      active voxels' cells in world units, or None for an empty grid
    - ``metadata``: the grid's metadata dict (includes the engine's
      ``meaning``, ``accumulator_sum``, run metadata and OpenVDB's own
      ``file_*`` statistics)
    """
    vdb = _openvdb()
    path = _check_file(path)
    grids, file_meta = vdb.readAll(path)
    out: Dict[str, Any] = {"path": path, "metadata": dict(file_meta), "grids": {}}
    for grid in grids:
        if grid.name in out["grids"]:
            raise ValueError(
                f"vdb file '{path}': grid name '{grid.name}' occurs more than once; " "summaries are keyed by name"
            )
        ibox = _active_index_bbox(grid)
        is_scalar = grid.valueTypeName in ("float", "double", "int32", "int64", "bool")
        out["grids"][grid.name] = {
            "name": grid.name,
            "value_type": grid.valueTypeName,
            "grid_class": grid.gridClass,
            "voxel_size": tuple(float(v) for v in grid.transform.voxelSize()),
            "active_voxel_count": int(grid.activeVoxelCount()),
            "sum": _active_sum(grid) if is_scalar else None,
            "index_bbox": ibox,
            "world_bbox": None if ibox is None else _world_bbox(grid.transform, ibox),
            "metadata": dict(grid.metadata),
        }
    return out


def _uniform_axis_aligned_voxel_size(grid, path: str) -> float:
    """Voxel size of a transform that is a uniform scale plus translation.

    origin + voxel_size only describe the index->world map for such
    transforms; anything else (rotation, shear, non-uniform or frustum) would
    make the returned triple silently wrong, so it is refused.
    """
    t = grid.transform
    o = np.asarray(t.indexToWorld((0, 0, 0)), dtype=np.float64)
    steps = np.array([np.asarray(t.indexToWorld(e), dtype=np.float64) - o for e in ((1, 0, 0), (0, 1, 0), (0, 0, 1))])
    h = float(steps[0, 0])
    expected = np.diag([h, h, h])
    if not (t.isLinear and h > 0 and np.allclose(steps, expected, rtol=1e-12, atol=0.0)):
        raise ValueError(
            f"vdb file '{path}': grid '{grid.name}' transform maps index axes to "
            f"{steps.tolist()}, not a uniform axis-aligned scale; grid_to_numpy "
            "supports only that"
        )
    return h


def _read_grid(vdb, path: str, name: str):
    """Grid ``name`` of the file, or the same grid under its other name (old file, new name or
    the reverse; LEGACY_GRID_NAMES). KeyError naming the file and the grid if neither is there."""
    names = [name]
    try:
        current = current_grid_name(name)
        names.append(current)
        names += [old for old in _legacy_names(current) if old != name]
    except KeyError:
        pass  # not an engine name: only the name itself
    for candidate in dict.fromkeys(names):
        try:
            return vdb.read(path, candidate)
        except KeyError:
            continue
    raise KeyError(f"vdb file '{path}' has no grid named '{name}'")


def _legacy_names(current: str) -> list[str]:
    """The legacy names (LEGACY_GRID_NAMES) whose current name is ``current``."""
    out = []
    for old, new in LEGACY_GRID_NAMES.items():
        if new == current:
            out.append(old)
        elif new.endswith("<fluorophore>") and current.startswith(new[: -len("<fluorophore>")]):
            out.append(old.replace("<fluorophore>", current[len(new) - len("<fluorophore>") :]))
    return out


def grid_to_numpy(path, name: str, max_voxels: int = DEFAULT_MAX_VOXELS):
    """Dense copy of one float grid over its active-voxel bounding box.

    Returns ``(array, origin_world, voxel_size)``:

    - ``array``: float32, shape (nx, ny, nz), ``array[a, b, c]`` is voxel
      (imin + a, jmin + b, kmin + c); voxels inside the box that are not
      active hold the grid's background (0 for engine tallies);
    - ``origin_world``: (x, y, z) world position of the *centre* of voxel
      ``array[0, 0, 0]``, scene units;
    - ``voxel_size``: float, scene units, so voxel ``array[a, b, c]`` is
      centred at ``origin_world + (a, b, c) * voxel_size``.

    An empty grid gives an array of shape (0, 0, 0) and origin (0, 0, 0).
    A legacy grid name (LEGACY_GRID_NAMES) reads the renamed grid of a new file, and a
    current name the old grid of an old file.
    Raises KeyError if the file has no grid ``name``, TypeError for a
    non-float grid, ValueError for a rotated/sheared/non-uniform transform or
    a box of more than ``max_voxels`` voxels.
    """
    vdb = _openvdb()
    path = _check_file(path)
    grid = _read_grid(vdb, path, name)
    if grid.valueTypeName != "float":
        raise TypeError(
            f"vdb file '{path}': grid '{name}' holds '{grid.valueTypeName}' values; " "grid_to_numpy reads float grids"
        )
    voxel_size = _uniform_axis_aligned_voxel_size(grid, path)
    ibox = _active_index_bbox(grid)
    if ibox is None:
        origin = tuple(float(v) for v in grid.transform.indexToWorld((0, 0, 0)))
        return np.zeros((0, 0, 0), dtype=np.float32), origin, voxel_size
    lo, hi = ibox
    shape = tuple(hi[a] - lo[a] + 1 for a in range(3))
    count = shape[0] * shape[1] * shape[2]
    if count > max_voxels:
        raise ValueError(
            f"vdb file '{path}': grid '{name}' active bounding box {lo}..{hi} has "
            f"{count} voxels > max_voxels = {max_voxels}"
        )
    array = np.zeros(shape, dtype=np.float32)
    grid.copyToArray(array, ijk=lo)
    origin = tuple(float(v) for v in grid.transform.indexToWorld(lo))
    return array, origin, voxel_size
