# SPDX-License-Identifier: MIT
"""Checks before a run starts, so a mistake costs a message, not a run.

Every check reads the exported regions (export.RegionExport: metres, world
space) or plain settings and raises :class:`errors.InputError` naming the
scene or object and the field; none creates a datablock or a file.

- :func:`region_sizes`: each region's extent and wall thickness in mm.  The
  thickness of a closed surface is estimated as 2·V/A (exact for a thin shell
  or slab of uniform thickness t: its area counts both faces, A ≈ 2·S, V = S·t).
- :func:`check_unit_scale`: the thinnest region against the transport mean
  free path 1/(μa + μs(1 − g)) — a colon modelled in metres but with the unit
  scale of millimetres is 1000 times too thin, and light goes straight through.
- :func:`check_overlaps`: regions of equal priority that share volume are ambiguous: the engine
  could not say which medium owns the overlap. The test is the package's (endophoton.overlaps:
  grid points inside both closed meshes, by ray parity; touching layers pass).
- :func:`estimate` / :func:`check_budget`: packets, records, memory and (from
  the last run's measured rate) time; a fixed packet or store-N run above a
  threshold is refused unless the scene allows large runs (quality presets run
  to a target: their packet count is only a cap, so they are not refused).
- :func:`check_voxels`: the grid's voxel count and a minimum voxel size.
- :func:`check_display`: the display settings results are drawn with (point
  radius, camera cone, volume decades and density) are finite and within their
  property's limits: a FloatProperty's min/max clamp numbers but let NaN through.
"""

import math
import os
import tempfile

import numpy as np

from .errors import InputError

# A region thinner than this many transport mean free paths, or thicker than
# the upper bound, is almost surely a unit-scale mistake (the paper's colon
# wall, 3 mm, is 12 transport mean free paths; the same wall modelled in mm
# numbers in a metre scene is 3 m = 12,000).
MIN_THICKNESS_MFP = 1.0
MAX_THICKNESS_MFP = 1e3
# A region larger than this across is a scale-up: an endoscope's scene (a colon
# segment, a polyp) is centimetres; a colon of mm numbers in a metre scene is 80 m.
MAX_EXTENT_M = 1.0
SCALE_UP_FIX = (
    "probably millimetre numbers in a metre scene (or a Unit Scale 1000 times too large). Fix: set "
    "Scene Properties > Units > Unit Scale to 0.001 if you modelled in millimetres (1 unit = 1 mm), or "
    "scale the objects down by 1000; or tick Allow Unusual Scale"
)
# A run above these asks first (scene setting "Allow Large Runs").
MAX_RECORDS = 5_000_000
MAX_PACKETS = 100_000_000
RECORD_BYTES = 200  # engine record (~100 B) + Blender point attributes (~100 B)
MAX_VOXELS = 256**3
MIN_VOXEL_M = 1e-7  # below 0.1 µm OpenVDB's transform becomes singular in float


def _volume_area(vertices, triangles):
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    a, b, c = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    volume = float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum()) / 6.0
    area = float(np.linalg.norm(np.cross(b - a, c - a), axis=1).sum()) / 2.0
    return volume, area


def region_sizes(regions):
    """[(name, extent_mm (3,), thickness_mm, transport mfp mm)] of the exported regions."""
    out = []
    for r in regions:
        volume, area = _volume_area(r.vertices, r.triangles)
        extent = (r.vertices.max(axis=0) - r.vertices.min(axis=0)).astype(np.float64) * 1e3
        thickness = 2.0 * volume / area * 1e3 if area > 0 else 0.0
        m = r.medium
        mu_tr = m["mua"] + m["mus"] * (1.0 - m["g"])  # cm^-1
        mfp_mm = 10.0 / mu_tr if mu_tr > 0 else math.inf
        out.append((r.name, extent, thickness, mfp_mm))
    return out


