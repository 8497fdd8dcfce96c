"""spectra.py's EEM and Spectrum are checked by the engine's rules (native/spectrum_check.h, through
_core.check_eem and _core.check_spectrum), the same check_eem that ep::EEM's constructor makes
(native/eem.cpp), and the engine validates light spectra again as Tabulated1D (native/spectrum.cpp).
These tests feed the same inputs to the package and to the engine's own paths and require the
same verdict — and, for EEMs, the same message word for word.
"""
import math
import re

import numpy as np
import pytest

from endophoton import _core
from endophoton.spectra import EEM, Spectrum

NAN = float("nan")

# (ex, em, values): every EEM rule of native/eem.cpp, each broken once.  Values
# go to the engine flattened row-major, as the package sends them.
BAD_EEMS = [
    ([300, 310, 320], [350, 360, 370, 380, 390], np.ones((3, 4))),
    ([300, 320, 310], [350, 360], np.ones((3, 2))),
    ([300], [360, 360], np.ones((1, 2))),
    ([300, 310], [350, NAN, 370], np.ones((2, 3))),
    ([300, 310], [350, 360], [[1, NAN], [1, 1]]),
    ([300, 310], [350, 360], [[1, 1], [math.inf, 1]]),
    ([300, 310], [350, 360, 370], [[1, 1, 1], [1, 1, -0.5]]),
    ([0, 310], [350, 360], np.ones((2, 2))),
    ([-1, 310], [350, 360], np.ones((2, 2))),
    ([300, 310], [1e-300, 360], np.ones((2, 2))),  # outside [1, 1e6] nm (native/spectrum.h)
    ([300, 2e6], [350, 360], np.ones((2, 2))),
    ([300, 310], [350, 360], np.zeros((2, 2))),
    ([], [350, 360], np.zeros((0, 2))),
    ([300], [350], [[1]]),
]
GOOD_EEMS = [
    ([300, 320, 340], [350, 360, 380], [[0, 1, 1], [2, 2, 0], [0, 0, 0]]),
    ([405], [450, 700], [[0, 1]]),
]


def _native_eem(name, ex, em, values):
    scene = _core.Scene(1.0, 1.0)
    flat = np.asarray(values, dtype=np.float64).ravel().tolist()
    return scene.add_fluorophore(name, list(map(float, ex)), list(map(float, em)), flat)


def _message(fn):
    try:
        fn()
    except ValueError as e:
        return str(e)
    return None


@pytest.mark.parametrize("ex, em, values", BAD_EEMS)
def test_bad_eem_same_message_on_both_sides(ex, em, values):
    py = _message(lambda: EEM(ex, em, values, name="collagen"))
    native = _message(lambda: _native_eem("collagen", ex, em, values))
    assert py is not None and native is not None
    assert py == native


def test_empty_eem_name_same_message():
    assert (
        _message(lambda: EEM([300], [350, 360], [[1, 1]], name=""))
        == _message(lambda: _native_eem("", [300], [350, 360], [[1, 1]]))
        == "eem: name must not be empty"
    )


@pytest.mark.parametrize("ex, em, values", GOOD_EEMS)
def test_good_eem_accepted_on_both_sides(ex, em, values):
    EEM(ex, em, values, name="x")
    assert _native_eem("x", ex, em, values) >= 0


# Spectra: the package's Spectrum and the engine's Tabulated1D (reached through a
# light's spectrum) word their messages for their own owners, so here the rule
# is compared: the same inputs are rejected, and the message names the same
# offending index and value.
BAD_SPECTRA = [
    ([400, 500, 600], [1, -0.5, 1], "1", "-0.5"),
    ([400, 500, 600], [1, NAN, 1], "1", "nan"),
    ([400, NAN, 600], [1, 1, 1], "1", "nan"),
    ([400, 600, 500], [1, 1, 1], "2", "500"),
    ([400, 500, 500], [1, 1, 1], "2", "500"),
    ([400, 500, 600], [1, 1], None, None),
]
# Rules only the package has: a Spectrum is a function of wavelength, so it needs a
# band (two entries) of positive wavelengths; the engine's Tabulated1D is a generic
# table (one entry = a constant, any x).  Both stated here so a change shows up.
PACKAGE_ONLY = [([400], [1]), ([-5, 500], [1, 1])]
GOOD_SPECTRA = [([400, 700], [1, 1]), ([400, 410, 700], [0, 2, 0.5])]


def _native_spectrum(wl, values):
    light = dict(
        position=[0.0, 0.0, 1.0],
        direction=[0.0, 0.0, -1.0],
        radius=0.0,
        half_angle=0.0,
        spectrum=(list(map(float, wl)), list(map(float, values))),
    )
    return _core.Source([light])


@pytest.mark.parametrize("wl, values, index, value", BAD_SPECTRA)
def test_bad_spectrum_rejected_on_both_sides(wl, values, index, value):
    py = _message(lambda: Spectrum(wl, values, name="light"))
    native = _message(lambda: _native_spectrum(wl, values))
    assert py is not None and native is not None, (py, native)
    if index is not None:
        for msg in (py, native):
            assert re.search(rf"\[{index}\] = {re.escape(value)}\b", msg), msg


@pytest.mark.parametrize("wl, values", GOOD_SPECTRA)
def test_good_spectrum_accepted_on_both_sides(wl, values):
    Spectrum(wl, values, name="light")
    _native_spectrum(wl, values)


@pytest.mark.parametrize("wl, values", PACKAGE_ONLY)
def test_package_only_spectrum_rules(wl, values):
    assert _message(lambda: Spectrum(wl, values, name="light")) is not None
    _native_spectrum(wl, values)
