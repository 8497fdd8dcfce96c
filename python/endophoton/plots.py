"""Plots of a beta sweep, after the seed paper's Figs. 4-7 and 9 (matplotlib Agg, PNG).

Every figure is written atomically (rendered to memory, then temp file +
os.replace).  Error bars are the batch-means standard errors carried by the
:class:`~endophoton.sweep.schema.SweepResult` (for the maximum depth: the sd of the
per-batch maxima, a spread measure, see :mod:`endophoton.analysis`).
"""

from __future__ import annotations

import io
import os
from typing import Any

import numpy as np

import matplotlib

matplotlib.use("Agg", force=False)
from matplotlib.figure import Figure  # noqa: E402  (object API: no pyplot state, thread-safe)

from . import analysis as an  # noqa: E402
from .io import atomic_write_bytes  # noqa: E402
from .sweep.schema import PLOT_FILES, polar_plots  # noqa: E402

__all__ = ["plot_packets", "plot_energy", "plot_important", "plot_depth", "plot_polar", "plot_all", "PLOT_FILES"]


def _save(fig: Figure, path: str | os.PathLike) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    return atomic_write_bytes(path, buf.getvalue())


def _xy(result: Any, name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return result.betas, result.column(name), result.column(name + "_stderr")


def _line_axes(title: str, ylabel: str) -> tuple[Figure, Any]:
    fig = Figure(figsize=(6.4, 4.2))
    ax = fig.add_subplot(1, 1, 1)
    ax.set_title(title)
    ax.set_xlabel("tilt angle beta (deg)")
    ax.set_ylabel(ylabel)
    ax.grid(True, alpha=0.3)
    return fig, ax


def _plot_linear_fit(ax, x: np.ndarray, y: np.ndarray, slope_format: str) -> None:
    """Dashed least-squares line over the data range, its slope and R² in the legend (no line if undefined)."""
    fit = an.linear_fit(x, y)
    if np.isfinite(fit["slope"]):
        xx = np.linspace(x.min(), x.max(), 50)
        ax.plot(
            xx,
            fit["slope"] * xx + fit["intercept"],
            "--",
            label=f"linear fit, slope {slope_format.format(fit['slope'])}, R$^2$ {fit['r2']:.3f}",
        )


def plot_packets(result: Any, path: str | os.PathLike) -> str:
    """Packets traced to store N records vs beta (seed Fig. 4), with the linear fit."""
    b, y, e = _xy(result, "packets_traced")
    n = int(result.rows[0]["store"]) if result.rows else 0
    fig, ax = _line_axes(f"Packets traced to store {n:,} records", "packets traced")
    ax.errorbar(b, y, yerr=e, fmt="o-", capsize=3, label="simulation")
    _plot_linear_fit(ax, b, y, "{:.4g}/deg")
    ax.legend()
    return _save(fig, path)


def plot_energy(result: Any, path: str | os.PathLike, deg: int = 6) -> str:
    """Relative total surface energy vs beta (seed Fig. 5) with polynomial fits and their maxima.

    Two series, each divided by its maximum over beta: energy per packet traced,
    and the sum over the stored records (the seed's definition).
    """
    fig, ax = _line_axes("Total surface energy (relative to the maximum over beta)", "relative energy")
    for name, label, style in (
        ("energy_per_packet_rel", "per packet traced", "o"),
        ("energy_total_rel", "sum over stored records (seed)", "s"),
    ):
        b, y, e = _xy(result, name)
        line = ax.errorbar(b, y, yerr=e, fmt=style, capsize=3, label=label)
        pk = an.poly_peak(b, y, deg)
        if pk["deg"] >= 1:
            xx = np.linspace(b.min(), b.max(), 400)
            color = line[0].get_color()
            ax.plot(
                xx,
                np.polyval(pk["coeffs"], xx),
                "-",
                color=color,
                alpha=0.7,
                label=f"degree-{pk['deg']} fit, max at {pk['x_peak']:.1f} deg",
            )
            ax.plot([pk["x_peak"]], [pk["y_peak"]], "*", color=color, markersize=14)
    ax.legend(fontsize=8)
    return _save(fig, path)


def plot_important(result: Any, path: str | os.PathLike) -> str:
    """Fraction of stored records pointing to the camera vs beta (seed Fig. 6)."""
    b, y, e = _xy(result, "important_fraction")
    angle = result.meta.get("max_angle_deg", 15.0)
    fig, ax = _line_axes(
        f"Records visible to the camera and within {angle:g} deg of it", "fraction of stored records (%)"
    )
    ax.errorbar(b, 100 * y, yerr=100 * e, fmt="o-", capsize=3, label="simulation")
    _plot_linear_fit(ax, b, 100 * y, "{:.3g} %/deg")
    ax.legend()
    return _save(fig, path)


def plot_depth(result: Any, path: str | os.PathLike) -> str:
    """Maximum penetration depth vs beta (seed Fig. 7), drawn negative (below the surface) like the seed.

    Error bars: sd of the per-batch maxima; the open markers are their mean.
    """
    b = result.betas
    y = result.column("max_depth_cm")
    m = result.column("max_depth_batch_mean_cm")
    s = result.column("max_depth_batch_sd_cm")
    fig, ax = _line_axes("Maximum penetration depth", "depth (cm, negative = below the surface)")
    ax.plot(b, -y, "o-", label="deepest record")
    ax.errorbar(b, -m, yerr=s, fmt="o", mfc="none", capsize=3, label="mean +- sd of batch maxima")
    ax.legend(loc="best", fontsize=8)
    return _save(fig, path)


def plot_polar(result: Any, beta: float, path: str | os.PathLike, frame: str = "light") -> str:
    """Exit-direction histogram at ``beta`` as the seed's Fig. 9: two polar panels.

    Left: elevation rings 45-90 deg, right: 0-45 deg; one closed curve per
    ring, radius = record count, angle = azimuth; shaded band = count +- stderr.
    ``frame="light"``: azimuth 0 = toward the record's light (180 = away from
    it); ``frame="fixed"``: azimuth 0 = the horizontal direction toward the
    tilted head, the same for every record (see docs/sweep.md).
    """
    if frame not in ("light", "fixed"):
        raise ValueError(f"frame = {frame!r} must be 'light' or 'fixed'")
    h = result.histogram(beta)
    sfx = "" if frame == "light" else "_fixed"
    if "counts" + sfx not in h:
        raise ValueError(f"beta = {beta}: no '{frame}'-frame histogram in the result")
    counts = np.asarray(h["counts" + sfx], dtype=np.float64)
    stderr = np.asarray(h["stderr" + sfx], dtype=np.float64)
    n_elev, n_azim = counts.shape
    width = 90.0 / n_elev
    phi = np.radians((np.arange(n_azim) + 0.5) * 360.0 / n_azim)
    phi_c = np.append(phi, phi[0] + 2 * np.pi)
    fig = Figure(figsize=(11, 6.0))
    zero = "toward the record's light" if frame == "light" else "toward the tilted head (fixed)"
    fig.suptitle(
        f"Exit directions, beta = {beta:g} deg ({int(counts.sum()):,} records)\n"
        f"azimuth 0 = {zero}; radius = records per bin"
    )
    groups = (
        ("elevation 45-90 deg", [i for i in range(n_elev) if i * width >= 45 - 1e-9]),
        ("elevation 0-45 deg", [i for i in range(n_elev) if (i + 1) * width <= 45 + 1e-9]),
    )
    for k, (title, rings) in enumerate(groups):
        ax = fig.add_subplot(1, 2, k + 1, projection="polar")
        ax.set_title(title, pad=14)
        for i in rings:
            c = np.append(counts[i], counts[i, 0])
            e = np.append(stderr[i], stderr[i, 0])
            (line,) = ax.plot(phi_c, c, "-", lw=1.3, label=f"{i * width:g}-{(i + 1) * width:g} deg")
            ax.fill_between(phi_c, np.maximum(c - e, 0), c + e, color=line.get_color(), alpha=0.2, lw=0)
        ax.set_ylim(bottom=0)
        ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=7)
    fig.subplots_adjust(left=0.04, right=0.86, top=0.78, bottom=0.05, wspace=0.45)
    return _save(fig, path)


def plot_all(result: Any, out_dir: str | os.PathLike) -> list:
    """Write every plot of the sweep into ``out_dir``; returns the list of paths.

    Files: packets_traced.png, energy.png, camera_fraction.png, max_depth.png,
    polar_beta_<beta>.png (light frame) and polar_fixed_beta_<beta>.png (fixed
    frame, when the result has it) for every beta.
    """
    os.makedirs(out_dir, exist_ok=True)
    paths = [
        plot_packets(result, os.path.join(out_dir, PLOT_FILES["packets"])),
        plot_energy(result, os.path.join(out_dir, PLOT_FILES["energy"])),
        plot_important(result, os.path.join(out_dir, PLOT_FILES["important"])),
        plot_depth(result, os.path.join(out_dir, PLOT_FILES["depth"])),
    ]
    for beta, frame, name in polar_plots(result):
        paths.append(plot_polar(result, beta, os.path.join(out_dir, name), frame=frame))
    return paths
