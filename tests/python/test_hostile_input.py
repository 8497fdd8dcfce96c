"""Hostile input to the API: each is refused before any tracing with a ValueError that names the field and
its value, and leaves nothing changed on disk."""

import itertools
import os
import re
import stat

import numpy as np
import pytest

import endophoton as ep

M = ep.Medium(mua=0.1, mus=10.0, g=0.9, n=1.4)
DOWN = ep.PencilSource(position=(0, 0, 1), direction=(0, 0, -1))


def box_scene():
    s = ep.Scene(unit="cm")
    s.add_box("box", (-1, -1, -1), (1, 1, 0), M)
    return s


# ---- grids.path: checked before the run, never replaces a special file or a link


def run_with_grid(path):
    return ep.run(box_scene(), DOWN, photons=100, grids=ep.GridRequest(0.1, str(path)))


def test_grid_path_fifo_is_refused_and_kept(tmp_path):
    fifo = tmp_path / "fifo1"
    os.mkfifo(fifo)
    with pytest.raises(ValueError, match=f"grids.path = '{fifo}' exists and is a FIFO"):
        run_with_grid(fifo)
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)
    assert sorted(os.listdir(tmp_path)) == ["fifo1"]


def test_grid_path_symlink_is_refused_and_its_target_kept(tmp_path):
    target = tmp_path / "target.vdb"
    target.write_text("kept")
    link = tmp_path / "link.vdb"
    link.symlink_to(target)
    with pytest.raises(ValueError, match=f"grids.path = '{link}' exists and is a symbolic link"):
        run_with_grid(link)
    assert link.is_symlink() and target.read_text() == "kept"


def test_grid_path_directory_is_refused(tmp_path):
    with pytest.raises(ValueError, match=f"grids.path = '{tmp_path}' exists and is a directory"):
        run_with_grid(tmp_path)


def test_grid_path_in_missing_directory_is_refused_before_tracing(tmp_path):
    path = tmp_path / "nodir" / "g.vdb"
    with pytest.raises(ValueError, match=f"grids.path = '{path}' is in the directory '{path.parent}'"):
        # 10^12 packets would take hours: the refusal must come first.
        ep.run(box_scene(), DOWN, photons=10**12, grids=ep.GridRequest(0.1, str(path)))


def test_grid_path_with_too_long_name_is_refused(tmp_path):
    path = tmp_path / ("x" * 300)
    with pytest.raises(ValueError, match="grids.path = .* has a file name of 300 characters"):
        run_with_grid(path)
    assert os.listdir(tmp_path) == []


def test_grid_path_regular_file_is_replaced_atomically(tmp_path):
    path = tmp_path / "g.vdb"
    path.write_text("old")
    r = run_with_grid(path)
    assert r.to_dict()["grid_path"] == str(path)
    assert path.read_bytes()[:4] == b" BDV"  # the OpenVDB magic number 0x56444220: the new file
    assert os.listdir(tmp_path) == ["g.vdb"]


# ---- a region too small for float32 ray tracing


def tiny_box_scene(size, unit="cm"):
    v, t = ep.box_mesh((-1, -1, -1), (1, 1, 0))
    s = ep.Scene(unit=unit)
    s.add_mesh("tiny", (v * size).astype(np.float32), t, M)
    return s


@pytest.mark.parametrize("unit", ["cm", "m"])
@pytest.mark.parametrize("size", [1e-16, 1e-20, 1e-30, 1e-40])
def test_region_below_the_smallest_side_is_refused_by_name(size, unit):
    """Boxes scaled by 1e-20 and less used to report missed = 1 with no warning."""
    source = ep.PencilSource(position=(0, 0, size), direction=(0, 0, -1))
    with pytest.raises(ValueError, match=r"region 'tiny': thinnest side .* scene units is below the limit 1e-15"):
        ep.run(tiny_box_scene(size, unit), source, photons=100)


