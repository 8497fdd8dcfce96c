# SPDX-License-Identifier: MIT
"""Defaults that are plain data (no bpy): role defaults, rig geometry, quality presets."""

from dataclasses import dataclass
from typing import Optional

# --- roles -----------------------------------------------------------------
#
# Choosing a role on an object loads these defaults (medium, priority,
# fluorophores); the user edits them afterwards.  The optical constants are
# the seed paper's colon tissue (its §3, after Wang & Jacques): n = 1.1,
# mua = 20 cm^-1, mus = 200 cm^-1, g = 0.9; the paper gives the polyp no other
# optics, only photofrin besides collagen.  Fluorophores follow the paper:
# tissue collagen d=0.2 c=0.4; polyp collagen (same) + photofrin d=0.1 c=0.33.

ROLE_DEFAULTS = {
    "TISSUE": {
        "medium": {"mua": 20.0, "mus": 200.0, "g": 0.9, "n": 1.1},
        "priority": 0,
        "fluorophores": (("collagen", 0.2, 0.4),),
    },
    "POLYP": {
        "medium": {"mua": 20.0, "mus": 200.0, "g": 0.9, "n": 1.1},
        "priority": 1,
        "fluorophores": (("collagen", 0.2, 0.4), ("photofrin", 0.1, 0.33)),
    },
}

# Fluorophore names with a default excitation-emission matrix in the package
# (data/eem/<name>.csv, ep.EEM.default(name)).
FLUOROPHORE_NAMES = ("collagen", "photofrin")

# --- endoscope tip (colonoscope-sized), millimetres / degrees -------------
RIG_HEAD_DIAMETER_MM = 12.0
RIG_LIGHT_DIAMETER_MM = 3.0
RIG_LIGHT_OFFSET_MM = 3.5
RIG_CONE_ANGLE_DEG = 15.0  # full apex angle of each light's cone
RIG_CAMERA_FOV_DEG = 120.0
RIG_DEFAULT_DISTANCE_MM = 10.0


# --- quality presets ---------------------------------------------------------
@dataclass(frozen=True)
class QualityPreset:
    label: str
    packets: int          # records kept in "store" mode; in packet mode the cap of the target run
    target_error: float   # relative standard error goal of the diffuse reflectance


# The presets run in target-accuracy mode (the engine stops once the relative
# standard error of the diffuse reflectance reaches target_error), the same
# values as the package's endophoton.QUALITY_PRESETS; `packets` caps the run
# (and is the record count in "store" mode, where the count is the request).
QUALITY_PRESETS = {
    "PREVIEW": QualityPreset("Preview", 20_000, 0.05),
    "STANDARD": QualityPreset("Standard", 200_000, 0.01),
    "REFERENCE": QualityPreset("Reference", 2_000_000, 0.002),
}

# Packet caps of the target runs, from the package when it is importable.
TARGET_CAPS = {"PREVIEW": 1_000_000, "STANDARD": 20_000_000, "REFERENCE": 200_000_000}


def resolve_budget(quality, mode, photons, store):
    """Turn the quality preset / custom counts into ``(kind, count, target_error)``.

    ``kind`` is ``"photons"`` (packets launched), ``"store"`` (records kept) or
    ``"target"`` (run to ``target_error``, at most ``count`` packets).
    ``quality`` is a key of QUALITY_PRESETS or ``"CUSTOM"`` (use the explicit counts).
    """
    kind = "store" if mode == "STORE" else "photons"
    if quality == "CUSTOM":
        return kind, (store if kind == "store" else photons), None
    preset = QUALITY_PRESETS[quality]
    if kind == "store":
        return kind, preset.packets, None
    return "target", TARGET_CAPS[quality], preset.target_error