def size_lines(regions):
    """Human-readable lines for the panel."""
    lines = []
    for name, extent, thickness, mfp_mm in region_sizes(regions):
        ratio = thickness / mfp_mm if math.isfinite(mfp_mm) else math.inf
        lines.append(
            f"{name}: {extent[0]:.3g}×{extent[1]:.3g}×{extent[2]:.3g} mm, "
            f"thickness ≈ {thickness:.3g} mm = {ratio:.3g} transport mfp"
        )
    return lines


def check_unit_scale(regions, scale_length, who):
    """Refuse a scene whose size says its unit is wrong: a region larger than MAX_EXTENT_M across
    or thicker than MAX_THICKNESS_MFP transport mean free paths (a scale-up), or thinner than
    MIN_THICKNESS_MFP (a scale-down); the message names the region and the fix."""
    scale = f"unit_settings.scale_length = {scale_length:g} m per unit"
    for name, extent, thickness, mfp_mm in region_sizes(regions):
        if float(np.max(extent)) > MAX_EXTENT_M * 1e3:
            raise InputError(
                f"{who}: region '{name}' is {float(np.max(extent)) / 1e3:.3g} m across with {scale}, larger than "
                f"{MAX_EXTENT_M:g} m (an endoscope's scene is centimetres): {SCALE_UP_FIX}"
            )
        if not math.isfinite(mfp_mm):
            continue
        ratio = thickness / mfp_mm
        if ratio > MAX_THICKNESS_MFP:
            raise InputError(
                f"{who}: region '{name}' is {thickness:.3g} mm thick with {scale}, {ratio:.3g} transport mean free "
                f"paths (1/(μa + μs(1−g)) = {mfp_mm:.3g} mm), more than {MAX_THICKNESS_MFP:g}: no light crosses "
                f"it, {SCALE_UP_FIX}"
            )
        if ratio < MIN_THICKNESS_MFP:
            raise InputError(
                f"{who}: unit_settings.scale_length = {scale_length:g} m per unit makes region '{name}' "
                f"{thickness:.3g} mm thick, {ratio:.3g} transport mean free paths "
                f"(1/(μa + μs(1−g)) = {mfp_mm:.3g} mm); expected {MIN_THICKNESS_MFP:g}–{MAX_THICKNESS_MFP:g}. "
                "Check the scene's Unit Scale (1.0 = metres, 0.001 = millimetres) or tick Allow Unusual Scale"
            )


def check_overlaps(regions):
    """Raise InputError naming two regions of equal priority that overlap. The test is the engine
    package's (endophoton.overlaps, the one rule of every path), asked here before the run so the
    message names the Blender objects."""
    from endophoton.overlaps import equal_priority_overlaps

    found = equal_priority_overlaps(regions)
    if found:
        a, b, priority = found[0]
        raise InputError(
            f"Objects '{a}' and '{b}' overlap with the same priority = {priority}; "
            "the engine could not tell which medium owns the overlap. Give the one that "
            "should win a higher priority (e.g. the polyp above the wall)"
        )


def estimate(inputs, last_rate=None):
    """Packets, records, memory (bytes) and seconds (None without a measured rate) of a run."""
    packets = inputs.count if inputs.kind in ("photons", "target") else None
    records = inputs.count  # store N: N records; otherwise one record per packet at most
    seconds = packets / last_rate if packets and last_rate else None
    return {"packets": packets, "records": records, "memory_bytes": records * RECORD_BYTES, "seconds": seconds}


def estimate_text(est):
    packets = "open-ended (store N)" if est["packets"] is None else f"≤ {est['packets']:,}"
    seconds = "unknown until a first run" if est["seconds"] is None else f"≈ {est['seconds']:.0f} s"
    return (
        f"packets {packets}, records ≤ {est['records']:,}, memory ≤ "
        f"{est['memory_bytes'] / 2**20:,.0f} MiB, time {seconds}"
    )


def check_budget(inputs, who, last_rate=None):
    est = estimate(inputs, last_rate)
    if inputs.kind == "target":
        return est  # a quality preset: its packet count is a cap, the target usually stops far earlier
    large = est["records"] > MAX_RECORDS or (est["packets"] or 0) > MAX_PACKETS
    if large:
        raise InputError(
            f"{who}: this run is large: {estimate_text(est)} (limits {MAX_RECORDS:,} records, "
            f"{MAX_PACKETS:,} packets). Tick Allow Large Runs to run it anyway"
        )
    return est


