"""The β sweep's data: the CSV columns, :class:`SweepResult` and the β-list grammar.

A sweep result is a table with one row per tilt angle β (the keys of
:data:`CSV_COLUMNS`, documented in ``docs/sweep.md`` in the same order), plus
per row the exit-direction histograms and the per-batch values behind every
standard error.  It is written as CSV (the rows) and as strict JSON (format
``endophoton-sweep/1``, everything) and read back from the JSON.
"""
from __future__ import annotations

import argparse
import math
import os
import sys
from dataclasses import dataclass, field
from typing import Iterable

import numpy as np

from ..io import atomic_write_text, jsonable, read_json_file, unjson, write_json

__all__ = [
    "CSV_COLUMNS",
    "VISIBILITY_COLUMNS",
    "PLOT_FILES",
    "SweepResult",
    "parse_betas",
    "MAX_BETAS",
    "polar_filename",
    "polar_plots",
    "output_file_names",
    "VISIBILITY_FILES",
    "SEED_STEP",
    "beta_seed",
    "BETA_RESOLUTION_DEG",
    "beta_text",
    "check_beta_spacing",
]

# CSV columns: name -> description.  docs/sweep.md lists exactly these, in this order
# (tests/python/test_sweep.py checks that the documentation and the header agree).
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

# Visibility columns (endophoton.sweep.view_sweep.add_visibility; None unless the sweep ran with visibility=...).
VISIBILITY_COLUMNS = {
    "fluorescence_contrast": "Weber contrast of the target's mean fluorescence radiance against the background's "
    "(the wall in the surround ring with surround_px, else the whole background region)",
    "fluorescence_contrast_stderr": "jackknife standard error (packet batches)",
    "white_contrast": "Weber contrast in the white-light image, made of all the light: every exit of the white pass "
    "in a fluorescent-only sweep (never the fluorescence image's records), or of the run itself",
    "white_contrast_stderr": "jackknife standard error",
    "red_green_contrast": "Weber contrast of the R/G ratio of the fluorescence image's mean linear sRGB",
    "red_green_contrast_stderr": "jackknife standard error",
    "red_green_camera_contrast": "the same with camera-like non-negative R, G sensitivities (defined under "
    "blue light, where linear-sRGB G of red or blue-green light is negative)",
    "red_green_camera_contrast_stderr": "jackknife standard error",
    "fluorescence_michelson": "Michelson contrast (T - B) / (T + B) of the fluorescence radiance",
    "fluorescence_michelson_stderr": "jackknife standard error",
    "white_michelson": "Michelson contrast of the white-light radiance",
    "white_michelson_stderr": "jackknife standard error",
    "region_fluorescence_contrast": "with a surround ring and a named background region: fluorescence_contrast "
    "against the whole region (for comparison), else empty",
    "region_fluorescence_contrast_stderr": "jackknife standard error",
    "region_white_contrast": "white_contrast against the whole background region (surround sweeps), else empty",
    "region_white_contrast_stderr": "jackknife standard error",
    "region_red_green_contrast": "red_green_contrast against the whole background region (surround sweeps), else empty",
    "region_red_green_contrast_stderr": "jackknife standard error",
    "target_pixels": "pixels of the view that see the target region",
    "background_pixels": "pixels of the view in the background (the surround ring, or the whole region)",
    "view_packets": "packets behind the fluorescence image (the store run plus any top-ups of a target sweep)",
    "white_packets": "packets behind the white-light image (the white pass, or the run itself)",
    "target_reached": "target sweeps: 1 if the criterion's stderr reached the requested error, 0 if the cap "
    "stopped the beta first; else empty",
}
CSV_COLUMNS.update(VISIBILITY_COLUMNS)


#: Prefix of the per-region columns: ``absorbed_by_region.<region>`` and ``..._stderr``, the engine's
#: fraction of the launched weight absorbed in each region and its batch-means stderr (ep.run's
#: ``absorbed_by_region`` / ``absorbed_by_region_stderr``). They follow :data:`CSV_COLUMNS` in the
#: CSV, one pair per region of the sweep's scene, in the scene's order.
REGION_COLUMN = "absorbed_by_region."


