"""The command line: ``python3 -m endophoton run SCENE.json`` prints one JSON object;
bad input exits non-zero and names the field on stderr. Also checks that every
example scene in examples/ loads and runs.

Physics tolerances as elsewhere: |x - ref| < K_SIGMA sigma + ref_unc.
"""
import copy
import json
import math
import os

import pytest

import endophoton as ep
from cli_helpers import run_cli as _cli, run_json
from physics_helpers import assert_energy_conserved, assert_within, mc_reference_sigma

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))
EXAMPLES = os.path.join(ROOT, "examples")
KEYS = ("photons", "specular_reflectance", "diffuse_reflectance", "transmittance", "absorbed")


def _run_json(path, photons, seed=1, threads=2):
    data = run_json("run", path, "--photons", photons, "--seed", seed, "--threads", threads)
    assert isinstance(data, dict)
    for k in KEYS:
        assert k in data, k
        if k != "photons":
            assert k + "_stderr" in data, k + "_stderr"
    assert data["photons"] == photons
    assert_energy_conserved(data)
    return data


@pytest.mark.slow
def test_cli_mcml_slab_matches_oracle():
    d = _run_json("examples/mcml_slab.json", 20_000)
    # oracles §1, van de Hulst (+-0.5e-5 rounding)
    assert d["specular_reflectance"] == 0.0
    assert_within("Rd", d["diffuse_reflectance"], d["diffuse_reflectance_stderr"], 0.09739, 0.5e-5)
    assert_within("Tt", d["transmittance"], d["transmittance_stderr"], 0.66096, 0.5e-5)
    assert_within("A", d["absorbed"], d["absorbed_stderr"], 1 - 0.09739 - 0.66096, 1e-5)


def test_cli_semi_infinite_n15_matches_oracle():
    d = _run_json("examples/semi_infinite_n15.json", 20_000, seed=2)
    assert_within("Rsp", d["specular_reflectance"], d["specular_reflectance_stderr"], 0.04, 1e-12)
    assert_within(
        "Rsp + Rd (Giovanelli)",
        d["specular_reflectance"] + d["diffuse_reflectance"],
        d["specular_reflectance_stderr"] + d["diffuse_reflectance_stderr"],
        0.2600,
        0.5e-4,
    )


def test_cli_three_layer_matches_oracle():
    d = _run_json("examples/three_layer.json", 20_000, seed=3)
    assert_within("Rsp", d["specular_reflectance"], d["specular_reflectance_stderr"], (0.37 / 2.37) ** 2, 1e-12)
    for key, ref in (("diffuse_reflectance", 0.237544), ("transmittance", 0.096490), ("absorbed", 0.641594)):
        assert_within(key, d[key], math.hypot(d[key + "_stderr"], mc_reference_sigma(ref, 1_000_000)), ref)
    assert set(d["absorbed_by_region"]) == {"layer1", "layer2", "layer3"}


def test_cli_seed_tissue_runs():
    d = _run_json("examples/seed_tissue.json", 5_000, seed=4)
    # exact specular part for n = 1.1 at normal incidence
    assert_within("Rsp", d["specular_reflectance"], d["specular_reflectance_stderr"], (0.1 / 2.1) ** 2, 1e-12)
    assert d["missed"] == 0.0
    assert 0.0 < d["diffuse_reflectance"] < 1.0 and d["transmittance"] < 1e-6


@pytest.mark.parametrize("name", ["mcml_slab.json", "semi_infinite_n15.json", "three_layer.json", "seed_tissue.json"])
def test_example_files_load_with_the_python_api(name):
    with open(os.path.join(EXAMPLES, name), encoding="utf-8") as fh:
        data = json.load(fh)
    scene = ep.Scene.from_dict(data)
    src = ep.source_from_dict(data["source"])
    res = ep.run(scene, src, photons=2000, seed=1, threads=1)
    assert_energy_conserved(res)
    assert res.missed == 0.0


def _write(tmp_path, data, name="bad.json"):
    p = tmp_path / name
    p.write_text(json.dumps(data))
    return str(p)


def _base():
    with open(os.path.join(EXAMPLES, "seed_tissue.json"), encoding="utf-8") as fh:
        return json.load(fh)


@pytest.mark.parametrize(
    "field,value,spelling", [("mus", -1, "-1"), ("mua", -0.5, "-0.5"), ("g", 1.2, "1.2"), ("n", 0.9, "0.9")]
)
def test_cli_bad_medium_exits_nonzero_naming_the_field(tmp_path, field, value, spelling):
    d = _base()
    d["regions"][0]["medium"][field] = value
    p = _cli("run", _write(tmp_path, d), "--photons", "100")
    assert p.returncode != 0
    assert p.stdout.strip() == "", p.stdout
    assert "tissue" in p.stderr and f"medium.{field}" in p.stderr and spelling in p.stderr, p.stderr
    assert "Traceback" not in p.stderr, p.stderr


