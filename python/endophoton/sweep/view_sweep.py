"""The endoscope's view across a beta sweep: the visibility plot with its fitted maximum, the contact
sheet of the views, and the report's answer to the paper's question (at which beta is the polyp most
visible, how sure are we, and how does that compare with the paper's 34 deg).

Inputs are plain sequences (betas, the rows' visibility columns, image paths) so the sweep, the
main job and the add-on can all call these without depending on each other.
"""
from __future__ import annotations

import io
import math
import os
from typing import Callable

import numpy as np

from ..io import no_nan, unjson
from ..paper import PAPER_TRENDS
from ..report import ALPHA, SIGMAS, value_verdict
from .schema import VISIBILITY_COLUMNS, VISIBILITY_FILES
from ..view.visibility import fit_peak
from . import view_runs
from .view_runs import view_of_beta

__all__ = [
    "PAPER_BETA_DEG",
    "VISIBILITY_COLUMNS",
    "visibility_columns",
    "rerun_of",
    "add_visibility",
    "write_visibility_outputs",
    "visibility_fits",
    "plot_visibility",
    "contact_sheet",
    "visibility_report",
    "lights_report",
    "flat_band",
    "criterion_answer",
    "plot_surround",
]

#: The seed paper's answer (its energy fit peaks near 34 deg): where pathological changes are best visible.
PAPER_BETA_DEG = float(PAPER_TRENDS["energy_peak_beta_deg"])
_SERIES = (
    ("red_green_contrast", "red/green contrast (fluorescence)"),
    ("fluorescence_contrast", "Weber contrast, fluorescence radiance"),
    ("white_contrast", "Weber contrast, white light"),
)


def rerun_of(result, **run_kwargs) -> Callable:
    """``run_more(packets, seed, fluorescent_only, view=None, record_escapes=True)``: ``ep.run`` of ``result``'s
    scene and source again with its fluorescence rule and lumen (the white pass, the next-event runs with their
    camera tally ``view`` and the top-ups of :func:`view_runs.view_of_beta`); ``run_kwargs`` (threads,
    progress, cancel, ...) are passed on."""
    opts = dict(getattr(result, "options", {}) or {})
    kw = {"fluorescence_rule": opts.get("fluorescence_rule", "paper"), "lumen": opts.get("lumen", True)}
    kw.update(run_kwargs)

    def run_more(packets, seed, fluorescent_only, view=None, record_escapes=True):
        from ..run import run

        extra = {} if view is None else {"view": view, "record_escapes": bool(record_escapes)}
        return run(
            result.scene,
            result.source,
            photons=int(packets),
            seed=int(seed),
            fluorescent_only=fluorescent_only,
            **extra,
            **kw,
        )

    return run_more


def visibility_columns(
    result,
    target: str,
    background: str | None,
    out_dir=None,
    prefix: str = "",
    *,
    surround_px=None,
    run_more: Callable | None = None,
    contrast_target=None,
    white_packets=None,
    **render_kwargs,
) -> dict:
    """Render the run's view and return the :data:`VISIBILITY_COLUMNS` as a flat, JSON-able dict (None
    where a contrast is undefined): :func:`view_runs.view_of_beta` (the white image from all the light,
    a white pass for a fluorescent-only run; ``contrast_target`` tops the view up). ``background`` is the
    whole region, or with ``surround_px`` the ring of that width around the target (of that region only,
    if one is named). ``render_kwargs`` go to ``render_view`` (``estimator`` among them); ``run_more``
    defaults to :func:`rerun_of` ``(result)``. With ``out_dir`` the view's images and arrays are saved
    there with file names starting ``prefix``."""
    if run_more is None:
        run_more = rerun_of(result)
    seed = int(dict(getattr(result, "options", {}) or {}).get("seed", 1))
    cols, view = view_of_beta(
        result,
        target,
        background,
        surround_px,
        run_more,
        seed,
        contrast_target=contrast_target,
        white_packets=white_packets,
        **render_kwargs,
    )
    if out_dir is not None:
        view.save(out_dir, prefix=prefix)
    out = {k: cols.get(k) for k in VISIBILITY_COLUMNS}
    if cols.get("cancelled"):  # a top-up was cancelled: add_visibility marks the row
        out["cancelled"] = 1
    return out


