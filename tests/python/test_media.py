"""Spectral tissue media (endophoton.media, docs/media.md): the haemoglobin table against published values,
a preset's mua and mus recomputed from the CSV in plain numpy, names and values refused by name, SCENE.json
presets (schema and loader agree), the add-on's preset menu, and the two renders of issue 35: the mucosa is
pink under white light, the adenomatous polyp darker and redder than the mucosa around it."""
import csv
import importlib.util
import json
import math
import os

import numpy as np
import pytest

import endophoton as ep
from endophoton import paper
from endophoton.view.camera import Camera
from endophoton.view.visibility import jackknife, weber
from physics_helpers import K_SIGMA

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
TABLE = os.path.join(ROOT, "data", "media", "haemoglobin_prahl.csv")
LN10 = math.log(10.0)


def _read_table():
    """The CSV read with the csv module (not the package's reader): {wavelength_nm: (eps_HbO2, eps_Hb)}."""
    rows = {}
    with open(TABLE, newline="", encoding="utf-8") as fh:
        for row in csv.reader(line for line in fh if not line.startswith("#")):
            if row[0] == "wavelength_nm":
                continue
            rows[float(row[0])] = (float(row[1]), float(row[2]))
    return rows


def _eps(rows, wl):
    """Linear interpolation between the two table rows around ``wl`` (nm), written out."""
    lo = 250.0 + 2.0 * math.floor((wl - 250.0) / 2.0)
    if lo == wl:
        return rows[wl]
    t = (wl - lo) / 2.0
    return tuple((1 - t) * a + t * b for a, b in zip(rows[lo], rows[lo + 2.0]))


# ---- the table -----------------------------------------------------------------------------------------------
def test_table_holds_prahls_published_values():
    """Values any reader can check on omlc.org/spectra/hemoglobin/summary.html (Prahl, after Gratzer and
    Kollias), cm^-1/M: the Soret peaks, the Q bands and the isosbestic point near 800 nm."""
    rows = _read_table()
    assert sorted(rows) == [250.0 + 2 * i for i in range(376)]  # 250-1000 nm every 2 nm
    wl = np.array(sorted(rows))
    hbo2 = np.array([rows[w][0] for w in wl])
    hb = np.array([rows[w][1] for w in wl])
    assert wl[np.argmax(hbo2)] == 414 and rows[414][0] == 524280  # HbO2 Soret peak
    assert rows[432][1] == rows[434][1] == 552160 and hb.max() == 552160  # Hb Soret peak
    assert rows[542][0] == 53292 and rows[576][0] == 55540 and rows[556][1] == 54540  # Q bands
    assert rows[800] == (816, 761.72)
    # HbO2 and Hb cross between 796 and 798 nm (the NIR isosbestic point), and nowhere else above 600 nm
    red = wl >= 600
    crossings = wl[red][:-1][np.diff(np.sign(hbo2[red] - hb[red])) != 0]
    assert crossings.tolist() == [796.0]
    # the package reads the same numbers
    pw, po, pd = ep.media.haemoglobin_table()
    assert np.array_equal(pw, wl) and np.array_equal(po, hbo2) and np.array_equal(pd, hb)


def test_whole_blood_absorption_at_the_soret_peak():
    """Prahl's conversion: mua = 2.303 eps x / 64,500 with x = 150 g/L: 2,808 cm^-1 for HbO2 at 414 nm."""
    assert ep.media.blood_mua(414.0, 1.0) == pytest.approx(LN10 * 524280 * 150 / 64500, rel=1e-12)
    assert 2807 < float(ep.media.blood_mua(414.0, 1.0)) < 2809


# ---- a preset recomputed ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("wl", [415.0, 541.0, 650.0])
def test_mucosa_mua_and_mus_recomputed_from_the_table(wl):
    """colon_mucosa: B c_Hb = 93.4 umol/L of haemoglobin (Wang 2009's normal sites) at S = 0.672, so
    mua = ln 10 * 93.4e-6 M * (0.672 eps_HbO2 + 0.328 eps_Hb); mus = 18.9 (lambda/500)^-1.286 / (1 - 0.9)."""
    o, d = _eps(_read_table(), wl)
    expected_mua = LN10 * 93.4e-6 * (0.672 * o + 0.328 * d)
    expected_mus = 18.9 * (wl / 500.0) ** -1.286 / (1.0 - 0.9)
    m = ep.media.preset("colon_mucosa")
    assert float(m.mua(wl)) == pytest.approx(expected_mua, rel=1e-9)
    assert float(m.mus(wl)) == pytest.approx(expected_mus, rel=2e-4)  # linear interpolation between 2 nm nodes
    assert (m.g, m.n) == (paper.TISSUE["g"], paper.TISSUE["n"])


