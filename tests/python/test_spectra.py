"""Tests for endophoton.spectra: validation, CSV I/O, default EEM data, efficiency.

Reference values come from hand computation, from published peak positions
(see data/eem/make_default_eems.py for the citations) or from scipy's
independent interpolation and integration, never from spectra.py itself.
"""
import math
import re

import numpy as np
import pytest
from scipy.integrate import trapezoid
from scipy.interpolate import RegularGridInterpolator
from scipy.signal import argrelmax

from endophoton.spectra import EEM, FLUOROPHORE_DEFAULTS, Fluorophore, Spectrum, default_fluorophores

NAN = float("nan")

# Hand-built EEM shared with tests/cpp/test_eem.cpp.
#   ex 300: [0, 1, 1]  integral 10*(0+1)/2 + 20*(1+1)/2 = 25
#   ex 320: [2, 2, 0]  integral 10*(2+2)/2 + 20*(2+0)/2 = 40
#   ex 340: [0, 0, 0]  integral 0
HAND_EX = [300.0, 320.0, 340.0]
HAND_EM = [350.0, 360.0, 380.0]
HAND_V = [[0, 1, 1], [2, 2, 0], [0, 0, 0]]


def raises_exactly(exc, message):
    return pytest.raises(exc, match="^" + re.escape(message) + "$")


# ---------------------------------------------------------------- Spectrum


def test_spectrum_interpolates_and_is_zero_outside():
    s = Spectrum([400, 500, 600], [0.0, 2.0, 1.0], name="light")
    assert s(450) == pytest.approx(1.0)
    assert s(550) == pytest.approx(1.5)
    assert s(399.9) == 0.0 and s(600.1) == 0.0 and s(NAN) == 0.0
    np.testing.assert_allclose(s(np.array([400, 500, 600, 700])), [0, 2, 1, 0])
    # Trapezoids by hand: 100*(0+2)/2 + 100*(2+1)/2 = 250 (value x nm).
    assert s.integral() == pytest.approx(250.0)
    assert isinstance(s(450), float)
    with pytest.raises(ValueError):
        s.values[0] = 5.0  # read-only


def test_spectrum_flat_is_one_on_its_band():
    f = Spectrum.flat()
    assert f(400) == 1.0 and f(550) == 1.0 and f(700) == 1.0
    assert f(399) == 0.0 and f(701) == 0.0
    assert f.integral() == pytest.approx(300.0)


@pytest.mark.parametrize(
    "wl, values, message",
    [
        ([400, 500, 600], [1, -0.5, 1], "spectrum 'light': values[1] = -0.5 must be >= 0"),
        ([400, 500, 600], [1, NAN, 1], "spectrum 'light': values[1] = nan must be finite"),
        ([400, NAN, 600], [1, 1, 1], "spectrum 'light': wavelength_nm[1] = nan must be finite"),
        (
            [400, 600, 500],
            [1, 1, 1],
            "spectrum 'light': wavelength_nm[2] = 500 must be greater than "
            "wavelength_nm[1] = 600 (wavelengths must be strictly increasing)",
        ),
        (
            [400, 500, 500],
            [1, 1, 1],
            "spectrum 'light': wavelength_nm[2] = 500 must be greater than "
            "wavelength_nm[1] = 500 (wavelengths must be strictly increasing)",
        ),
        ([-5, 500], [1, 1], "spectrum 'light': wavelength_nm[0] = -5 must be > 0"),
        (
            [400, 500, 600],
            [1, 1],
            "spectrum 'light': wavelength_nm has 3 entries but values has 2; " "they must have the same length",
        ),
        ([[400, 500]], [1, 1], "spectrum 'light': wavelength_nm must be 1-D, got shape (1, 2)"),
        ([400, 500], [[1, 1]], "spectrum 'light': values must be 1-D, got shape (1, 2)"),
        ([400], [1], "spectrum 'light': wavelength_nm needs at least 2 entries, got 1"),
    ],
)
def test_spectrum_validation_messages(wl, values, message):
    with raises_exactly(ValueError, message):
        Spectrum(wl, values, name="light")


# ---------------------------------------------------------------- EEM validation


