"""Spectral tissue media: haemoglobin absorption and power-law scattering, and colon presets.

A tissue is blood spread through a scattering matrix (Jacques 2013, Phys. Med. Biol. 58 R37):

    mua(lambda) = B * [S * mua_HbO2(lambda) + (1 - S) * mua_Hb(lambda)] + mua_background   (cm^-1)
    mua_X(lambda) = ln(10) * eps_X(lambda) * c_Hb,   c_Hb = 150 g/L / 64,500 g/mol = 2.33 mM
    mus'(lambda) = a * (lambda / 500 nm)^(-b),   mus = mus' / (1 - g)                        (cm^-1)

B = ``blood_fraction`` (volume fraction of whole blood, [0, 1]), S = ``saturation`` (oxygen saturation of
its haemoglobin, [0, 1]), eps = the molar extinction coefficients (decadic, cm^-1/M) of Prahl's compilation
in data/media/haemoglobin_prahl.csv (250-1000 nm every 2 nm). The spectra of a preset are tabulated on that
grid; the engine interpolates linearly and takes a Spectrum as 0 outside its range, so below 250 nm and
above 1000 nm a preset has mua = mua_background and mus = 0: light there is out of the model.

``preset(name)`` builds a named medium (:func:`preset_names`); ``tissue(...)`` builds any other. Every
preset value and its source: docs/media.md. The logarithms and powers are endophoton.det's (SLEEF through the
native module), so that a medium's coefficients have the same bits on every machine.
"""
from __future__ import annotations

import functools
from pathlib import Path

import numpy as np

from . import det, paper
from .io import check_real, shown
from .medium import Medium
from .spectra import Spectrum

__all__ = [
    "HB_GRAMS_PER_LITRE",
    "HB_GRAMS_PER_MOLE",
    "REFERENCE_WAVELENGTH_NM",
    "PRESETS",
    "haemoglobin_table",
    "blood_mua",
    "reduced_scattering",
    "power_law_through",
    "blood_fraction_of",
    "tissue",
    "preset",
    "preset_names",
    "preset_description",
]

#: Haemoglobin of whole blood, g/L: "a typical value ... for whole blood is x = 150 g Hb/liter" (Prahl,
#: omlc.org/spectra/hemoglobin, the table's own page).
HB_GRAMS_PER_LITRE = 150.0
#: Gram molecular weight of haemoglobin (tetramer), g/mol, as on Prahl's page for this table.
HB_GRAMS_PER_MOLE = 64_500.0
#: The scattering power law's reference wavelength, nm (Jacques 2013, Eq. 1).
REFERENCE_WAVELENGTH_NM = 500.0

_TABLE_NAME = "haemoglobin_prahl.csv"


def power_law_through(point1, point2) -> dict:
    """The (a_cm, b) of mus' = a (lambda / 500 nm)^(-b) through two (wavelength_nm, mus'_cm) points."""
    (l1, v1), (l2, v2) = point1, point2
    b = det.log(v1 / v2) / det.log(l2 / l1)
    return dict(a_cm=v2 * det.pow(l2 / REFERENCE_WAVELENGTH_NM, b), b=b)


def blood_fraction_of(hb_umol_per_l) -> float:
    """Volume fraction of whole blood holding ``hb_umol_per_l`` haemoglobin (umol/L of tissue): c / 2.33 mM."""
    return check_real("hb_umol_per_l", hb_umol_per_l, 0.0, 1e6) * 1e-6 / (HB_GRAMS_PER_LITRE / HB_GRAMS_PER_MOLE)


#: Blood of normal colon sites measured in vivo by diffuse reflectance (Wang et al. 2009, Opt. Express 17:2805):
#: total haemoglobin 93.4 umol/L, oxygen saturation 67.2 %.
NORMAL_COLON_BLOOD = dict(blood_fraction=blood_fraction_of(93.4), saturation=0.672)
#: Blood of premalignant (adenomatous) colon sites in the same study: 136.9 umol/L, 51.3 %.
PREMALIGNANT_COLON_BLOOD = dict(blood_fraction=blood_fraction_of(136.9), saturation=0.513)
#: Reduced scattering of "other soft tissues" (Jacques 2013, Table 2): a = 18.9 cm^-1, b = 1.286.
SOFT_TISSUE_SCATTERING = dict(a_cm=18.9, b=1.286)
#: Reduced scattering of ex vivo human colon wall (Marchesini et al. 1994): 14.2 cm^-1 at 300 nm and 6.2 cm^-1
#: at 800 nm, the power law through them: a = 9.22 cm^-1, b = 0.845.
COLON_WALL_SCATTERING = power_law_through((300.0, 14.2), (800.0, 6.2))

