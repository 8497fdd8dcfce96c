#!/usr/bin/python3
"""Generate the default excitation-emission matrices data/eem/{collagen,photofrin}.csv.

Run:  /usr/bin/python3 data/eem/make_default_eems.py   (numpy only, deterministic)

These EEMs are PARAMETRIC APPROXIMATIONS built from published peak positions,
not measurements.  The seed paper (Zacher 2009) used EEMs measured by DaCosta,
Andersson & Wilson (Photochem. Photobiol. 78(4):384-392, 2003; the seed's
ref. [13]); those tables are not redistributed here.  A measured EEM in the
same CSV format (see docs/fluorescence.md) replaces a default one without code
changes.

Model.  By Kasha's rule a fluorophore emits from its lowest excited state
whatever the excitation wavelength, so its EEM factorises into an excitation
spectrum X(ex) and an emission spectrum M(em):

    F(ex, em) = X(ex) * M(em) * [em > ex + STOKES_GAP_NM]

X and M are sums of bands that are Gaussian in wavenumber nu = 1e7 / lambda
(cm^-1), the natural variable for electronic band shapes; a band is given by
its peak wavelength, its full width at half maximum in nm (converted to
wavenumber at the peak) and a relative height.  The indicator enforces the
Stokes shift: no emission at or within STOKES_GAP_NM of the excitation
wavelength, so a fluorescence event never raises the photon energy.  Values
are normalised so that the matrix maximum is 1 and are read as relative
photon counts per nm of emission.

Units: wavelengths in nm, widths in nm (FWHM at the peak), heights relative.
"""
import os
import tempfile

import numpy as np

EXCITATION_NM = np.arange(250.0, 700.0 + 0.5, 5.0)   # 91 rows
EMISSION_NM = np.arange(300.0, 800.0 + 0.5, 5.0)     # 101 columns
STOKES_GAP_NM = 10.0
FLOOR = 1e-30          # relative values below this are written as 0

# (peak nm, FWHM nm, relative height)
FLUOROPHORES = {
    "collagen": {
        "title": "collagen (type I, structural protein; endogenous)",
        # Collagen autofluorescence: excitation maximum ~325-340 nm, emission
        # maximum ~390-405 nm (Richards-Kortum & Sevick-Muraca 1996, Annu. Rev.
        # Phys. Chem. 47:555; DaCosta et al. 2003, Photochem. Photobiol. 78:384).
        # One band is used; real collagen EEMs show further, weaker
        # cross-link bands that this approximation omits.
        "excitation": [(330.0, 60.0, 1.0)],
        "emission": [(395.0, 90.0, 1.0)],
        "sources": [
            "Richards-Kortum R, Sevick-Muraca E. Quantitative optical spectroscopy for tissue",
            "  diagnosis. Annu Rev Phys Chem 47:555-606, 1996 (collagen ex ~325-340 / em ~390-405 nm).",
            "DaCosta RS, Andersson H, Wilson BC. Molecular fluorescence excitation-emission matrices",
            "  relevant to tissue spectroscopy. Photochem Photobiol 78(4):384-392, 2003 (seed ref. [13]).",
        ],
    },
    "photofrin": {
        "title": "Photofrin (porfimer sodium; haematoporphyrin-derivative mixture; exogenous)",
        # Porphyrin excitation follows its absorption: a strong Soret band near
        # 400-405 nm and four weak Q bands near 505, 540, 570 and 630 nm (630 nm
        # is the clinical PDT wavelength).  Emission: the characteristic
        # porphyrin doublet near 630 and 690 nm.  Positions as commonly reported
        # for Photofrin/HpD; the RELATIVE HEIGHTS AND WIDTHS ARE APPROXIMATIONS
        # chosen to mimic the usual spectra, not fitted to data.
        "excitation": [
            (405.0, 35.0, 1.0),     # Soret
            (505.0, 25.0, 0.08),    # Q IV
            (540.0, 25.0, 0.055),   # Q III
            (570.0, 25.0, 0.045),   # Q II
            (630.0, 20.0, 0.025),   # Q I
        ],
        "emission": [
            (630.0, 20.0, 1.0),
            (690.0, 30.0, 0.45),
        ],
        "sources": [
            "DaCosta RS, Andersson H, Wilson BC. Photochem Photobiol 78(4):384-392, 2003 (EEMs of",
            "  PDT drugs incl. Photofrin in solution; seed ref. [13]).",
            "Dougherty TJ et al. Photodynamic therapy. J Natl Cancer Inst 90(12):889-905, 1998",
            "  (Photofrin activated at 630 nm).",
            "Porphyrin spectroscopy generally: Soret ~400 nm, Q bands ~500-630 nm, fluorescence",
            "  doublet ~630 / ~690 nm.",
        ],
    },
}


