"""Markdown report of a beta sweep, set beside the seed paper's reported trends.

:func:`write_report` writes ``report.md``.  Every number in it is computed from
the :class:`~endophoton.sweep.schema.SweepResult`; the only constants are the paper's
reported trend values in :data:`endophoton.paper.PAPER_TRENDS`, labelled as the paper's.

Uncertainties of derived trends (slopes, fitted peaks, differences between
angles) follow the batch-means rule of :mod:`endophoton.analysis`: the derived
statistic is computed once per batch b (from the b-th batch value of every
beta), and its standard error is sd(batch values, ddof=1) / sqrt(B).  Unless
the sweep gave every beta a seed of its own (``seed_per_beta``), all betas run
with the same seed, so packet k draws the same random numbers at every beta;
batch b is the b-th of B equal blocks of each run's own packets, so where the
betas traced different numbers of packets (a fixed store) batch b of two betas
holds the same packets only in part.

Verdict rules (stated in the report):

* a paper *value* is "consistent" when |ours - paper| <= 3 sigma (sigma = our
  stderr; the paper gives none), otherwise "differs";
* a paper *direction* (rises / falls) "agrees" when our slope or difference
  has the same sign and is at least 3 sigma from zero, "not significant" when it
  is within 3 sigma of zero, "opposite" when it is 3 sigma the other way;
* azimuthal uniformity at beta = 0 is accepted when the Bonferroni-corrected
  smallest per-ring chi-square p-value is >= 0.01.
"""

from __future__ import annotations

import os
import warnings
from typing import Any, Callable, Mapping

import numpy as np

from . import analysis as an
from .io import atomic_write_text, no_nan, unjson
from .paper import PAPER_TRENDS
from .sweep.schema import PLOT_FILES, SEED_STEP, polar_filename

__all__ = ["PAPER_TRENDS", "write_report", "compute_trends"]

SIGMAS = 3.0  # verdict threshold in standard errors (a convention, see module docstring)
ALPHA = 0.01  # significance level of the beta = 0 uniformity test


# --------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------


def _batch_matrix(result: Any, name: str) -> np.ndarray:
    """(n_beta, B) matrix of per-batch values of ``name`` (nan-padded)."""
    rows = [np.asarray(b[name], dtype=np.float64) for b in result.batches]
    B = max((r.size for r in rows), default=0)
    out = np.full((len(rows), B), np.nan)
    for i, r in enumerate(rows):
        out[i, : r.size] = r
    return out


def _batched(
    betas: np.ndarray, full: np.ndarray, mat: np.ndarray, fn: Callable[[np.ndarray, np.ndarray], float]
) -> tuple[float, float, np.ndarray]:
    """Derived statistic fn(betas, values): overall value, batch-means stderr, per-batch values."""
    value = float(fn(betas, full))
    per = np.array([fn(betas, mat[:, b]) for b in range(mat.shape[1])], dtype=np.float64)
    return value, an.batch_se(per), per


def _fmt(x: float, digits: int = 4) -> str:
    if x is None or not np.isfinite(x):
        return "n/a"
    if abs(x) >= 1000:
        return f"{x:,.0f}"
    return f"{x:.{digits}g}"


def _fmt_p(p: float) -> str:
    """p-value; an underflow to 0 is shown as < 1e-300."""
    if p is None or not np.isfinite(p):
        return "n/a"
    return "< 1e-300" if p == 0 else f"{p:.2g}"


def _p_rel(p: float) -> str:
    """'= 0.28' or '< 1e-300' (for 'p <rel>')."""
    txt = _fmt_p(p)
    return txt if txt.startswith("<") else "= " + txt


def _pm(v: float, se: float, digits: int = 4) -> str:
    return f"{_fmt(v, digits)} ± {_fmt(se, 2)}"


def _pct(v: float, se: float | None = None) -> str:
    if v is None or not np.isfinite(v):
        return "n/a"
    return f"{100 * v:.2f} %" if se is None else f"{100 * v:.2f} ± {100 * se:.2f} %"


def value_verdict(ours: float, se: float, paper: float) -> tuple[str, float]:
    """The rule for a value against the paper's: ("consistent", z) when |ours - paper| <= SIGMAS
    standard errors, else ("differs", z); ("n/a", nan) without a positive finite error."""
    if not (np.isfinite(ours) and np.isfinite(se)) or se <= 0:
        return ("n/a", float("nan"))
    z = (ours - paper) / se
    return ("consistent" if abs(z) <= SIGMAS else "differs", z)


def _direction_verdict(value: float, se: float, paper_sign: int) -> tuple[str, float]:
    if not (np.isfinite(value) and np.isfinite(se)) or se <= 0:
        return ("n/a", float("nan"))
    z = value / se
    if abs(z) < SIGMAS:
        return ("not significant", z)
    return ("agrees" if np.sign(z) == paper_sign else "opposite", z)