def _column(rows, key):
    """Column ``key`` of ``rows`` as a float array for fits and plots: an undefined (None) cell is nan,
    which the fit leaves out and matplotlib does not draw."""
    return np.array([unjson(r.get(key)) for r in rows], dtype=np.float64)


def visibility_fits(betas, rows) -> dict:
    """:func:`visibility.fit_peak` of each visibility column over beta: {column: fit}."""
    b = np.asarray(betas, dtype=np.float64)
    return {key: fit_peak(b, _column(rows, key), _column(rows, key + "_stderr")) for key, _ in _CRITERIA}


def plot_visibility(betas, rows, path) -> str:
    """Contrasts against beta with error bars, the fitted parabola and its maximum +- stderr, and the
    paper's 34 deg; written atomically as PNG."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure

    from ..io import atomic_write_bytes

    b = np.asarray(betas, dtype=np.float64)
    fits = visibility_fits(b, rows)
    fig = Figure(figsize=(7.5, 4.5))
    ax = fig.add_subplot(1, 1, 1)
    drawn = 0
    for (key, label), colour in zip(_SERIES, ("tab:red", "tab:purple", "tab:gray")):
        y, se = _column(rows, key), _column(rows, key + "_stderr")
        ok = np.isfinite(y)  # an undefined (None) contrast is not drawn; an undefined stderr has no bar
        if not ok.any():  # undefined at every beta (e.g. the target never in view): no series
            continue
        drawn += 1
        f = fits[key]
        if f["x_peak"] is not None and not _varies(f):  # flat within its errors: no maximum to mark
            label += f" (no dependence on β, {_p_text(f['flat_p'])})"
        ax.errorbar(b[ok], y[ok], yerr=np.nan_to_num(se[ok]), fmt="o", color=colour, capsize=3, label=label)
        if f["x_peak"] is not None:
            xs = np.linspace(*f["fit_range"], 200)
            ax.plot(xs, np.polyval(f["coeffs"], xs), "-", color=colour, lw=1)
        if f["x_peak"] is not None and f["vertex"] and _varies(f):
            ax.axvspan(f["x_peak"] - f["x_peak_stderr"], f["x_peak"] + f["x_peak_stderr"], color=colour, alpha=0.12)
            ax.axvline(f["x_peak"], color=colour, ls=":", lw=1)
    if not drawn:
        ax.text(0.5, 0.5, "no contrast is defined at any β", transform=ax.transAxes, ha="center", va="center")
    ax.axvline(PAPER_BETA_DEG, color="k", ls="--", lw=1, label=f"paper: {PAPER_BETA_DEG:g}°")
    ax.set_xlabel("β (deg)")
    ax.set_ylabel("contrast of the target against the background")
    ax.set_title("Polyp visibility against β (fitted maximum ± stderr shaded)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    return atomic_write_bytes(path, buf.getvalue())


def contact_sheet(image_paths, betas, path, columns: int = 4, title: str = "fluorescence view") -> str:
    """A grid of the views (PNG paths, one per beta) labelled with beta; written atomically as PNG."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.image as mpimg
    from matplotlib.figure import Figure

    from ..io import atomic_write_bytes

    n = len(image_paths)
    if n == 0:
        raise ValueError("contact_sheet: image_paths is empty")
    cols = min(columns, n)
    rows = math.ceil(n / cols)
    fig = Figure(figsize=(2.4 * cols, 2.8 * rows))
    for i, (p, beta) in enumerate(zip(image_paths, betas)):
        ax = fig.add_subplot(rows, cols, i + 1)
        ax.imshow(mpimg.imread(os.fspath(p)), interpolation="nearest")
        ax.set_title(f"β = {float(beta):g}°", fontsize=9)
        ax.axis("off")
    fig.suptitle(title)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    return atomic_write_bytes(path, buf.getvalue())


def _fmt(v, digits=1):
    return "n/a" if v is None else f"{v:.{digits}f}"