@pytest.mark.parametrize(
    "ex, em, values, message",
    [
        # wrongly shaped values (the contract's own example), and a transposed matrix
        (
            [300, 310, 320],
            [350, 360, 370, 380, 390],
            np.ones((3, 4)),
            "eem 'collagen': values has 12 entries, expected 3 x 5 = 15",
        ),
        (
            [300, 310, 320],
            [350, 360, 370, 380, 390],
            np.ones((5, 3)),
            "eem 'collagen': values has shape (5, 3), expected 3 x 5 (n_ex x n_em)",
        ),
        # non-monotonic wavelengths
        (
            [300, 320, 310],
            [350, 360],
            np.ones((3, 2)),
            "eem 'collagen': excitation_nm[2] = 310 must be greater than excitation_nm[1] = 320 "
            "(wavelengths must be strictly increasing)",
        ),
        (
            [300],
            [360, 360],
            np.ones((1, 2)),
            "eem 'collagen': emission_nm[1] = 360 must be greater than emission_nm[0] = 360 "
            "(wavelengths must be strictly increasing)",
        ),
        # NaN
        ([300, 310], [350, NAN, 370], np.ones((2, 3)), "eem 'collagen': emission_nm[1] = nan must be finite"),
        (
            [300, 310],
            [350, 360],
            [[1, NAN], [1, 1]],
            "eem 'collagen': values[0][1] (ex 300 nm, em 360 nm) = nan must be finite",
        ),
        (
            [300, 310],
            [350, 360],
            [[1, 1], [math.inf, 1]],
            "eem 'collagen': values[1][0] (ex 310 nm, em 350 nm) = inf must be finite",
        ),
        # negative
        (
            [300, 310],
            [350, 360, 370],
            [[1, 1, 1], [1, 1, -0.5]],
            "eem 'collagen': values[1][2] (ex 310 nm, em 370 nm) = -0.5 must be >= 0",
        ),
        ([0, 310], [350, 360], np.ones((2, 2)), "eem 'collagen': excitation_nm[0] = 0 must be > 0"),
        # nothing emits / too few entries
        ([300, 310], [350, 360], np.zeros((2, 2)), "eem 'collagen': values are all 0; at least one must be positive"),
        ([], [350, 360], np.zeros((0, 2)), "eem 'collagen': excitation_nm needs at least 1 entry, got 0"),
        ([300], [350], [[1]], "eem 'collagen': emission_nm needs at least 2 entries, got 1"),
    ],
)
def test_eem_validation_messages(ex, em, values, message):
    with raises_exactly(ValueError, message):
        EEM(ex, em, values, name="collagen")


def test_eem_empty_name_rejected():
    with raises_exactly(ValueError, "eem: name must not be empty"):
        EEM([300], [350, 360], [[1, 1]], name="")


def test_eem_arrays_are_read_only_copies():
    v = np.array(HAND_V, dtype=float)
    e = EEM(HAND_EX, HAND_EM, v, name="hand")
    v[0, 0] = 99.0  # the caller's array is not aliased
    assert e.values[0, 0] == 0.0
    with pytest.raises(ValueError):
        e.values[0, 0] = 1.0
    assert e.shape == (3, 3)
    np.testing.assert_allclose(e.row_integrals, [25.0, 40.0, 0.0])


# ---------------------------------------------------------------- Fluorophore


def test_fluorophore_defaults_and_validation():
    f = Fluorophore("collagen", 0.2, 0.4)
    assert (f.name, f.d, f.c) == ("collagen", 0.2, 0.4)
    assert f.eem.name == "collagen" and f.eem.shape == (91, 101)
    with raises_exactly(ValueError, "fluorophore 'collagen': d = 1.5 must be in [0, 1]"):
        Fluorophore("collagen", 1.5, 0.4)
    with raises_exactly(ValueError, "fluorophore 'collagen': c = -0.1 must be in [0, 1]"):
        Fluorophore("collagen", 0.2, -0.1)
    with raises_exactly(ValueError, "fluorophore 'collagen': d = nan must be in [0, 1]"):
        Fluorophore("collagen", NAN, 0.4)
    with raises_exactly(ValueError, "fluorophore 'collagen': c = 'x' must be a number in [0, 1]"):
        Fluorophore("collagen", 0.2, "x")
    with raises_exactly(ValueError, "fluorophore 'collagen': eem = [1, 2, 3] (list) must be an endophoton EEM or None"):
        Fluorophore("collagen", 0.2, 0.4, eem=[1, 2, 3])
    with raises_exactly(
        ValueError, "fluorophore 'collagen': eem = 'collagen.csv' (str) must be an endophoton EEM or None"
    ):
        Fluorophore("collagen", 0.2, 0.4, eem="collagen.csv")
    with pytest.raises(ValueError, match=r"^fluorophore 'collagen': eem = array\(.{0,30}\) \(ndarray\) must be"):
        Fluorophore("collagen", 0.2, 0.4, eem=np.zeros(10_000))  # a long value is shown short