#: The named media. Spectral presets give the tissue() parameters; "paper" is the seed's constant medium
#: (endophoton.paper.TISSUE). Sources of every number: docs/media.md.
PRESETS: dict = {
    "colon_mucosa": dict(
        description="normal colon mucosa: Wang 2009 normal-site blood (93.4 umol/L Hb, S 0.672), "
        "Jacques 2013 soft-tissue scattering",
        **NORMAL_COLON_BLOOD,
        **SOFT_TISSUE_SCATTERING,
    ),
    "colon_submucosa": dict(
        description="colon submucosa: normal-site blood (Wang 2009), scattering of the ex vivo colon wall "
        "(Marchesini 1994)",
        **NORMAL_COLON_BLOOD,
        **COLON_WALL_SCATTERING,
    ),
    "adenomatous_polyp": dict(
        description="adenomatous polyp: Wang 2009 premalignant blood (136.9 umol/L Hb, S 0.513), "
        "Jacques 2013 soft-tissue scattering",
        **PREMALIGNANT_COLON_BLOOD,
        **SOFT_TISSUE_SCATTERING,
    ),
    "paper": dict(description="the seed paper's constant tissue (Zacher 2009 §3): mua 20, mus 200 cm^-1, g 0.9, n 1.1"),
}

#: g and n of the spectral presets: the seed paper's (endophoton.paper.TISSUE), so that the spectral colon
#: and the paper's model differ in mua(lambda) and mus(lambda) only (docs/media.md).
PRESET_G = paper.TISSUE["g"]
PRESET_N = paper.TISSUE["n"]


def _table_paths():
    here = Path(__file__).resolve().parent
    return [here / "data" / "media" / _TABLE_NAME, here.parents[1] / "data" / "media" / _TABLE_NAME]


@functools.lru_cache(maxsize=1)
def haemoglobin_table() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(wavelength_nm, eps_HbO2, eps_Hb): Prahl's molar extinction coefficients, cm^-1/M (decadic),
    250-1000 nm every 2 nm (read-only arrays). Searched in the installed package's data/media, then the
    repository's data/media."""
    path = next((p for p in _table_paths() if p.is_file()), None)
    if path is None:
        raise RuntimeError(f"{_TABLE_NAME} not found in {[str(p.parent) for p in _table_paths()]} (reinstall)")
    lines = [ln for ln in path.read_text(encoding="utf-8").splitlines() if ln.strip() and not ln.startswith("#")]
    if not lines or lines[0].split(",")[0] != "wavelength_nm":
        raise RuntimeError(f"{path}: the first line after the comments must be the header 'wavelength_nm,...'")
    a = np.array([[float(x) for x in ln.split(",")] for ln in lines[1:]], dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != 3 or not np.all(np.diff(a[:, 0]) > 0) or not np.all(a >= 0):
        raise RuntimeError(f"{path}: rows must be 'wavelength_nm,hbo2,hb' with increasing wavelengths, values >= 0")
    cols = tuple(np.ascontiguousarray(a[:, i]) for i in range(3))
    for c in cols:
        c.flags.writeable = False
    return cols


def _check_fraction(name: str, v) -> float:
    return check_real(name, v, 0.0, 1.0)


def _wavelengths(v) -> np.ndarray:
    """``v`` (nm, a number or an array) as a float array; ValueError naming wavelength_nm otherwise."""
    try:
        x = np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"wavelength_nm = {shown(v)} must be a number or an array of numbers (nm)") from None
    if x.size and not np.all(np.isfinite(x) & (x > 0)):
        raise ValueError(f"wavelength_nm = {shown(v)} must hold finite wavelengths > 0 (nm)")
    return x