_CRITERIA = (
    ("red_green_contrast", "red/green contrast"),
    ("red_green_camera_contrast", "red/green contrast, camera channels"),
    ("fluorescence_contrast", "fluorescence Weber contrast"),
    ("white_contrast", "white-light Weber contrast"),
    ("fluorescence_michelson", "fluorescence Michelson contrast"),
    ("white_michelson", "white-light Michelson contrast"),
)


def flat_band(rows, key) -> float | None:
    """X of "flat within ±X over the swept range": the largest |y_β − ȳ| + 2 stderr_β, ȳ the weighted mean
    of the β values (weights 1/stderr²). Each β's true contrast lies within ±X of ȳ at 2σ; None without a
    defined value with a positive stderr."""
    y, se = _column(rows, key), _column(rows, key + "_stderr")
    ok = np.isfinite(y) & np.isfinite(se) & (se > 0)
    if not ok.any():
        return None
    w = 1.0 / se[ok] ** 2
    mean = float(np.sum(w * y[ok]) / np.sum(w))
    return float(np.max(np.abs(y[ok] - mean) + 2.0 * se[ok]))


def criterion_answer(f, rows, key, betas) -> str:
    """One criterion's answer: the β at maximum with its error and 68 % range, the end of the range where a
    contrast that varies is largest, or "flat within ±X over the swept range"."""
    if f["x_peak"] is None:
        return "n/a (fewer than 3 β with a defined value)"
    if not _varies(f):
        b = np.asarray(betas, dtype=np.float64)
        return f"flat within ±{flat_band(rows, key):.3g} over the swept range ({b.min():g}–{b.max():g}°)"
    if not f["vertex"]:
        return f"largest at β = {f['x_peak']:.1f}°, at the end of the points fitted: no maximum fitted"
    if f["x_peak_stderr"] is None:
        return f"most visible at β = {f['x_peak']:.1f}°"
    return (
        f"most visible at β = {f['x_peak']:.1f}° ± {f['x_peak_stderr']:.1f}° "
        f"(68 %: {f['x_peak_lo']:.1f}–{f['x_peak_hi']:.1f}°)"
    )


def _varies(f) -> bool:
    """True when the contrast depends on beta beyond its standard errors: the chi-square test of one
    value for every beta (``fit_peak``'s ``flat_p``) rejects it at the report's level ``ALPHA``."""
    return f["flat_p"] is not None and f["flat_p"] < ALPHA


def _p_text(p: float) -> str:
    """A p-value as text ("p = 0.67"; one below the smallest double, "p < 1e-300")."""
    return f"p = {p:.2g}" if p > 0 else "p < 1e-300"


def _flat_words(f) -> str:
    return f"χ² = {f['flat_chi2']:.1f}, {f['flat_dof']} degrees of freedom, {_p_text(f['flat_p'])}"


def _seed_words(seed_per_beta: bool) -> str:
    """What the sweep's seeds mean for the flatness test (bench/visibility_seeds.py measures it)."""
    if seed_per_beta:
        return (
            "The test takes the β values' errors as independent, and they are: every β ran with a seed of "
            "its own, so the test holds its level."
        )
    return (
        "The test takes the β values' errors as independent, while the sweep ran every β with the same "
        "seed, which correlates them positively, so the test is conservative: a contrast it calls flat "
        "shows no dependence on β at this store, but a small one can be missed (docs/render.md; "
        "`--seed-per-beta` runs a sweep whose test holds its level)."
    )


def _peak_sentence(f, label: str) -> str:
    """Where a contrast that varies with beta is largest, with the fit's verdict against 34 deg."""
    if not f["vertex"]:
        where = (
            "an end of the swept range, so the true maximum may lie outside it"
            if not f["interior"]
            else (
                "an end of the five points fitted around its largest value, whose parabola has no maximum "
                "inside them: no β of maximum is fitted"
            )
        )
        return f"The {label} varies with β ({_flat_words(f)}) and is largest at β = {f['x_peak']:.1f}°, {where}."
    # The report's rule for a value against the paper's (report.value_verdict, SIGMAS).
    verdict, z = value_verdict(f["x_peak"], f["x_peak_stderr"], PAPER_BETA_DEG)
    if verdict == "n/a":
        against = (
            f"The paper's 34° is {abs(f['x_peak'] - PAPER_BETA_DEG):.1f}° away; the fit's spread is zero, "
            "so no σ distance is given."
        )
    else:
        words = "consistent with" if verdict == "consistent" else "different from"
        against = f"The paper's 34° is {abs(z):.1f} σ away: {words} it (within {SIGMAS:g} σ is consistent)."
    return (
        f"By the {label}, the polyp is most visible at β = {f['x_peak']:.1f}° ± {f['x_peak_stderr']:.1f}° "
        f"(68 % range {f['x_peak_lo']:.1f}–{f['x_peak_hi']:.1f}°; the contrast varies with β, {_flat_words(f)}). "
        + against
    )


