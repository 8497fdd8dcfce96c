"""Optical properties of a region."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Union

import numpy as np

from .io import real_or_none, shown
from .spectra import Spectrum

Coefficient = Union[float, Spectrum]


def _check_coefficient(owner: str, field: str, value) -> None:
    if isinstance(value, Spectrum):
        return  # validated by Spectrum itself (finite, >= 0, increasing wavelengths)
    x = real_or_none(value)
    if x is None:
        raise ValueError(f"{owner}medium.{field} = {shown(value)} must be a number (cm^-1) or an endophoton.Spectrum")
    if not math.isfinite(x) or x < 0:
        raise ValueError(f"{owner}medium.{field} = {shown(value)} must be a finite number >= 0 (cm^-1)")


@dataclass(frozen=True)
class Medium:
    """A homogeneous turbid medium.

    Parameters
    ----------
    mua : absorption coefficient in cm^-1 (a number, or a Spectrum over wavelength in nm)
    mus : scattering coefficient in cm^-1 (a number, or a Spectrum)
    g : Henyey-Greenstein anisotropy, in [-1, 1] (1: no deflection, -1: reversal)
    n : refractive index, >= 1
    """

    mua: Coefficient = 0.0
    mus: Coefficient = 0.0
    g: float = 0.0
    n: float = 1.0

    def __post_init__(self):
        self.validate()
        for name in ("mua", "mus", "g", "n"):  # numpy scalars as Python floats
            if isinstance(getattr(self, name), np.generic):
                object.__setattr__(self, name, float(getattr(self, name)))

    def validate(self, owner: str = "") -> None:
        """Raise ValueError naming ``owner`` (e.g. "region 'tissue': "), the field and the value."""
        _check_coefficient(owner, "mua", self.mua)
        _check_coefficient(owner, "mus", self.mus)
        for field, lo, hi, rule in (("g", -1.0, 1.0, "must be in [-1, 1]"), ("n", 1.0, 100.0, "must be in [1, 100]")):
            v = getattr(self, field)
            x = real_or_none(v)
            if x is None:
                raise ValueError(f"{owner}medium.{field} = {shown(v)} must be a number")
            if not math.isfinite(x) or x < lo or x > hi:
                raise ValueError(f"{owner}medium.{field} = {shown(v)} {rule}")

    @property
    def spectral(self) -> bool:
        return isinstance(self.mua, Spectrum) or isinstance(self.mus, Spectrum)

    def native_args(self) -> dict:
        def split(v):
            if isinstance(v, Spectrum):
                return 0.0, (list(map(float, v.wavelength_nm)), list(map(float, v.values)))
            return float(v), None

        mua, mua_t = split(self.mua)
        mus, mus_t = split(self.mus)
        return dict(mua=mua, mus=mus, g=float(self.g), n=float(self.n), mua_table=mua_t, mus_table=mus_t)

    def to_dict(self) -> dict:
        def enc(v):
            if isinstance(v, Spectrum):
                return {"wavelength_nm": list(map(float, v.wavelength_nm)), "values": list(map(float, v.values))}
            return float(v)

        return {"mua": enc(self.mua), "mus": enc(self.mus), "g": float(self.g), "n": float(self.n)}
