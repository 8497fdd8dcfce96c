"""The seed paper's beta sweep (§5, Figs. 4-9): tilt the endoscope head, store N photons, analyse.

For each tilt angle beta (degrees from the surface normal) the sweep builds the
endoscope rig with :meth:`endophoton.EndoscopeRig.from_beta`, runs the engine in
store-N mode (``ep.run(scene, rig, store=N, fluorescent_only=...)``) and reduces
the surface photon map with :mod:`endophoton.analysis`:

* packets traced to store N records (Fig. 4);
* total surface energy: per packet traced, per stored record and the sum over
  the stored records (the paper's "total power", Fig. 5), each also relative to
  its maximum over beta;
* the fraction of stored records that point to the camera (Fig. 6);
* the maximum penetration depth (Fig. 7);
* the exit-direction histogram, 10 elevation x 36 azimuth bins (Figs. 8-9),
  its per-ring azimuthal uniformity p-values and the azimuth asymmetry of the
  low (< 45 deg) and high (>= 45 deg) elevation rings.

Every statistic carries a batch-means standard error (B contiguous packet
batches, B = 20 by default; see :mod:`endophoton.analysis`).  The columns of the
CSV/JSON outputs are documented in ``docs/sweep.md``.

The same code runs in plain Python and inside Blender (:func:`sweep_blend`).
"""

from __future__ import annotations

import argparse
import inspect
import json
import math
import os
import sys
import tempfile
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Iterable, Mapping, Sequence

import numpy as np

from . import analysis as an
from . import meshes

__all__ = [
    "SweepResult",
    "sweep",
    "sweep_blend",
    "blender_regions_to_scene",
    "enable_addon",
    "analyse_run",
    "write_outputs",
    "default_flat_scene",
    "rig_geometry",
    "CSV_COLUMNS",
    "add_sweep_arguments",
    "sweep_main",
    "atomic_write_text",
    "atomic_write_bytes",
    "parse_betas",
]

UNIT_CM = {"m": 100.0, "cm": 1.0, "mm": 0.1}

# The paper's scene (seed §3 and §5; docs/sweep.md).  Lengths in cm.
TISSUE = dict(mua=20.0, mus=200.0, g=0.9, n=1.1)      # cm^-1, cm^-1, -, -
COLLAGEN = dict(d=0.2, c=0.4)
PHOTOFRIN = dict(d=0.1, c=0.33)

# --------------------------------------------------------------------------
# CSV columns: name -> description.  docs/sweep.md lists exactly these, in this order
# (tests/python/test_sweep.py checks that the documentation and the header agree).
# --------------------------------------------------------------------------
CSV_COLUMNS: dict[str, str] = {
    "beta_deg": "tilt of the endoscope head from the surface normal, degrees",
    "store": "records requested (store-N mode)",
    "records": "escape records actually stored",
    "packets_traced": "packets traced until the N-th record was stored",
    "packets_traced_stderr": "stderr of packets_traced: packets_traced x relative stderr of record_rate (delta method)",
    "record_rate": "records stored per packet traced",
    "record_rate_stderr": "batch-means stderr of record_rate",
    "energy_per_packet": "sum of record energy / packets traced (energy = weight x 500 nm / wavelength)",
    "energy_per_packet_stderr": "batch-means stderr of energy_per_packet",
    "energy_per_packet_rel": "energy_per_packet / its maximum over the sweep",
    "energy_per_packet_rel_stderr": "energy_per_packet_stderr / the same maximum (the maximum's own error ignored)",
    "energy_per_record": "mean energy of a stored record",
    "energy_per_record_stderr": "batch-means stderr of energy_per_record (ratio statistic)",
    "energy_total": "sum of the energy of the stored records (the seed's total power of the photon map)",
    "energy_total_stderr": "records x energy_per_record_stderr",
    "energy_total_rel": "energy_total / its maximum over the sweep",
    "energy_total_rel_stderr": "energy_total_stderr / the same maximum",
    "important_fraction": "fraction of stored records visible to the camera and within max_angle of the direction to it",
    "important_fraction_stderr": "batch-means stderr of important_fraction (ratio statistic)",
    "important_count": "number of important records",
    "max_depth_cm": "deepest max_depth of any stored record, cm (positive downward)",
    "max_depth_batch_mean_cm": "mean of the B per-batch maxima of max_depth, cm",
    "max_depth_batch_sd_cm": "sd of the B per-batch maxima of max_depth, cm (uncertainty proxy)",
    "azimuth_asym_low": "mean cos(azimuth) of records with elevation < 45 deg (negative = toward 180 deg, away from the light)",
    "azimuth_asym_low_stderr": "batch-means stderr of azimuth_asym_low",
    "azimuth_asym_high": "mean cos(azimuth) of records with elevation >= 45 deg",
    "azimuth_asym_high_stderr": "batch-means stderr of azimuth_asym_high",
    "high_elevation_fraction": "fraction of records with elevation >= 45 deg",
    "high_elevation_fraction_stderr": "batch-means stderr of high_elevation_fraction",
    "azimuth_chi2_p_min": "smallest per-ring azimuthal-uniformity chi-square p-value (10 rings)",
    "azimuth_chi2_p_bonferroni": "min(1, n_rings x azimuth_chi2_p_min)",
    "azimuth_asym_low_fixed": "as azimuth_asym_low in the fixed frame (azimuth 0 = horizontal direction toward the tilted head)",
    "azimuth_asym_low_fixed_stderr": "batch-means stderr of azimuth_asym_low_fixed",
    "azimuth_asym_high_fixed": "as azimuth_asym_high in the fixed frame",
    "azimuth_asym_high_fixed_stderr": "batch-means stderr of azimuth_asym_high_fixed",
    "azimuth_chi2_p_min_fixed": "as azimuth_chi2_p_min in the fixed frame",
    "azimuth_chi2_p_bonferroni_fixed": "as azimuth_chi2_p_bonferroni in the fixed frame",
    "seconds": "wall time of the engine run, s",
    "seed": "seed of the run",
    "cancelled": "1 if the run was cancelled (partial), else 0",
}