#: The answer's words for the colour criteria (the table's names for the others).
_ANSWER_LABELS = {
    "red_green_contrast": "red/green contrast (photofrin's red fluorescence against the wall)",
    "red_green_camera_contrast": "red/green contrast in the camera's channels (photofrin's red fluorescence "
    "against the wall)",
}


def _answer(fits, meta=None) -> str:
    """The report's answer: from the sweep's colour criterion (:func:`_light_criterion`: the one a target sweep
    ran to, else the camera channels under blue light and sRGB under white) when it varies with beta; else it
    says so, and the Weber contrasts that do vary answer in its place."""
    key, name = _light_criterion(meta)
    rg = fits[key]
    if rg["x_peak"] is None:
        return f"Too few β values with a defined {name} to locate a maximum."
    label = _ANSWER_LABELS.get(key, name)
    if _varies(rg):
        return "**Answer.** " + _peak_sentence(rg, label)
    text = (
        f"**Answer.** By the {label}, no β is shown to make the polyp more visible than another: the "
        f"contrast does not vary with β detectably beyond its standard errors ({_flat_words(rg)} ≥ "
        f"{ALPHA:g}), so its largest value, at β = {rg['x_max']:g}°, is noise, and it can neither confirm "
        "nor rule out the paper's 34°."
    )
    for other_key, other in _CRITERIA[2:4]:
        f = fits[other_key]
        if other_key != key and f["x_peak"] is not None and _varies(f):
            text += " " + _peak_sentence(f, other)
    return text


def _estimator(meta) -> str:
    """The sweep's camera estimator: "nee", "kernel", or "exitance" (also for "auto" and none given: a store run
    has no camera tally)."""
    vis = dict((meta or {}).get("visibility") or {})
    if view_runs._nee_estimator(vis):
        return "nee"
    return "kernel" if view_runs._kernel_estimator(vis) else "exitance"


def _records_words(meta) -> str:
    """Which records make each image (the report says so)."""
    if _estimator(meta) == "nee":
        return "Both images come from the `nee` estimator's own tallies of all the light and of the fluorescent light."
    if (meta or {}).get("fluorescent_only", True):
        return (
            "The fluorescence image (and the red/green contrast) is made of the store run's fluorescent records; "
            "the white-light image of a white pass, a run of its own seed that records every exit (all the light), "
            "so the white and fluorescence contrasts never share a record (`sweep.view_runs`)."
        )
    return "The white-light image is made of every stored exit (all the light), the fluorescence image of the fluorescent ones."


def _background_words(background, surround_px) -> str:
    if surround_px is None:
        return f"the whole region `{background}`"
    where = "" if background is None else f" of `{background}`"
    return f"the wall{where} seen in a ring of {surround_px:g} pixels around the target (docs/render.md)"


def _target_words(rows, meta) -> str:
    """The error each β reached, against a target sweep's request."""
    t = (meta or {}).get("contrast_target")
    if not t:
        return ""
    key = view_runs.CRITERIA[t["criterion"]][0]
    se = _column(rows, key + "_stderr")
    reached = sum(1 for r in rows if r.get("target_reached") == 1)
    packets = _column(rows, "view_packets" if t["criterion"] != "white" else "white_packets")
    worst = f"{np.nanmax(se):.3g}" if np.isfinite(se).any() else "n/a"
    spread = f"{np.nanmin(packets):,.0f}–{np.nanmax(packets):,.0f}" if np.isfinite(packets).any() else "n/a"
    return (
        f"Target: each β ran until the {t['criterion']} contrast's standard error was ≤ {t['stderr']:g} or "
        f"{t['max_packets']:,} packets were behind its image; {reached} of {len(rows)} β reached it (largest "
        f"stderr {worst}; packets per β {spread})."
    )