def test_region_at_the_smallest_side_runs_like_a_large_one():
    """Without scattering or absorption the result is the same at any scale: Fresnel at both faces."""
    clear = ep.Medium(mua=0.0, mus=0.0, g=0.0, n=1.4)
    results = []
    for size in (1.0, 1e-15):
        v, t = ep.box_mesh((-1, -1, -1), (1, 1, 0))
        s = ep.Scene(unit="cm")
        s.add_mesh("tiny", (v * size).astype(np.float32), t, clear)
        r = ep.run(s, ep.PencilSource(position=(0, 0, size), direction=(0, 0, -1)), photons=1000).to_dict()
        results.append(r)
    rsp = ((1.4 - 1) / (1.4 + 1)) ** 2
    for r in results:
        assert r["missed"] == 0 and r["specular_reflectance"] == pytest.approx(rsp, rel=1e-6)
        # Normal incidence: each pass through the far face transmits 1 - rsp, and reflects rsp back.
        t = (1 - rsp) ** 2 / (1 - rsp**2)
        assert abs(r["transmittance"] - t) < 4.5 * r["transmittance_stderr"] + 1e-12
    # The same random numbers take the same decisions at both scales.
    for k in ("specular_reflectance", "diffuse_reflectance", "transmittance", "missed"):
        assert results[0][k] == results[1][k]


# ---- wavelengths: a physical range, so that spectral tallies stay finite


@pytest.mark.parametrize(
    "ex, em, field, value",
    [
        ([300, 400], [1e-300, 2e-300], "emission_nm[0]", "1e-300"),
        ([0.5, 400], [400, 500], "excitation_nm[0]", "0.5"),
        ([300, 400], [400, 2e6], "emission_nm[1]", "2e+06"),
    ],
)
def test_eem_wavelengths_outside_the_physical_range_are_refused(ex, em, field, value):
    with pytest.raises(
        ValueError, match=rf"eem 'eem': {re.escape(field)} = {re.escape(value)} is outside \[1, 1e\+06\] nm"
    ):
        ep.EEM(ex, em, np.ones((2, 2)))


def test_spectrum_wavelength_outside_the_physical_range_is_refused():
    with pytest.raises(ValueError, match=r"wavelength_nm\[0\] = 1e-05 is outside \[1, 1e\+06\] nm"):
        ep.Spectrum([1e-5, 500], [1, 1])


@pytest.mark.parametrize(
    "em, field, value", [([1e-300, 400], "emission_nm[0]", "1e-300"), ([400, 2e6], "emission_nm[1]", "2e+06")]
)
def test_engine_eem_refuses_wavelengths_outside_the_range(em, field, value):
    """The engine's own check (native/eem.cpp), reached through the binding without the package's."""
    with pytest.raises(
        ValueError, match=rf"^eem 'z': {re.escape(field)} = {re.escape(value)} is outside \[1, 1e\+06\] nm"
    ):
        ep._core.Scene(1.0, 1.0).add_fluorophore("z", [300.0], em, [1.0, 1.0])


def test_wavelength_range_has_one_owner_and_the_schema_carries_it():
    """endophoton.spectra reads the range from the engine; the schema's spectrum.wavelength_nm has it too."""
    assert (ep.spectra.MIN_WAVELENGTH_NM, ep.spectra.MAX_WAVELENGTH_NM) == (1.0, 1e6)
    assert (ep._core.MIN_WAVELENGTH_NM, ep._core.MAX_WAVELENGTH_NM) == (1.0, 1e6)
    items = ep.scene_schema.schema()["definitions"]["spectrum"]["properties"]["wavelength_nm"]["items"]
    assert (items["minimum"], items["maximum"]) == (ep.spectra.MIN_WAVELENGTH_NM, ep.spectra.MAX_WAVELENGTH_NM)


