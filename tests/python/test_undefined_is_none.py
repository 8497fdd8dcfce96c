"""An undefined result value is None, never NaN (docs/sweep.md, docs/render.md): in memory, after a
JSON round trip, and in the files, which are byte for byte what they were when the rows held NaN
(``null`` in sweep.json, an empty cell in sweep.csv)."""

import json
import math

import numpy as np
import pytest

import endophoton as ep
from endophoton import analysis as an
from endophoton import report as rp
from endophoton.sweep import reduce as sweep_reduce
from endophoton.sweep import view_sweep
from endophoton.io import finite_or_none, jsonable, no_nan
from endophoton.sweep.schema import CSV_COLUMNS, VISIBILITY_COLUMNS, SweepResult

from physics_helpers import assert_nan_free


@pytest.fixture(scope="module")
def plain_sweep():
    """A real two-angle sweep without ``visibility=`` (its visibility columns are undefined)."""
    return ep.sweep(ep.default_flat_scene(), betas=[0, 20], store=500, threads=1, progress=False)


def _nan_form(res):
    """``res`` with NaN wherever a row holds None: the rows as they were before None (the old form)."""
    rows = [{k: float("nan") if v is None else v for k, v in r.items()} for r in res.rows]
    return SweepResult(rows=rows, histograms=res.histograms, batches=res.batches, meta=res.meta)


def _files(res, folder):
    """(sweep.csv, sweep.json) bytes of ``res`` written into ``folder``."""
    folder.mkdir()
    res.to_csv(folder / "sweep.csv")
    res.to_json(folder / "sweep.json")
    return (folder / "sweep.csv").read_bytes(), (folder / "sweep.json").read_bytes()


def _assert_files_as_before(res, tmp_path, undefined):
    """The files of ``res`` are those of its NaN form, and each key of ``undefined`` is null in the JSON
    rows and an empty CSV cell in every row."""
    new, old = _files(res, tmp_path / "none"), _files(_nan_form(res), tmp_path / "nan")
    assert new == old
    rows = json.loads(new[1])["rows"]
    lines = new[0].decode().splitlines()
    header = lines[0].split(",")
    assert header == res.columns() and header[: len(CSV_COLUMNS)] == list(CSV_COLUMNS)
    for row, line in zip(rows, lines[1:]):
        cells = dict(zip(header, line.split(",")))
        for k in undefined:
            assert row[k] is None and cells[k] == "", k


def test_finite_or_none_and_no_nan():
    assert finite_or_none(float("nan")) is None and finite_or_none(np.float64("-inf")) is None
    assert finite_or_none(np.float32(0.5)) == 0.5 and type(finite_or_none(np.float64(2.0))) is float
    assert finite_or_none(3) == 3 and finite_or_none(True) is True and finite_or_none(None) is None
    nested = {"a": [1.0, (float("nan"), {"b": -math.inf})], "c": np.int64(2), "d": np.array([np.nan])}
    out = no_nan(nested)
    assert out["a"] == [1.0, (None, {"b": None})] and type(out["c"]) is int
    assert np.isnan(out["d"][0])  # a numpy array keeps nan as its mark of an undefined entry
    assert jsonable(nested)["a"] == [1.0, [None, {"b": None}]]  # the JSON writer follows the same rule
    with pytest.raises(AssertionError, match=r"result\['a'\]\[1\]\[0\] = nan"):
        assert_nan_free(nested)
    with pytest.raises(AssertionError, match=r"result\['d'\]\[0\] is not finite"):
        assert_nan_free({"d": np.array([np.nan])})


def test_sweep_without_visibility_holds_none_and_writes_null_and_empty_cells(plain_sweep, tmp_path):
    res = plain_sweep
    for row in res.rows:
        assert all(row[k] is None for k in VISIBILITY_COLUMNS)
    assert_nan_free(res)  # rows, histograms, batches and meta: no NaN anywhere
    _assert_files_as_before(res, tmp_path, VISIBILITY_COLUMNS)
    back = SweepResult.from_json(tmp_path / "none" / "sweep.json")
    assert back.rows == res.rows and all(back.rows[0][k] is None for k in VISIBILITY_COLUMNS)
    assert np.isnan(back.column("fluorescence_contrast")).all()  # the plotting column: nan for None
    trends = rp.compute_trends(res)
    assert_nan_free(trends)
    assert trends["packets_fit"]["slope"] is not None