# --------------------------------------------------------------------------
# atomic file writes
# --------------------------------------------------------------------------

def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> str:
    """Write ``data`` to ``path`` atomically (temp file in the same folder + os.replace)."""
    path = os.fspath(path)
    folder = os.path.dirname(os.path.abspath(path))
    os.makedirs(folder, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix="." + os.path.basename(path) + ".", suffix=".tmp", dir=folder)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise
    return path


def atomic_write_text(path: str | os.PathLike, text: str) -> str:
    """Write UTF-8 ``text`` to ``path`` atomically."""
    return atomic_write_bytes(path, text.encode("utf-8"))


def _jsonable(x: Any) -> Any:
    """numpy -> Python; non-finite floats -> None (strict JSON)."""
    if isinstance(x, Mapping):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    if isinstance(x, (np.bool_, bool)):
        return bool(x)
    if isinstance(x, (np.integer, int)):
        return int(x)
    if isinstance(x, (np.floating, float)):
        return float(x) if math.isfinite(float(x)) else None
    return x


def _unjson(x: Any) -> float:
    return float("nan") if x is None else x


# --------------------------------------------------------------------------
# result container
# --------------------------------------------------------------------------

@dataclass
class SweepResult:
    """Result of :func:`sweep`.

    Attributes
    ----------
    rows : one dict per beta with the keys of :data:`CSV_COLUMNS`.
    histograms : per row (same order) a dict with ``counts`` and ``stderr``
        (n_elev x n_azim float arrays, record counts) and ``chi2_p`` (per ring).
    batches : per row a dict of per-batch arrays (length B) used for the
        batch-means standard errors of derived trends (``energy_per_packet``,
        ``energy_per_record``, ``important_fraction``, ``record_rate``,
        ``max_depth_cm``, ``azimuth_asym_low``, ``azimuth_asym_high``).
    meta : run settings (seed, store, n_batches, scene, rig parameters, ...).
    """

    rows: list = field(default_factory=list)
    histograms: list = field(default_factory=list)
    batches: list = field(default_factory=list)
    meta: dict = field(default_factory=dict)

    @property
    def betas(self) -> np.ndarray:
        """Tilt angles in degrees."""
        return np.array([r["beta_deg"] for r in self.rows], dtype=np.float64)

    def column(self, name: str) -> np.ndarray:
        """One CSV column over beta as a float array (missing values -> nan)."""
        if name not in CSV_COLUMNS:
            raise ValueError(f"column '{name}' is not a sweep column")
        return np.array([_unjson(r.get(name)) for r in self.rows], dtype=np.float64)

    def histogram(self, beta: float) -> dict:
        """The histogram dict of the row whose beta equals ``beta`` (degrees)."""
        for r, h in zip(self.rows, self.histograms):
            if abs(r["beta_deg"] - beta) < 1e-9:
                return h
        raise ValueError(f"beta = {beta} not in the sweep")

    def to_csv(self, path: str | os.PathLike) -> str:
        """Write the rows as CSV (header = CSV_COLUMNS keys; nan as empty), atomically."""
        lines = [",".join(CSV_COLUMNS)]
        for r in self.rows:
            cells = []
            for k in CSV_COLUMNS:
                v = r.get(k)
                if v is None or (isinstance(v, float) and not math.isfinite(v)):
                    cells.append("")
                elif isinstance(v, float):
                    cells.append(repr(float(v)))
                else:
                    cells.append(str(v))
            lines.append(",".join(cells))
        return atomic_write_text(path, "\n".join(lines) + "\n")

    def to_dict(self) -> dict:
        """JSON-able dict: ``format``, ``meta``, ``columns`` (descriptions), ``rows``, ``histograms``, ``batches``."""
        return _jsonable({
            "format": "endophoton-sweep/1",
            "meta": self.meta,
            "columns": CSV_COLUMNS,
            "rows": self.rows,
            "histograms": self.histograms,
            "batches": self.batches,
        })

    def to_json(self, path: str | os.PathLike) -> str:
        """Write :meth:`to_dict` as strict JSON (non-finite -> null), atomically."""
        return atomic_write_text(path, json.dumps(self.to_dict(), indent=1, allow_nan=False) + "\n")

    @classmethod
    def from_json(cls, path: str | os.PathLike) -> "SweepResult":
        """Read a file written by :meth:`to_json` (arrays come back as numpy float arrays)."""
        with open(path, "r", encoding="utf-8") as f:
            d = json.load(f)
        if d.get("format") != "endophoton-sweep/1":
            raise ValueError(f"{path}: format = {d.get('format')!r} is not endophoton-sweep/1")
        rows = [{k: _unjson(v) for k, v in r.items()} for r in d["rows"]]
        arr = lambda v: np.array([[_unjson(x) for x in row] for row in v], dtype=np.float64) \
            if v and isinstance(v[0], list) else np.array([_unjson(x) for x in v], dtype=np.float64)
        hists = [{k: arr(v) for k, v in h.items()} for h in d["histograms"]]
        batches = [{k: arr(v) for k, v in b.items()} for b in d["batches"]]
        return cls(rows=rows, histograms=hists, batches=batches, meta=d.get("meta", {}))


