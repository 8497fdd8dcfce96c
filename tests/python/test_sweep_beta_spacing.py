"""β lists whose angles lie closer than the sweep's resolution, and fits over such angles.

β = 0 and 1e-200 used to reach numpy.polyfit in the report: its column scaling turned the
Vandermonde matrix into inf/NaN and LAPACK (DLASCL) ended the process (Blender exited silently
mid-sweep). The list is now refused by name before anything runs, and every fit of the reports
returns its not-fitted outcome on such x values instead of calling LAPACK.
"""

import argparse
import math
import types

import numpy as np
import pytest

import endophoton as ep
from endophoton.sweep import driver as sw
from endophoton import analysis
from endophoton.sweep import cli as sweep_cli
from endophoton.view import visibility
from endophoton.sweep.schema import BETA_RESOLUTION_DEG, SweepResult, beta_text, check_beta_spacing, parse_betas

CLOSE = [[0.0, 1e-200], [0.0, 1e-280], [0.0, 1e-300], [10.0, 10.0 + 5e-7]]


def _no_run(*a, **k):
    raise AssertionError("a run started")


@pytest.mark.parametrize("betas", CLOSE)
def test_sweep_refuses_betas_closer_than_the_resolution_naming_both(betas, monkeypatch, tmp_path):
    monkeypatch.setattr(sw, "run", _no_run)
    out = tmp_path / "out"
    text = f"betas: β = {beta_text(betas[0])} and β = {beta_text(betas[1])} are closer than 1e-06 degrees"
    with pytest.raises(ValueError) as ei:
        ep.sweep(types.SimpleNamespace(unit="cm"), betas=betas, store=100, progress=False, out_dir=str(out))
    assert text in str(ei.value)
    assert not out.exists()


def test_sweep_refuses_the_same_beta_twice_and_a_spec_string_too(monkeypatch):
    monkeypatch.setattr(sw, "run", _no_run)
    with pytest.raises(ValueError, match=r"^betas: β = 0 is given twice"):
        ep.sweep(types.SimpleNamespace(unit="cm"), betas=[0, 10, 0], store=100, progress=False)
    with pytest.raises(ValueError, match=r"betas = '0,1e-200': β = 0 and β = 1e-200 are closer than 1e-06"):
        ep.sweep(types.SimpleNamespace(unit="cm"), betas="0,1e-200", store=100, progress=False)


def test_the_resolution_itself_is_accepted_and_the_order_does_not_matter():
    assert BETA_RESOLUTION_DEG == 1e-6
    check_beta_spacing([0.0, 1e-6, 30.0])  # exactly the resolution apart: two angles
    assert parse_betas("0,1e-6") == [0.0, 1e-6]
    with pytest.raises(ValueError, match=r"β = 5 and β = 5.0000001 are closer"):
        check_beta_spacing([30.0, 5.0000001, 0.0, 5.0], "betas")
    with pytest.raises(argparse.ArgumentTypeError, match=r"--betas '0:1e-5:1e-7': β = 0 and β = 1e-07 are closer"):
        parse_betas("0:1e-5:1e-7")
    assert parse_betas("0,1e-200", spacing=False) == [0.0, 1e-200]  # the add-on words that error itself


def test_sweep_cli_refuses_close_betas_exit_2_naming_the_option(capsys, monkeypatch, tmp_path):
    from endophoton.cli import main as cli_main

    monkeypatch.setattr(sweep_cli, "sweep", _no_run)
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as ei:
        cli_main(["sweep", "--betas", "0,1e-200", "--no-progress"])
    assert ei.value.code == 2
    err = capsys.readouterr().err
    assert "argument --betas: --betas '0,1e-200': β = 0 and β = 1e-200 are closer than 1e-06 degrees" in err, err
    assert "Traceback" not in err and not (tmp_path / "sweep_out").exists()


def test_sweep_cli_forwards_every_beta_as_given():
    """Into Blender: 89.9999999 stays 89.9999999 (``:g`` made it 90, a β the user never typed)."""
    p = argparse.ArgumentParser()
    sweep_cli.add_sweep_arguments(p)
    args = p.parse_args(["--betas", "0,12.3456789,89.9999999,1e-5"])
    argv = sweep_cli.forward_argv(args)
    assert argv[argv.index("--betas") + 1] == "0,12.3456789,89.9999999,1e-05"
    assert p.parse_args(argv).betas == [0.0, 12.3456789, 89.9999999, 1e-5]


