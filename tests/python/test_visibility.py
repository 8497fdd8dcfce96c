"""Visibility across a sweep: the fitted maximum and its uncertainty, the sweep hook, plots and report."""
import math
import os

import numpy as np
import pytest

import endophoton as ep
from endophoton.visibility import fit_peak, jackknife
from endophoton.view_sweep import (
    VISIBILITY_COLUMNS,
    add_visibility,
    visibility_columns,
    contact_sheet,
    plot_visibility,
    visibility_report,
    write_visibility_outputs,
)

from _synth import polyp_box_scene


def _delta_method_vertex_se(x, se, coeffs):
    """Independent stderr of the vertex -b/(2a) of a weighted quadratic fit (delta method)."""
    X = np.vander(x, 3)
    cov = np.linalg.inv(X.T @ (X / se[:, None] ** 2))
    a, b, _ = coeffs
    grad = np.array([b / (2 * a * a), -1 / (2 * a), 0.0])
    return math.sqrt(grad @ cov @ grad)


def test_fit_peak_finds_the_vertex_and_its_uncertainty():
    x = np.arange(0.0, 60.0, 5.0)
    y_true = 1.0 - (x - 31.0) ** 2 / 900.0
    se = np.full(x.size, 0.02)
    f = fit_peak(x, y_true, se)
    assert f["x_peak"] == pytest.approx(31.0, abs=1e-6) and f["interior"]
    window = (x >= f["fit_range"][0]) & (x <= f["fit_range"][1])
    expected = _delta_method_vertex_se(x[window], se[window], f["coeffs"])
    assert f["x_peak_stderr"] == pytest.approx(expected, rel=0.15)
    assert f["x_peak_lo"] < 31.0 < f["x_peak_hi"]


def test_fit_peak_at_the_end_of_a_monotone_range_is_not_interior():
    x = np.arange(0.0, 30.0, 5.0)
    f = fit_peak(x, 0.1 * x, np.full(x.size, 0.01))
    assert f["x_peak"] == 25.0 and not f["interior"]
    assert fit_peak([0, 1], [1, 2], [0.1, 0.1])["x_peak"] is None


def test_jackknife_of_a_mean_equals_batch_means():
    rng = np.random.default_rng(3)
    sums = rng.normal(10.0, 1.0, 20)
    Pb = np.full(20, 100)
    v, se = jackknife(sums, Pb, lambda m: float(m))
    assert v == pytest.approx(sums.sum() / 2000)
    assert se == pytest.approx(np.std(sums / 100, ddof=1) / math.sqrt(20), rel=1e-9)


def test_visibility_columns_hook_plot_sheet_and_report(tmp_path):
    s = polyp_box_scene(0.33)
    rows, betas, images = [], [0.0, 20.0, 40.0], []
    for beta in betas:
        rig = ep.EndoscopeRig.from_beta(beta, 2.0, point=(0, 0, 0.3), camera_resolution=(16, 16), cone_angle_deg=60)
        res = ep.run(s, rig, photons=20_000, seed=1, spectral=True)
        cols = visibility_columns(res, "polyp", "wall", out_dir=tmp_path, prefix=f"beta{beta:g}_")
        assert set(cols) == set(VISIBILITY_COLUMNS)
        assert cols["target_pixels"] + cols["background_pixels"] <= 16 * 16
        rows.append(cols)
        images.append(tmp_path / f"beta{beta:g}_fluorescence.png")
        assert images[-1].exists()
    assert os.path.getsize(plot_visibility(betas, rows, tmp_path / "visibility.png")) > 1000
    assert os.path.getsize(contact_sheet(images, betas, tmp_path / "sheet.png")) > 1000
    text = visibility_report(betas, rows)
    assert "34" in text and "most visible" in text
    # The sweep hook: rows gain the columns, views land in out/views, then plot + sheet + report section.
    out = tmp_path / "sweep"
    hook_rows = []
    for beta in betas:
        rig = ep.EndoscopeRig.from_beta(beta, 2.0, point=(0, 0, 0.3), camera_resolution=(16, 16), cone_angle_deg=60)
        row = {"beta_deg": beta}
        add_visibility(
            row,
            ep.run(s, rig, photons=5_000, seed=2, spectral=True),
            beta,
            {"target": "polyp", "background": "wall", "width": 12, "height": 12},
            out,
        )
        assert set(VISIBILITY_COLUMNS) <= set(row)
        hook_rows.append(row)
    paths = write_visibility_outputs(betas, hook_rows, out)
    assert os.path.exists(paths["plot"]) and os.path.exists(paths["contact_sheet"])
    assert paths["report"].startswith("## At which")
    with pytest.raises(ValueError, match="visibility: missing key 'background'"):
        add_visibility({}, None, 0.0, {"target": "polyp"})


def test_sweep_with_visibility_writes_columns_views_plot_sheet_and_answer(tmp_path):
    res = ep.sweep(
        ep.default_flat_scene(),
        betas=[0, 20, 40],
        store=3000,
        progress=False,
        out_dir=tmp_path,
        visibility={"target": "polyp", "background": "tissue", "width": 24, "height": 24},
    )
    for row in res.rows:
        assert row["target_pixels"] > 0 and row["background_pixels"] > 0
        assert math.isfinite(row["fluorescence_contrast"]) and row["fluorescence_contrast_stderr"] > 0
    header = (tmp_path / "sweep.csv").read_text().splitlines()[0].split(",")
    assert header[-len(VISIBILITY_COLUMNS) :] == list(VISIBILITY_COLUMNS)
    for name in ("visibility.png", "views_contact_sheet.png", "views/beta20_fluorescence.png"):
        assert (tmp_path / name).exists(), name
    assert "## At which β is the polyp most visible?" in (tmp_path / "report.md").read_text()
    assert res.meta["visibility"]["target"] == "polyp"


def test_sweep_without_visibility_leaves_the_columns_undefined():
    res = ep.sweep(ep.default_flat_scene(), betas=[0], store=500, progress=False)
    assert all(res.rows[0][k] is None for k in VISIBILITY_COLUMNS)  # undefined is None, never NaN


def test_sweep_cli_target_needs_background(tmp_path):
    import subprocess
    import sys

    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    env = dict(os.environ, PYTHONPATH=os.path.join(root, "python"))
    p = subprocess.run(
        [
            sys.executable,
            "-m",
            "endophoton",
            "sweep",
            "--betas",
            "0",
            "--store",
            "100",
            "--out",
            str(tmp_path),
            "--target",
            "polyp",
            "--no-progress",
        ],
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert p.returncode == 2 and "--background = None" in p.stderr