# --------------------------------------------------------------------------
# the paper's scene
# --------------------------------------------------------------------------

def default_flat_scene(unit: str = "cm", polyp: str | None = "dome", polyp_radius_cm: float = 0.3,
                       polyp_height_cm: float = 0.15, half_width_cm: float = 50.0,
                       thickness_cm: float = 10.0, mesh_resolution: tuple[int, int] = (24, 48)):
    """The seed's §5 scene, built with the package's scene API (``ep.Scene``).

    * ambient: air, n = 1;
    * ``tissue``: box ``[-half_width, half_width]^2 x [-thickness, 0]`` cm, n = 1.1,
      mua = 20 cm^-1, mus = 200 cm^-1, g = 0.9, fluorophore collagen d = 0.2, c = 0.4,
      priority 0.  10 cm is "infinitely thick" here: the reduced attenuation
      mua + mus (1 - g) = 40 cm^-1 gives ~0.1 cm penetration;
    * ``polyp`` (same optical properties; collagen d = 0.2, c = 0.4 and photofrin
      d = 0.1, c = 0.33), priority 1, centred at the origin:

      - ``"dome"`` (default): ellipsoid with semi-axes (r, r, h) about the
        origin; its lower half lies inside the tissue (the higher priority
        makes it polyp), the upper half is a flattened dome of height h above
        the surface z = 0;
      - ``"embedded"``: the lower half ellipsoid (bowl) with its flat lid 1e-4 cm
        below z = 0, so the surface stays exactly flat;
      - ``None``: no polyp.

    Lengths are given in cm and converted to ``unit`` ("m", "cm" or "mm").
    Returns an ``ep.Scene``.
    """
    import endophoton as ep

    if unit not in UNIT_CM:
        raise ValueError(f"unit = {unit!r} must be one of {sorted(UNIT_CM)}")
    if polyp not in ("dome", "embedded", None):
        raise ValueError(f"polyp = {polyp!r} must be 'dome', 'embedded' or None")
    s = 1.0 / UNIT_CM[unit]  # scene units per cm
    scene = ep.Scene(unit=unit, ambient_n=1.0)
    medium = ep.Medium(**TISSUE)
    collagen = ep.Fluorophore("collagen", COLLAGEN["d"], COLLAGEN["c"])
    photofrin = ep.Fluorophore("photofrin", PHOTOFRIN["d"], PHOTOFRIN["c"])
    w, t = half_width_cm * s, thickness_cm * s
    scene.add_box("tissue", min=(-w, -w, -t), max=(w, w, 0.0), medium=medium, priority=0,
                  fluorophores=[collagen])
    if polyp is not None:
        n_lat, n_lon = mesh_resolution
        radii = (polyp_radius_cm * s, polyp_radius_cm * s, polyp_height_cm * s)
        if polyp == "dome":
            v, tri = meshes.ellipsoid((0.0, 0.0, 0.0), radii, n_lat=n_lat, n_lon=n_lon)
        else:
            v, tri = meshes.half_ellipsoid((0.0, 0.0, -1e-4 * s), radii, n_lat=max(1, n_lat // 2),
                                           n_lon=n_lon, upper=False)
        scene.add_mesh("polyp", v, tri, medium, priority=1,
                       fluorophores=[ep.Fluorophore("collagen", COLLAGEN["d"], COLLAGEN["c"]), photofrin])
    return scene


# --------------------------------------------------------------------------
# rig geometry (light positions, camera) for the analysis
# --------------------------------------------------------------------------

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
    if unit not in UNIT_CM:
        raise ValueError(f"unit = {unit!r} must be one of {sorted(UNIT_CM)}")
    s_mm = 0.1 / UNIT_CM[unit]  # scene units per mm
    T = _get(rig, "transform")
    T = None if T is None else np.asarray(T, dtype=np.float64)
    if T is not None:
        R = T[:3, :3] / np.linalg.norm(T[:3, :3], axis=0)  # scale ignored, as the rig does
    lights = _get(rig, "light_positions")
    if callable(lights):
        lights = lights(unit)
    if lights is None and _get(rig, "lights") is not None:
        lights = [(_get(l, "center") if _get(l, "center") is not None else _get(l, "position"))
                  for l in _get(rig, "lights")]
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
        camera = dict(position=T[:3, 3].copy(), forward=-R[:, 2], up=R[:, 1].copy(),
                      fov_deg=float(_get(rig, "camera_fov_deg", 120.0)),
                      resolution=tuple(_get(rig, "camera_resolution", (256, 256))))
    camera = {k: (np.asarray(v, dtype=np.float64) if k in ("position", "forward", "up") else v)
              for k, v in camera.items()}
    camera["resolution"] = tuple(int(x) for x in camera["resolution"])
    camera["fov_deg"] = float(camera["fov_deg"])
    n = np.asarray(normal, dtype=np.float64)
    n = n / np.linalg.norm(n)
    reference = None
    for cand in (-camera["forward"], (lights[0] - lights[-1]) if lights.shape[0] > 1 else None,
                 np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])):
        if cand is None:
            continue
        r = cand - np.dot(cand, n) * n
        if np.linalg.norm(r) > 1e-9 * max(np.linalg.norm(cand), 1e-300):
            reference = r / np.linalg.norm(r)
            break
    return dict(light_positions=lights, camera=camera, reference=reference)


