"""``python3 -m endophoton render SCENE.json ... --out DIR``: files, the JSON contract of issue 10, exit 2."""
import copy
import json
import os

import numpy as np
import pytest

from cli_helpers import run_cli

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))

SCENE = {
    "unit": "cm",
    "ambient_n": 1.0,
    "regions": [
        {
            "name": "wall",
            "priority": 0,
            "medium": {"mua": 1, "mus": 10, "g": 0.0, "n": 1.0},
            "box": {"min": [-3, -3, -2], "max": [3, 3, 0]},
            "fluorophores": [{"name": "collagen", "d": 0.2, "c": 0.4}],
        },
        {
            "name": "polyp",
            "priority": 1,
            "medium": {"mua": 1, "mus": 10, "g": 0.0, "n": 1.0},
            "box": {"min": [-0.6, -0.6, -0.3], "max": [0.6, 0.6, 0.3]},
            "fluorophores": [{"name": "collagen", "d": 0.2, "c": 0.4}, {"name": "photofrin", "d": 0.1, "c": 0.33}],
        },
    ],
    "source": {"type": "disk", "position": [0, 0, 2], "direction": [0, 0, -1], "radius": 1.5},
    "camera": {"position": [0, 0, 2.5], "look_at": [0, 0, 0], "up": [0, 1, 0], "fov_deg": 50},
    "run": {"photons": 20000, "seed": 1},
}
REGION_KEYS = {
    "pixels",
    "white_radiance",
    "white_radiance_stderr",
    "fluorescence_radiance",
    "fluorescence_radiance_stderr",
}
CONTRAST_KEYS = {
    "target",
    "background",
    "fluorescence",
    "fluorescence_stderr",
    "white",
    "white_stderr",
    "red_green",
    "red_green_stderr",
}


def _render(tmp_path, scene, *args):
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(scene))
    return run_cli("render", path, *args)


@pytest.mark.slow
def test_render_cli_writes_images_arrays_and_json(tmp_path):
    import matplotlib.image as mpimg

    out = tmp_path / "out"
    p = _render(
        tmp_path,
        SCENE,
        "--width",
        "20",
        "--height",
        "14",
        "--photons",
        "30000",
        "--seed",
        "2",
        "--threads",
        "1",
        "--out",
        str(out),
        "--target",
        "polyp",
        "--background",
        "wall",
    )
    assert p.returncode == 0, p.stderr
    assert p.stdout.strip().count("\n") == 0
    d = json.loads(p.stdout)
    assert (d["width"], d["height"]) == (20, 14)
    assert d["estimator"] == "exitance"  # the default: the most efficient estimate that passes the cross-checks
    assert set(d["regions"]) == {"wall", "polyp"}
    for r in d["regions"].values():
        assert REGION_KEYS <= set(r)
    assert sum(r["pixels"] for r in d["regions"].values()) == 20 * 14  # every pixel sees tissue
    assert set(d["contrast"]) == CONTRAST_KEYS
    assert (d["contrast"]["target"], d["contrast"]["background"]) == ("polyp", "wall")
    for name in ("white", "fluorescence"):
        img = mpimg.imread(out / f"{name}.png")
        assert img.shape[:2] == (14, 20)
    arr = np.load(out / "view.npz")
    assert arr["white_radiance"].shape == (14, 20) and arr["white_rgb"].shape == (14, 20, 3)
    # The JSON's region mean is the mean of the saved per-pixel radiance over the region's pixels.
    wall = arr["region_map"] == list(arr["region_names"]).index("wall")
    assert d["regions"]["wall"]["white_radiance"] == pytest.approx(arr["white_radiance"][wall].mean(), rel=1e-9)


@pytest.mark.slow
def test_render_cli_uses_the_endoscope_camera_by_default(tmp_path):
    scene = copy.deepcopy(SCENE)
    del scene["camera"]
    scene["source"] = {"type": "endoscope", "beta_deg": 20, "distance": 1.5}
    p = _render(tmp_path, scene, "--width", "8", "--height", "8", "--photons", "5000", "--out", str(tmp_path / "o"))
    assert p.returncode == 0, p.stderr
    d = json.loads(p.stdout)
    assert (d["width"], d["height"]) == (8, 8)