def test_trends_of_one_angle_are_none_where_undefined():
    res = ep.sweep(ep.default_flat_scene(), betas=[0], store=500, threads=1, progress=False)
    t = rp.compute_trends(res)
    assert t["depth_sd"] is None and t["packets_fit"]["slope"] is None  # one angle: no spread, no line
    assert_nan_free(t)


def test_relative_columns_are_none_when_the_maximum_is_zero(plain_sweep, tmp_path):
    rows = [dict(r, energy_total=0.0, energy_total_stderr=0.0) for r in plain_sweep.rows]
    rows[1]["energy_per_packet"] = None  # an undefined value stays undefined relative to the maximum
    sweep_reduce.finish_relative(rows)
    assert all(r["energy_total_rel"] is None and r["energy_total_rel_stderr"] is None for r in rows)
    assert rows[0]["energy_per_packet_rel"] == 1.0 and rows[1]["energy_per_packet_rel"] is None
    assert rows[1]["energy_per_packet_rel_stderr"] is not None  # its stderr is defined
    res = SweepResult(rows=rows, histograms=plain_sweep.histograms, batches=plain_sweep.batches, meta={})
    assert_nan_free(res)
    _assert_files_as_before(res, tmp_path, ("energy_total_rel", "energy_total_rel_stderr"))


def test_reduction_without_fixed_frame_finite_p_or_record_rate_is_none(monkeypatch, tmp_path):
    rig = ep.EndoscopeRig.from_beta(20, distance=1.0, point=(0, 0, 0), normal=(0, 0, 1))
    res = ep.run(ep.default_flat_scene(), rig, store=500, seed=1, threads=1)
    geo = sweep_reduce.rig_geometry(rig, "cm")
    P = int(res.packets_traced)
    row, _, _ = sweep_reduce.analyse_run(res.escapes, P, geo["light_positions"], geo["camera"], reference=None)
    fixed = [k for k in CSV_COLUMNS if "_fixed" in k]
    assert len(fixed) == 6 and all(row[k] is None for k in fixed)
    assert row["packets_traced_stderr"] > 0 and row["azimuth_chi2_p_bonferroni"] is not None
    monkeypatch.setattr(an, "azimuthal_uniformity_test", lambda counts: np.full(counts.shape[0], np.nan))
    rate = an.record_rate
    monkeypatch.setattr(an, "record_rate", lambda *a, **k: (0.0,) + tuple(rate(*a, **k)[1:]))
    row, _, _ = sweep_reduce.analyse_run(res.escapes, P, geo["light_positions"], geo["camera"], reference=None)
    for k in ("azimuth_chi2_p_min", "azimuth_chi2_p_bonferroni", "packets_traced_stderr"):
        assert row[k] is None, k
    assert_nan_free(row)
    full = {k: row.get(k) for k in CSV_COLUMNS}
    result = SweepResult(rows=[full], meta={})
    _assert_files_as_before(result, tmp_path, ["azimuth_chi2_p_bonferroni", "packets_traced_stderr"] + fixed)


def test_add_visibility_keeps_undefined_contrasts_none_and_the_plot_skips_them(monkeypatch, tmp_path):
    cols = {k: None for k in VISIBILITY_COLUMNS}
    cols.update(white_contrast=float("nan"), target_pixels=3, background_pixels=np.int64(40))
    monkeypatch.setattr(view_sweep, "visibility_columns", lambda *a, **k: dict(cols))
    row = view_sweep.add_visibility({"beta_deg": 0.0}, None, 0.0, {"target": "polyp", "background": "tissue"})
    assert row["fluorescence_contrast"] is None and row["white_contrast"] is None
    assert row["target_pixels"] == 3 and type(row["background_pixels"]) is int
    assert_nan_free(row)
    betas = [0.0, 10.0, 20.0, 30.0]
    rows = [dict(row, red_green_contrast=0.1 * i, red_green_contrast_stderr=0.01) for i in range(4)]
    rows[2]["red_green_contrast"] = None  # an undefined point is left out of the fit and the plot
    fits = view_sweep.visibility_fits(betas, rows)
    assert fits["red_green_contrast"]["n"] == 3 and fits["fluorescence_contrast"]["x_peak"] is None
    assert view_sweep.plot_visibility(betas, rows, tmp_path / "visibility.png").endswith("visibility.png")
    assert "n/a" in view_sweep.visibility_report(betas, rows)