# --------------------------------------------------------------------------
# analysis of one run
# --------------------------------------------------------------------------

def analyse_run(escapes: Mapping[str, Any], packets_traced: int, light_positions: Any, camera: Any,
                n_batches: int = an.DEFAULT_BATCHES, max_angle_deg: float = 15.0,
                n_elev: int = 10, n_azim: int = 36, reference: Any = None) -> tuple[dict, dict, dict]:
    """Reduce one run's escape records to (row, histogram, batches); see :data:`CSV_COLUMNS`.

    ``packets_traced`` is P for the batch means (packets 0..P-1 were traced).
    The exit-direction histogram is made in the light frame (azimuth 0 toward
    the record's light) and, if ``reference`` (world direction) is given, in the
    fixed frame too (``*_fixed`` keys; without it they are nan).
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
        counts, stderr, hb = an.exit_direction_histogram(escapes, light_positions, n_elev, n_azim, B, P,
                                                         return_batches=True, reference=ref)
        a_low_b = an.azimuth_asymmetry(hb, low)
        a_high_b = an.azimuth_asymmetry(hb, high)
        pvals = an.azimuthal_uniformity_test(counts)
        finite_p = pvals[np.isfinite(pvals)]
        pmin = float(finite_p.min()) if finite_p.size else float("nan")
        vals = {"azimuth_asym_low": an.azimuth_asymmetry(counts, low), "azimuth_asym_low_stderr": an.batch_se(a_low_b),
                "azimuth_asym_high": an.azimuth_asymmetry(counts, high),
                "azimuth_asym_high_stderr": an.batch_se(a_high_b),
                "azimuth_chi2_p_min": pmin,
                "azimuth_chi2_p_bonferroni": min(1.0, pmin * finite_p.size) if finite_p.size else float("nan")}
        return vals, {"counts": counts, "stderr": stderr, "chi2_p": pvals}, \
            {"azimuth_asym_low": a_low_b, "azimuth_asym_high": a_high_b}, hb

    vals, hist, fb, hb = frame(None)
    tot_b = hb.sum(axis=(1, 2))
    high_b = hb[:, high, :].sum(axis=(1, 2))
    hf, hf_se, hf_b = an._ratio_with_se(high_b, tot_b)
    row = {
        "records": K,
        "packets_traced": P,
        "packets_traced_stderr": P * rate_se / rate if rate > 0 else float("nan"),
        "record_rate": rate, "record_rate_stderr": rate_se,
        "energy_per_packet": epp, "energy_per_packet_stderr": epp_se,
        "energy_per_record": epr, "energy_per_record_stderr": epr_se,
        "energy_total": epr * K, "energy_total_stderr": epr_se * K,
        "important_fraction": imp, "important_fraction_stderr": imp_se,
        "important_count": imp_count,
        "max_depth_cm": mdepth, "max_depth_batch_mean_cm": md_mean, "max_depth_batch_sd_cm": md_sd,
        **vals,
        "high_elevation_fraction": hf, "high_elevation_fraction_stderr": hf_se,
    }
    batches = {"energy_per_packet": epp_b, "energy_per_record": epr_b, "important_fraction": imp_b,
               "record_rate": rate_b, "max_depth_cm": md_b, **fb, "high_elevation_fraction": hf_b}
    if reference is not None:
        vals_f, hist_f, fb_f, _ = frame(reference)
        row.update({_fixed_name(k): v for k, v in vals_f.items()})
        hist.update({k + "_fixed": v for k, v in hist_f.items()})
        batches.update({k + "_fixed": v for k, v in fb_f.items()})
    else:
        row.update({_fixed_name(k): float("nan") for k in vals})
    return row, hist, batches


def _fixed_name(key: str) -> str:
    """Column name of ``key`` in the fixed frame: x -> x_fixed, x_stderr -> x_fixed_stderr."""
    return key[:-7] + "_fixed_stderr" if key.endswith("_stderr") else key + "_fixed"


def _finish_relative(rows: list) -> None:
    """Fill the *_rel columns (value / max over the sweep)."""
    for name in ("energy_per_packet", "energy_total"):
        vals = np.array([r[name] for r in rows], dtype=np.float64)
        finite = vals[np.isfinite(vals)]
        mx = float(finite.max()) if finite.size else float("nan")
        for r in rows:
            ok = math.isfinite(mx) and mx > 0
            r[name + "_rel"] = r[name] / mx if ok else float("nan")
            r[name + "_rel_stderr"] = r[name + "_stderr"] / mx if ok else float("nan")


# --------------------------------------------------------------------------
# the sweep
# --------------------------------------------------------------------------

def _call_builder(builder: Callable, beta: float):
    try:
        n_params = len([p for p in inspect.signature(builder).parameters.values()
                        if p.default is inspect.Parameter.empty
                        and p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD)])
    except (TypeError, ValueError):
        n_params = 1
    return builder(beta) if n_params >= 1 else builder()


def _rig_from_beta(rig_cls: Any, beta: float, distance: float, point, normal, tilt_axis, unit: str,
                   rig_kwargs: Mapping[str, Any]):
    """``rig_cls.from_beta(...)``; passes ``unit=`` only if from_beta names it (design.md lists it)."""
    kw = dict(beta_deg=float(beta), distance=float(distance), point=tuple(map(float, point)),
              normal=tuple(map(float, normal)), tilt_axis=tuple(map(float, tilt_axis)), **rig_kwargs)
    try:
        if "unit" in inspect.signature(rig_cls.from_beta).parameters:
            kw["unit"] = unit
    except (TypeError, ValueError):
        pass
    return rig_cls.from_beta(**kw)


def _scene_unit(scene: Any) -> str:
    unit = getattr(scene, "unit", None)
    if unit not in UNIT_CM:
        raise ValueError(f"scene.unit = {unit!r} must be one of {sorted(UNIT_CM)}")
    return unit


class _Progress:
    """tqdm bar over beta, with the engine's done/total shown as postfix (terminal only)."""

    def __init__(self, betas: Sequence[float], enabled: bool, user: Callable | None):
        self.user = user
        self.bar = None
        self._last = 0.0
        self._i = 0
        self._n = len(betas)
        if enabled:
            try:
                from tqdm import tqdm
                self.bar = tqdm(total=len(betas), desc="beta sweep", unit="beta", file=sys.stderr,
                                dynamic_ncols=True)
            except ImportError:  # pragma: no cover - tqdm is a dependency
                self.bar = None

    def start(self, i: int, beta: float) -> None:
        self._i = i
        if self.bar is not None:
            self.bar.set_description(f"beta = {beta:g} deg")

    def engine(self, done: int, total: int):
        """Engine progress callback; returns the user callback's value (False stops the run)."""
        now = time.monotonic()
        if self.bar is not None and now - self._last > 0.5:
            self._last = now
            self.bar.set_postfix_str(f"{done:,}/{total:,}" if total else f"{done:,} packets")
        if self.user is not None:
            return self.user(self._i, self._n, done, total)
        return None

    def step(self) -> None:
        if self.bar is not None:
            self.bar.update(1)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def sweep(scene_or_builder: Any = None, betas: Iterable[float] = range(0, 60, 5), store: int = 500_000,
          seed: int = 1, threads: int = 0, fluorescent_only: bool = True, fluorescence_rule: str = "paper",
          distance: float | None = None, point: Sequence[float] = (0.0, 0.0, 0.0),
          normal: Sequence[float] = (0.0, 0.0, 1.0), tilt_axis: Sequence[float] = (0.0, 1.0, 0.0),
          progress: bool | Callable = True, out_dir: str | os.PathLike | None = None,
          n_batches: int = an.DEFAULT_BATCHES, max_angle_deg: float = 15.0,
          rig_kwargs: Mapping[str, Any] | None = None, rig_builder: Callable | None = None,
          run_kwargs: Mapping[str, Any] | None = None, cancel: Any = None,
          plots: bool = True, report: bool = True, on_beta: Callable | None = None) -> SweepResult:
    """Run the seed's beta sweep and analyse every run.

    Parameters
    ----------
    scene_or_builder : an ``ep.Scene`` used for every beta, a callable
        ``builder(beta_deg) -> ep.Scene`` (or ``builder()``), or ``None`` for
        :func:`default_flat_scene`.
    betas : tilt angles, degrees.
    store : N, escape records to store per beta (store-N mode).
    seed : engine seed; the same seed is used for every beta (common random
        numbers make differences between betas less noisy).
    threads : engine threads (0 = all cores).
    fluorescent_only, fluorescence_rule : passed to ``ep.run``.
    distance : head distance from ``point`` in scene units (default 1 cm).
    point, normal, tilt_axis : see ``ep.EndoscopeRig.from_beta`` (scene units).
    progress : True = tqdm bar on stderr; False = silent; a callable
        ``progress(i_beta, n_beta, done, total)`` is called as the engine reports
        (returning False stops the current run, like a cancel).
    out_dir : if given, write ``sweep.csv``, ``sweep.json``, the plots and
        ``report.md`` there (``plots``/``report`` switch the last two).
    n_batches : B for the batch-means standard errors.
    max_angle_deg : angle criterion of the important fraction (seed: 15 deg).
    rig_kwargs : extra keyword arguments to ``EndoscopeRig.from_beta``.
    rig_builder : ``rig_builder(beta_deg, scene) -> rig`` replaces from_beta.
    run_kwargs : extra keyword arguments to ``ep.run``.
    cancel : an ``ep.CancelToken``; a cancelled run ends the sweep early.
    on_beta : a callable ``on_beta(i_beta, n_beta, row)`` called after each beta's
        run is analysed (``row`` is its CSV row, still without the ``*_rel``
        columns, which need every beta; ``row["packets_traced"]`` sizes the
        next run, e.g. for a progress estimate in store-N mode).

    Returns
    -------
    SweepResult (rows in the order of ``betas``).
    """
    import endophoton as ep

    betas = [float(b) for b in betas]
    if not betas:
        raise ValueError("betas: empty")
    if int(store) < n_batches:
        raise ValueError(f"store = {store} must be >= n_batches = {n_batches}")
    rig_kwargs = dict(rig_kwargs or {})
    run_kwargs = dict(run_kwargs or {})
    user_cb = progress if callable(progress) else None
    bar = _Progress(betas, enabled=(progress is True), user=user_cb)

    static_scene = None
    if scene_or_builder is None:
        static_scene = default_flat_scene()
    elif not callable(scene_or_builder) or hasattr(scene_or_builder, "add_mesh"):
        static_scene = scene_or_builder

    rows, hists, batches = [], [], []
    meta: dict = {
        "seed": int(seed), "store": int(store), "threads": int(threads), "n_batches": int(n_batches),
        "fluorescent_only": bool(fluorescent_only), "fluorescence_rule": fluorescence_rule,
        "max_angle_deg": float(max_angle_deg), "point": list(map(float, point)),
        "normal": list(map(float, normal)), "tilt_axis": list(map(float, tilt_axis)),
        "rig_kwargs": {k: v for k, v in rig_kwargs.items() if isinstance(v, (int, float, str, tuple, list))},
        "scene": "default_flat_scene(unit='cm', polyp='dome')" if scene_or_builder is None else
                 ("builder" if static_scene is None else "user scene"),
        "engine_version": getattr(ep, "__version__", None),
        "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "n_elev": 10, "n_azim": 36,
    }
    try:
        for i, beta in enumerate(betas):
            if cancel is not None and getattr(cancel, "cancelled", False):
                meta["cancelled_at_beta"] = beta   # cancelled between two runs: nothing to analyse
                break
            bar.start(i, beta)
            scene = static_scene if static_scene is not None else _call_builder(scene_or_builder, beta)
            unit = _scene_unit(scene)
            dist = (1.0 / UNIT_CM[unit]) if distance is None else float(distance)
            meta.setdefault("unit", unit)
            meta.setdefault("distance", dist)
            if rig_builder is not None:
                rig = rig_builder(beta, scene)
            else:
                rig = _rig_from_beta(ep.EndoscopeRig, beta, dist, point, normal, tilt_axis, unit, rig_kwargs)
            geo = rig_geometry(rig, unit, normal)
            kw = dict(store=int(store), fluorescent_only=bool(fluorescent_only),
                      fluorescence_rule=fluorescence_rule, seed=int(seed), threads=int(threads),
                      progress=bar.engine)
            if cancel is not None:
                kw["cancel"] = cancel
            kw.update(run_kwargs)
            t0 = time.perf_counter()
            res = ep.run(scene, rig, **kw)
            seconds = float(getattr(res, "seconds", time.perf_counter() - t0))
            esc = res.escapes
            if esc is None:
                raise ValueError("ep.run returned no escape records (record_escapes off?)")
            cancelled = bool(getattr(res, "cancelled", False))
            if cancelled and np.asarray(esc.get("packet", ())).size == 0:
                meta["cancelled_at_beta"] = beta   # cancelled before the first record: no row
                break
            P = int(getattr(res, "packets_traced", 0) or 0)
            if P <= 0:
                P = int(np.asarray(esc["packet"]).max()) + 1
            row, hist, bt = analyse_run(esc, P, geo["light_positions"], geo["camera"], n_batches, max_angle_deg,
                                        reference=geo["reference"])
            full = {"beta_deg": beta, "store": int(store), **row, "seconds": seconds, "seed": int(seed),
                    "cancelled": int(cancelled)}
            rows.append(full)
            hists.append(hist)
            batches.append(bt)
            meta.setdefault("light_positions", {})[f"{beta:g}"] = geo["light_positions"].tolist()
            meta.setdefault("camera", {})[f"{beta:g}"] = _jsonable(geo["camera"])
            meta.setdefault("azimuth_reference", {})[f"{beta:g}"] = _jsonable(geo["reference"])
            bar.step()
            if on_beta is not None:
                on_beta(i, len(betas), full)
            if cancelled:
                meta["cancelled_at_beta"] = beta
                break
    finally:
        bar.close()
    _finish_relative(rows)
    meta["cancelled"] = "cancelled_at_beta" in meta
    meta["finished"] = time.strftime("%Y-%m-%dT%H:%M:%S%z")
    result = SweepResult(rows=rows, histograms=hists, batches=batches, meta=meta)
    if out_dir is not None:
        write_outputs(result, out_dir, plots=plots, report=report)
    return result