def test_polyp_has_more_blood_and_less_oxygen_than_the_mucosa():
    mucosa, polyp = ep.media.PRESETS["colon_mucosa"], ep.media.PRESETS["adenomatous_polyp"]
    assert polyp["blood_fraction"] == pytest.approx(136.9 / 93.4 * mucosa["blood_fraction"], rel=1e-12)
    assert mucosa["blood_fraction"] == pytest.approx(93.4e-6 * 64500 / 150, rel=1e-12)  # 4.02 %
    assert polyp["saturation"] < mucosa["saturation"]
    wl = np.arange(400.0, 701.0, 10.0)
    assert np.all(ep.media.preset("adenomatous_polyp").mua(wl) > ep.media.preset("colon_mucosa").mua(wl))


def test_submucosa_scattering_passes_through_marchesinis_two_values():
    """Marchesini 1994, ex vivo colon: mus' = 14.2 cm^-1 at 300 nm and 6.2 cm^-1 at 800 nm."""
    p = ep.media.PRESETS["colon_submucosa"]
    for wl, musp in ((300.0, 14.2), (800.0, 6.2)):
        assert float(ep.media.reduced_scattering(wl, p["a_cm"], p["b"])) == pytest.approx(musp, rel=1e-12)


def test_paper_preset_is_the_seeds_constant_medium():
    m = ep.media.preset("paper")
    assert not m.spectral and {"mua": m.mua, "mus": m.mus, "g": m.g, "n": m.n} == paper.TISSUE


# ---- names and values ------------------------------------------------------------------------------------------
def test_presets_are_listed_and_fetched_by_name():
    names = ep.media.preset_names()
    assert names == ["adenomatous_polyp", "colon_mucosa", "colon_submucosa", "paper"]
    for name in names:
        assert isinstance(ep.media.preset(name), ep.Medium)
        assert ep.media.preset_description(name)


@pytest.mark.parametrize("name", ["colon", "", None, 3, "Colon_Mucosa"])
def test_unknown_preset_is_refused_by_name(name):
    with pytest.raises(ValueError, match=r"preset = .* is not a medium preset \(known: adenomatous_polyp"):
        ep.media.preset(name)


@pytest.mark.parametrize(
    "field,value",
    [
        ("blood_fraction", 1.5),
        ("blood_fraction", float("nan")),
        ("saturation", -0.1),
        ("saturation", "high"),
        ("a_cm", 0.0),
        ("b", 5.0),
        ("g", 1.0),
        ("background_mua_cm", -1.0),
        ("n", 0.5),
    ],
)
def test_bad_tissue_values_are_refused_naming_the_field(field, value):
    args = dict(blood_fraction=0.04, saturation=0.7, a_cm=18.9, b=1.3)
    args[field] = value
    with pytest.raises(ValueError, match=rf"(^|\.){field} = "):
        ep.media.tissue(**args)


def test_wavelengths_outside_the_table_or_not_numbers_are_refused():
    with pytest.raises(ValueError, match=r"wavelength_nm = .* must lie in \[250, 1000\] nm"):
        ep.media.blood_mua([500.0, 1200.0], 0.5)
    with pytest.raises(ValueError, match=r"wavelength_nm = 'red' must be a number"):
        ep.media.blood_mua("red", 0.5)
    with pytest.raises(ValueError, match=r"wavelength_nm = .* must hold finite wavelengths > 0"):
        ep.media.reduced_scattering([500.0, float("nan")], 18.9, 1.3)


# ---- SCENE.json ---------------------------------------------------------------------------------------------
def _doc(medium):
    return {
        "unit": "cm",
        "ambient_n": 1.0,
        "regions": [{"name": "wall", "medium": medium, "box": {"min": [-1, -1, -1], "max": [1, 1, 0]}}],
    }