# --------------------------------------------------------------------------
# trends
# --------------------------------------------------------------------------


def compute_trends(result: Any, paper: Mapping[str, Any] = PAPER_TRENDS) -> dict:
    """All comparison numbers of the report, computed from ``result``: a dict of plain floats, lists
    and dicts (betas and fitted peaks in degrees, depths in cm), None where a number is undefined
    (never NaN)."""
    return no_nan(_trends(result, paper))


def _trends(result: Any, paper: Mapping[str, Any]) -> dict:
    """:func:`compute_trends` with nan for an undefined number (the report's working values). A batch
    without records (a small store split into many batches) makes some numbers undefined: numpy's
    warnings about them are silenced, as those numbers are nan here and None or "n/a" outside."""
    with np.errstate(divide="ignore", invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # nanmax/nanmean of all-nan batches
        return _trend_values(result, paper)


def _trend_values(result: Any, paper: Mapping[str, Any]) -> dict:
    """The body of :func:`_trends`."""
    b = result.betas
    n = b.size
    t: dict = {"betas": b.tolist(), "n_beta": n}
    if n == 0:
        return t
    i0, i1 = 0, n - 1
    records = result.column("records")

    # ---- packets traced (Fig. 4) -------------------------------------------------
    P = result.column("packets_traced")
    Pse = result.column("packets_traced_stderr")
    rate_m = _batch_matrix(result, "record_rate")
    p_m = records[:, None] / rate_m  # per-batch packets needed for the stored records
    t["packets_first"], t["packets_first_se"] = P[i0], Pse[i0]
    t["packets_last"], t["packets_last_se"] = P[i1], Pse[i1]
    t["packets_per_record_first"] = P[i0] / records[i0]
    drop = lambda x, y: (y[0] - y[-1]) / y[0]
    t["packets_drop"], t["packets_drop_se"], _ = _batched(b, P, p_m, drop)
    lin = lambda x, y: an.linear_fit(x, y)["slope"]
    t["packets_fit"] = an.linear_fit(b, P)
    t["packets_slope"], t["packets_slope_se"], _ = _batched(b, P, p_m, lin)
    flat_from = paper["packets_flat_until_deg"]
    sel = b >= flat_from
    t["packets_fit_beyond"] = an.linear_fit(b[sel], P[sel]) if sel.sum() >= 2 else None
    t["packets_rel_slope_per_deg"] = t["packets_slope"] / P[i0]
    if n >= 2:
        step = lambda x, y: (y[1] - y[0]) / y[0]
        t["packets_first_step"], t["packets_first_step_se"], _ = _batched(b, P, p_m, step)

    # ---- energy (Fig. 5) ---------------------------------------------------------
    deg = paper["energy_fit_degree"]
    e_pp = result.column("energy_per_packet")
    e_tot = result.column("energy_total")
    epp_m = _batch_matrix(result, "energy_per_packet")
    etot_m = records[:, None] * _batch_matrix(result, "energy_per_record")
    peak = lambda x, y: an.poly_peak(x, y / np.nanmax(y), deg)["x_peak"]
    for key, full, mat in (("energy_per_packet", e_pp, epp_m), ("energy_total", e_tot, etot_m)):
        t[key + "_argmin_beta"] = float(b[int(np.nanargmin(full))])
        t[key + "_argmax_beta"] = float(b[int(np.nanargmax(full))])
        fit = an.poly_peak(b, full / np.nanmax(full), deg)
        t[key + "_fit"] = fit
        t[key + "_peak"], t[key + "_peak_se"], _ = _batched(b, full, mat, peak)
        if n >= 2:
            d01 = lambda x, y: (y[1] - y[0]) / np.nanmax(y)
            t[key + "_rise_first_step"], t[key + "_rise_first_step_se"], _ = _batched(b, full, mat, d01)

    # ---- camera fraction (Fig. 6) ------------------------------------------------
    f = result.column("important_fraction")
    fse = result.column("important_fraction_stderr")
    f_m = _batch_matrix(result, "important_fraction")
    t["camera_first"], t["camera_first_se"] = f[i0], fse[i0]
    t["camera_last"], t["camera_last_se"] = f[i1], fse[i1]
    t["camera_max"], t["camera_max_beta"] = float(np.nanmax(f)), float(b[int(np.nanargmax(f))])
    t["camera_fit"] = an.linear_fit(b, f)
    t["camera_slope"], t["camera_slope_se"], _ = _batched(b, f, f_m, lin)
    t["camera_fit_at_paper_last"] = (
        t["camera_fit"]["slope"] * paper["camera_fraction_last_beta_deg"] + t["camera_fit"]["intercept"]
    )
    fit_at = lambda x, y: (
        an.linear_fit(x, y)["slope"] * paper["camera_fraction_last_beta_deg"] + an.linear_fit(x, y)["intercept"]
    )
    _, t["camera_fit_at_paper_last_se"], _ = _batched(b, f, f_m, fit_at)

    # ---- max depth (Fig. 7) ------------------------------------------------------
    md = result.column("max_depth_cm")
    t["depth_mean"] = float(np.nanmean(md))
    t["depth_sd"] = float(np.nanstd(md, ddof=1)) if n > 1 else float("nan")
    t["depth_min"], t["depth_max"] = float(np.nanmin(md)), float(np.nanmax(md))
    t["depth_r"] = an.pearson_r(b, md)
    t["depth_fit"] = an.linear_fit(b, md)
    md_m = _batch_matrix(result, "max_depth_cm")
    t["depth_slope"], t["depth_slope_se"], _ = _batched(b, md, md_m, lin)
    t["depth_batch_sd_mean"] = float(np.nanmean(result.column("max_depth_batch_sd_cm")))

    # ---- exit-direction histogram (Fig. 9) ---------------------------------------
    zero = [i for i in range(n) if abs(b[i] - paper["histogram_uniform_at_deg"]) < 1e-9]
    diff = lambda x, y: y[-1] - y[0]
    frames = [""] + (["_fixed"] if all("chi2_p_fixed" in h for h in result.histograms) else [])
    t["frames"] = frames
    for sfx in frames:
        if zero:
            h = result.histograms[zero[0]]
            t["uniform_beta"] = float(b[zero[0]])
            t["uniform_records"] = float(np.asarray(h["counts"]).sum())
            t["uniform_p" + sfx] = np.asarray(h["chi2_p" + sfx], dtype=np.float64).tolist()
            t["uniform_p_bonferroni" + sfx] = float(unjson(result.rows[zero[0]]["azimuth_chi2_p_bonferroni" + sfx]))
        for part in ("low", "high"):
            name = f"azimuth_asym_{part}{sfx}"
            col = result.column(name)
            col_se = result.column(name + "_stderr")
            key = f"asym_{part}{sfx}"
            t[key + "_first"], t[key + "_first_se"] = col[i0], col_se[i0]
            t[key + "_last"], t[key + "_last_se"] = col[i1], col_se[i1]
            t[key + "_change"], t[key + "_change_se"], _ = _batched(b, col, _batch_matrix(result, name), diff)
        # circular mean azimuth of the low rings at the last beta, degrees
        h_last = np.asarray(result.histograms[i1]["counts" + sfx], dtype=np.float64)
        n_elev, n_azim = h_last.shape
        low_rings = [i for i in range(n_elev) if (i + 1) * 90.0 / n_elev <= 45.0 + 1e-9]
        phi = np.radians((np.arange(n_azim) + 0.5) * 360.0 / n_azim)
        c = h_last[low_rings].sum(axis=0)
        cs, sn = float((c * np.cos(phi)).sum()), float((c * np.sin(phi)).sum())
        t["low_mean_azimuth_last_deg" + sfx] = float(np.degrees(np.arctan2(sn, cs)) % 360.0)
        t["low_resultant_last" + sfx] = float(np.hypot(sn, cs) / c.sum()) if c.sum() > 0 else float("nan")
    hf = result.column("high_elevation_fraction")
    hf_m = _batch_matrix(result, "high_elevation_fraction")
    t["high_frac_first"], t["high_frac_last"] = hf[i0], hf[i1]
    t["high_frac_change"], t["high_frac_change_se"], _ = _batched(b, hf, hf_m, diff)
    return t


def _camera_at(r: Any, t: Mapping[str, Any], beta: float) -> tuple[float, float, str]:
    """Camera fraction and its stderr at ``beta``: the measured row if the sweep has that angle,
    else the linear fit of :func:`compute_trends` (which evaluates it at the paper's last angle)."""
    b = r.betas
    at = [i for i in range(t["n_beta"]) if abs(b[i] - beta) < 1e-9]
    if at:
        row = r.rows[at[0]]
        return unjson(row["important_fraction"]), unjson(row["important_fraction_stderr"]), "measured"
    src = "linear fit (extrapolated)" if beta > b.max() or beta < b.min() else "linear fit (interpolated)"
    return t["camera_fit_at_paper_last"], t["camera_fit_at_paper_last_se"], src


def _depth_rel(t: Mapping[str, Any], pt: Mapping[str, Any]) -> float:
    """Our mean deepest record relative to the paper's depth, minus 1."""
    return (t["depth_mean"] - pt["max_depth_cm"]) / pt["max_depth_cm"]


def _write_run(w: Callable, r: Any, t: Mapping[str, Any], pt: Mapping[str, Any]) -> None:
    """Run settings and the per-angle table."""
    b = r.betas
    m = r.meta
    w("## Run\n")
    w(
        f"- angles beta: {', '.join(f'{x:g}' for x in b)} deg; records requested per angle: {int(m.get('store', 0)):,} "
        f"(**paper**: {pt['store']:,} at {pt['betas_deg'][0]}-{pt['betas_deg'][-1]} deg)"
    )
    w(
        f"- seed {m.get('seed')} "
        f"({'angle k: seed + k × ' + hex(SEED_STEP) + ' mod 2^64' if m.get('seed_per_beta') else 'same for every angle'}), "
        f"threads {m.get('threads')}, "
        f"fluorescent only: {m.get('fluorescent_only')}, fluorescence rule: {m.get('fluorescence_rule')}"
    )
    w(
        f"- scene: {m.get('scene')}; unit {m.get('unit')}; head distance {m.get('distance')} scene units; "
        f"tilt axis {m.get('tilt_axis')}"
    )
    w(
        f"- standard errors: batch means over B = {m.get('n_batches')} contiguous packet batches; derived trends "
        f"(slopes, fitted peaks, differences) are computed per batch and their sd / sqrt(B) is reported."
    )
    w(f"- total engine time: {_fmt(float(np.nansum(r.column('seconds'))), 4)} s\n")
    if any(row.get("cancelled") for row in r.rows):
        w("**The sweep was cancelled; the last row is partial.**\n")
    elif m.get("cancelled"):  # cancelled between two runs: every row is whole, the later angles are missing
        w(
            f"**The sweep was cancelled at beta = {m.get('cancelled_at_beta')} deg; the angles from there on are missing.**\n"
        )

    w("## Per-angle results\n")
    w(
        "| beta (deg) | packets traced | energy / packet (rel.) | energy sum of stored (rel.) | camera fraction | "
        "max depth (cm) | batch-max depth (cm) | asym. < 45° (light) | asym. ≥ 45° (light) | min ring χ² p (light) | "
        "asym. < 45° (fixed) | asym. ≥ 45° (fixed) | min ring χ² p (fixed) |"
    )
    w("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for row in r.rows:
        w(
            f"| {row['beta_deg']:g} | {_pm(row['packets_traced'], row['packets_traced_stderr'], 7)} | "
            f"{_pm(row['energy_per_packet_rel'], row['energy_per_packet_rel_stderr'])} | "
            f"{_pm(row['energy_total_rel'], row['energy_total_rel_stderr'])} | "
            f"{_pct(row['important_fraction'], row['important_fraction_stderr'])} | "
            f"{_fmt(row['max_depth_cm'])} | {_pm(row['max_depth_batch_mean_cm'], row['max_depth_batch_sd_cm'])} | "
            f"{_pm(row['azimuth_asym_low'], row['azimuth_asym_low_stderr'], 3)} | "
            f"{_pm(row['azimuth_asym_high'], row['azimuth_asym_high_stderr'], 3)} | "
            f"{_fmt_p(row['azimuth_chi2_p_min'])} | "
            f"{_pm(row.get('azimuth_asym_low_fixed'), row.get('azimuth_asym_low_fixed_stderr'), 3)} | "
            f"{_pm(row.get('azimuth_asym_high_fixed'), row.get('azimuth_asym_high_fixed_stderr'), 3)} | "
            f"{_fmt_p(row.get('azimuth_chi2_p_min_fixed'))} |"
        )
    w(
        "\nasym. = mean cos(azimuth) of the exit directions in the rings below / above 45° elevation; a negative "
        "value means the exits lean toward azimuth 180°.  Light frame: azimuth 0° points from the exit point toward "
        "the light that emitted the packet; fixed frame: azimuth 0° is the horizontal direction toward the tilted "
        "head, the same for all records (see the histogram section).  min ring χ² p: smallest per-ring "
        "azimuthal-uniformity p-value (10 rings, not corrected).\n"
    )
    w(
        f"Verdict rules: a paper value is *consistent* if our value is within {SIGMAS:g} standard errors of it "
        f"(the paper gives no uncertainty); a paper direction *agrees* if our slope/difference has the same sign and "
        f"is at least {SIGMAS:g} standard errors from zero.\n"
    )


def _write_packets(w: Callable, r: Any, t: Mapping[str, Any], pt: Mapping[str, Any]) -> None:
    """Fig. 4: packets traced to store N records."""
    b = r.betas
    # ---- Fig. 4 ----
    w("## Photons traced (Fig. 4)\n")
    w(f"![packets traced]({PLOT_FILES['packets']})\n")
    w(
        f"- **paper**: more than {pt['packets_traced_min']:,} packets traced to store {pt['store']:,} "
        f"(≈ {pt['packets_traced_min'] / pt['store']:g} per stored photon); flat near 0°, then linear, about "
        f"{100 * pt['packets_relative_drop']:g} % fewer at the largest angle."
    )
    w(
        f"- ours: {_pm(t['packets_first'], t['packets_first_se'], 7)} packets at β = {b[0]:g}° for "
        f"{int(r.rows[0]['records']):,} records ({_fmt(t['packets_per_record_first'])} per stored record; the "
        f"paper's > {pt['packets_traced_min'] / pt['store']:g}: "
        f"**{'agrees' if t['packets_per_record_first'] > pt['packets_traced_min'] / pt['store'] else 'differs'}**); "
        f"{_pm(t['packets_last'], t['packets_last_se'], 7)} at β = {b[-1]:g}°."
    )
    if "packets_first_step" in t:
        vf, zf = _direction_verdict(t["packets_first_step"], t["packets_first_step_se"], -1)
        w(
            f"- first step β = {b[0]:g}° → {b[1]:g}°: relative change "
            f"{_pct(t['packets_first_step'], t['packets_first_step_se'])} ({_fmt(zf, 3)} σ; "
            f"{'flat within 3 σ, as the paper' if vf == 'not significant' else 'not flat'})."
        )
    v, z = _direction_verdict(t["packets_drop"], t["packets_drop_se"], +1)
    v2, z2 = value_verdict(t["packets_drop"], t["packets_drop_se"], pt["packets_relative_drop"])
    w(
        f"- relative drop first → last angle: {_pct(t['packets_drop'], t['packets_drop_se'])}; "
        f"direction (fewer at larger β): **{v}** ({_fmt(z, 3)} σ); size vs the paper's "
        f"{100 * pt['packets_relative_drop']:g} %: **{v2}** ({_fmt(z2, 3)} σ)."
    )
    fit = t["packets_fit"]
    w(
        f"- linear fit over all angles: slope {_pm(t['packets_slope'], t['packets_slope_se'])} packets/deg "
        f"({_fmt(100 * t['packets_rel_slope_per_deg'], 3)} % of the β = {b[0]:g}° value per degree), R² = {_fmt(fit['r2'], 3)}."
    )
    if t.get("packets_fit_beyond"):
        fb = t["packets_fit_beyond"]
        w(
            f"- linear fit for β ≥ {pt['packets_flat_until_deg']}° (the paper's linear range): slope "
            f"{_fmt(fb['slope'])} packets/deg, R² = {_fmt(fb['r2'], 3)} ({fb['n']} angles)."
        )
    w("")


def _write_energy(w: Callable, r: Any, t: Mapping[str, Any], pt: Mapping[str, Any]) -> None:
    """Fig. 5: total surface energy and its fitted peak."""
    b = r.betas
    # ---- Fig. 5 ----
    w("## Total surface energy (Fig. 5)\n")
    w(f"![energy]({PLOT_FILES['energy']})\n")
    w(
        f"- **paper**: lowest at β = {pt['energy_min_beta_deg']}°; a degree-{pt['energy_fit_degree']} polynomial fit "
        f"peaks near β ≈ {pt['energy_peak_beta_deg']}°.  The paper sums the energy of the stored photons."
    )
    for key, label in (
        ("energy_total", "sum over the stored records (the paper's definition)"),
        ("energy_per_packet", "energy per packet traced"),
    ):
        fit = t[key + "_fit"]
        w(
            f"- {label}: lowest at β = {t[key + '_argmin_beta']:g}°, highest data point at β = "
            f"{t[key + '_argmax_beta']:g}°; degree-{fit['deg']} fit maximum at β = "
            f"{_pm(t[key + '_peak'], t[key + '_peak_se'], 3)}° "
            f"({'interior' if fit['interior'] else 'at the end of the range'}"
            f"{'; interior local maxima at ' + ', '.join(f'{x:.1f}°' for x in fit['local_maxima']) if fit['local_maxima'] else ''})."
        )
        vmin = "agrees" if abs(t[key + "_argmin_beta"] - pt["energy_min_beta_deg"]) < 1e-9 else "differs"
        if fit["interior"]:
            vp, zp = value_verdict(t[key + "_peak"], t[key + "_peak_se"], pt["energy_peak_beta_deg"])
        else:
            vp, zp = "differs (the fit has no interior maximum)", float("nan")
        rise = t.get(key + "_rise_first_step")
        vr, zr = (
            _direction_verdict(rise, t.get(key + "_rise_first_step_se", float("nan")), +1)
            if rise is not None
            else ("n/a", float("nan"))
        )
        w(
            f"  - minimum at β = {pt['energy_min_beta_deg']}°: **{vmin}**; rise from β = {b[0]:g}° to the next "
            f"angle: {_pm(rise if rise is not None else float('nan'), t.get(key + '_rise_first_step_se', float('nan')), 3)} "
            f"of the maximum, **{vr}** ({_fmt(zr, 3)} σ); fitted peak vs {pt['energy_peak_beta_deg']}°: **{vp}**"
            f"{f' ({_fmt(zp, 3)} σ)' if np.isfinite(zp) else ''}."
        )
    if t["energy_total_fit"]["deg"] < pt["energy_fit_degree"]:
        w(
            f"- note: only {t['n_beta']} angles, so the fit degree is {t['energy_total_fit']['deg']} instead of "
            f"{pt['energy_fit_degree']}."
        )
    w("")


def _write_camera(w: Callable, r: Any, t: Mapping[str, Any], pt: Mapping[str, Any]) -> None:
    """Fig. 6: fraction of stored records pointing to the camera."""
    b = r.betas
    m = r.meta
    # ---- Fig. 6 ----
    w("## Photons pointing to the camera (Fig. 6)\n")
    w(f"![camera fraction]({PLOT_FILES['important']})\n")
    w(
        f"- **paper**: under {100 * pt['camera_fraction_max']:g} % of the stored photons are visible and within "
        f"{pt['camera_max_angle_deg']:g}° of the direction to the camera; roughly linear decrease to about "
        f"{100 * pt['camera_fraction_last']:g} % at β = {pt['camera_fraction_last_beta_deg']}°."
    )
    w(
        f"- ours (criterion {m.get('max_angle_deg', 15):g}°): {_pct(t['camera_first'], t['camera_first_se'])} at "
        f"β = {b[0]:g}°, {_pct(t['camera_last'], t['camera_last_se'])} at β = {b[-1]:g}°; maximum "
        f"{_pct(t['camera_max'])} at β = {t['camera_max_beta']:g}° "
        f"({'below' if t['camera_max'] < pt['camera_fraction_max'] else 'not below'} the paper's "
        f"{100 * pt['camera_fraction_max']:g} %)."
    )
    v, z = _direction_verdict(t["camera_slope"], t["camera_slope_se"], -1)
    w(
        f"- linear fit: slope {_fmt(100 * t['camera_slope'], 3)} ± {_fmt(100 * t['camera_slope_se'], 2)} "
        f"percentage points/deg, R² = {_fmt(t['camera_fit']['r2'], 3)}; decrease: **{v}** ({_fmt(z, 3)} σ)."
    )
    last_b = pt["camera_fraction_last_beta_deg"]
    val, se, src = _camera_at(r, t, last_b)
    vv, zz = value_verdict(val, se, pt["camera_fraction_last"])
    w(
        f"- at β = {last_b}° ({src}): {_pct(val, se)} vs the paper's {100 * pt['camera_fraction_last']:g} %: "
        f"**{vv}** ({_fmt(zz, 3)} σ).\n"
    )


def _write_depth(w: Callable, r: Any, t: Mapping[str, Any], pt: Mapping[str, Any]) -> None:
    """Fig. 7: maximum penetration depth."""
    # ---- Fig. 7 ----
    w("## Maximum penetration depth (Fig. 7)\n")
    w(f"![max depth]({PLOT_FILES['depth']})\n")
    w(f"- **paper**: about {pt['max_depth_cm']} cm at every angle, no correlation with β.")
    w(
        f"- ours: deepest record {_fmt(t['depth_mean'])} ± {_fmt(t['depth_sd'], 2)} cm (mean ± sd over the "
        f"{t['n_beta']} angles; range {_fmt(t['depth_min'])}-{_fmt(t['depth_max'])} cm); the per-batch maxima "
        f"scatter by {_fmt(t['depth_batch_sd_mean'], 2)} cm (mean sd)."
    )
    v, z = _direction_verdict(t["depth_slope"], t["depth_slope_se"], 0)
    w(
        f"- correlation with β: Pearson r = {_fmt(t['depth_r'], 3)}; linear slope "
        f"{_pm(t['depth_slope'], t['depth_slope_se'], 3)} cm/deg ({_fmt(z, 3)} σ from zero: "
        f"{'no significant dependence on β, as the paper' if v == 'not significant' else 'a significant dependence on β, unlike the paper'})."
    )
    rel = _depth_rel(t, pt)
    w(
        f"- level vs the paper's {pt['max_depth_cm']} cm: {_fmt(100 * rel, 3)} % "
        f"({_fmt((t['depth_mean'] - pt['max_depth_cm']) / t['depth_sd'], 3) if np.isfinite(t['depth_sd']) and t['depth_sd'] > 0 else 'n/a'} "
        f"× the sd over angles).  A sample maximum grows with the number of packets traced, so the level depends "
        f"on N; the paper's value is one maximum per angle as well.\n"
    )


def _write_histograms(w: Callable, r: Any, t: Mapping[str, Any], pt: Mapping[str, Any]) -> list:
    """Figs. 8-9: exit-direction histograms in both azimuth frames; returns summary rows."""
    b = r.betas
    # ---- Fig. 9 ----
    w("## Exit-direction histogram (Figs. 8-9)\n")
    for beta in b:
        w(f"![polar beta {beta:g}, light frame]({polar_filename(beta)})")
        if "_fixed" in t["frames"]:
            w(f"![polar beta {beta:g}, fixed frame]({polar_filename(beta, 'fixed')})")
    w("")
    w(
        f"- **paper**: azimuthally uniform at β = {pt['histogram_uniform_at_deg']}°; as β grows the rings below "
        f"{pt['histogram_high_above_deg']}° elevation become ellipses shifted toward azimuth "
        f"{pt['histogram_low_shift_to_deg']}°; rings above {pt['histogram_high_above_deg']}° stay nearly unchanged."
    )
    w(
        "Two azimuth frames (docs/sweep.md).  *Light frame* (the project's definition): azimuth 0° points from each "
        "exit point toward the light that emitted the packet.  *Fixed frame*: azimuth 0° is the same horizontal "
        "direction for every record, toward the tilted head (at β = 0 the line between the lights); this is how "
        "a single hemisphere of bins over the whole photon map (the seed's Fig. 8) reads most naturally.  In the "
        "light frame the reference turns with the exit point's position around the spot, so any net outward "
        "flow of light away from the illuminated spot shows up as a lean toward 180° even at β = 0.\n"
    )
    lines_summary = []
    for sfx in t["frames"]:
        fname = "light frame" if sfx == "" else "fixed frame"
        w(f"### {fname.capitalize()}\n")
        if "uniform_p" + sfx in t:
            ok = t["uniform_p_bonferroni" + sfx] >= ALPHA
            w(
                f"- uniformity at β = {t['uniform_beta']:g}° ({int(t['uniform_records']):,} records): per-ring "
                f"chi-square p-values (elevation 0-9°, 9-18°, ...): "
                f"{', '.join(_fmt_p(p) for p in t['uniform_p' + sfx])}; Bonferroni-corrected smallest p "
                f"{_p_rel(t['uniform_p_bonferroni' + sfx])} → "
                f"**{'uniform (agrees)' if ok else 'not uniform at the 1 % level (differs)'}**."
            )
            lines_summary.append(
                (
                    f"uniform azimuth at β = 0° ({fname})",
                    f"Bonferroni p {_p_rel(t['uniform_p_bonferroni' + sfx])}",
                    "agrees" if ok else "differs",
                )
            )
        else:
            w(f"- β = {pt['histogram_uniform_at_deg']}° not in the sweep: uniformity not tested.")
        lo, hi = "asym_low" + sfx, "asym_high" + sfx
        v, z = _direction_verdict(t[lo + "_change"], t[lo + "_change_se"], -1)
        w(
            f"- rings below 45°: mean cos(azimuth) {_pm(t[lo + '_first'], t[lo + '_first_se'], 3)} at "
            f"β = {b[0]:g}° → {_pm(t[lo + '_last'], t[lo + '_last_se'], 3)} at β = {b[-1]:g}° (change "
            f"{_pm(t[lo + '_change'], t[lo + '_change_se'], 3)}); shift toward 180°: **{v}** ({_fmt(z, 3)} σ).  "
            f"Circular mean azimuth of these rings at β = {b[-1]:g}°: {_fmt(t['low_mean_azimuth_last_deg' + sfx], 4)}° "
            f"(resultant length {_fmt(t['low_resultant_last' + sfx], 3)})."
        )
        vh, zh = _direction_verdict(t[hi + "_change"], t[hi + "_change_se"], -1)
        ratio = abs(t[hi + "_change"]) / abs(t[lo + "_change"]) if t[lo + "_change"] else float("nan")
        smaller = np.isfinite(ratio) and ratio < 1
        if v != "agrees":
            high_verdict = "not comparable (the low rings do not shift toward 180°)"
        else:
            high_verdict = "agrees" if smaller else "differs"
        w(
            f"- rings at/above 45°: mean cos(azimuth) {_pm(t[hi + '_first'], t[hi + '_first_se'], 3)} → "
            f"{_pm(t[hi + '_last'], t[hi + '_last_se'], 3)} (change "
            f"{_pm(t[hi + '_change'], t[hi + '_change_se'], 3)}, {_fmt(zh, 3)} σ; "
            f"{_fmt(ratio, 3)} × the low-ring change).  "
            f"Verdict: **{high_verdict}**"
            f"{' (smaller than the low-ring change)' if high_verdict == 'agrees' else ''}.\n"
        )
        lines_summary.append(
            (
                f"low rings shift toward 180° ({fname})",
                f"Δ mean cos = {_pm(t[lo + '_change'], t[lo + '_change_se'], 3)}",
                v,
            )
        )
        lines_summary.append(
            (
                f"rings > 45° nearly unchanged ({fname})",
                f"Δ mean cos = {_pm(t[hi + '_change'], t[hi + '_change_se'], 3)} "
                f"({_fmt(ratio, 3)} × low-ring change)",
                high_verdict,
            )
        )
    w(
        f"- fraction of records at/above 45° elevation: {_pct(t['high_frac_first'])} at β = {b[0]:g}° → "
        f"{_pct(t['high_frac_last'])} at β = {b[-1]:g}° (change {_pct(t['high_frac_change'], t['high_frac_change_se'])}).\n"
    )

    return lines_summary


def _write_summary(w: Callable, r: Any, t: Mapping[str, Any], pt: Mapping[str, Any], lines_summary: list) -> None:
    """The summary table: each paper trend beside ours and the verdict."""
    w("## Summary\n")
    val, se, src = _camera_at(r, t, pt["camera_fraction_last_beta_deg"])
    vv = value_verdict(val, se, pt["camera_fraction_last"])[0]
    rel = _depth_rel(t, pt)
    w("| paper trend | ours | verdict |")
    w("|---|---|---|")
    vd, zd = _direction_verdict(t["packets_drop"], t["packets_drop_se"], +1)
    w(
        f"| packets traced fall ~{100 * pt['packets_relative_drop']:g} % from first to last angle | "
        f"{_pct(t['packets_drop'], t['packets_drop_se'])} | direction {vd}; size "
        f"{value_verdict(t['packets_drop'], t['packets_drop_se'], pt['packets_relative_drop'])[0]} |"
    )
    w(
        f"| energy lowest at β = {pt['energy_min_beta_deg']}° | lowest at β = {t['energy_total_argmin_beta']:g}° "
        f"(sum of stored), {t['energy_per_packet_argmin_beta']:g}° (per packet) | "
        f"{'agrees' if t['energy_total_argmin_beta'] == pt['energy_min_beta_deg'] else 'differs'} (sum of stored) |"
    )
    w(
        f"| degree-{pt['energy_fit_degree']} fit peak ≈ {pt['energy_peak_beta_deg']}° | "
        f"{_pm(t['energy_total_peak'], t['energy_total_peak_se'], 3)}° (sum of stored), "
        f"{_pm(t['energy_per_packet_peak'], t['energy_per_packet_peak_se'], 3)}° (per packet) | "
        f"{value_verdict(t['energy_total_peak'], t['energy_total_peak_se'], pt['energy_peak_beta_deg'])[0] if t['energy_total_fit']['interior'] else 'differs (no interior maximum)'} (sum of stored) |"
    )
    w(
        f"| camera fraction < {100 * pt['camera_fraction_max']:g} %, falling | max {_pct(t['camera_max'])}, slope "
        f"{_fmt(100 * t['camera_slope'], 3)} ± {_fmt(100 * t['camera_slope_se'], 2)} pp/deg | "
        f"{'below' if t['camera_max'] < pt['camera_fraction_max'] else 'above'}; falling "
        f"{_direction_verdict(t['camera_slope'], t['camera_slope_se'], -1)[0]} |"
    )
    w(
        f"| camera fraction ≈ {100 * pt['camera_fraction_last']:g} % at {pt['camera_fraction_last_beta_deg']}° | "
        f"{_pct(val, se)} ({src}) | {vv} |"
    )
    w(
        f"| max depth ≈ {pt['max_depth_cm']} cm, independent of β | {_fmt(t['depth_mean'])} ± "
        f"{_fmt(t['depth_sd'], 2)} cm, r = {_fmt(t['depth_r'], 3)} | dependence on β: "
        f"{_direction_verdict(t['depth_slope'], t['depth_slope_se'], 0)[0]}; level {_fmt(100 * rel, 3)} % off |"
    )
    for a, bb, c in lines_summary:
        w(f"| {a} | {bb} | {c} |")
    w("")


# --------------------------------------------------------------------------
# report
# --------------------------------------------------------------------------


def write_report(
    sweep_result: Any,
    out_dir: str | os.PathLike,
    paper_trends: Mapping[str, Any] = PAPER_TRENDS,
    filename: str = "report.md",
) -> str:
    """Write ``report.md`` into ``out_dir`` (atomically) and return its path.

    The report lists the run settings, the per-beta table, links to the plots
    (file names of :func:`endophoton.plots.plot_all`) and, for each of the
    paper's trends, the paper's statement beside our numbers with a verdict
    (rules in this module's docstring).
    """
    r = sweep_result
    pt = dict(PAPER_TRENDS)
    pt.update(paper_trends or {})
    t = _trends(r, pt)
    L: list = []
    w = L.append
    w("# EndoPhoton beta sweep: comparison with the seed paper\n")
    w(
        "Seed: A. Zacher, *Initial angle of light rays and their influence on the total distribution, "
        "scattering and absorption in human tissue* (2009), §5, Figs. 4-9.  Values marked **paper** are the "
        "paper's reported trends (docs/sweep.md); every other number is computed from this run.\n"
    )
    if t["n_beta"] == 0:
        w("The sweep has no rows.\n")
        return atomic_write_text(os.path.join(out_dir, filename), "\n".join(L))
    for section in (_write_run, _write_packets, _write_energy, _write_camera, _write_depth):
        section(w, r, t, pt)
    _write_summary(w, r, t, pt, _write_histograms(w, r, t, pt))
    return atomic_write_text(os.path.join(out_dir, filename), "\n".join(L))