def write_outputs(result: SweepResult, out_dir: str | os.PathLike, plots: bool = True,
                  report: bool = True) -> dict:
    """Write sweep.csv, sweep.json, the plots and report.md into ``out_dir``; returns the paths."""
    os.makedirs(out_dir, exist_ok=True)
    paths = {"csv": result.to_csv(os.path.join(out_dir, "sweep.csv")),
             "json": result.to_json(os.path.join(out_dir, "sweep.json"))}
    if plots and result.rows:   # a sweep cancelled before its first record has no rows to plot
        from . import plots as pl
        paths["plots"] = pl.plot_all(result, out_dir)
    if report and result.rows:
        from . import report as rp
        paths["report"] = rp.write_report(result, out_dir)
    return paths


# --------------------------------------------------------------------------
# Blender path
# --------------------------------------------------------------------------

def sweep_blend(blend: Any = None, use_blend_rig: bool = True, **kwargs) -> SweepResult:
    """Run :func:`sweep` on a Blender scene read through the add-on's export module.

    Must run inside Blender with the EndoPhoton add-on registered (its object
    properties hold the roles, media and fluorophores).  ``blend`` is a
    ``bpy.types.Scene``, a path to a ``.blend`` file (opened with
    ``bpy.ops.wm.open_mainfile``) or ``None`` for the current scene.

    * regions: ``endophoton_addon.export.export_regions(scene, view_layer,
      depsgraph)`` (evaluated meshes, world space, metres), added to an
      ``ep.Scene(unit="m")`` exactly as the add-on's own run does;
    * rig: rebuilt for each beta with ``EndoscopeRig.from_beta``.  With
      ``use_blend_rig`` and an endoscope rig in the scene (the scene's chosen
      rig, or its only one) its target, normal, tilt axis, distance and head
      dimensions are used (``endophoton_addon.rig.rig_parameters``); otherwise
      the defaults of :func:`sweep` (1 cm, origin, +z, tilt about y).  Keyword
      arguments given here win over both.

    The same regions, rig and seed give the same numbers as :func:`sweep` on an
    ``ep.Scene`` built from the same arrays in plain Python.  Keyword arguments
    are those of :func:`sweep`.
    """
    try:
        import bpy
    except ImportError as e:
        raise RuntimeError("sweep_blend must run inside Blender (the CLI's --blend starts it)") from e
    try:
        from endophoton_addon import export as addon_export
        from endophoton_addon import rig as addon_rig
    except ImportError as e:
        raise RuntimeError("the EndoPhoton add-on (endophoton_addon) is not importable in this Blender") from e
    import endophoton as ep

    if isinstance(blend, (str, os.PathLike)):
        bpy.ops.wm.open_mainfile(filepath=os.fspath(blend))
        bscene = bpy.context.scene
    elif blend is None:
        bscene = bpy.context.scene
    else:
        bscene = blend
    if not hasattr(bscene, "endophoton"):
        raise RuntimeError("the EndoPhoton add-on is not registered (scene.endophoton is missing)")
    view_layer = bpy.context.view_layer if bscene == bpy.context.scene else bscene.view_layers[0]
    depsgraph = bpy.context.evaluated_depsgraph_get() if bscene == bpy.context.scene else \
        bscene.view_layers[0].depsgraph
    regions = addon_export.export_regions(bscene, view_layer, depsgraph)
    scene = blender_regions_to_scene(ep, regions)

    kw = dict(kwargs)
    if use_blend_rig:
        chosen = bscene.endophoton.rig
        rigs = [chosen] if chosen is not None else list(addon_rig.find_rigs(bscene))
        if len(rigs) == 1:
            obj = rigs[0]
            scale = float(bscene.unit_settings.scale_length)
            rs = obj.endophoton_rig
            kw.setdefault("distance", float(rs.distance) * scale)
            kw.setdefault("point", tuple(float(x) * scale for x in rs.target))
            kw.setdefault("normal", tuple(float(x) for x in rs.normal))
            kw.setdefault("tilt_axis", tuple(float(x) for x in rs.tilt_axis))
            rk = dict(addon_rig.rig_parameters(obj, scale))
            rk.update(kw.get("rig_kwargs") or {})
            kw["rig_kwargs"] = rk
    result = sweep(scene, **kw)
    result.meta["scene"] = f"blender scene '{bscene.name}'" + (f" ({bpy.data.filepath})" if bpy.data.filepath else "")
    return result


