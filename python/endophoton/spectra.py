"""Spectra, excitation-emission matrices (EEMs) and fluorophores.

The classes here carry user arrays to the engine, which uses the C++
counterparts ``ep::Tabulated1D`` (native/spectrum.h) and ``ep::EEM``
(native/eem.h).  The engine owns their rules: a Spectrum and an EEM are checked
by ``_core.check_spectrum`` and ``_core.check_eem`` (native/spectrum_check.h),
the checks ``ep::EEM`` itself makes, before the arrays are kept.

Units: wavelengths in nm throughout.  Spectrum values are in the caller's
units (relative power for a light, cm^-1 for a coefficient).  EEM values are
relative photon counts per nm of emission; only ratios matter.

See docs/fluorescence.md for the fluorescence model and the CSV format.
"""

import reprlib
from pathlib import Path

import numpy as np

from . import _core
from .io import atomic_write_text, read_input_text, shown
from .paper import FLUOROPHORES

__all__ = [
    "Spectrum",
    "EEM",
    "Fluorophore",
    "FLUOROPHORE_DEFAULTS",
    "default_fluorophores",
]

# Fluorophores of the seed paper's experiment per region kind, as (name, d, c):
# endophoton.paper holds the values (d = probability of interacting with the
# fluorophore, c = concentration of fluorescent molecules, both in [0, 1]).
FLUOROPHORE_DEFAULTS = {kind: list(fluorophores) for kind, fluorophores in FLUOROPHORES.items()}


def _g(v):
    """Format a number as %g does (for the reprs and the fluorophore's messages)."""
    return f"{float(v):g}"


#: Range of every wavelength a Spectrum or EEM may hold, nm: soft X-rays (1 nm) to the far infrared (1 mm).
#: Far wider than any optical tissue data, and it keeps the spectral energy weight 500 nm / wavelength in
#: [5e-4, 500], so that no tally or its variance overflows (1e-300 nm made escaped_energy_stderr = inf).
#: The engine owns the rule (kMinWavelengthNm, kMaxWavelengthNm in native/spectrum.h; its EEM checks it too).
MIN_WAVELENGTH_NM = float(_core.MIN_WAVELENGTH_NM)
MAX_WAVELENGTH_NM = float(_core.MAX_WAVELENGTH_NM)


def _as_float_array(value, where, field):
    try:
        return np.array(value, dtype=np.float64)
    except (TypeError, ValueError, OverflowError) as exc:
        raise ValueError(f"{where}{field} must be numeric: {exc}") from None


def _trapezoid_rows(x, v):
    """Trapezoid integral of each row of v (..., n) over x (n,): exact for piecewise-linear rows."""
    return np.sum(0.5 * np.diff(x) * (v[..., 1:] + v[..., :-1]), axis=-1)


class Spectrum:
    """A piecewise-linear, non-negative function of wavelength.

    Parameters
    ----------
    wavelength_nm : 1-D array, nm, in [1, 1e6] (MIN_WAVELENGTH_NM, MAX_WAVELENGTH_NM), strictly increasing,
        >= 2 entries.
    values : 1-D array of the same length, finite, >= 0, in the caller's units
        (relative power for a light, cm^-1 for mua / mus).
    name : used in error messages.

    ``spectrum(wl)`` interpolates linearly and is 0 outside
    [wavelength_nm[0], wavelength_nm[-1]], like ``ep::Tabulated1D::eval``.
    """

    __slots__ = ("_wl", "_values", "_name")

    def __init__(self, wavelength_nm, values, name="spectrum"):
        self._name = str(name)
        where = f"spectrum '{self._name}': "
        wl = _as_float_array(wavelength_nm, where, "wavelength_nm")
        v = _as_float_array(values, where, "values")
        _core.check_spectrum(self._name, wl, v)
        wl.flags.writeable = False
        v.flags.writeable = False
        self._wl, self._values = wl, v

    @classmethod
    def flat(cls, lo=400.0, hi=700.0, name="flat"):
        """Value 1 on [lo, hi] nm, 0 outside (the default white light, 400-700 nm)."""
        return cls([lo, hi], [1.0, 1.0], name=name)

    @property
    def wavelength_nm(self):
        """Node wavelengths, nm (read-only float64 array)."""
        return self._wl

    @property
    def values(self):
        """Node values, caller's units (read-only float64 array)."""
        return self._values

    @property
    def name(self):
        return self._name

    def __call__(self, wavelength_nm):
        """Linear interpolation at wavelength_nm (nm, scalar or array); 0 outside the table."""
        wl = np.asarray(wavelength_nm, dtype=np.float64)
        out = np.interp(wl, self._wl, self._values, left=0.0, right=0.0)
        out = np.where(np.isnan(wl), 0.0, out)
        return float(out) if out.ndim == 0 else out

    def integral(self):
        """Integral over the table, value units x nm (exact trapezoid)."""
        return float(_trapezoid_rows(self._wl, self._values))

    def __len__(self):
        return self._wl.size

    def __repr__(self):
        return f"Spectrum(name={self._name!r}, {self._wl.size} nodes, " f"{_g(self._wl[0])}-{_g(self._wl[-1])} nm)"