@pytest.mark.parametrize("name", ["colon_mucosa", "colon_submucosa", "adenomatous_polyp", "paper"])
def test_scene_json_takes_a_preset_by_name(name):
    scene = ep.Scene.from_dict(_doc({"preset": name}))
    assert scene.regions[0].medium == ep.media.preset(name)
    again = ep.Scene.from_dict(scene.to_dict())  # written out as numbers / spectra, read back the same
    m, m2 = scene.regions[0].medium, again.regions[0].medium
    for field in ("mua", "mus"):
        a, b = getattr(m, field), getattr(m2, field)
        if isinstance(a, ep.Spectrum):
            assert np.array_equal(a.wavelength_nm, b.wavelength_nm) and np.array_equal(a.values, b.values)
        else:
            assert a == b


@pytest.mark.parametrize(
    "medium,message",
    [
        ({"preset": "colon"}, r"region 'wall': medium\.preset = 'colon' is not one of \['adenomatous_polyp'"),
        ({"preset": 3}, r"region 'wall': medium\.preset = 3 is not of type 'string'"),
        ({"preset": "paper", "g": 0.8}, r"region 'wall': medium: unknown key 'g' \(allowed: preset\)"),
        ("colon_mucosa", r"region 'wall': medium = 'colon_mucosa' is not of type 'object'"),
        ({"mua": 1.0}, r"region 'wall': medium: missing key: 'mus'"),
    ],
)
def test_scene_json_refuses_bad_presets_by_name(medium, message):
    with pytest.raises(ValueError, match=message):
        ep.Scene.from_dict(_doc(medium))


def test_schema_lists_the_loaders_presets():
    """docs/scene.schema.json's medium_preset enum is endophoton.media.preset_names() (one list, two places)."""
    enum = ep.scene_schema.schema()["definitions"]["medium_preset"]["properties"]["preset"]["enum"]
    assert enum == ep.media.preset_names()