def blender_regions_to_scene(ep: Any, regions: Sequence[Any]):
    """``ep.Scene(unit="m")`` from the add-on's ``RegionExport`` list (as the add-on's own run builds it)."""
    scene = ep.Scene(unit="m")
    for region in regions:
        fluorophores = [ep.Fluorophore(name, d, c) for name, d, c in region.fluorophores]
        scene.add_mesh(region.name, region.vertices, region.triangles, ep.Medium(**region.medium),
                       priority=region.priority, fluorophores=fluorophores)
    return scene


def _run_blender(args: argparse.Namespace) -> int:
    """Start ``blender -b FILE`` and run the sweep inside it (CLI --blend)."""
    import shutil
    import subprocess

    blender = shutil.which(os.environ.get("BLENDER", "blender"))
    if blender is None:
        print("error: blender not found (set $BLENDER)", file=sys.stderr)
        return 2
    pkg_parent = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    argv = _forward_argv(args)
    expr = ("import sys; sys.path.insert(0, %r); from endophoton import beta_sweep as s; "
            "sys.exit(s._blender_entry(%r))" % (pkg_parent, argv))
    # the .blend is opened by blender itself; _blender_entry enables the add-on first
    cmd = [blender, "-b", os.fspath(args.blend), "--python-exit-code", "1", "--python-expr", expr]
    env = dict(os.environ)
    env.setdefault("ENDOPHOTON_PYTHONPATH", pkg_parent)
    return subprocess.call(cmd, env=env)


