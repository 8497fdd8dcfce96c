"""Chi-square comparisons of camera images shared by the estimators' cross-checks (test_render_nee.py,
test_render_exitance.py): one owner of the rule that two images agree."""
from __future__ import annotations

import math

import numpy as np


def pixel_chi2(a, sa, b, sb, rel=0.25):
    """Chi-square of two images over the pixels where both have converged to ``rel`` relative error."""
    ok = (sa < rel * a) & (sb < rel * b)
    return float(np.sum((a - b)[ok] ** 2 / (sa[ok] ** 2 + sb[ok] ** 2))), int(ok.sum())


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
