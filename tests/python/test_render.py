"""The endoscope's view (endophoton.render): radiance estimators against analytic Lambertian records,
the physical (aperture) camera against the kernel estimate, flat fields, colour and the photofrin contrast.

Synthetic surface photon maps with a known radiance check the estimators' normalisation; engine runs
check the acceptance criteria of issue 10. Every tolerance is 3 sigma of the reported standard errors
plus a stated model allowance.
"""
import math

import numpy as np
import pytest

import endophoton as ep
from endophoton import analysis
from endophoton.camera import Camera
from endophoton.render import emission_filter_function, excitation_spectrum, render_view


class _Records:
    """A stand-in for ep.Result built from synthetic escape records."""

    def __init__(self, scene, escapes, packets, source=None):
        self.scene, self.escapes, self.source = scene, escapes, source
        self.packets_traced = self.photons = packets


def _plane_scene():
    s = ep.Scene(unit="cm")
    s.add_box("tissue", (-5, -5, -1), (5, 5, 0), ep.Medium(mua=1.0, mus=10.0))
    return s


def _lambertian(n, half=1.0, wavelength=500.0, seed=1):
    """n records uniform on [-half, half]^2 at z = 0 with cosine-weighted directions: radiance
    L = n / (P A pi) per packet (A = (2 half)^2 cm^2), the same in every direction."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-half, half, size=(n, 2))
    u1, u2 = rng.random(n), rng.random(n)
    r, phi = np.sqrt(u1), 2 * np.pi * u2
    d = np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(1 - u1)], axis=1)
    wl = np.broadcast_to(np.asarray(wavelength, dtype=np.float32), (n,)).copy()
    return {"position": np.column_stack([xy, np.zeros(n)]).astype(np.float32), "direction": d.astype(np.float32),
            "normal": np.tile(np.float32([0, 0, 1]), (n, 1)), "weight": np.ones(n),
            "energy": 500.0 / wl.astype(np.float64), "wavelength": wl, "fluorescent": np.zeros(n, np.uint8),
            "packet": np.arange(n, dtype=np.uint64), "region": np.zeros(n, np.int32)}


def _region_value(view, key="white"):
    return view.regions()["tissue"][key + "_radiance"], view.regions()["tissue"][key + "_radiance_stderr"]


def test_kernel_and_aperture_estimate_lambertian_radiance():
    n = 400_000
    res = _Records(_plane_scene(), _lambertian(n), n)
    L_true = 1.0 / (4.0 * math.pi)                    # n / (P * 4 cm^2 * pi)
    cam = Camera.look_at((0, 0, 2), (0, 0, 0), up=(0, 1, 0), fov_deg=30, aperture_radius=0.3)
    view = render_view(res, cam, 8, 8, kernel_radius=0.1, kernel_angle_deg=15)
    L, se = _region_value(view)
    assert abs(L - L_true) < 3 * se + 0.005 * L_true      # 0.5 %: cone-averaged cos(theta) near the normal
    ap = view.aperture["white"]
    La, sa = ap["radiance"].mean(), np.sqrt(np.sum(ap["radiance_stderr"] ** 2)) / ap["radiance"].size
    assert abs(La - L_true) < 3 * sa
    assert view.region_pixels[0] == 64 and np.all(view.region_map == 0)
    assert np.all(np.isfinite(view.images["white"]["radiance_stderr"]))


def test_scene_units_do_not_change_radiance():
    # The same records in mm: radiance per cm^2 must not change.
    n = 200_000
    esc = _lambertian(n)
    esc["position"] = esc["position"] * 10
    s = ep.Scene(unit="mm")
    s.add_box("tissue", (-50, -50, -10), (50, 50, 0), ep.Medium(mua=1.0, mus=10.0))
    cam = Camera.look_at((0, 0, 20), (0, 0, 0), up=(0, 1, 0), fov_deg=30)
    view = render_view(_Records(s, esc, n), cam, 8, 8, kernel_radius=1.0)
    L, se = _region_value(view)
    assert abs(L - 1 / (4 * math.pi)) < 3 * se + 0.005 / (4 * math.pi)


@pytest.mark.parametrize("lam,channel", [(630.0, 0), (450.0, 2)])
def test_spectral_records_render_their_hue(lam, channel):
    n = 100_000
    view = render_view(_Records(_plane_scene(), _lambertian(n, wavelength=lam), n),
                       Camera.look_at((0, 0, 2), (0, 0, 0), up=(0, 1, 0), fov_deg=30), 6, 6, kernel_radius=0.15)
    px = view.images["white"]["srgb8"].reshape(-1, 3).mean(axis=0)
    assert px[channel] > 150
    assert all(px[channel] > 2 * px[c] for c in range(3) if c != channel)


def test_flat_spectrum_records_render_neutral():
    n = 200_000
    rng = np.random.default_rng(5)
    esc = _lambertian(n)
    esc["wavelength"] = rng.uniform(400, 700, n).astype(np.float32)   # photon counts flat in 400-700 nm
    esc["energy"] = 500.0 / esc["wavelength"].astype(np.float64)
    view = render_view(_Records(_plane_scene(), esc, n), Camera.look_at((0, 0, 2), (0, 0, 0), up=(0, 1, 0),
                                                                        fov_deg=30), 6, 6, kernel_radius=0.15)
    rgb = view.region_batches["white_rgb"][0].sum(axis=1)
    # Tolerance: 2 % of the white point plus the sampling noise of the wavelengths (~1 %).
    assert rgb / rgb[1] == pytest.approx([1, 1, 1], abs=0.03)


def test_primary_rays_see_the_analytic_surface_and_regions():
    s = ep.Scene(unit="cm")
    s.add_box("wall", (-5, -5, -1), (5, 5, 0), ep.Medium(mua=1.0, mus=10.0))
    s.add_box("polyp", (-0.5, -0.5, -0.2), (0.5, 0.5, 0.3), ep.Medium(mua=1.0, mus=10.0), priority=1)
    n = 1000
    res = _Records(s, _lambertian(n), n)
    cam = Camera.look_at((0, 0, 2), (0, 0, 0), up=(0, 1, 0), fov_deg=60)
    view = render_view(res, cam, 16, 16, kernel_radius=0.1)
    # Independent pinhole recomputation: pixel centre rays hit z = 0.3 inside |x|,|y| < 0.5, else z = 0.
    t = math.tan(math.radians(30))
    c = ((np.arange(16) + 0.5) / 16 * 2 - 1) * t
    X, Y = np.meshgrid(c, -c)
    on_polyp = (np.abs(X * 1.7) < 0.5) & (np.abs(Y * 1.7) < 0.5)
    assert np.array_equal(view.region_map == 1, on_polyp)
    assert np.allclose(view.depth, np.where(on_polyp, 1.7, 2.0), rtol=1e-6)


def test_camera_inside_tissue_and_bad_knobs_are_errors():
    res = _Records(_plane_scene(), _lambertian(100), 100)
    with pytest.raises(ValueError, match="camera.position"):
        render_view(res, Camera.look_at((0, 0, -0.5), (0, 0, -0.9), up=(0, 1, 0)), 4, 4)
    cam = Camera.look_at((0, 0, 2), (0, 0, 0), up=(0, 1, 0))
    for kw, field in ((dict(kernel_radius=-1.0), "kernel_radius"), (dict(kernel_angle_deg=0), "kernel_angle_deg"),
                      (dict(width=0), "width"), (dict(exposure="x"), "exposure"),
                      (dict(emission_filter="red"), "emission_filter"), (dict(white_balance="d50"), "white_balance")):
        with pytest.raises(ValueError, match=field):
            render_view(res, cam, **({"width": 4, "height": 4} | kw))
    with pytest.raises(ValueError, match="camera.up"):
        Camera.look_at((0, 0, 2), (0, 0, 0), up=(0, 0, 1))
    with pytest.raises(ValueError, match="record_escapes"):
        render_view(_Records(_plane_scene(), None, 10), cam, 4, 4)


def test_excitation_and_emission_filter_rules():
    assert excitation_spectrum("white") is None
    blue = excitation_spectrum("blue")
    lam = np.arange(380.0, 430.0, 0.01)
    v = blue(lam)
    above = lam[v >= 0.5 * v.max()]
    assert lam[np.argmax(v)] == pytest.approx(405.0, abs=0.01) and above[-1] - above[0] == pytest.approx(10, abs=0.1)
    T, desc = emission_filter_function("auto", blue)
    assert desc.startswith("long-pass") and T(405.0) == 0 and T(630.0) == 1
    assert float(desc.split()[1]) == pytest.approx(405 + 10 + 10 * math.sqrt(math.log(100) / math.log(16)), abs=0.6)
    T, desc = emission_filter_function("auto", None)
    assert desc == "all-pass"
