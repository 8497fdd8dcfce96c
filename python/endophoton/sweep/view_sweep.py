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

import numpy as np

from ..io import no_nan, unjson
from ..paper import PAPER_TRENDS
from ..view.render import render_view
from ..report import ALPHA, SIGMAS, value_verdict
from .schema import VISIBILITY_COLUMNS, VISIBILITY_FILES
from ..view.visibility import contrast, fit_peak

__all__ = [
    "PAPER_BETA_DEG",
    "VISIBILITY_COLUMNS",
    "visibility_columns",
    "add_visibility",
    "write_visibility_outputs",
    "visibility_fits",
    "plot_visibility",
    "contact_sheet",
    "visibility_report",
]

#: The seed paper's answer (its energy fit peaks near 34 deg): where pathological changes are best visible.
PAPER_BETA_DEG = float(PAPER_TRENDS["energy_peak_beta_deg"])
_SERIES = (
    ("red_green_contrast", "red/green contrast (fluorescence)"),
    ("fluorescence_contrast", "Weber contrast, fluorescence radiance"),
    ("white_contrast", "Weber contrast, white light"),
)


def visibility_columns(result, target: str, background: str, out_dir=None, prefix: str = "", **render_kwargs) -> dict:
    """Hook for the beta sweep: render the run's view and return the :data:`VISIBILITY_COLUMNS` as a
    flat, JSON-able dict (None where a contrast is undefined). ``render_kwargs`` go to ``render_view``;
    with ``out_dir`` the view's images and arrays are saved there with file names starting ``prefix``."""
    view = render_view(result, **render_kwargs)
    pixels = {field: view.pixels_of(name, field) for field, name in (("target", target), ("background", background))}
    if not all(pixels.values()):  # a region out of view (e.g. the polyp at a steep beta): undefined, not an error
        cols = {k: None for k in VISIBILITY_COLUMNS}
        cols["target_pixels"], cols["background_pixels"] = pixels["target"], pixels["background"]
        if out_dir is not None:
            view.save(out_dir, prefix=prefix)
        return cols
    c = contrast(view, target, background)
    cols = {}
    for key in ("fluorescence", "white", "red_green"):
        cols[key + "_contrast"] = c[key]
        cols[key + "_contrast_stderr"] = c[key + "_stderr"]
    cam = contrast(view, target, background, "camera")
    cols["red_green_camera_contrast"] = cam["red_green"]
    cols["red_green_camera_contrast_stderr"] = cam["red_green_stderr"]
    cols["target_pixels"], cols["background_pixels"] = pixels["target"], pixels["background"]
    if out_dir is not None:
        view.save(out_dir, prefix=prefix)
    return cols


def _column(rows, key):
    """Column ``key`` of ``rows`` as a float array for fits and plots: an undefined (None) cell is nan,
    which the fit leaves out and matplotlib does not draw."""
    return np.array([unjson(r.get(key)) for r in rows], dtype=np.float64)


def visibility_fits(betas, rows) -> dict:
    """:func:`visibility.fit_peak` of each visibility column over beta: {column: fit}."""
    b = np.asarray(betas, dtype=np.float64)
    return {key: fit_peak(b, _column(rows, key), _column(rows, key + "_stderr")) for key, _ in _SERIES}


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
    ("fluorescence_contrast", "fluorescence Weber contrast"),
    ("white_contrast", "white-light Weber contrast"),
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


def _answer(fits) -> str:
    """The report's answer: from the red/green contrast when it varies with beta; else it says so,
    and the other criteria that do vary answer in its place."""
    rg = fits["red_green_contrast"]
    if rg["x_peak"] is None:
        return "Too few β values with a defined red/green contrast to locate a maximum."
    label = "red/green contrast (photofrin's red fluorescence against the wall)"
    if _varies(rg):
        return "**Answer.** " + _peak_sentence(rg, label)
    text = (
        f"**Answer.** By the {label}, no β is shown to make the polyp more visible than another: the "
        f"contrast does not vary with β detectably beyond its standard errors ({_flat_words(rg)} ≥ "
        f"{ALPHA:g}), so its largest value, at β = {rg['x_max']:g}°, is noise, and it can neither confirm "
        "nor rule out the paper's 34°."
    )
    for key, other in _CRITERIA[1:]:
        f = fits[key]
        if f["x_peak"] is not None and _varies(f):
            text += " " + _peak_sentence(f, other)
    return text