def test_unknown_fluorophore_without_eem_names_it_and_lists_known():
    with raises_exactly(
        ValueError, "fluorophore 'nadh': no eem given and no default EEM named " "'nadh' (known: collagen, photofrin)"
    ):
        Fluorophore("nadh", 0.1, 0.1)
    with raises_exactly(
        ValueError, "unknown fluorophore 'nadh': no default EEM named 'nadh' " "(known: collagen, photofrin)"
    ):
        EEM.default("nadh")
    with pytest.raises(ValueError, match="unknown fluorophore '../collagen'"):
        EEM.default("../collagen")
    # An unknown name is fine when its EEM is given.
    own = EEM(HAND_EX, HAND_EM, HAND_V, name="hand")
    assert Fluorophore("nadh", 0.1, 0.1, eem=own).eem is own


def test_fluorophore_defaults_are_the_seed_papers():
    # Zacher 2009, section 3: d_collagen = 0.2, d_photofrin = 0.1,
    # c_collagen = 0.4, c_photofrin = 0.33; the polyp holds both.
    assert FLUOROPHORE_DEFAULTS == {
        "tissue": [("collagen", 0.2, 0.4)],
        "polyp": [("collagen", 0.2, 0.4), ("photofrin", 0.1, 0.33)],
    }
    polyp = default_fluorophores("polyp")
    assert [(f.name, f.d, f.c) for f in polyp] == FLUOROPHORE_DEFAULTS["polyp"]
    with pytest.raises(ValueError, match="kind = 'colon' is unknown"):
        default_fluorophores("colon")


# ---------------------------------------------------------------- CSV


def test_csv_round_trip_is_exact(tmp_path):
    rng = np.random.default_rng(7)
    ex = np.sort(rng.uniform(250, 500, 7))
    em = np.sort(rng.uniform(300, 800, 11))
    values = rng.uniform(0, 1, (7, 11)) ** 3
    values[0, :3] = 0.0
    e = EEM(ex, em, values, name="random")
    path = tmp_path / "random.csv"
    e.to_csv(path, comment="made by a test\nsecond line")
    back = EEM.from_csv(path)
    assert back.name == "random"
    np.testing.assert_array_equal(back.excitation_nm, e.excitation_nm)
    np.testing.assert_array_equal(back.emission_nm, e.emission_nm)
    np.testing.assert_array_equal(back.values, e.values)
    text = path.read_text()
    assert "# made by a test\n# second line\n" in text
    assert [p.name for p in tmp_path.iterdir()] == ["random.csv"]  # no temp file left
    assert path.stat().st_mode & 0o777 == 0o644  # not mkstemp's 0600


def test_default_csv_round_trip(tmp_path):
    for name in ("collagen", "photofrin"):
        e = EEM.default(name)
        e.to_csv(tmp_path / f"{name}.csv")
        back = EEM.from_csv(tmp_path / f"{name}.csv", name=name)
        np.testing.assert_array_equal(back.values, e.values)
        np.testing.assert_array_equal(back.excitation_nm, e.excitation_nm)


@pytest.mark.parametrize(
    "text, message",
    [
        ("# only a comment\n", "needs a header row and at least 1 excitation row, found 0 data row(s)"),
        ("ex\\em,350,360\n300,1,x\n", "line 2, cell 3: 'x' is not a number"),
        ("ex\\em,350,360\n300,1\n", "line 2: expected 3 cells (excitation + 2 values), got 2"),
        ("300,350,360\n300,1,1\n", "line 1: the first data row must start with the label ex\\em"),
        ("ex\\em,350,360\n300,1,-1\n", "eem 'bad': values[0][1] (ex 300 nm, em 360 nm) = -1 must be >= 0"),
    ],
)
def test_csv_errors_name_file_line_and_value(tmp_path, text, message):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(ValueError, match=re.escape(message)):
        EEM.from_csv(path)


def test_csv_accepts_blank_lines_and_trailing_commas(tmp_path):
    path = tmp_path / "x.csv"
    path.write_text("# c\n\nex\\em,350,360,\n300,1,2,\n\n310,0,4\n")
    e = EEM.from_csv(path, name="x")
    np.testing.assert_array_equal(e.values, [[1, 2], [0, 4]])