def visibility_report(
    betas,
    rows,
    target: str = "polyp",
    background: str | None = "wall",
    seed_per_beta: bool = True,
    surround_px=None,
    meta=None,
) -> str:
    """Markdown section answering the paper's question from the visibility columns, for every criterion;
    ``seed_per_beta`` says whether the betas ran with seeds of their own (independent errors: the flatness
    test holds its level) or with one seed (correlated errors: the test is conservative); ``surround_px`` and
    ``meta`` (the sweep's) word the background, the records of each image and a target sweep's errors."""
    fits = visibility_fits(betas, rows)
    lines = [
        "## At which β is the polyp most visible?",
        "",
        f"Visibility of `{target}` against {_background_words(background, surround_px)} in the endoscope's "
        "own view (ep.render_view), per β: Weber and Michelson contrasts of the mean fluorescence and "
        "white-light radiance and the red/green ratio contrast of the fluorescence image, each with a "
        "jackknife standard error over packet batches. " + _records_words(meta) + " The maximum is the "
        "vertex of a weighted parabola through the five points around the largest value; its uncertainty "
        "comes from a parametric bootstrap of the points within their standard errors (`visibility.fit_peak`). "
        "Whether a contrast depends on β at all is the chi-square test of one value for every β; at p ≥ "
        f"{ALPHA:g} it is flat: no β is a maximum, and the answer gives the band ±X around the weighted mean "
        "that holds every β's value at 2σ. " + _seed_words(seed_per_beta),
        "",
    ]
    if _target_words(rows, meta):
        lines += [_target_words(rows, meta), ""]
    lines += [
        "| criterion | answer | β at maximum | ± stderr | 68 % range | varies with β (p) | largest stderr |",
        "|---|---|---|---|---|---|---|",
    ]
    for key, label in _CRITERIA:
        f = fits[key]
        varies = "n/a" if f["flat_p"] is None else f"{'yes' if _varies(f) else 'no'} ({_p_text(f['flat_p'])})"
        se = _column(rows, key + "_stderr")
        worst = f"{np.nanmax(se):.3g}" if np.isfinite(se).any() else "n/a"
        lines.append(
            f"| {label} | {criterion_answer(f, rows, key, betas)} | {_fmt(f['x_peak'])}° | "
            f"{_fmt(f['x_peak_stderr'])}° | {_fmt(f['x_peak_lo'])}–{_fmt(f['x_peak_hi'])}° | {varies} | {worst} |"
        )
    lines += ["", _answer(fits, meta)]
    if surround_px is not None and np.isfinite(_column(rows, "region_red_green_contrast")).any():
        lines += ["", _surround_words(betas, rows, background, surround_px)]
    return "\n".join(lines) + "\n"


def _surround_words(betas, rows, background, surround_px) -> str:
    """The surround ring against the whole region: how far apart their contrasts are, in σ."""
    parts = []
    for key, label in (
        ("red_green_contrast", "red/green"),
        ("fluorescence_contrast", "fluorescence Weber"),
        ("white_contrast", "white-light Weber"),
    ):
        a, sa = _column(rows, key), _column(rows, key + "_stderr")
        b, sb = _column(rows, "region_" + key), _column(rows, "region_" + key + "_stderr")
        ok = np.isfinite(a) & np.isfinite(b) & np.isfinite(sa) & np.isfinite(sb)
        if ok.any():
            z = np.abs(a[ok] - b[ok]) / np.sqrt(sa[ok] ** 2 + sb[ok] ** 2)
            parts.append(
                f"{label}: ring {np.nanmean(a[ok]):.3g} against whole region {np.nanmean(b[ok]):.3g} on average, "
                f"up to {z.max():.1f} σ apart (σ of the two, taken as independent)"
            )
    return (
        f"**Surround against the whole region** ({VISIBILITY_FILES['surround']}): the contrast against the wall "
        f"in the {surround_px:g}-pixel ring and against all of `{background}`. " + "; ".join(parts) + "."
    )