@pytest.mark.parametrize(
    "wl, value, rule",
    [(1e-300, "1e-300", "less than the minimum of 1"), (2e6, "2000000.0", "greater than the maximum of 1000000.0")],
)
def test_scene_json_spectrum_wavelength_outside_the_range_is_named(wl, value, rule):
    doc = {
        "regions": [
            {
                "name": "box",
                "medium": {"mua": {"wavelength_nm": [wl, 1e6 if wl < 1 else 500], "values": [1, 1]}, "mus": 10},
                "box": {"min": [-1, -1, -1], "max": [1, 1, 0]},
            }
        ]
    }
    with pytest.raises(
        ValueError, match=rf"^region 'box': medium.mua.wavelength_nm\[0\] = {re.escape(value)} is {rule}$"
    ):
        ep.Scene.from_dict(doc)


def test_eem_at_the_range_ends_gives_finite_spectral_results():
    """The audit's EEM at 1e-300 nm made escaped_energy_stderr = inf; at the range's ends all stays finite."""
    e = ep.EEM([300, 400], [ep.spectra.MIN_WAVELENGTH_NM, ep.spectra.MAX_WAVELENGTH_NM], np.ones((2, 2)))
    s = ep.Scene(unit="cm")
    s.add_box("box", (-1, -1, -1), (1, 1, 0), M, fluorophores=[ep.Fluorophore("z", 1, 1, eem=e)])
    r = ep.run(s, DOWN, photons=2000, spectral=True).to_dict()
    assert all(np.isfinite(v) for k, v in r.items() if isinstance(v, float))
    assert r["fluorescence_events"] > 0


def test_eem_from_csv_names_a_missing_or_binary_file(tmp_path):
    missing = tmp_path / "nonexistent.csv"
    with pytest.raises(ValueError, match=rf"eem file '{re.escape(str(missing))}': cannot read: No such file"):
        ep.EEM.from_csv(missing)
    binary = tmp_path / "binary.csv"
    binary.write_bytes(bytes(range(256)) * 4)
    with pytest.raises(ValueError, match=rf"eem file '{re.escape(str(binary))}': not UTF-8 text"):
        ep.EEM.from_csv(binary)


# ---- lengths and counts at the API have the limits of the JSON schema and of ep.run


def test_camera_aperture_radius_beyond_the_schema_limit_is_refused():
    with pytest.raises(ValueError, match=r"camera.aperture_radius = 1e\+300 must be a finite number in \[0, 1e\+12\]"):
        ep.Camera.look_at(position=(0, 0, 3), look_at=(0, 0, 0), up=(0, 1, 0), fov_deg=60, aperture_radius=1e300)
    with pytest.raises(ValueError, match=r"camera.focus_distance = 1e\+300 must be a finite number in \(0, 1e\+12\]"):
        ep.Camera.look_at((0, 0, 3), (0, 0, 0), up=(0, 1, 0), aperture_radius=0.1, focus_distance=1e300)


def test_rig_head_diameter_beyond_the_schema_limit_is_refused():
    rig = {"type": "endoscope", "beta_deg": 20, "distance": 1, "head_diameter_mm": 1e300}
    with pytest.raises(ValueError, match=r"rig.head_diameter_mm = 1e\+300 must be a finite number \[0, 1e\+12\]"):
        ep.source_from_dict(rig)


def records_result():
    return ep.run(box_scene(), DOWN, photons=200, record_escapes=True)


@pytest.mark.parametrize("threads, why", [(-1, r"must be in \[0, 4096\]"), (10**6, r"must be in \[0, 4096\]")])
def test_render_view_threads_have_the_rule_of_run(threads, why):
    cam = ep.Camera.look_at((0, 0, 3), (0, 0, 0), up=(0, 1, 0))
    with pytest.raises(ValueError, match=f"threads = {threads} {why}"):
        ep.render_view(records_result(), cam, 4, 4, threads=threads)
    with pytest.raises(ValueError, match=f"threads = {threads} {why}"):
        ep.run(box_scene(), DOWN, photons=100, threads=threads)


def test_render_view_of_none_names_its_first_argument():
    with pytest.raises(ValueError, match="result = None: render_view's first argument must be an ep.Result"):
        ep.render_view(None)


