"""Reduction of one store-N run to a row of the β sweep (seed §5, Figs. 4-9).

:func:`rig_geometry` reads the light positions and the camera of a rig;
:func:`analyse_run` reduces one run's surface photon map (escape records) to a
CSV row, the exit-direction histograms and the per-batch values, all through
:mod:`endophoton.analysis` (batch-means standard errors);
:func:`finish_relative` adds the columns relative to the sweep's maximum.
"""
from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np

from .. import analysis as an
from ..analysis.batches import _ratio_with_se
from ..io import finite_or_none, no_nan
from ..paper import IMPORTANT_ANGLE_DEG
from ..units import unit_cm

__all__ = ["rig_geometry", "analyse_run", "finish_relative"]


def _get(obj: Any, name: str, default: Any = None) -> Any:
    if isinstance(obj, Mapping):
        return obj.get(name, default)
    return getattr(obj, name, default)


def rig_geometry(rig: Any, unit: str = "cm", normal: Sequence[float] = (0.0, 0.0, 1.0)) -> dict:
    """Light positions (L,3) and pinhole camera of an endoscope rig, in scene units.

    Uses the rig's own ``light_positions(unit)`` and ``camera(unit)`` (methods of
    ``ep.EndoscopeRig``; plain attributes or dict entries are accepted too).
    Without them it derives both from the documented head frame
    (docs/design.md): ``rig.transform`` maps head -> world, the camera sits at
    the head origin looking along head -Z with head +Y up, the lights are at
    (+-light_offset_mm, 0, 0) in the head frame; fov and resolution from
    ``camera_fov_deg``/``camera_resolution``.
    Returns ``dict(light_positions=(L,3) array, camera=dict(position, forward,
    up, fov_deg, resolution), reference=3-vector)``.  ``reference`` is the
    fixed-frame azimuth-0 direction: the component of -camera.forward (from the
    target toward the head) perpendicular to the surface ``normal``; at beta = 0
    that vanishes and the line light 1 -> light 0 (the head's x axis, the
    same horizontal direction as the tilt for beta > 0) is used.
    """
    s_mm = 0.1 / unit_cm(unit)  # scene units per mm
    T = _get(rig, "transform")
    T = None if T is None else np.asarray(T, dtype=np.float64)
    if T is not None:
        R = T[:3, :3] / np.linalg.norm(T[:3, :3], axis=0)  # scale ignored, as the rig does
    lights = _get(rig, "light_positions")
    if callable(lights):
        lights = lights(unit)
    if lights is None and _get(rig, "lights") is not None:
        lights = [
            (_get(l, "center") if _get(l, "center") is not None else _get(l, "position")) for l in _get(rig, "lights")
        ]
    if lights is None:
        if T is None:
            raise ValueError("rig: has neither light_positions/lights nor transform")
        off = float(_get(rig, "light_offset_mm", 3.5)) * s_mm
        lights = [T[:3, 3] + R @ np.array([sx * off, 0.0, 0.0]) for sx in (1.0, -1.0)]
    lights = np.asarray(lights, dtype=np.float64).reshape(-1, 3)

    cam = _get(rig, "camera")
    if callable(cam):
        cam = cam(unit)
    keys = ("position", "forward", "up", "fov_deg", "resolution")
    if cam is not None and all(_get(cam, k) is not None for k in keys):
        camera = {k: _get(cam, k) for k in keys}
    else:
        if T is None:
            raise ValueError("rig: has neither camera nor transform")
        camera = dict(
            position=T[:3, 3].copy(),
            forward=-R[:, 2],
            up=R[:, 1].copy(),
            fov_deg=float(_get(rig, "camera_fov_deg", 120.0)),
            resolution=tuple(_get(rig, "camera_resolution", (256, 256))),
        )
    camera = {
        k: (np.asarray(v, dtype=np.float64) if k in ("position", "forward", "up") else v) for k, v in camera.items()
    }
    camera["resolution"] = tuple(int(x) for x in camera["resolution"])
    camera["fov_deg"] = float(camera["fov_deg"])
    n = np.asarray(normal, dtype=np.float64)
    n = n / np.linalg.norm(n)
    reference = None
    for cand in (
        -camera["forward"],
        (lights[0] - lights[-1]) if lights.shape[0] > 1 else None,
        np.array([1.0, 0.0, 0.0]),
        np.array([0.0, 1.0, 0.0]),
    ):
        if cand is None:
            continue
        r = cand - np.dot(cand, n) * n
        if np.linalg.norm(r) > 1e-9 * max(np.linalg.norm(cand), 1e-300):
            reference = r / np.linalg.norm(r)
            break
    return dict(light_positions=lights, camera=camera, reference=reference)