def band(wavelength_nm, peak_nm, fwhm_nm):
    """Gaussian band in wavenumber, unit height at peak_nm.

    wavelength_nm, peak_nm, fwhm_nm in nm; returns a dimensionless array.
    The FWHM is converted to wavenumber at the peak, d(nu) = 1e7 d(lambda) / lambda^2.
    """
    nu = 1e7 / np.asarray(wavelength_nm, dtype=float)
    nu0 = 1e7 / peak_nm
    sigma = 1e7 * fwhm_nm / peak_nm**2 / (2.0 * np.sqrt(2.0 * np.log(2.0)))
    return np.exp(-0.5 * ((nu - nu0) / sigma) ** 2)


def spectrum(wavelength_nm, bands):
    """Sum of bands [(peak nm, FWHM nm, height)] on wavelength_nm (nm)."""
    return sum(h * band(wavelength_nm, p, w) for p, w, h in bands)


def build(spec):
    """EEM values (n_ex, n_em), maximum 1, for one entry of FLUOROPHORES."""
    x = spectrum(EXCITATION_NM, spec["excitation"])
    m = spectrum(EMISSION_NM, spec["emission"])
    values = np.outer(x, m)
    values[EMISSION_NM[None, :] <= EXCITATION_NM[:, None] + STOKES_GAP_NM] = 0.0
    values /= values.max()
    # Far band tails reach 1e-300 and below (denormals); they carry no
    # information, so values under FLOOR (relative to the maximum) become 0.
    values[values < FLOOR] = 0.0
    return values


def header(name, spec):
    lines = [
        f"EndoPhoton default excitation-emission matrix: {spec['title']}",
        "",
        "PARAMETRIC APPROXIMATION, NOT A MEASUREMENT.  Generated deterministically by",
        "data/eem/make_default_eems.py; edit and rerun that script rather than this file.",
        "",
        "Model: F(ex, em) = X(ex) * M(em) * [em > ex + %g nm]  (Kasha's rule; Stokes gap)," % STOKES_GAP_NM,
        "X, M = sums of bands Gaussian in wavenumber; (peak nm, FWHM nm, relative height):",
        "  excitation: " + ", ".join("(%g, %g, %g)" % b for b in spec["excitation"]),
        "  emission:   " + ", ".join("(%g, %g, %g)" % b for b in spec["emission"]),
        "Values are relative photon counts per nm of emission, matrix maximum = 1;",
        "values below %g are written as 0." % FLOOR,
        "",
        "Peak positions from:",
        *("  " + s for s in spec["sources"]),
        "",
        "Format: '#' lines are comments.  First data row: the label ex\\em, then the",
        "emission wavelengths (nm).  Each further row: an excitation wavelength (nm), then",
        "the relative fluorescence at each emission wavelength (>= 0).  Wavelengths strictly",
        "increasing.  To use a measured EEM, write it in this format (any units: only ratios",
        "matter) and load it with endophoton.EEM.from_csv(path, name=%r), or save it as" % name,
        "data/eem/%s.csv to replace this default." % name,
    ]
    return "".join(("# " + line).rstrip() + "\n" for line in lines)


def to_csv_text(name, spec, values):
    out = [header(name, spec)]
    out.append("ex\\em," + ",".join("%g" % w for w in EMISSION_NM) + "\n")
    for ex, row in zip(EXCITATION_NM, values):
        out.append("%g," % ex + ",".join("%.6g" % v for v in row) + "\n")
    return "".join(out)


def write_atomic(path, text):
    """Write text to path via a temporary file in the same directory and a rename."""
    directory = os.path.dirname(os.path.abspath(path))
    fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix=".csv", dir=directory)
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline="\n") as f:
            f.write(text)
        os.chmod(tmp, 0o644)   # mkstemp creates 0600; data files are meant to be shared
        os.replace(tmp, path)
    except BaseException:
        os.unlink(tmp)
        raise


def main():
    here = os.path.dirname(os.path.abspath(__file__))
    for name, spec in FLUOROPHORES.items():
        values = build(spec)
        path = os.path.join(here, name + ".csv")
        write_atomic(path, to_csv_text(name, spec, values))
        i, j = np.unravel_index(np.argmax(values), values.shape)
        print("%s: %d x %d, peak at ex %g nm / em %g nm -> %s (%d bytes)"
              % (name, values.shape[0], values.shape[1], EXCITATION_NM[i], EMISSION_NM[j],
                 path, os.path.getsize(path)))


if __name__ == "__main__":
    main()
