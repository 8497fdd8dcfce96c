# SPDX-License-Identifier: MIT
"""The Sweep β panel's question, "at which β is the target most visible?": what the sweep is asked
(the ``visibility`` request of ``endophoton.sweep``, the command line's ``--target/--background
--view-size --estimator``) and the answer it gives (the package's visibility fit and report words).

One place to extend: a new option of the visibility sweep (e.g. a surround region, a target
accuracy) is a property of ``EndoPhotonSweepSettings``, its name in :data:`VISIBILITY_FIELDS` (the
panel draws them in that order) and its keyword in :func:`visibility_request`.  Nothing here
imports bpy at module level; the worker thread calls :func:`visibility_summary`.
"""

import math

from .errors import InputError

# Sweep settings the panel draws in its Visibility box, in order (see the module docstring).
VISIBILITY_FIELDS = ("target_region", "background_region", "view_size", "view_estimator")
# Labels that fit the default sidebar width beside their field ("" = the property's own name).
SHORT_LABELS = {
    "target_region": "Target",
    "background_region": "vs",
    "view_size": "View px",
    "view_estimator": "Estimator",
}
ROLE_ORDER = {"target": ("POLYP", "TISSUE"), "background": ("TISSUE", "POLYP")}
_ITEMS = {}  # Blender needs a dynamic enum's strings kept alive


def region_items(scene, which):
    """Enum items of the scene's regions (objects with a role) for the ``which`` picker
    ("target": polyps first, "background": tissue first, so the first item is the usual choice)."""
    order = ROLE_ORDER[which]
    regions = [obj for obj in scene.objects if obj.type == "MESH" and obj.endophoton.role in order]
    regions.sort(key=lambda obj: (order.index(obj.endophoton.role), obj.name))
    items = [(obj.name, obj.name, f"{obj.endophoton.role.capitalize()} region '{obj.name}'") for obj in regions]
    if not items:
        items = [("NONE", "(no region)", "Give meshes a role (Object panel) to choose regions")]
    return _ITEMS.setdefault((which, tuple(items)), items)


def visibility_request(settings, region_names, who):
    """The ``visibility`` keyword of ``endophoton.sweep`` for the scene's sweep ``settings`` (None
    when Visibility is off); raises InputError naming the field when a region is not in the scene
    or the target is the background.  No view files are written during the sweep (a cancelled sweep
    writes nothing); the plot and the report's section are written at the end."""
    if not settings.visibility:
        return None
    target, background = settings.target_region, settings.background_region
    for field, name in (("target_region", target), ("background_region", background)):
        if name not in region_names:
            raise InputError(
                f"{who}: sweep.{field} = '{name}' is not a region of the scene "
                f"({', '.join(region_names) or 'none'}); pick one in the Sweep β panel"
            )
    if target == background:
        raise InputError(f"{who}: sweep.target_region = sweep.background_region = '{target}'; pick two regions")
    if settings.view_size < 8:
        raise InputError(f"{who}: sweep.view_size = {settings.view_size} must be >= 8 pixels")
    size = settings.view_size
    estimator = str(settings.view_estimator).lower()
    return {"target": target, "background": background, "width": size, "height": size, "estimator": estimator}


def _answer_paragraph(view_sweep, result, vis):
    """The report's answer (its last paragraph, without the bold 'Answer.')."""
    text = view_sweep.visibility_report(
        result.betas,
        result.rows,
        vis["target"],
        vis["background"],
        seed_per_beta=bool(result.meta.get("seed_per_beta", False)),
    )
    last = text.strip().splitlines()[-1]
    return last.replace("**Answer.** ", "", 1).replace("**", "")


def visibility_summary(result):
    """Plain values of the answer of a visibility sweep (worker thread, no bpy): the β of largest
    red/green contrast ± its standard error, the p-value of "no dependence on β", the verdict
    against the paper's 34° and the report's answer sentence; {} for a sweep without visibility."""
    vis = result.meta.get("visibility")
    if not vis:
        return {}
    from endophoton.report import ALPHA, value_verdict
    from endophoton.sweep import view_sweep

    fit = view_sweep.visibility_fits(result.betas, result.rows)["red_green_contrast"]
    out = {
        "visibility_target": str(vis["target"]),
        "visibility_background": str(vis["background"]),
        "visibility_answer": _answer_paragraph(view_sweep, result, vis),
        "visibility_paper_beta": float(view_sweep.PAPER_BETA_DEG),
    }
    if fit["x_peak"] is None:
        out["visibility_verdict"] = "no fit: too few β values with a defined contrast"
        return out
    out["visibility_beta"] = float(fit["x_peak"])
    if fit["x_peak_stderr"] is not None and math.isfinite(fit["x_peak_stderr"]):
        out["visibility_beta_se"] = float(fit["x_peak_stderr"])
    if fit["flat_p"] is not None:
        out["visibility_p_flat"] = float(fit["flat_p"])
    if fit["flat_p"] is None or fit["flat_p"] >= ALPHA:
        out["visibility_verdict"] = "no β is shown to be better (contrast flat within its errors)"
    elif not fit["vertex"]:
        out["visibility_verdict"] = "largest at an end of the fitted points: widen the β range"
    else:
        se = fit["x_peak_stderr"]
        verdict, z = ("n/a", math.nan) if se is None else value_verdict(fit["x_peak"], se, view_sweep.PAPER_BETA_DEG)
        words = {"consistent": "consistent with", "differs": "differs from"}.get(verdict)
        paper = f"the paper's {view_sweep.PAPER_BETA_DEG:g}°"
        out["visibility_verdict"] = f"{words} {paper} ({abs(z):.1f} σ)" if words else f"no σ distance to {paper}"
    return out


def answer_rows(summary):
    """(label, value) rows of the answer for the panel ([] for a sweep without visibility)."""
    if "visibility_target" not in summary:
        return []
    rows = [
        (
            "Question",
            f"at which β is '{summary['visibility_target']}' most visible against "
            f"'{summary['visibility_background']}'?",
        )
    ]
    beta = summary.get("visibility_beta")
    if beta is not None:
        se = summary.get("visibility_beta_se")
        error = f" ± {se:.1f}" if se is not None else ""
        p = summary.get("visibility_p_flat")
        flat = f" (flat: p = {p:.2g})" if p is not None else ""
        rows.append(("Most visible β", f"{beta:.1f}{error}° by the red/green contrast{flat}"))
    rows.append(("Verdict", summary.get("visibility_verdict", "")))
    rows.append(("Answer", summary.get("visibility_answer", "")))
    return rows