def plot_surround(betas, rows, path) -> str:
    """The contrasts against the surround ring and against the whole background region, over β (PNG)."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure

    from ..io import atomic_write_bytes

    b = np.asarray(betas, dtype=np.float64)
    fig = Figure(figsize=(10, 3.8))
    for i, (key, label) in enumerate(
        (
            ("red_green_contrast", "red/green"),
            ("fluorescence_contrast", "fluorescence Weber"),
            ("white_contrast", "white-light Weber"),
        )
    ):
        ax = fig.add_subplot(1, 3, i + 1)
        for prefix, name, colour in (("", "surround ring", "tab:red"), ("region_", "whole region", "tab:gray")):
            y, se = _column(rows, prefix + key), _column(rows, prefix + key + "_stderr")
            ok = np.isfinite(y)
            if ok.any():
                ax.errorbar(
                    b[ok], y[ok], yerr=np.nan_to_num(se[ok]), fmt="o-", color=colour, capsize=3, label=name, ms=3
                )
        ax.set_xlabel("β (deg)")
        ax.set_title(label, fontsize=10)
        ax.legend(fontsize=7)
    fig.suptitle("Contrast of the target: against the surround ring and against the whole region")
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    return atomic_write_bytes(path, buf.getvalue())


def add_visibility(
    row: dict, result, beta: float, visibility, out_dir=None, run_more=None, contrast_target=None
) -> dict:
    """Sweep hook: add the visibility columns of one beta's run to its row, saving its views to
    ``out_dir/views/beta<β>_*.png`` when ``out_dir`` is given. ``visibility`` is a mapping with ``target``,
    ``background`` (a region, or None: every surface in the ring), optional ``surround_px`` (the ring's width
    in pixels: the background is the wall in that ring; None: the whole background region), ``white_packets``
    (the white pass's packets), ``images_dir`` (where the views go; default ``out_dir/views``) and
    ``render_view`` keyword arguments (width, height, kernel_radius, estimator, ...). ``run_more`` and
    ``contrast_target``: :func:`visibility_columns`. An undefined contrast is None, the sweep's mark for an
    undefined cell (never NaN); a top-up run that was cancelled sets the row's ``cancelled``."""
    vis = dict(visibility)
    try:
        target, background = vis.pop("target"), vis.pop("background")
    except KeyError as e:
        raise ValueError(f"visibility: missing key {e.args[0]!r} (give target and background regions)") from None
    img_dir = vis.pop("images_dir", None)
    if img_dir is None and out_dir is not None:
        img_dir = os.path.join(os.fspath(out_dir), "views")
    cols = visibility_columns(
        result,
        target,
        background,
        out_dir=img_dir,
        prefix=f"beta{float(beta):g}_",
        run_more=run_more,
        contrast_target=contrast_target,
        **vis,
    )
    if cols.pop("cancelled", 0):
        row["cancelled"] = 1
    row.update(no_nan({k: v for k, v in cols.items() if k in VISIBILITY_COLUMNS}))
    return row


def write_visibility_outputs(
    betas,
    rows,
    out_dir,
    target: str = "polyp",
    background: str | None = "wall",
    seed_per_beta: bool = True,
    surround_px=None,
    meta=None,
) -> dict:
    """After a sweep with visibility columns: ``visibility.png`` (plot with fitted maxima),
    ``views_contact_sheet.png`` (fluorescence views across beta, if saved), with a surround ring and a
    background region ``surround_vs_region.png``, and the report section (returned under ``"report"``; the
    caller appends it to report.md; :func:`visibility_report`)."""
    out = {"plot": plot_visibility(betas, rows, os.path.join(out_dir, VISIBILITY_FILES["plot"]))}
    views = [os.path.join(out_dir, "views", f"beta{float(b):g}_fluorescence.png") for b in betas]
    if views and all(os.path.exists(p) for p in views):
        out["contact_sheet"] = contact_sheet(views, betas, os.path.join(out_dir, VISIBILITY_FILES["contact_sheet"]))
    if surround_px is not None and np.isfinite(_column(rows, "region_red_green_contrast")).any():
        out["surround"] = plot_surround(betas, rows, os.path.join(out_dir, VISIBILITY_FILES["surround"]))
    out["report"] = visibility_report(
        betas, rows, target, background, seed_per_beta=seed_per_beta, surround_px=surround_px, meta=meta
    )
    return out


def _light_criterion(meta) -> tuple[str, str]:
    """The colour criterion of a sweep: the one a target sweep ran to; else camera channels under blue light
    (linear-sRGB G of red fluorescence is negative there), sRGB under white light."""
    t = (meta or {}).get("contrast_target")
    if t:  # the criterion the sweep ran to
        return next((k, name) for k, name in _CRITERIA if k == view_runs.CRITERIA[t["criterion"]][0])
    blue = "blue" in str((meta or {}).get("light", "white"))
    return (
        ("red_green_camera_contrast", "red/green contrast, camera channels")
        if blue
        else (
            "red_green_contrast",
            "red/green contrast",
        )
    )


def lights_report(sweeps) -> str:
    """Markdown comparing the answers of sweeps of one scene under different lights: ``sweeps`` is a list
    of ``(label, SweepResult)``. Per light: the colour contrast's answer (β at maximum ± error, 68 % range,
    or flat within ±X), its mean level over β with the error of that mean, the largest per-β error, and the
    paper's 34°; then the lights side by side."""
    lines = ["## The answer on the colon, under each light", ""]
    lines += [
        "| light | estimator | criterion | answer | mean contrast over β | largest stderr at a β | against the paper's 34° |",
        "|---|---|---|---|---|---|---|",
    ]
    levels = []
    for label, res in sweeps:
        estimator = _estimator(res.meta)
        key, name = _light_criterion(res.meta)
        rows, betas = res.rows, res.betas
        f = visibility_fits(betas, rows)[key]
        y, se = _column(rows, key), _column(rows, key + "_stderr")
        ok = np.isfinite(y) & np.isfinite(se) & (se > 0)
        if ok.any():
            w = 1.0 / se[ok] ** 2
            mean, mean_se = float(np.sum(w * y[ok]) / np.sum(w)), float(1.0 / math.sqrt(np.sum(w)))
            level = f"{mean:.3g} ± {mean_se:.2g}"
            levels.append((label, mean, mean_se, estimator))
        else:
            level = "n/a"
        worst = f"{np.nanmax(se):.3g}" if np.isfinite(se).any() else "n/a"
        if f["x_peak"] is not None and _varies(f) and f["vertex"] and f["x_peak_stderr"]:
            verdict, z = value_verdict(f["x_peak"], f["x_peak_stderr"], PAPER_BETA_DEG)
            paper = f"{abs(z):.1f} σ away: {'consistent' if verdict == 'consistent' else 'different'}"
        elif f["x_peak"] is not None and not _varies(f):
            paper = "flat: neither confirmed nor ruled out"
        else:
            paper = "no maximum fitted"
        answer = criterion_answer(f, rows, key, betas)
        lines.append(f"| {label} | {estimator} | {name} | {answer} | {level} | {worst} | {paper} |")
    if len(levels) >= 2:
        lines += ["", _lights_sentence(levels[0], levels[1])]
    return "\n".join(lines) + "\n"


def _lights_sentence(first, second) -> str:
    """The two lights' mean colour contrasts side by side, compared only when one estimator made both (the
    kernel estimate's contrast is biased against the next-event one's, docs/render.md)."""
    (la, a, sa, ea), (lb, b, sb, eb) = first, second
    text = f"Over the swept β the polyp's colour contrast averages {a:.3g} ± {sa:.2g} under {la} light and {b:.3g} ± {sb:.2g} under {lb} light"
    if ea != eb:
        return (
            text + f": not compared, since the {la} light's views come from the {ea} estimate and the {lb} light's "
            f"from the {eb} estimate, and the kernel estimate's contrast is biased (docs/render.md)."
        )
    z = abs(a - b) / math.hypot(sa, sb)
    return (
        text
        + f" ({z:.1f} σ apart): "
        + (f"{la if a > b else lb} light shows the polyp more clearly." if z >= SIGMAS else "no difference shown.")
        + " (Each light's criterion is in the table: under blue light the camera channels, since linear-sRGB "
        "G of red fluorescence seen through the long-pass filter is negative.)"
    )
