"""Spectra to colour: CIE 1931 2-degree XYZ, linear sRGB, 8-bit sRGB.

The rules, written down once (docs/render.md repeats them):

* **Colour-matching functions.** The CIE 1931 2-degree observer is taken from
  the analytic fit of Wyman, Sloan & Shirley, "Simple Analytic Approximations to
  the CIE XYZ Color Matching Functions", JCGT 2(2), 2013 (their multi-lobe
  piecewise Gaussian). It is close enough to the CIE 15 table for images; the
  tests check the published landmarks (y-bar peak ~1.0 near 555 nm, z-bar peak
  ~1.78 near 445 nm, the x-bar lobe near 442 nm).
* **Spectrum to XYZ.** A pixel's spectrum is a sum of escape records, each a
  delta at its wavelength carrying its *energy* (weight x 500/lambda: the CMFs
  weigh spectral power, not photon counts). Its integral against the CMFs is
  therefore the sum of CMF values at the records' wavelengths: exact, with no
  binning error. ``spectrum_bins`` bins the same records for output only.
* **XYZ to linear sRGB.** IEC 61966-2-1 matrix (D65 white).
* **White balance (von Kries in XYZ).** X, Y, Z are each multiplied by
  ``white_D65[k] / white_light[k]``, where ``white_light`` is the XYZ of the
  balancing light's own spectrum (as power, normalised to Y = 1) and
  ``white_D65`` = (0.95047, 1, 1.08883). The light's own spectrum therefore
  maps exactly to the D65 white point, i.e. to R = G = B: a white,
  non-absorbing scene renders neutral grey.
* **Exposure.** ``auto``: one factor per image, chosen so that the 99th
  percentile, over the pixels that see a surface, of each pixel's largest
  linear sRGB channel maps to 0.5 (one stop below clipping). The largest
  channel rather than the luminance Y, so a saturated blue or red field
  (small Y, large B or R) is not pushed into clipping. A number fixes the factor (use the same
  number to compare images from different runs). The factor used is reported.
* **Out of gamut.** Spectral colours (e.g. 450 nm or 630 nm records) lie
  outside the sRGB triangle: some linear channel is negative. After exposure,
  each channel is clipped to [0, 1] independently (negative to 0, above 1 to
  1). This keeps the hue family of saturated colours and lightens them a
  little; the float arrays (``.npz``) keep the unclipped linear values.
* **Encoding.** sRGB transfer function (12.92 c for c <= 0.0031308, else
  1.055 c^(1/2.4) - 0.055), then round to 8 bits.

The colour-matching functions, the white point and the XYZ-to-sRGB products feed the channel tables
a run with ``view=`` hands the engine (view.nee.channel_tables), so they are computed with
endophoton.det (SLEEF's exp, products added in a fixed order) and exact rational arithmetic (the white
point), not numpy's dispatched exp, the BLAS or LAPACK: the same bits on every x86-64 machine.
"""
from __future__ import annotations

import math
from fractions import Fraction

import numpy as np

from .. import det

__all__ = [
    "cmf_xyz",
    "XYZ_TO_SRGB",
    "WHITE_D65",
    "xyz_to_linear_srgb",
    "srgb_encode",
    "to_srgb8",
    "white_balance_gains",
    "record_xyz",
    "auto_exposure",
    "spectrum_bins",
    "light_xyz",
]

# (weight, mu, sigma_below, sigma_above) lobes of Wyman, Sloan & Shirley (2013), lambda in nm.
_LOBES = {
    "x": ((1.056, 599.8, 37.9, 31.0), (0.362, 442.0, 16.0, 26.7), (-0.065, 501.1, 20.4, 26.2)),
    "y": ((0.821, 568.8, 46.9, 40.5), (0.286, 530.9, 16.3, 31.1)),
    "z": ((1.217, 437.0, 11.8, 36.0), (0.681, 459.0, 26.0, 13.8)),
}

#: IEC 61966-2-1: XYZ (D65) to linear sRGB.
XYZ_TO_SRGB = np.array([[3.2406, -1.5372, -0.4986], [-0.9689, 1.8758, 0.0415], [0.0557, -0.2040, 1.0570]])


def _solve3_exact(A, b) -> np.ndarray:
    """x with A x = b for a 3x3 A, each entry the exact solution rounded once: Cramer's rule in
    fractions.Fraction (exact rational arithmetic), not np.linalg.solve, whose LAPACK (OpenBLAS's)
    picks its kernels by the processor."""
    A = [[Fraction(v) for v in row] for row in np.asarray(A, dtype=np.float64).tolist()]
    b = [Fraction(v) for v in np.asarray(b, dtype=np.float64).tolist()]

    def det3(m):
        return (
            m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
            - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
        )

    d = det3(A)
    replaced = ([[b[r] if c == i else A[r][c] for c in range(3)] for r in range(3)] for i in range(3))
    return np.array([float(det3(m) / d) for m in replaced])