# ---- the add-on's preset menu ---------------------------------------------------------------------------------
def _addon_presets():
    path = os.path.join(ROOT, "addon", "endophoton_addon", "presets.py")
    spec = importlib.util.spec_from_file_location("_presets_under_test", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_addon_offers_the_spectral_presets_with_the_packages_values():
    """The add-on registers without the package, so its menu holds a copy: the ep.media name of each spectral
    entry, and the medium fields it shows (the preset at presets.SPECTRAL_SHOWN_NM). Any drift fails here."""
    addon = _addon_presets()
    spectral = {p.spectral: p for p in addon.TISSUE_PRESETS.values() if p.spectral}
    assert sorted(spectral) == [n for n in ep.media.preset_names() if n != "paper"]
    wl = addon.SPECTRAL_SHOWN_NM
    for name, p in spectral.items():
        m = ep.media.preset(name)
        shown = {"mua": float(m.mua(wl)), "mus": float(m.mus(wl)), "g": m.g, "n": m.n}
        assert p.medium == pytest.approx(shown, rel=5e-3), name


# ---- renders (issue 35, acceptance 1 and 2) --------------------------------------------------------------------
def _ratio(rgb, pb, a, b):
    return jackknife(rgb[[a, b]], pb, lambda m: m[0] / m[1])


def test_spectral_mucosa_renders_pink_under_white_light():
    """A flat colon_mucosa slab seen by the endoscope (EndoscopeRig, flat 400-700 nm white light, beta = 0,
    1 cm): mean linear R > G > B over the lit pixels, and each ratio of the region's means above 1 beyond K_SIGMA
    sigma (jackknife over batches). Grey tissue stays neutral: test_render.py's
    test_white_non_absorbing_scene_renders_neutral (same light, white balance and estimator)."""
    scene = ep.Scene(unit="cm")
    scene.add_box("wall", (-3, -3, -1), (3, 3, 0), ep.media.preset("colon_mucosa"))
    res = ep.run(scene, ep.EndoscopeRig.from_beta(0.0, 1.0), photons=50_000, seed=5, spectral=True, threads=2)
    view = ep.render_view(res, None, 24, 24, kernel_radius=0.1, kernel_angle_deg=30, threads=2)
    img = view.images["white"]
    lit = img["radiance"] > 0
    assert lit.sum() >= 100  # pixels the kernel found records for (the periphery of a 120 deg view is dark)
    r, g, b = img["rgb"][lit].mean(axis=0)
    assert r > g > b > 0, (r, g, b)
    rgb, pb = view.region_batches["white_rgb"][0], view.packets_per_batch
    for a, c in ((0, 1), (1, 2)):
        ratio, se = _ratio(rgb, pb, a, c)
        assert ratio - 1 > K_SIGMA * se, (a, c, ratio, se)


#: Packets of the polyp render (docs/media.md quotes it with its CPU time).
POLYP_PACKETS = 600_000


def _polyp_view(polyp_preset):
    """colon_mucosa wall with a flush 1.2 x 1.2 x 0.5 cm polyp region at the centre of its surface, under an
    even white disk light (radius 2 cm), seen from 3 cm above with a 50 deg camera: every pixel of the wall is
    the polyp's surroundings under the same irradiance."""
    scene = ep.Scene(unit="cm")
    scene.add_box("wall", (-3, -3, -1), (3, 3, 0), ep.media.preset("colon_mucosa"))
    scene.add_box("polyp", (-0.6, -0.6, -0.5), (0.6, 0.6, 0.0), ep.media.preset(polyp_preset), priority=1)
    light = ep.DiskSource(position=(0, 0, 1), direction=(0, 0, -1), radius=2.0)
    res = ep.run(scene, light, photons=POLYP_PACKETS, seed=1, spectral=True, threads=2)
    camera = Camera.look_at((0, 0, 3), (0, 0, 0), up=(0, 1, 0), fov_deg=50)
    return ep.render_view(res, camera, 32, 32, kernel_radius=0.15, kernel_angle_deg=45, threads=2, estimator="kernel")


def _darker_redder(view):
    """(white Weber contrast, its stderr), (Weber contrast of the white image's R/G ratio, its stderr) of the
    polyp against the wall."""
    c = view.contrast("polyp", "wall")
    rgb = view.region_batches["white_rgb"][[view.region_index("polyp"), view.region_index("wall")]][:, :2]
    red = jackknife(rgb, view.packets_per_batch, lambda m: weber(m[0, 0] / m[0, 1], m[1, 0] / m[1, 1]))
    return (c["white"], c["white_stderr"]), red


@pytest.mark.slow
def test_adenomatous_polyp_is_darker_and_redder_than_the_mucosa_around_it():
    """Acceptance 2 of issue 35: with 47 % more blood at lower saturation (Wang 2009) the polyp's white-light
    radiance is lower (Weber < 0) and its R/G higher (Weber > 0), each beyond 3 sigma. The same geometry with
    a mucosa 'polyp' shows neither beyond K_SIGMA sigma: the contrast is the blood's, not the geometry's."""
    (white, white_se), (red, red_se) = _darker_redder(_polyp_view("adenomatous_polyp"))
    assert white < -3 * white_se and red > 3 * red_se, (white, white_se, red, red_se)
    (white0, white0_se), (red0, red0_se) = _darker_redder(_polyp_view("colon_mucosa"))
    assert abs(white0) < K_SIGMA * white0_se and abs(red0) < K_SIGMA * red0_se, (white0, white0_se, red0, red0_se)


def test_example_scene_takes_its_media_by_name_and_runs():
    """examples/spectral_colon.json (docs/media.md's render command) loads its three presets and runs."""
    path = os.path.join(ROOT, "examples", "spectral_colon.json")
    scene = ep.Scene.from_json(path)
    media = {r.name: r.medium for r in scene.regions}
    assert media == {
        "mucosa": ep.media.preset("colon_mucosa"),
        "submucosa": ep.media.preset("colon_submucosa"),
        "polyp": ep.media.preset("adenomatous_polyp"),
    }
    with open(path, encoding="utf-8") as fh:
        source = ep.source_from_dict(json.load(fh)["source"])
    res = ep.run(scene, source, photons=2_000, seed=3, spectral=True, threads=1)
    assert 0 < res.diffuse_reflectance < 1