class EEM:
    """Excitation-emission matrix of one fluorophore.

    Parameters
    ----------
    excitation_nm : (n_ex,) nm, in [1, 1e6], strictly increasing, n_ex >= 1.
    emission_nm : (n_em,) nm, same rules, n_em >= 2.
    values : (n_ex, n_em) relative fluorescence (photon counts per nm of
        emission, any scale), finite, >= 0, at least one > 0.
    name : identifies the EEM in error messages.

    Raises ValueError naming the field and value: the engine's rules (``_core.check_eem``), as ``ep::EEM`` checks.
    """

    __slots__ = ("_name", "_ex", "_em", "_values", "_row_integral")

    def __init__(self, excitation_nm, emission_nm, values, name="eem"):
        self._name = str(name)
        if not self._name:
            raise ValueError("eem: name must not be empty")
        where = f"eem '{self._name}': "
        ex = _as_float_array(excitation_nm, where, "excitation_nm")
        em = _as_float_array(emission_nm, where, "emission_nm")
        v = _as_float_array(values, where, "values")
        _core.check_eem(self._name, ex, em, v)
        for a in (ex, em, v):
            a.flags.writeable = False
        self._ex, self._em, self._values = ex, em, v
        self._row_integral = _trapezoid_rows(em, v)
        self._row_integral.flags.writeable = False

    # ---- accessors ------------------------------------------------------
    @property
    def name(self):
        return self._name

    @property
    def excitation_nm(self):
        """Excitation wavelengths (rows), nm, read-only."""
        return self._ex

    @property
    def emission_nm(self):
        """Emission wavelengths (columns), nm, read-only."""
        return self._em

    @property
    def values(self):
        """(n_ex, n_em) relative fluorescence, read-only."""
        return self._values

    @property
    def row_integrals(self):
        """Integral of each row over emission, value units x nm, read-only."""
        return self._row_integral

    @property
    def shape(self):
        return self._values.shape

    # ---- physics ----------------------------------------------------------
    def efficiency(self, lambda_ex):
        """Relative excitation efficiency eta(lambda_ex) in [0, 1]; lambda_ex in nm.

        eta = I(lambda_ex) / max_i I_i, where I_i is the emission integral of
        row i and I(lambda) interpolates the I_i linearly (integration over
        emission commutes with linear interpolation between rows).  0 outside
        the excitation range and for NaN.  Scalar in, float out; array in,
        array out.  Same definition as ``ep::EEM::efficiency``.
        """
        lam = np.asarray(lambda_ex, dtype=np.float64)
        eta = np.interp(lam, self._ex, self._row_integral, left=0.0, right=0.0)
        eta = np.where(np.isnan(lam), 0.0, np.minimum(1.0, eta / self._row_integral.max()))
        return float(eta) if eta.ndim == 0 else eta

    # ---- files ------------------------------------------------------------
    @classmethod
    def from_csv(cls, path, name=None):
        """Read an EEM from the CSV format of data/eem (see docs/fluorescence.md).

        Lines starting with '#' and blank lines are skipped.  First data row:
        a text label (``ex\\em``) then the emission wavelengths (nm); every
        further row: the excitation wavelength (nm) then one value per
        emission wavelength.  name defaults to the file's stem.
        """
        path = Path(path)
        name = path.stem if name is None else name
        where = f"eem file '{path}'"
        # a regular file within MAX_INPUT_BYTES["eem file"], UTF-8 (errors name the file)
        lines = read_input_text(path, "eem file").splitlines()
        rows = []
        for lineno, line in enumerate(lines, start=1):
            text = line.strip()
            if not text or text.startswith("#"):
                continue
            cells = [c.strip() for c in text.split(",")]
            while cells and cells[-1] == "":  # trailing commas from spreadsheets
                cells.pop()
            rows.append((lineno, cells))
        if len(rows) < 2:
            raise ValueError(
                f"{where}: needs a header row and at least 1 excitation row, " f"found {len(rows)} data row(s)"
            )

        def number(lineno, k, cell):
            try:
                return float(cell)
            except ValueError:
                raise ValueError(f"{where} line {lineno}, cell {k + 1}: {cell!r} is not a number") from None

        head_line, head = rows[0]
        try:
            float(head[0])
            label_is_number = True
        except ValueError:
            label_is_number = False
        if label_is_number:
            raise ValueError(
                f"{where} line {head_line}: the first data row must start with the "
                f"label ex\\em followed by the emission wavelengths, got {head[0]!r}"
            )
        em = [number(head_line, k, c) for k, c in enumerate(head) if k > 0]
        ex, values = [], []
        for lineno, cells in rows[1:]:
            if len(cells) != len(em) + 1:
                raise ValueError(
                    f"{where} line {lineno}: expected {len(em) + 1} cells "
                    f"(excitation + {len(em)} values), got {len(cells)}"
                )
            nums = [number(lineno, k, c) for k, c in enumerate(cells)]
            ex.append(nums[0])
            values.append(nums[1:])
        return cls(ex, em, np.array(values, dtype=np.float64).reshape(len(ex), len(em)), name=name)

    def to_csv(self, path, comment=None):
        """Write the EEM to path (atomically) in the format from_csv reads.

        Values are written with repr(), so reading them back is exact.
        comment: optional extra text for the '#' header (provenance).
        """
        lines = [
            f"# excitation-emission matrix '{self._name}', written by endophoton.spectra",
            "# rows: excitation wavelength (nm); columns: emission wavelength (nm);" " values: relative fluorescence",
        ]
        if comment:
            lines += ["# " + c for c in str(comment).splitlines()]
        lines.append("ex\\em," + ",".join(repr(float(w)) for w in self._em))
        for x, row in zip(self._ex, self._values):
            lines.append(repr(float(x)) + "," + ",".join(repr(float(v)) for v in row))
        atomic_write_text(path, "\n".join(lines) + "\n", make_dirs=False)

    # ---- defaults ---------------------------------------------------------
    @staticmethod
    def default_dirs():
        """Directories searched for default EEMs, in order, that exist.

        1. ``endophoton/data/eem`` inside the installed package;
        2. the repository's ``data/eem`` (two levels above python/endophoton).
        """
        here = Path(__file__).resolve().parent
        candidates = [here / "data" / "eem", here.parents[1] / "data" / "eem"]
        return [d for d in candidates if d.is_dir()]

    @staticmethod
    def default_names():
        """Sorted names of the default EEMs (CSV stems in default_dirs())."""
        return sorted({p.stem for d in EEM.default_dirs() for p in d.glob("*.csv")})

    @classmethod
    def default(cls, name):
        """The default EEM for fluorophore `name` (e.g. "collagen", "photofrin")."""
        name = str(name)
        if name and "/" not in name and "\\" not in name and name not in (".", ".."):
            for d in cls.default_dirs():
                path = d / (name + ".csv")
                if path.is_file():
                    return cls.from_csv(path, name=name)
        known = ", ".join(cls.default_names()) or "none found"
        raise ValueError(f"unknown fluorophore '{name}': no default EEM named '{name}' " f"(known: {known})")

    def __repr__(self):
        return (
            f"EEM(name={self._name!r}, {self._ex.size} x {self._em.size}, "
            f"ex {_g(self._ex[0])}-{_g(self._ex[-1])} nm, "
            f"em {_g(self._em[0])}-{_g(self._em[-1])} nm)"
        )