def analyse_run(
    escapes: Mapping[str, Any],
    packets_traced: int,
    light_positions: Any,
    camera: Any,
    n_batches: int = an.DEFAULT_BATCHES,
    max_angle_deg: float = IMPORTANT_ANGLE_DEG,
    n_elev: int = 10,
    n_azim: int = 36,
    reference: Any = None,
) -> tuple[dict, dict, dict]:
    """Reduce one run's escape records to (row, histogram, batches); see :data:`CSV_COLUMNS`.

    ``packets_traced`` is P for the batch means (packets 0..P-1 were traced).
    The exit-direction histogram is made in the light frame (azimuth 0 toward
    the record's light) and, if ``reference`` (world direction) is given, in the
    fixed frame too (``*_fixed`` keys; without it they are None).  An undefined value is
    ``None``, never NaN (:func:`endophoton.io.no_nan`): e.g. the chi-square p-values when no ring
    holds records, ``packets_traced_stderr`` when no record was stored per packet.
    """
    K = int(np.asarray(escapes["packet"]).shape[0]) if "packet" in escapes else 0
    if K == 0:
        raise ValueError("escapes['packet']: no records; nothing to analyse")
    B = n_batches
    P = int(packets_traced)
    rate, rate_se, rate_b = an.record_rate(escapes, P, B, return_batches=True)
    epp, epp_se, epp_b = an.total_energy(escapes, P, per_packet=True, n_batches=B, return_batches=True)
    epr, epr_se, epr_b = an.mean_energy_per_record(escapes, P, B, return_batches=True)
    imp, imp_se, imp_b = an.important_fraction(escapes, camera, max_angle_deg, B, P, return_batches=True)
    imp_count = int(an.important_mask(escapes, camera, max_angle_deg).sum())
    mdepth = an.max_depth(escapes)
    md_mean, md_sd, md_b = an.max_depth_spread(escapes, B, P, return_batches=True)
    low = [i for i in range(n_elev) if (i + 1) * 90.0 / n_elev <= 45.0 + 1e-9]
    high = [i for i in range(n_elev) if i * 90.0 / n_elev >= 45.0 - 1e-9]
    # rings that straddle 45 deg (odd n_elev) belong to neither group

    def frame(ref):
        counts, stderr, hb = an.exit_direction_histogram(
            escapes, light_positions, n_elev, n_azim, B, P, return_batches=True, reference=ref
        )
        a_low_b = an.azimuth_asymmetry(hb, low)
        a_high_b = an.azimuth_asymmetry(hb, high)
        pvals = an.azimuthal_uniformity_test(counts)
        finite_p = pvals[np.isfinite(pvals)]
        pmin = float(finite_p.min()) if finite_p.size else None
        vals = {
            "azimuth_asym_low": an.azimuth_asymmetry(counts, low),
            "azimuth_asym_low_stderr": an.batch_se(a_low_b),
            "azimuth_asym_high": an.azimuth_asymmetry(counts, high),
            "azimuth_asym_high_stderr": an.batch_se(a_high_b),
            "azimuth_chi2_p_min": pmin,
            "azimuth_chi2_p_bonferroni": min(1.0, pmin * finite_p.size) if finite_p.size else None,
        }
        return (
            vals,
            {"counts": counts, "stderr": stderr, "chi2_p": pvals},
            {"azimuth_asym_low": a_low_b, "azimuth_asym_high": a_high_b},
            hb,
        )

    vals, hist, fb, hb = frame(None)
    tot_b = hb.sum(axis=(1, 2))
    high_b = hb[:, high, :].sum(axis=(1, 2))
    hf, hf_se, hf_b = _ratio_with_se(high_b, tot_b)
    row = {
        "records": K,
        "packets_traced": P,
        "packets_traced_stderr": P * rate_se / rate if rate > 0 else None,
        "record_rate": rate,
        "record_rate_stderr": rate_se,
        "energy_per_packet": epp,
        "energy_per_packet_stderr": epp_se,
        "energy_per_record": epr,
        "energy_per_record_stderr": epr_se,
        "energy_total": epr * K,
        "energy_total_stderr": epr_se * K,
        "important_fraction": imp,
        "important_fraction_stderr": imp_se,
        "important_count": imp_count,
        "max_depth_cm": mdepth,
        "max_depth_batch_mean_cm": md_mean,
        "max_depth_batch_sd_cm": md_sd,
        **vals,
        "high_elevation_fraction": hf,
        "high_elevation_fraction_stderr": hf_se,
    }
    batches = {
        "energy_per_packet": epp_b,
        "energy_per_record": epr_b,
        "important_fraction": imp_b,
        "record_rate": rate_b,
        "max_depth_cm": md_b,
        **fb,
        "high_elevation_fraction": hf_b,
    }
    if reference is not None:
        vals_f, hist_f, fb_f, _ = frame(reference)
        row.update({_fixed_name(k): v for k, v in vals_f.items()})
        hist.update({k + "_fixed": v for k, v in hist_f.items()})
        batches.update({k + "_fixed": v for k, v in fb_f.items()})
    else:
        row.update({_fixed_name(k): None for k in vals})
    return no_nan(row), hist, batches


def _fixed_name(key: str) -> str:
    """Column name of ``key`` in the fixed frame: x -> x_fixed, x_stderr -> x_fixed_stderr."""
    return key[:-7] + "_fixed_stderr" if key.endswith("_stderr") else key + "_fixed"


def finish_relative(rows: list) -> None:
    """Fill the *_rel columns (value / max over the sweep); None where the value is undefined
    or the maximum is not a positive finite number (e.g. every value 0)."""
    for name in ("energy_per_packet", "energy_total"):
        vals = np.array([r[name] for r in rows], dtype=np.float64)  # None -> nan
        finite = vals[np.isfinite(vals)]
        mx = float(finite.max()) if finite.size else 0.0
        for r in rows:
            for suffix in ("", "_stderr"):
                v = r[name + suffix]
                r[name + "_rel" + suffix] = finite_or_none(v / mx) if mx > 0 and v is not None else None