@pytest.mark.slow
@pytest.mark.parametrize(
    "change,args,needle",
    [
        (None, ("--width", "0"), "--width = 0"),
        (None, ("--target", "polyp"), "--background"),
        (None, ("--target", "stomach", "--background", "wall"), "target = 'stomach'"),
        (("camera", "fov_deg", -5), (), "camera.fov_deg = -5"),
        (("camera", "lens", 1), (), "camera: unknown key 'lens'"),
        (("camera", "look_at", [0, 0, 2.5]), (), "camera.look_at"),
        (("camera", None, None), (), "camera:"),
        (None, ("--excitation", "green"), "excitation = 'green'"),
        (None, ("--kernel-radius", "1e-300"), "--kernel-radius = 1e-300 is too small"),
        (None, ("--kernel-angle", "1e-308"), "--kernel-angle = 1e-308 is too small"),
        (None, ("--kernel-radius", "1e308"), "--kernel-radius = 1e+308 is too large"),
        (None, ("--kernel-angle", "nan"), "--kernel-angle = nan must be in (0, 90]"),
        (None, ("--out", "/proc/x"), "--out /proc/x: cannot create the directory: "),
        (None, ("--out", "/etc/passwd"), "--out /etc/passwd: cannot create the directory: File exists"),
    ],
)
def test_render_cli_bad_input_exits_2_naming_field_and_value(tmp_path, change, args, needle):
    scene = copy.deepcopy(SCENE)
    if change is not None:
        key, field, value = change
        if field is None:
            del scene[key]
        else:
            scene[key][field] = value
    p = _render(
        tmp_path, scene, "--photons", "2000", "--width", "4", "--height", "4", "--out", str(tmp_path / "o"), *args
    )
    assert p.returncode == 2, (p.returncode, p.stderr)
    assert needle in p.stderr, p.stderr
    assert "Traceback" not in p.stderr


@pytest.mark.parametrize("command", ["run", "render"])
def test_scene_file_that_is_not_utf8_is_named(tmp_path, capsys, command):
    from endophoton.cli import main as cli_main

    path = tmp_path / "latin1.json"
    path.write_bytes(b'{"unit": "\xff"}')
    args = [command, str(path)] + (["--out", str(tmp_path / "o")] if command == "render" else [])
    assert cli_main(args) == 2
    err = capsys.readouterr().err
    assert f"endophoton: error: scene file {str(path)!r}: not UTF-8 text (byte 0xff" in err, err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("aperture,blocked", [(False, "view.npz"), (True, "aperture_fluorescence.png")])
def test_render_cli_refuses_an_output_path_that_is_a_directory_before_writing_any(tmp_path, aperture, blocked):
    """A folder named like one of the outputs (the last one written) is refused with exit 2 naming it,
    before the run: the old files stay as they were, no new one appears."""
    out = tmp_path / "o"
    (out / blocked).mkdir(parents=True)
    (out / "white.png").write_bytes(b"old")
    scene = copy.deepcopy(SCENE)
    if aperture:
        scene["camera"]["aperture_radius"] = 0.2
    p = _render(tmp_path, scene, "--photons", "2000", "--width", "4", "--height", "4", "--out", str(out))
    assert p.returncode == 2, (p.returncode, p.stderr)
    assert f"output file {str(out / blocked)!r} is a directory" in p.stderr and "Traceback" not in p.stderr
    assert sorted(os.listdir(out)) == sorted([blocked, "white.png"]) and (out / "white.png").read_bytes() == b"old"


def test_view_save_checks_every_path_before_writing_any(tmp_path):
    import endophoton as ep

    scene = ep.Scene(unit="cm")
    scene.add_box("wall", min=(-3, -3, -2), max=(3, 3, 0), medium=ep.Medium(mua=1, mus=10, g=0.0, n=1.0))
    source = ep.sources.source_from_dict(SCENE["source"])
    res = ep.run(scene, source, photons=2000, seed=1, record_escapes=True, spectral=True, threads=1)
    view = ep.render_view(res, SCENE["camera"], 4, 4)
    (tmp_path / "beta5_view.npz").mkdir()
    with pytest.raises(ValueError, match=r"output file '.*beta5_view\.npz' is a directory: remove or rename it"):
        view.save(tmp_path, prefix="beta5_")
    assert os.listdir(tmp_path) == ["beta5_view.npz"]
    assert set(view.save(tmp_path, prefix="beta0_")) == {"white", "fluorescence", "arrays"}


@pytest.mark.slow
def test_look_back_is_a_way_of_the_next_event_estimate(tmp_path):
    """The next-event estimate draws look-back virtual events by default (the JSON's nee counters say how
    many), none with --no-look-back; --no-look-back without --estimator nee exits 2 naming the flag, before
    the run."""
    scene = copy.deepcopy(SCENE)
    for r in scene["regions"]:
        r["medium"]["g"] = 0.9  # the look-back's mixture leans on forward scattering
    common = ("--photons", "3000", "--width", "6", "--height", "6", "--threads", "1", "--estimator", "nee")
    counts = {}
    for flag in (("--no-look-back",), ()):
        p = _render(tmp_path, scene, *common, "--out", str(tmp_path / f"o{len(flag)}"), *flag)
        assert p.returncode == 0, p.stderr
        d = json.loads(p.stdout)
        assert d["estimator"] == "nee" and d["nee"]["scored"] > 0
        counts[not flag] = d["nee"]["looked_back"]
    assert counts == {False: 0, True: counts[True]} and counts[True] > 0, counts
    p = _render(tmp_path, scene, *common, "--estimator", "kernel", "--no-look-back", "--out", str(tmp_path / "k"))
    assert p.returncode == 2 and "--no-look-back: give --estimator nee" in p.stderr, p.stderr
    assert not (tmp_path / "k").exists()