def test_cli_run_checks_the_scene_files_camera_as_render_does(tmp_path):
    # run does not use the camera, but the file is one SCENE.json for both commands.
    d = _base()
    d["camera"] = {"position": [0, 0, 5], "look_at": [0, 0, 0], "up": [0, 1, 0], "fov_deg": float("nan")}
    p = _cli("run", _write(tmp_path, d), "--photons", "100")
    assert p.returncode == 2, (p.returncode, p.stderr)
    assert "fov_deg" in p.stderr and "nan" in p.stderr.lower() and "Traceback" not in p.stderr, p.stderr


@pytest.mark.parametrize(
    "budget,named",
    [(("--quality", "preview"), "--quality preview"), (("--target-rel-error", "0.05"), "--target-rel-error 0.05")],
)
def test_cli_photons_with_an_accuracy_run_is_refused_by_name(tmp_path, budget, named):
    # ep.run refuses photons= with quality= or target=; the CLI used to drop --photons silently.
    p = _cli("run", _write(tmp_path, _base()), "--photons", "1000", *budget)
    assert p.returncode == 2, (p.returncode, p.stderr)
    assert p.stdout.strip() == "", p.stdout
    assert "--photons 1000" in p.stderr and named in p.stderr and "Traceback" not in p.stderr, p.stderr


def test_cli_quality_with_max_photons_is_refused_by_name(tmp_path):
    # A preset brings its own cap; --max-photons used to be dropped silently (1,126,912 packets traced).
    p = _cli("run", _write(tmp_path, _base()), "--quality", "reference", "--max-photons", "5000")
    assert p.returncode == 2, (p.returncode, p.stderr)
    assert "--quality reference" in p.stderr and "--max-photons 5000" in p.stderr, p.stderr
    assert "Traceback" not in p.stderr, p.stderr


@pytest.mark.parametrize("option", [("--target-tally", "absorbed"), ("--max-photons", "5000")])
def test_cli_target_options_without_a_target_are_refused_by_name(tmp_path, option):
    # They belong to a --target-rel-error run; without one they used to be ignored (run.photons ran).
    p = _cli("run", _write(tmp_path, _base()), *option)
    assert p.returncode == 2, (p.returncode, p.stderr)
    assert p.stdout.strip() == "", p.stdout
    assert f"{option[0]} {option[1]} belongs to a --target-rel-error run" in p.stderr, p.stderr
    assert "Traceback" not in p.stderr, p.stderr


def test_cli_target_tally_is_the_target_runs_tally(tmp_path):
    p = _cli("run", _write(tmp_path, _base()), "--target-rel-error", "0.2", "--target-tally", "absorbed")
    assert p.returncode == 0, p.stderr
    out = json.loads(p.stdout)
    assert out["stop_reason"] == "target" and out["absorbed_stderr"] <= 0.2 * out["absorbed"], out


def test_cli_quality_with_a_target_is_refused_by_name(tmp_path):
    p = _cli("run", _write(tmp_path, _base()), "--quality", "preview", "--target-rel-error", "0.05")
    assert p.returncode == 2, (p.returncode, p.stderr)
    assert "quality = 'preview'" in p.stderr and "Traceback" not in p.stderr, p.stderr


def test_cli_unknown_key_exits_nonzero_naming_it(tmp_path):
    d = _base()
    d["regions"][0]["medium"]["mus_prime"] = 20
    p = _cli("run", _write(tmp_path, d), "--photons", "100")
    assert p.returncode != 0
    assert "tissue" in p.stderr and "mus_prime" in p.stderr, p.stderr
    assert "Traceback" not in p.stderr, p.stderr


def test_cli_open_mesh_exits_nonzero(tmp_path):
    d = _base()
    region = d["regions"][0]
    del region["box"]
    v, t = ep.box_mesh((-1, -1, -1), (1, 1, 0))
    region["mesh"] = {"vertices": v.tolist(), "triangles": t[:-1].tolist()}  # one triangle missing
    p = _cli("run", _write(tmp_path, d), "--photons", "100")
    assert p.returncode != 0
    assert "tissue" in p.stderr and ("watertight" in p.stderr or "open" in p.stderr), p.stderr
    assert "Traceback" not in p.stderr, p.stderr


def test_cli_missing_file_exits_nonzero(tmp_path):
    p = _cli("run", str(tmp_path / "nope.json"), "--photons", "100")
    assert p.returncode != 0
    assert "nope.json" in p.stderr