def region_cells(res) -> dict:
    """The per-region cells of one run's row (:data:`REGION_COLUMN`), from its ``Result``."""
    values, errors = getattr(res, "absorbed_by_region", {}), getattr(res, "absorbed_by_region_stderr", {})
    cells = {}
    for name, v in values.items():
        cells[REGION_COLUMN + name] = float(v)
        cells[REGION_COLUMN + name + "_stderr"] = float(errors[name])
    return cells


def _csv_cell(text: str) -> str:
    """A header cell: quoted (RFC 4180) if a region's name holds a comma, a quote or a line break."""
    return '"' + text.replace('"', '""') + '"' if any(c in text for c in ',"\r\n') else text


def region_columns(rows) -> list:
    """The per-region column names the rows hold, in order of first appearance."""
    seen = {}
    for r in rows:
        seen.update((k, None) for k in r if k.startswith(REGION_COLUMN))
    return list(seen)


@dataclass
class SweepResult:
    """Result of :func:`sweep`.

    Attributes
    ----------
    rows : one dict per beta with the keys of :data:`CSV_COLUMNS`; an undefined value is None,
        never NaN (``null`` in the JSON file, an empty cell in the CSV).
    histograms : per row (same order) a dict with ``counts`` and ``stderr``
        (n_elev x n_azim float arrays, record counts) and ``chi2_p`` (per ring; nan for a ring
        without records: in numpy arrays nan marks an undefined entry, ``null`` in the JSON).
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
        """One CSV column over beta as a float array, for arithmetic and plots: a missing or undefined
        (None) cell is nan there (the rows themselves hold None)."""
        if name not in CSV_COLUMNS and not (name.startswith(REGION_COLUMN) and name in region_columns(self.rows)):
            raise ValueError(f"column '{name}' is not a sweep column")
        return np.array([unjson(r.get(name)) for r in self.rows], dtype=np.float64)

    def histogram(self, beta: float) -> dict:
        """The histogram dict of the row whose beta equals ``beta`` (degrees)."""
        for r, h in zip(self.rows, self.histograms):
            if abs(r["beta_deg"] - beta) < 1e-9:
                return h
        raise ValueError(f"beta = {beta} not in the sweep")

    def columns(self) -> list:
        """The CSV's columns: :data:`CSV_COLUMNS`, then the rows' per-region ones (:data:`REGION_COLUMN`)."""
        return list(CSV_COLUMNS) + region_columns(self.rows)

    def to_csv(self, path: str | os.PathLike) -> str:
        """Write the rows as CSV (header = CSV_COLUMNS keys, then the per-region columns
        :data:`REGION_COLUMN`; None, or a non-finite float, as an empty cell), atomically."""
        columns = self.columns()
        lines = [",".join(_csv_cell(c) for c in columns)]
        for r in self.rows:
            cells = []
            for k in columns:
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
        return jsonable(
            {
                "format": "endophoton-sweep/1",
                "meta": self.meta,
                "columns": CSV_COLUMNS,
                "rows": self.rows,
                "histograms": self.histograms,
                "batches": self.batches,
            }
        )

    def to_json(self, path: str | os.PathLike) -> str:
        """Write :meth:`to_dict` as strict JSON (non-finite -> null), atomically."""
        return write_json(path, self.to_dict())

    @classmethod
    def from_json(cls, path: str | os.PathLike) -> "SweepResult":
        """Read a file written by :meth:`to_json`: a ``null`` cell of a row comes back as None, arrays as
        numpy float arrays (``null`` -> nan)."""
        d = read_json_file(path, "sweep file")
        if d.get("format") != "endophoton-sweep/1":
            raise ValueError(f"{path}: format = {d.get('format')!r} is not endophoton-sweep/1")
        rows = [dict(r) for r in d["rows"]]
        arr = (
            lambda v: np.array([[unjson(x) for x in row] for row in v], dtype=np.float64)
            if v and isinstance(v[0], list)
            else np.array([unjson(x) for x in v], dtype=np.float64)
        )
        hists = [{k: arr(v) for k, v in h.items()} for h in d["histograms"]]
        batches = [{k: arr(v) for k, v in b.items()} for b in d["batches"]]
        return cls(rows=rows, histograms=hists, batches=batches, meta=d.get("meta", {}))


#: Most angles one β list may hold (``--betas``, ``ep.sweep(betas=...)``): each is a full run.
MAX_BETAS = 10_000

#: A seed per β (``ep.sweep(seed_per_beta=True)``, ``--seed-per-beta``): β k runs with
#: seed + k * SEED_STEP (mod 2^64), an odd step (2^64 / golden ratio), so that no two β of one
#: sweep share a seed.
SEED_STEP = 0x9E3779B97F4A7C15


def beta_seed(seed: int, k: int, per_beta: bool) -> int:
    """The engine seed of a sweep's k-th β: ``seed`` at every β (common random numbers), or with
    ``per_beta`` ``(seed + k * SEED_STEP) mod 2**64``, a seed of its own (independent runs)."""
    return (int(seed) + int(k) * SEED_STEP) % 2**64 if per_beta else int(seed)


#: Two β of one sweep must differ by at least this many degrees. A millionth of a degree tilts the
#: head of a rig 1 cm from the tissue by 0.2 nm, far below any length the geometry resolves; β values
#: closer than that are one angle run twice. It also keeps every fit over β well posed: numpy.polyfit
#: scales the Vandermonde columns by their norms, and β spaced 1e-200 apart make those inf/NaN, which
#: LAPACK (DLASCL) answers by ending the process. SweepResult.histogram matches β to 1e-9.
BETA_RESOLUTION_DEG = 1e-6


def beta_text(beta: float) -> str:
    """``beta`` (degrees) for a message, as given: the shortest text that reads back as the same
    float ("80", "89.99999", "1e-200"), never rounded as ``:g`` would (89.9999999 is not 90)."""
    text = repr(float(beta))
    return text[:-2] if text.endswith(".0") else text


def check_beta_spacing(betas: Iterable[float], field: str = "betas") -> None:
    """ValueError naming ``field`` and two values if two β (degrees) lie closer than
    :data:`BETA_RESOLUTION_DEG` (the same value twice included); the one check of the β lists of
    ``ep.sweep``, the command line's ``--betas`` and the add-on's ``sweep.betas``."""
    finite = sorted(float(b) for b in betas if math.isfinite(float(b)))
    for a, b in zip(finite, finite[1:]):
        if a == b:
            raise ValueError(f"{field}: β = {beta_text(a)} is given twice; give each angle once")
        if b - a < BETA_RESOLUTION_DEG:
            raise ValueError(
                f"{field}: β = {beta_text(a)} and β = {beta_text(b)} are closer than "
                f"{BETA_RESOLUTION_DEG:g} degrees, the sweep's resolution; drop one"
            )


def _count_text(n: float) -> str:
    """An angle count for a message: exact up to a million, else 3 digits (1e18)."""
    if not math.isfinite(n):
        return f"over {sys.float_info.max:.2g}".replace("e+", "e")
    return str(int(n)) if n < 1e6 else f"{n:.3g}".replace("e+", "e")


def parse_betas(text: str, field: str = "--betas", spacing: bool = True) -> list:
    """Parse ``"0,5,10"`` or ``"start:stop:step"`` (stop exclusive, like range) into floats (degrees).

    start and stop must be finite and step > 0 (a step beyond the range gives just start); at most
    :data:`MAX_BETAS` angles, counted before any list is built; no two closer than
    :data:`BETA_RESOLUTION_DEG` (:func:`check_beta_spacing`; ``spacing=False`` leaves that check to a
    caller that words its errors itself). Errors are ``argparse.ArgumentTypeError`` naming ``field``
    and the text.
    """
    text = str(text).strip()
    usage = f"{field} {text!r}: use '0,5,10' or 'start:stop:step'"
    if ":" in text:
        parts = text.split(":")
        try:
            if len(parts) != 3:
                raise ValueError
            start, stop, step = (float(x) for x in parts)
        except ValueError:
            raise argparse.ArgumentTypeError(usage) from None
        for name, v in (("start", start), ("stop", stop)):
            if not math.isfinite(v):
                raise argparse.ArgumentTypeError(f"{field} {text!r}: {name} = {v} must be a finite angle")
        if not step > 0:  # NaN too
            raise argparse.ArgumentTypeError(f"{field} {text!r}: step = {step} must be a positive number")
        span = stop - start  # inf if it overflows
        if span <= 0:
            n = 0.0
        elif math.isinf(step):
            n = 1.0
        else:
            q = span / step  # inf if it overflows
            # stop excluded up to rounding (0.3:0.9:0.2 is 3 angles); start < stop gives start at least
            n = q if not math.isfinite(q) or q > MAX_BETAS + 1 else max(1, math.floor(q - 1e-9) + 1)
        if n > MAX_BETAS:
            raise argparse.ArgumentTypeError(f"{field} {text!r} gives {_count_text(n)} angles, more than {MAX_BETAS}")
        vals = [start + k * step if k else start for k in range(int(n))]  # 0 * inf step is NaN
    else:
        try:
            vals = [float(x) for x in text.split(",") if x.strip()]
        except ValueError:
            raise argparse.ArgumentTypeError(usage) from None
        if len(vals) > MAX_BETAS:
            raise argparse.ArgumentTypeError(
                f"{field} {text[:40]!r}... gives {len(vals)} angles, more than {MAX_BETAS}"
            )
    if not vals:
        raise argparse.ArgumentTypeError(f"{field} {text!r}: no angles")
    try:
        if spacing:
            check_beta_spacing(vals, f"{field} {text!r}" if len(text) <= 60 else f"{field} {text[:40]!r}...")
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None
    return vals


#: File names of the sweep's trend plots (endophoton.plots), linked from report.md.
PLOT_FILES = {
    "packets": "packets_traced.png",
    "energy": "energy.png",
    "important": "camera_fraction.png",
    "depth": "max_depth.png",
}


def polar_filename(beta: float, frame: str = "light") -> str:
    """File name of the polar plot for ``beta`` (degrees), e.g. polar_beta_05.png, polar_fixed_beta_12.5.png."""
    stem = "polar_beta_" if frame == "light" else "polar_fixed_beta_"
    return f"{stem}{beta:02.0f}.png" if float(beta).is_integer() else f"{stem}{beta:g}.png"


#: File names of a sweep with visibility (endophoton.sweep.view_sweep): the plot and the contact sheet.
VISIBILITY_FILES = {
    "plot": "visibility.png",
    "contact_sheet": "views_contact_sheet.png",
    "surround": "surround_vs_region.png",
}


def polar_plots(result) -> list[tuple[float, str, str]]:
    """(beta, frame, file name) of every polar plot of ``result``: the light frame for each beta,
    the fixed frame too where the result has it."""
    out = []
    for beta in result.betas:
        out.append((float(beta), "light", polar_filename(beta)))
        if "counts_fixed" in result.histogram(float(beta)):
            out.append((float(beta), "fixed", polar_filename(beta, "fixed")))
    return out


def output_file_names(betas, visibility: bool = False, plots: bool = True, report: bool = True) -> list[str]:
    """The files endophoton.sweep.driver.write_outputs may write for a sweep over ``betas`` (degrees),
    by name in its folder: a superset (both polar frames for every beta), so that the command line
    can check them before the sweep runs."""
    names = ["sweep.csv", "sweep.json"]
    if plots:
        names += list(PLOT_FILES.values())
        names += [polar_filename(b, frame) for b in betas for frame in ("light", "fixed")]
        if visibility:
            names += list(VISIBILITY_FILES.values())
    if report:
        names.append("report.md")
    return names