def visibility_report(betas, rows, target: str = "polyp", background: str = "wall", seed_per_beta: bool = False) -> str:
    """Markdown section answering the paper's question from the visibility columns; ``seed_per_beta``
    says whether the betas ran with seeds of their own (independent errors: the flatness test holds
    its level) or with one seed (correlated errors: the test is conservative)."""
    fits = visibility_fits(betas, rows)
    lines = [
        "## At which β is the polyp most visible?",
        "",
        f"Visibility of `{target}` against `{background}` in the endoscope's own view (ep.render_view, "
        "kernel estimate), per β: Weber contrasts of the mean fluorescence and white-light radiance and "
        "the red/green ratio contrast of the fluorescence image, each with a jackknife standard error "
        "over packet batches. The maximum is the vertex of a weighted parabola through the five points "
        "around the largest value; its uncertainty comes from a parametric bootstrap of the points "
        "within their standard errors (`visibility.fit_peak`). Whether a contrast depends on β at all "
        "is the chi-square test of one value for every β; at p ≥ "
        f"{ALPHA:g} its largest value is not a maximum but noise. " + _seed_words(seed_per_beta),
        "",
        "| criterion | β at maximum | ± stderr | 68 % range | fitted maximum | inside the swept range | varies with β (p) |",
        "|---|---|---|---|---|---|---|",
    ]
    for key, label in _CRITERIA:
        f = fits[key]
        varies = "n/a" if f["flat_p"] is None else f"{'yes' if _varies(f) else 'no'} ({_p_text(f['flat_p'])})"
        lines.append(
            f"| {label} | {_fmt(f['x_peak'])}° | {_fmt(f['x_peak_stderr'])}° | "
            f"{_fmt(f['x_peak_lo'])}–{_fmt(f['x_peak_hi'])}° | {'yes' if f['vertex'] else 'no'} | "
            f"{'yes' if f['interior'] else 'no'} | {varies} |"
        )
    lines += ["", _answer(fits)]
    return "\n".join(lines) + "\n"


def add_visibility(row: dict, result, beta: float, visibility, out_dir=None) -> dict:
    """Sweep hook: add the visibility columns of one beta's run to its row, saving its views to
    ``out_dir/views/beta<β>_*.png`` when ``out_dir`` is given. ``visibility`` is a mapping with ``target``,
    ``background``, optional ``images_dir`` (where the views go; default ``out_dir/views``) and optional
    ``render_view`` keyword arguments (width, height, kernel_radius, ...). An undefined contrast is None,
    the sweep's mark for an undefined cell (never NaN)."""
    vis = dict(visibility)
    try:
        target, background = vis.pop("target"), vis.pop("background")
    except KeyError as e:
        raise ValueError(f"visibility: missing key {e.args[0]!r} (give target and background regions)") from None
    img_dir = vis.pop("images_dir", None)
    if img_dir is None and out_dir is not None:
        img_dir = os.path.join(os.fspath(out_dir), "views")
    cols = visibility_columns(result, target, background, out_dir=img_dir, prefix=f"beta{float(beta):g}_", **vis)
    row.update(no_nan(cols))
    return row


def write_visibility_outputs(
    betas, rows, out_dir, target: str = "polyp", background: str = "wall", seed_per_beta: bool = False
) -> dict:
    """After a sweep with visibility columns: ``visibility.png`` (plot with fitted maxima),
    ``views_contact_sheet.png`` (fluorescence views across beta, if saved) and the report section
    (returned under ``"report"``; the caller appends it to report.md). ``seed_per_beta``: whether
    the sweep ran every beta with a seed of its own (the report's words on the flatness test)."""
    out = {"plot": plot_visibility(betas, rows, os.path.join(out_dir, VISIBILITY_FILES["plot"]))}
    views = [os.path.join(out_dir, "views", f"beta{float(b):g}_fluorescence.png") for b in betas]
    if views and all(os.path.exists(p) for p in views):
        out["contact_sheet"] = contact_sheet(views, betas, os.path.join(out_dir, VISIBILITY_FILES["contact_sheet"]))
    out["report"] = visibility_report(betas, rows, target, background, seed_per_beta=seed_per_beta)
    return out