def _forward_argv(args: argparse.Namespace) -> list:
    argv = ["--betas", ",".join(f"{b:g}" for b in args.betas), "--store", str(args.store),
            "--seed", str(args.seed), "--threads", str(args.threads), "--out", os.path.abspath(args.out),
            "--batches", str(args.batches), "--fluorescence-rule", args.fluorescence_rule]
    if args.distance is not None:
        argv += ["--distance", str(args.distance)]
    if args.all_photons:
        argv.append("--all-photons")
    if args.no_progress:
        argv.append("--no-progress")
    return argv


def enable_addon() -> None:
    """Inside Blender: make sure the EndoPhoton add-on is registered.

    Tries ``addon_utils.enable("endophoton_addon")`` (an installed add-on); if
    Blender does not know it, imports it from the source tree's ``addon/``
    folder (next to ``python/``) or from ``$ENDOPHOTON_ADDON_PATH`` and calls its
    ``register()``.
    """
    import bpy

    if hasattr(bpy.types.Scene, "endophoton"):
        return
    try:
        import addon_utils
        if any(m.__name__ == "endophoton_addon" for m in addon_utils.modules()):
            addon_utils.enable("endophoton_addon", default_set=False)
            if hasattr(bpy.types.Scene, "endophoton"):
                return
    except Exception:  # not installed as an add-on: fall back to the source tree
        pass
    here = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    folder = os.environ.get("ENDOPHOTON_ADDON_PATH") or os.path.join(here, "addon")
    if folder not in sys.path:
        sys.path.insert(0, folder)
    import endophoton_addon
    endophoton_addon.register()