class Fluorophore:
    """A fluorophore in a region: name, d, c and its EEM.

    d : probability that an interaction involves this fluorophore, in [0, 1].
    c : concentration of fluorescent molecules, in [0, 1].
        A packet fluoresces when xi1 < d (times eta for the "eem" rule) and
        xi2 < c (seed paper, section 4; docs/fluorescence.md).
    eem : an EEM, or None for ``EEM.default(name)``.
    """

    __slots__ = ("_name", "_d", "_c", "_eem")

    def __init__(self, name, d, c, eem=None):
        if not isinstance(name, str) or not name:
            raise ValueError(f"fluorophore: name must be a non-empty string, got {name!r}")
        self._name = name
        self._d = self._probability("d", d)
        self._c = self._probability("c", c)
        if eem is None:
            try:
                eem = EEM.default(name)
            except ValueError:
                known = ", ".join(EEM.default_names()) or "none found"
                raise ValueError(
                    f"fluorophore '{name}': no eem given and no default EEM named " f"'{name}' (known: {known})"
                ) from None
        elif not isinstance(eem, EEM):
            raise ValueError(
                f"fluorophore '{name}': eem = {reprlib.repr(eem)} ({type(eem).__name__}) must be an "
                "endophoton EEM or None"
            )
        self._eem = eem

    def _probability(self, field, value):
        try:
            x = float(value)
        except (TypeError, ValueError, OverflowError):
            raise ValueError(
                f"fluorophore '{self._name}': {field} = {shown(value)} must be a number in [0, 1]"
            ) from None
        if not (0.0 <= x <= 1.0):  # also rejects NaN
            raise ValueError(f"fluorophore '{self._name}': {field} = {_g(x)} must be in [0, 1]")
        return x

    @property
    def name(self):
        return self._name

    @property
    def d(self):
        """Interaction probability, dimensionless in [0, 1]."""
        return self._d

    @property
    def c(self):
        """Concentration of fluorescent molecules, dimensionless in [0, 1]."""
        return self._c

    @property
    def eem(self):
        return self._eem

    def __repr__(self):
        return f"Fluorophore({self._name!r}, d={_g(self._d)}, c={_g(self._c)}, eem={self._eem.name!r})"


def default_fluorophores(kind):
    """Fluorophores of the seed experiment: kind "tissue" or "polyp" (FLUOROPHORE_DEFAULTS)."""
    if kind not in FLUOROPHORE_DEFAULTS:
        raise ValueError(
            f"default_fluorophores: kind = {kind!r} is unknown " f"(known: {', '.join(sorted(FLUOROPHORE_DEFAULTS))})"
        )
    return [Fluorophore(n, d, c) for n, d, c in FLUOROPHORE_DEFAULTS[kind]]
