"""Colour: the CIE 1931 fit against published values, the sRGB rules, white balance and hue of spectral lines."""
import numpy as np
import pytest

from endophoton.view import colour

# CIE 1931 2-degree table (CIE 15), values at 5 nm nodes: (lambda, x, y, z).
CIE_TABLE = [
    (450, 0.3362, 0.0380, 1.7721),
    (500, 0.0049, 0.3230, 0.2720),
    (555, 0.5121, 1.0000, 0.0057),
    (600, 1.0622, 0.6310, 0.0008),
    (650, 0.2835, 0.1070, 0.0000),
]


def test_cmf_landmarks():
    lam = np.arange(360.0, 830.0, 0.1)
    f = colour.cmf_xyz(lam)
    y_peak = lam[np.argmax(f[:, 1])]
    assert 550 <= y_peak <= 560 and f[:, 1].max() == pytest.approx(1.0, abs=0.01)
    z_peak = lam[np.argmax(f[:, 2])]
    assert 440 <= z_peak <= 450 and f[:, 2].max() == pytest.approx(1.78, abs=0.02)
    blue = (lam > 400) & (lam < 480)
    assert lam[blue][np.argmax(f[blue, 0])] == pytest.approx(442.0, abs=2.0)
    assert f[blue, 0].max() == pytest.approx(0.348, abs=0.03)  # CIE x-bar at 440-445 nm: 0.3483


@pytest.mark.parametrize("lam,x,y,z", CIE_TABLE)
def test_cmf_against_cie_table(lam, x, y, z):
    # Wyman et al. report the multi-lobe fit within a few hundredths of the table.
    assert colour.cmf_xyz(lam) == pytest.approx([x, y, z], abs=0.04)


def test_srgb_matrix_maps_d65_to_white():
    d65 = np.array([0.95047, 1.0, 1.08883])  # IEC 61966-2-1 white point, Y = 1
    assert colour.xyz_to_linear_srgb(d65) == pytest.approx([1, 1, 1], abs=2e-3)
    assert colour.WHITE_D65 == pytest.approx(d65, abs=2e-3)


def test_srgb_encoding():
    assert colour.srgb_encode([0.0, 0.0031308, 0.5, 1.0]) == pytest.approx(
        [0.0, 12.92 * 0.0031308, 1.055 * 0.5 ** (1 / 2.4) - 0.055, 1.0]
    )
    assert colour.to_srgb8(np.array([[2.0, -1.0, 0.5]]), 1.0).tolist() == [[255, 0, 188]]


def test_flat_white_light_is_neutral_after_von_kries():
    gains = colour.white_balance_gains(None)
    lam = np.arange(400.0, 700.0, 0.25) + 0.125  # records of a flat 400-700 nm light (photon counts)
    xyz = colour.record_xyz(lam, 500.0 / lam).sum(axis=0)
    rgb = colour.xyz_to_linear_srgb(xyz, gains)
    assert rgb / rgb[1] == pytest.approx([1, 1, 1], abs=1e-3)
    raw = colour.xyz_to_linear_srgb(xyz)  # without balance: a flat spectrum is not D65
    assert abs(raw[0] / raw[1] - 1) > 0.02 or abs(raw[2] / raw[1] - 1) > 0.02


@pytest.mark.parametrize("lam,channel", [(630.0, 0), (450.0, 2)])
def test_spectral_lines_hue(lam, channel):
    gains = colour.white_balance_gains(None)
    rgb = colour.xyz_to_linear_srgb(colour.record_xyz([lam], [1.0])[0], gains)
    px = colour.to_srgb8(rgb[None, :], 0.5 / rgb.max())[0].astype(int)
    assert px[channel] > 150
    assert all(px[channel] > 2 * px[c] for c in range(3) if c != channel)


def test_auto_exposure_rule():
    y = np.linspace(0.0, 2.0, 1001)
    assert colour.auto_exposure(y) == pytest.approx(0.5 / np.percentile(y, 99))
    assert colour.auto_exposure(np.zeros(10)) == 1.0