def test_huge_direction_is_normalised_and_zero_direction_named():
    assert ep.PencilSource(position=(0, 0, 1), direction=(0, 0, -1e300)).direction.tolist() == [0, 0, -1]
    with pytest.raises(ValueError, match=r"source.direction = \(0, 0, 0\) has zero length"):
        ep.PencilSource(position=(0, 0, 1), direction=(0, 0, 0))


# ---- fluorophores and PLY indices


def test_fluorophores_none_means_none_and_a_string_is_named():
    s = ep.Scene(unit="cm")
    assert s.add_box("a", (0, 0, 0), (1, 1, 1), M, fluorophores=None).fluorophores == ()
    v, t = ep.box_mesh((2, 0, 0), (3, 1, 1))
    assert s.add_mesh("b", v, t, M, fluorophores=None).fluorophores == ()
    with pytest.raises(
        ValueError, match="region 'c': fluorophores = 'collagen' must be a list of endophoton.Fluorophore"
    ):
        s.add_box("c", (4, 0, 0), (5, 1, 1), M, fluorophores="collagen")


class _Guarded:
    """Iterates ``source``, counting the entries read; fails the test (instead of hanging it) past ``stop``."""

    def __init__(self, source, stop=10_000):
        self.source, self.stop, self.read = iter(source), stop, 0

    def __iter__(self):
        return self

    def __next__(self):
        assert self.read < self.stop, f"read {self.read} entries of an endless iterator"
        self.read += 1
        return next(self.source)


def test_endless_fluorophores_are_refused_not_read_forever():
    """At most MAX_FLUOROPHORES + 1 entries are read: an endless iterator is refused by its first wrong
    entry or by its length, and the scene is left without the region."""
    s = ep.Scene(unit="cm")
    collagen = ep.Fluorophore("collagen", 0.2, 0.4)
    assert ep.scene_schema.MAX_FLUOROPHORES == 64
    repeat, count = _Guarded(itertools.repeat(collagen)), _Guarded(itertools.count())
    with pytest.raises(ValueError, match=r"^region 'a': fluorophores has more than 64 entries"):
        s.add_box("a", (0, 0, 0), (1, 1, 1), M, fluorophores=repeat)
    with pytest.raises(ValueError, match=r"^region 'a': fluorophores entry 0 must be an endophoton.Fluorophore"):
        s.add_box("a", (0, 0, 0), (1, 1, 1), M, fluorophores=count)
    assert (repeat.read, count.read) == (65, 1)
    assert s.regions == []
    most = itertools.islice(itertools.repeat(collagen), 64)
    assert s.add_box("a", (0, 0, 0), (1, 1, 1), M, fluorophores=most).fluorophores == (collagen,) * 64


def test_schema_limits_fluorophores_as_the_api_does():
    """The schema's regions[].fluorophores maxItems is the API's MAX_FLUOROPHORES (one rule)."""
    region = ep.scene_schema.schema()["definitions"]["region"]
    assert region["properties"]["fluorophores"]["maxItems"] == ep.scene_schema.MAX_FLUOROPHORES


PLY_HEAD = (
    "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
    "element face 4\nproperty list uchar float vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n"
)


def test_ply_float_indices_must_be_integers(tmp_path):
    bad = tmp_path / "bad.ply"
    bad.write_text(PLY_HEAD + "3 0 2.7 3\n3 0 1 3\n3 0 2 1\n3 1 2 3\n")
    with pytest.raises(ValueError, match=r"bad.ply.*PLY face 0: vertex index 2.7 is not an integer"):
        ep.mesh_io.load_mesh(str(bad))
    good = tmp_path / "good.ply"
    good.write_text(PLY_HEAD + "3 0 2 1\n3 0 1 3\n3 0 3 2\n3 1 2 3\n")
    assert ep.mesh_io.load_mesh(str(good))[1].tolist() == [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]