def check_voxels(regions, voxel_m, who):
    if voxel_m < MIN_VOXEL_M:
        raise InputError(
            f"{who}: simulation.voxel_size = {voxel_m:g} m is below {MIN_VOXEL_M:g} m; "
            "check the voxel size and the scene's Unit Scale"
        )
    lo = np.min([r.vertices.min(axis=0) for r in regions], axis=0).astype(np.float64)
    hi = np.max([r.vertices.max(axis=0) for r in regions], axis=0).astype(np.float64)
    voxels = float(np.prod(np.ceil((hi - lo) / voxel_m) + 1))
    if voxels > MAX_VOXELS:
        size = f"the scene's {((hi - lo) * 1e3).round(3).tolist()} mm"
        if float(np.max(hi - lo)) > MAX_EXTENT_M:  # the scene, not the voxel, is too large
            fix = f"the scene is {float(np.max(hi - lo)):.3g} m across: {SCALE_UP_FIX}"
        else:
            smallest = voxel_m * (voxels / MAX_VOXELS) ** (1.0 / 3.0) * 1.05
            fix = f"choose a voxel size of at least {smallest * 1e3:.3g} mm, or turn Volume Grids off"
        raise InputError(
            f"{who}: simulation.voxel_size = {voxel_m * 1e3:g} mm gives up to {voxels:.3g} voxels over {size} "
            f"(limit {MAX_VOXELS:.3g}); {fix}"
        )


DISPLAY_FIELDS = ("point_radius", "camera_cone_deg", "volume_decades", "volume_density")


def check_display(settings, who):
    """Raise InputError naming the first display field of the scene's ``settings``
    (scene.endophoton) that is not a finite number within its property's hard limits."""
    for name in DISPLAY_FIELDS:
        value = getattr(settings, name)
        prop = settings.bl_rna.properties[name]
        lo, hi = prop.hard_min, prop.hard_max
        if not (math.isfinite(value) and lo <= value <= hi):
            limits = f">= {lo:g}" if hi >= 3e38 else f"in [{lo:g}, {hi:g}]"
            raise InputError(f"{who}: simulation.{name} = {value:g} must be a finite number {limits}")


def resolve_folder(raw, field, default_name, value=None):
    """Absolute output folder for a folder field ('' = //default_name next to the
    saved .blend, else in the temp folder).  Checks it can be created and written;
    creates nothing.  ``field`` names owner and field for the message, ``value``
    the field's value when that is not the folder itself (a file path's folder)."""
    import bpy

    raw = raw.strip()
    field = f"{field} = '{raw if value is None else value}'"
    if not raw:
        path = (
            bpy.path.abspath("//" + default_name)
            if bpy.data.filepath
            else os.path.join(tempfile.gettempdir(), default_name)
        )
    else:
        if raw.startswith("//") and not bpy.data.filepath:
            raise InputError(
                f"{field} is relative to the .blend file, which is not saved; "
                "save the file or choose an absolute folder"
            )
        path = bpy.path.abspath(raw)
    path = os.path.normpath(os.path.abspath(path))
    existing = path
    while not os.path.exists(existing):
        parent = os.path.dirname(existing)
        if parent == existing:
            break
        existing = parent
    if not os.path.isdir(existing):
        raise InputError(f"{field}: '{existing}' is a file, not a folder")
    if not os.access(existing, os.W_OK | os.X_OK) or not _can_create_in(existing):
        raise InputError(f"{field}: '{existing}' is not writable; choose another folder")
    return path


def _can_create_in(folder):
    """Whether a folder can be made in ``folder`` (os.access says yes to root everywhere, also in
    /proc): a probe folder is made and removed again, so nothing is left."""
    try:
        probe = tempfile.mkdtemp(prefix=".endophoton_probe_", dir=folder)
    except OSError:
        return False
    os.rmdir(probe)
    return True