# ---------------------------------------------------------------- default data


def test_collagen_peak_is_in_the_published_range():
    # Collagen: excitation maximum ~325-340 nm, emission ~390-405 nm
    # (Richards-Kortum & Sevick-Muraca 1996; DaCosta et al. 2003).
    e = EEM.default("collagen")
    i, j = np.unravel_index(np.argmax(e.values), e.shape)
    assert 325 <= e.excitation_nm[i] <= 340
    assert 390 <= e.emission_nm[j] <= 405


def test_photofrin_peaks_are_in_the_published_ranges():
    e = EEM.default("photofrin")
    i, j = np.unravel_index(np.argmax(e.values), e.shape)
    assert 400 <= e.excitation_nm[i] <= 410  # Soret band
    assert 620 <= e.emission_nm[j] <= 640  # main emission peak
    # The emission row at the Soret peak has exactly two maxima, ~630 and ~690 nm.
    row = e.values[i]
    peaks = e.emission_nm[argrelmax(row)[0]]
    assert len(peaks) == 2
    assert 620 <= peaks[0] <= 640 and 680 <= peaks[1] <= 700
    # Excitation (emission-integrated) maxima: Soret ~405 and Q bands near
    # 505, 540, 570, 630 nm, all much weaker than the Soret.
    eta = e.efficiency(e.excitation_nm)
    maxima = e.excitation_nm[argrelmax(eta)[0]]
    assert len(maxima) == 5
    for found, published in zip(maxima, [405, 505, 540, 570, 630]):
        assert abs(found - published) <= 5
    assert np.all(eta[argrelmax(eta)[0]][1:] < 0.2)


@pytest.mark.parametrize("name", ["collagen", "photofrin"])
def test_default_eems_obey_the_stokes_gap(name):
    e = EEM.default(name)
    ex, em = np.meshgrid(e.excitation_nm, e.emission_nm, indexing="ij")
    assert np.all(e.values[em <= ex + 10.0] == 0.0)
    assert e.excitation_nm[0] == 250 and e.excitation_nm[-1] == 700
    assert e.emission_nm[0] == 300 and e.emission_nm[-1] == 800
    assert e.values.max() == pytest.approx(1.0)


# ---------------------------------------------------------------- efficiency


def test_efficiency_of_hand_built_eem():
    e = EEM(HAND_EX, HAND_EM, HAND_V, name="hand")
    assert e.efficiency(300) == pytest.approx(25 / 40)
    assert e.efficiency(320) == pytest.approx(1.0)
    assert e.efficiency(310) == pytest.approx((0.5 * 25 + 0.5 * 40) / 40)
    assert e.efficiency(330) == pytest.approx(0.5)
    assert e.efficiency(340) == 0.0
    assert e.efficiency(299.9) == 0.0 and e.efficiency(340.1) == 0.0 and e.efficiency(NAN) == 0.0
    assert isinstance(e.efficiency(310), float)
    np.testing.assert_allclose(e.efficiency([300, 310, 350]), [0.625, 0.8125, 0.0])


def independent_efficiency(e, lam):
    """eta by scipy: linear grid interpolation of F, fine trapezoid over emission."""
    interp = RegularGridInterpolator((e.excitation_nm, e.emission_nm), e.values, method="linear")
    # 8 sub-steps per emission interval; the grid contains every node, so the
    # trapezoid rule is exact for the piecewise-linear row.
    em = np.concatenate(
        [np.linspace(a, b, 8, endpoint=False) for a, b in zip(e.emission_nm[:-1], e.emission_nm[1:])]
        + [e.emission_nm[-1:]]
    )

    def row_integral(x):
        return trapezoid(interp(np.column_stack([np.full_like(em, x), em])), em)

    max_row = max(row_integral(x) for x in e.excitation_nm)
    return np.array([row_integral(x) / max_row if e.excitation_nm[0] <= x <= e.excitation_nm[-1] else 0.0 for x in lam])


@pytest.mark.parametrize("name", ["collagen", "photofrin"])
def test_efficiency_matches_independent_integral(name):
    e = EEM.default(name)
    rng = np.random.default_rng(3)
    lam = np.concatenate([rng.uniform(250, 700, 40), [250, 330, 405, 632.8, 700, 240, 710]])
    np.testing.assert_allclose(e.efficiency(lam), independent_efficiency(e, lam), rtol=1e-10, atol=1e-300)