def test_write_outputs_refuses_a_result_with_close_betas_before_creating_the_folder(tmp_path):
    """A SweepResult read from a hand-made JSON file never reaches the plots' and report's fits."""
    res = SweepResult(rows=[{"beta_deg": 0.0}, {"beta_deg": 1e-200}], histograms=[], batches=[], meta={})
    with pytest.raises(ValueError, match=r"result.betas: β = 0 and β = 1e-200 are closer"):
        sw.write_outputs(res, tmp_path / "out")
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("step", [1e-200, 1e-280, 1e-300])
def test_polyfit_ready_says_no_where_polyfit_would_reach_lapack_with_inf_or_nan(step):
    x = np.arange(5) * step
    y = np.array([1.0, 2.0, 3.0, 2.0, 1.0])
    for deg in (1, 2, 4):
        assert not analysis.polyfit_ready(x, y, deg)
    assert analysis.polyfit_ready(np.arange(5.0), y, 2)
    assert analysis.polyfit_ready(np.arange(5.0), y, 2, w=np.full(5, 10.0))
    assert not analysis.polyfit_ready(np.arange(5.0), y, 2, w=np.array([1, 1, math.inf, 1, 1]))
    assert not analysis.polyfit_ready(np.array([0, 1, math.nan, 3, 4]), y, 2)
    assert not analysis.polyfit_ready(np.arange(5.0) * 1e200, y, 2)  # x^2 overflows
    assert not analysis.polyfit_ready(np.arange(2.0), y[:2], 2)  # fewer points than coefficients


@pytest.mark.parametrize("step", [1e-200, 1e-300])
def test_fit_peak_is_not_fitted_on_betas_too_close_to_fit(step):
    x = np.arange(7) * step
    y = np.array([1.0, 2.0, 3.0, 4.0, 3.0, 2.0, 1.0])
    fit = visibility.fit_peak(x, y, np.full(7, 0.1), n_boot=50)
    assert fit["x_peak"] is None and fit["x_peak_stderr"] is None and fit["coeffs"] == [] and fit["n"] == 7
    # the same values at 1-degree steps are fitted: the peak is the middle point
    fit = visibility.fit_peak(np.arange(7.0), y, np.full(7, 0.1), n_boot=50)
    assert fit["vertex"] and abs(fit["x_peak"] - 3.0) < 1e-9 and fit["x_peak_stderr"] > 0


def test_analysis_fits_are_not_fitted_on_betas_too_close_to_fit():
    x = np.array([0.0, 1e-200, 2e-200, 3e-200])
    y = np.array([1.0, 2.0, 4.0, 3.0])
    lin = analysis.linear_fit(x, y)
    assert math.isnan(lin["slope"]) and math.isnan(lin["intercept"]) and lin["n"] == 4
    pk = analysis.poly_peak(x, y, 6)
    assert math.isnan(pk["x_peak"]) and pk["coeffs"] == []
    # ordinary betas: the very fits of analysis (the line through (0, 1) and (1, 3) has slope 2)
    assert analysis.linear_fit([0.0, 1.0, math.nan], [1.0, 3.0, 5.0])["slope"] == pytest.approx(2.0)
    assert analysis.poly_peak([0.0, 1.0, 2.0], [0.0, 1.0, 0.0], 6)["x_peak"] == pytest.approx(1.0)


def test_check_placements_is_the_sweeps_own_check_and_names_the_betas_as_given(monkeypatch):
    """The add-on calls it before its sweep starts; ep.sweep makes the same check (one owner)."""
    scene = ep.default_flat_scene()
    sw.check_placements(scene, [0, 30, 58])  # heads in the ambient: no error
    expected = r"betas: at rig.beta_deg = 80, 89.99999 the endoscope head enters the tissue; drop them\. "
    with pytest.raises(ValueError, match=expected + r".*region 'tissue'"):
        sw.check_placements(scene, [0, 80, 89.99999])
    monkeypatch.setattr(sw, "run", _no_run)
    with pytest.raises(ValueError, match=expected):
        ep.sweep(scene, betas=[0, 80, 89.99999], store=100, progress=False)
    with pytest.raises(ValueError, match=r"rig.beta_deg = 90(\.0)? must be a finite angle in \(-90, 90\)"):
        sw.check_placements(scene, [0, 90])  # the rig's own error
