# SPDX-License-Identifier: MIT
"""Defaults that are plain data (no bpy): role defaults, rig geometry, quality presets."""

from dataclasses import dataclass


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


# --- tissue presets (medium only; chosen per object) ------------------------
@dataclass(frozen=True)
class TissuePreset:
    label: str
    medium: dict  # mua, mus in cm^-1, g, n
    source: str  # where the numbers come from, and what is assumed
    spectral: str = ""  # name of an endophoton.media preset: the engine gets its mua(λ), mus(λ)


# A spectral preset's medium fields show its values at this wavelength (nm), for the panel and the size
# guard; the engine takes the spectra (endophoton.media.preset). tests/python/test_media.py holds these
# copies to the package's values.
SPECTRAL_SHOWN_NM = 550.0
_SPECTRAL_NOTE = (
    "Spectral: the engine takes μa(λ) = blood × haemoglobin (Prahl's table) and μs'(λ) = a(λ/500 nm)^−b; "
    "the fields show the values at 550 nm (editing one makes the medium constant again). Sources: docs/media.md"
)


TISSUE_PRESETS = {
    "PAPER": TissuePreset(
        "Paper's tissue",
        {"mua": 20.0, "mus": 200.0, "g": 0.9, "n": 1.1},
        "Seed paper §3 (after its ref. [3]): single-layer tissue, n = 1.1, μa = 20 cm⁻¹, μs = 200 cm⁻¹, "
        "g = 0.9, under air",
    ),
    "COLON_800": TissuePreset(
        "Colon ex vivo, 800 nm",
        {"mua": 1.0, "mus": 62.0, "g": 0.9, "n": 1.4},
        "Marchesini et al., Lasers Surg. Med. 15(4):351–357 (1994), ex vivo human colon, integrating "
        "sphere: μa = 1.0 cm⁻¹ and μs' = 6.2 cm⁻¹ at 800 nm. The paper gives μs' only: g = 0.9 and "
        "n = 1.4 are assumed (typical soft tissue), so μs = μs'/(1 − g) = 62 cm⁻¹",
    ),
    "COLON_300": TissuePreset(
        "Colon ex vivo, 300 nm",
        {"mua": 47.7, "mus": 142.0, "g": 0.9, "n": 1.4},
        "Marchesini et al., Lasers Surg. Med. 15(4):351–357 (1994), ex vivo human colon: μa = 47.7 cm⁻¹ "
        "and μs' = 14.2 cm⁻¹ at 300 nm; g = 0.9 and n = 1.4 assumed, μs = μs'/(1 − g) = 142 cm⁻¹",
    ),
    "COLON_MUCOSA": TissuePreset(
        "Colon mucosa (spectral)",
        {"mua": 9.984, "mus": 167.2, "g": 0.9, "n": 1.1},
        "Normal colon mucosa: blood 4.0 % (93.4 µmol/L haemoglobin) at 67 % saturation, Wang et al., Opt. "
        "Express 17:2805 (2009); scattering of soft tissue, a = 18.9 cm⁻¹, b = 1.286, Jacques, Phys. Med. "
        "Biol. 58:R37 (2013); g, n the paper's. " + _SPECTRAL_NOTE,
        spectral="colon_mucosa",
    ),
    "COLON_SUBMUCOSA": TissuePreset(
        "Colon submucosa (spectral)",
        {"mua": 9.984, "mus": 85.09, "g": 0.9, "n": 1.1},
        "Colon submucosa: blood as the mucosa (Wang 2009); scattering of the ex vivo colon wall, μs' = 14.2 "
        "cm⁻¹ at 300 nm and 6.2 cm⁻¹ at 800 nm, Marchesini et al. (1994); g, n the paper's. " + _SPECTRAL_NOTE,
        spectral="colon_submucosa",
    ),
    "ADENOMATOUS_POLYP": TissuePreset(
        "Adenomatous polyp (spectral)",
        {"mua": 15.16, "mus": 167.2, "g": 0.9, "n": 1.1},
        "Adenomatous polyp: blood 5.9 % (136.9 µmol/L haemoglobin) at 51 % saturation, premalignant sites of "
        "Wang et al. (2009); soft-tissue scattering (Jacques 2013); g, n the paper's. " + _SPECTRAL_NOTE,
        spectral="adenomatous_polyp",
    ),
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
    packets: int  # records kept in "store" mode; in packet mode the cap of the target run
    target_error: float  # relative standard error goal of the diffuse reflectance


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
