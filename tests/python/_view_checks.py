"""Chi-square comparisons of camera images shared by the estimators' cross-checks (test_render_nee.py,
test_render_exitance.py): one owner of the rule that two images agree."""
from __future__ import annotations

import math

import numpy as np


def pixel_chi2(a, sa, b, sb, rel=0.25):
    """Chi-square of two images over the pixels where both have converged to ``rel`` relative error."""
    ok = (sa < rel * a) & (sb < rel * b)
    return float(np.sum((a - b)[ok] ** 2 / (sa[ok] ** 2 + sb[ok] ** 2))), int(ok.sum())


def assert_sees_scale_error(a, sa, b, sb, scale=1.2, power=0.9, rel=0.25):
    """Power of the agreement check (pixel_chi2 against chi2_limit): were ``a`` off by ``scale``, the
    check would fail with probability >= ``power``. Under that error the chi-square is noncentral, with
    the converged pixels' dof and noncentrality sum ((scale - 1) mu)^2 / (scale^2 sa^2 + sb^2), mu the
    two images' mean: a statement about the errors, not about one draw of the scaled image (which a
    changed random stream would turn over whenever the power is marginal). Arrays of one element test
    one value (dof 1: z against K_SIGMA)."""
    from scipy import stats

    from physics_helpers import chi2_limit

    a, sa, b, sb = (np.atleast_1d(np.asarray(x, dtype=float)) for x in (a, sa, b, sb))
    ok = (sa < rel * a) & (sb < rel * b)
    mu = 0.5 * (a + b)[ok]
    lam = float(np.sum(((scale - 1) * mu) ** 2 / (scale**2 * sa[ok] ** 2 + sb[ok] ** 2)))
    dof = int(ok.sum())
    assert dof >= 1, "no converged pixel"
    caught = float(stats.ncx2.sf(chi2_limit(dof), dof, lam))
    assert (
        caught >= power
    ), f"a {scale - 1:.0%} scale error is caught with probability {caught:.3f} (dof {dof}, noncentrality {lam:.1f})"


def aperture_region_chi2(view, other, regions, keys=("white", "fluorescence")):
    """Chi-square of ``view``'s regions' mean radiances against ``other``'s aperture image (the mean of its
    pixels in the region; its stderr from the pixels' stderrs, independent pixels); a region and image with no
    light in either (both errors 0) is skipped."""
    ra = view.regions()
    chi, dof = 0.0, 0
    for name in regions:
        m = other.region_map == other.region_names.index(name)
        for key in keys:
            L, S = other.aperture[key]["radiance"][m], other.aperture[key]["radiance_stderr"][m]
            sm = math.sqrt(float(np.sum(S**2))) / L.size
            se = math.hypot(ra[name][key + "_radiance_stderr"], sm)
            if se == 0:
                continue
            chi += ((ra[name][key + "_radiance"] - L.mean()) / se) ** 2
            dof += 1
    return chi, dof


def colon_scene(beta_deg=20.0):
    """bench/colon_scene.py's colon scene and rig at ``beta_deg`` (the cross-checks' colon view)."""
    import importlib.util
    import os

    here = os.path.dirname(os.path.abspath(__file__))
    spec = importlib.util.spec_from_file_location(
        "colon_scene", os.path.join(here, "..", "..", "bench", "colon_scene.py")
    )
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.colon_scene(beta_deg=beta_deg)