#: D65 white point, Y = 1 (the XYZ that the sRGB matrix maps to R = G = B = 1).
WHITE_D65 = _solve3_exact(XYZ_TO_SRGB, np.ones(3))


def _lobe(lam, mu, s1, s2):
    s = np.where(lam < mu, s1, s2)
    z = (lam - mu) / s
    return det.exp(-0.5 * (z * z))


def cmf_xyz(wavelength_nm) -> np.ndarray:
    """CIE 1931 2-degree colour-matching functions at ``wavelength_nm`` (nm): array (..., 3) of x, y, z bar."""
    lam = np.asarray(wavelength_nm, dtype=np.float64)
    out = np.zeros(lam.shape + (3,))
    for k, name in enumerate("xyz"):
        for w, mu, s1, s2 in _LOBES[name]:
            out[..., k] += w * _lobe(lam, mu, s1, s2)
    out[~np.isfinite(lam)] = 0.0
    return out


def record_xyz(wavelength_nm, energy) -> np.ndarray:
    """XYZ contribution (K, 3) of records: energy x CMF(lambda) (energy = weight x 500/lambda)."""
    return cmf_xyz(wavelength_nm) * np.asarray(energy, dtype=np.float64)[..., None]


def light_xyz(spectrum, lo: float = 360.0, hi: float = 830.0, step: float = 0.5) -> np.ndarray:
    """XYZ of a light given as a photon-number spectrum (an ``ep.Spectrum``; None = flat 400-700 nm).

    The engine samples packet wavelengths in proportion to the spectrum's values, so
    they are photon counts per nm; the power weighs each by 500/lambda, as the records' energy does.
    Integrated on a fine grid (``step`` nm); returned normalised to Y = 1.
    """
    lam = np.arange(lo, hi + step / 2, step)
    if spectrum is None:
        s = ((lam >= 400.0) & (lam <= 700.0)).astype(float)
    else:
        s = np.asarray(spectrum(lam), dtype=np.float64)
    xyz = (cmf_xyz(lam) * (s * 500.0 / lam)[:, None]).sum(axis=0) * step
    if not (xyz[1] > 0):
        raise ValueError("white_balance: the light has no luminance (Y = 0); it cannot define white")
    return xyz / xyz[1]


def white_balance_gains(spectrum) -> np.ndarray:
    """Von Kries gains in XYZ: WHITE_D65 / light_xyz(spectrum) (3,), so the light maps to D65 white."""
    return WHITE_D65 / light_xyz(spectrum)


def xyz_to_linear_srgb(xyz, gains=None) -> np.ndarray:
    """Linear sRGB (..., 3) of XYZ (..., 3), after optional von Kries ``gains`` (3,). Not clipped."""
    xyz = np.asarray(xyz, dtype=np.float64)
    if gains is not None:
        xyz = xyz * np.asarray(gains, dtype=np.float64)
    return det.matvec(XYZ_TO_SRGB, xyz)


def srgb_encode(linear) -> np.ndarray:
    """sRGB transfer function of linear values already clipped to [0, 1]."""
    c = np.clip(np.asarray(linear, dtype=np.float64), 0.0, 1.0)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * np.power(c, 1.0 / 2.4) - 0.055)


def auto_exposure(value, mask=None) -> float:
    """Exposure rule: factor mapping the 99th percentile of ``value`` (each pixel's largest linear
    channel) over ``mask`` to 0.5; 1 if that percentile is 0."""
    y = np.asarray(value, dtype=np.float64)
    if mask is not None:
        y = y[np.asarray(mask, dtype=bool)]
    y = y[np.isfinite(y)]
    if y.size == 0:
        return 1.0
    p = float(np.percentile(y, 99.0))
    return 0.5 / p if p > 0 and math.isfinite(p) else 1.0


def to_srgb8(linear_rgb, exposure: float) -> np.ndarray:
    """8-bit sRGB (uint8, same shape) of linear sRGB: times ``exposure``, each channel clipped to [0, 1]
    (the out-of-gamut rule), encoded, rounded."""
    lin = np.nan_to_num(np.asarray(linear_rgb, dtype=np.float64) * float(exposure), nan=0.0, posinf=1.0, neginf=0.0)
    return np.round(255.0 * srgb_encode(np.clip(lin, 0.0, 1.0))).astype(np.uint8)


def spectrum_bins(lo: float = 380.0, hi: float = 780.0, width: float = 10.0) -> np.ndarray:
    """Edges (nm) of the wavelength bins used for the saved per-pixel spectra."""
    return np.arange(lo, hi + width / 2, width)