def blood_mua(wavelength_nm, saturation) -> np.ndarray:
    """Absorption coefficient of whole blood (150 g/L haemoglobin), cm^-1, at ``wavelength_nm`` (nm, within
    250-1000; linear interpolation of the table) for oxygen ``saturation`` in [0, 1]."""
    s = _check_fraction("saturation", saturation)
    wl, hbo2, hb = haemoglobin_table()
    x = _wavelengths(wavelength_nm)
    if x.size and (x.min() < wl[0] or x.max() > wl[-1]):
        raise ValueError(
            f"wavelength_nm = {shown(wavelength_nm)} must lie in [{wl[0]:g}, {wl[-1]:g}] nm (the haemoglobin table)"
        )
    eps = s * np.interp(x, wl, hbo2) + (1.0 - s) * np.interp(x, wl, hb)
    return det.log(10.0) * eps * (HB_GRAMS_PER_LITRE / HB_GRAMS_PER_MOLE)


def reduced_scattering(wavelength_nm, a_cm, b) -> np.ndarray:
    """mus'(lambda) = a_cm * (lambda / 500 nm)^(-b), cm^-1 (Jacques 2013, Eq. 1); wavelength_nm in nm."""
    a = check_real("a_cm", a_cm, 0.0, 1e4, lo_open=True)
    p = check_real("b", b, 0.0, 4.0)
    return a * det.pow(_wavelengths(wavelength_nm) / REFERENCE_WAVELENGTH_NM, -p)


def tissue(
    blood_fraction,
    saturation,
    a_cm,
    b,
    g=PRESET_G,
    n=PRESET_N,
    background_mua_cm=0.0,
    name: str = "tissue",
) -> Medium:
    """A medium of blood in a power-law scatterer, tabulated at the haemoglobin table's wavelengths.

    blood_fraction : volume fraction of whole blood, [0, 1] (Hb concentration / 2.33 mM)
    saturation : oxygen saturation of the haemoglobin, [0, 1]
    a_cm : reduced scattering at 500 nm, cm^-1, > 0;  b : scattering power, [0, 4] (4 = Rayleigh)
    g : anisotropy, [-1, 1) (mus = mus' / (1 - g));  n : refractive index, [1, 100]
    background_mua_cm : absorption added at every wavelength, cm^-1, >= 0
    name : names the spectra in error messages
    """
    B = _check_fraction("blood_fraction", blood_fraction)
    gg = check_real("g", g, -1.0, 1.0)
    if gg >= 1.0:
        raise ValueError(f"g = {shown(g)} must be < 1 (mus = mus' / (1 - g))")
    bg = check_real("background_mua_cm", background_mua_cm, 0.0, 1e4)
    wl = haemoglobin_table()[0]
    mua = B * blood_mua(wl, saturation) + bg
    mus = reduced_scattering(wl, a_cm, b) / (1.0 - gg)
    return Medium(mua=Spectrum(wl, mua, name=f"{name}.mua"), mus=Spectrum(wl, mus, name=f"{name}.mus"), g=gg, n=n)


def preset_names() -> list[str]:
    """Names :func:`preset` accepts, sorted."""
    return sorted(PRESETS)


def _known(name) -> dict:
    if not isinstance(name, str) or name not in PRESETS:
        raise ValueError(f"preset = {shown(name)} is not a medium preset (known: {', '.join(preset_names())})")
    return PRESETS[name]


def preset_description(name: str) -> str:
    """One line saying what the preset is and where its values come from."""
    return _known(name)["description"]


def preset(name: str) -> Medium:
    """The named medium (see :func:`preset_names`); ValueError naming the name if unknown. Media are
    immutable, so one object per name is built and shared."""
    _known(name)
    return _build_preset(name)


@functools.lru_cache(maxsize=None)
def _build_preset(name: str) -> Medium:
    p = PRESETS[name]
    if name == "paper":
        return Medium(**paper.TISSUE)
    return tissue(**{k: v for k, v in p.items() if k != "description"}, name=name)