def _blender_entry(argv: list) -> int:
    """Inside Blender: parse the forwarded arguments and sweep the open .blend."""
    p = argparse.ArgumentParser(prog="endophoton sweep (blender)")
    add_sweep_arguments(p)
    args = p.parse_args(argv)
    enable_addon()
    res = sweep_blend(None, **_sweep_kwargs(args))
    write_outputs(res, args.out)
    print(f"sweep: wrote {args.out}")
    return 0


# --------------------------------------------------------------------------
# CLI
# --------------------------------------------------------------------------

def parse_betas(text: str) -> list:
    """Parse ``"0,5,10"`` or ``"start:stop:step"`` (stop exclusive, like range) into floats (degrees)."""
    text = str(text).strip()
    try:
        if ":" in text:
            parts = [float(x) for x in text.split(":")]
            if len(parts) != 3 or parts[2] <= 0:
                raise ValueError
            start, stop, step = parts
            n = int(math.floor((stop - start) / step - 1e-9)) + 1
            vals = [start + k * step for k in range(max(n, 0))]
        else:
            vals = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"--betas {text!r}: use '0,5,10' or 'start:stop:step'") from None
    if not vals:
        raise argparse.ArgumentTypeError(f"--betas {text!r}: no angles")
    return vals


def add_sweep_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add the ``sweep`` subcommand's arguments to ``parser``."""
    parser.add_argument("--betas", type=parse_betas, default=parse_betas("0:60:5"),
                        help="tilt angles in degrees: '0,5,10' or 'start:stop:step' (default 0:60:5)")
    parser.add_argument("--store", type=int, default=500_000, help="records stored per beta (default 500000)")
    parser.add_argument("--seed", type=int, default=1, help="engine seed, same for every beta (default 1)")
    parser.add_argument("--threads", type=int, default=0, help="engine threads, 0 = all cores")
    parser.add_argument("--out", default="sweep_out", help="output folder (default ./sweep_out)")
    parser.add_argument("--blend", default=None,
                        help=".blend file: run the sweep on it inside 'blender -b' (default: the paper's scene)")
    parser.add_argument("--distance", type=float, default=None,
                        help="head distance from the target point, scene units (default 1 cm)")
    parser.add_argument("--batches", type=int, default=an.DEFAULT_BATCHES,
                        help="batches for batch-means standard errors (default 20)")
    parser.add_argument("--fluorescence-rule", choices=("paper", "eem"), default="paper")
    parser.add_argument("--all-photons", action="store_true",
                        help="store every escaping packet, not only fluorescent ones")
    parser.add_argument("--polyp", choices=("dome", "embedded", "none"), default="dome",
                        help="polyp of the default scene (default dome)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    return parser


def _sweep_kwargs(args: argparse.Namespace) -> dict:
    return dict(betas=args.betas, store=args.store, seed=args.seed, threads=args.threads,
                fluorescent_only=not args.all_photons, fluorescence_rule=args.fluorescence_rule,
                distance=args.distance, progress=not args.no_progress, n_batches=args.batches)


def sweep_main(args: argparse.Namespace) -> int:
    """Entry point of ``python -m endophoton sweep``; returns the exit code.

    Writes sweep.csv, sweep.json, the PNG plots and report.md into ``--out``.
    """
    if getattr(args, "blend", None):
        try:
            import bpy  # noqa: F401
            in_blender = True
        except ImportError:
            in_blender = False
        if not in_blender:
            return _run_blender(args)
        enable_addon()
        res = sweep_blend(args.blend, **_sweep_kwargs(args))
    else:
        polyp = None if args.polyp == "none" else args.polyp
        scene = default_flat_scene(polyp=polyp)
        res = sweep(scene, **_sweep_kwargs(args))
        res.meta["scene"] = f"default_flat_scene(unit='cm', polyp={polyp!r})"
    paths = write_outputs(res, args.out)
    print(f"sweep: {len(res.rows)} angle(s); wrote {paths['csv']}, {paths['json']}, "
          f"{len(paths.get('plots', []))} plot(s), {paths.get('report')}")
    return 130 if res.meta.get("cancelled") or any(r["cancelled"] for r in res.rows) else 0
