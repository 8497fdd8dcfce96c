"""Reductions of the escape records with batch-means errors: escaped energy (total, per packet,
per record), records per packet, and the deepest record with its spread."""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from .batches import DEFAULT_BATCHES, _batch_sums, _check_batches, _column, _packets, _ratio_with_se, batch_index
from .batches import batch_se


def total_energy(
    escapes: Mapping[str, Any],
    n_packets: int | None = None,
    per_packet: bool = False,
    n_batches: int = DEFAULT_BATCHES,
    return_batches: bool = False,
):
    """Total energy of the escape records (units of ``energy``: weight x 500 nm / lambda).

    ``per_packet=False`` (default): value = sum of ``energy`` over all records.
    ``per_packet=True``: value = that sum / P, the energy escaping per packet
    traced (P = ``n_packets``, default ``max(packet)+1``).

    Standard error: per batch b the energy per packet e_b = (sum of energy in
    batch b) / (packets in batch b); se(per packet) = sd(e_b)/sqrt(B); the total
    is P x (energy per packet), so se(total) = P x se(per packet).
    Returns ``(value, stderr)`` (+ per-batch per-packet values if ``return_batches``).
    """
    B = _check_batches(n_batches)
    packet = _packets(escapes)
    e = _column(escapes, "energy", 1, None, packet.shape[0]).astype(np.float64)
    batch, ppb = batch_index(packet, B, n_packets)
    P = int(ppb.sum())
    sums = _batch_sums(batch, e, B)
    per = sums / ppb
    se_per = batch_se(per)
    total = float(e.sum())
    if per_packet:
        out = (total / P, se_per)
    else:
        out = (total, P * se_per)
    return (*out, per) if return_batches else out


def mean_energy_per_record(
    escapes: Mapping[str, Any],
    n_packets: int | None = None,
    n_batches: int = DEFAULT_BATCHES,
    return_batches: bool = False,
):
    """Mean ``energy`` per stored record (ratio statistic: per-batch ratio, sd/sqrt(B)).

    The seed's "total energy of the N stored photons" is N times this value.
    """
    B = _check_batches(n_batches)
    packet = _packets(escapes)
    e = _column(escapes, "energy", 1, None, packet.shape[0]).astype(np.float64)
    if packet.size == 0:
        raise ValueError("escapes['packet']: no records")
    batch, _ = batch_index(packet, B, n_packets)
    value, se, ratios = _ratio_with_se(_batch_sums(batch, e, B), _batch_sums(batch, np.ones(e.size), B))
    return (value, se, ratios) if return_batches else (value, se)


def record_rate(
    escapes: Mapping[str, Any], n_packets: int, n_batches: int = DEFAULT_BATCHES, return_batches: bool = False
):
    """Records stored per packet traced (records / P), with batch-means stderr.

    In store-N mode the number of packets traced is N / rate, so its relative
    stderr equals the relative stderr of the rate (delta method).
    """
    B = _check_batches(n_batches)
    packet = _packets(escapes)
    batch, ppb = batch_index(packet, B, n_packets)
    per = _batch_sums(batch, np.ones(packet.size), B) / ppb
    value = packet.size / float(ppb.sum())
    se = batch_se(per)
    return (value, se, per) if return_batches else (value, se)


def max_depth(escapes: Mapping[str, Any]) -> float:
    """Deepest ``max_depth`` over all records, in cm (positive = below the entry surface).

    The seed paper plots this as a negative number (about -0.12 cm).
    """
    md = _column(escapes, "max_depth", 1)
    if md.size == 0:
        raise ValueError("escapes['max_depth']: no records")
    return float(md.max())


def max_depth_spread(
    escapes: Mapping[str, Any],
    n_batches: int = DEFAULT_BATCHES,
    n_packets: int | None = None,
    return_batches: bool = False,
):
    """Uncertainty proxy for :func:`max_depth`: mean and sd (ddof=1) of the B per-batch maxima (cm).

    A sample maximum has no batch-means standard error (it is not an average);
    the spread of the batch maxima shows how much the deepest record fluctuates
    between independent sub-runs of P/B packets.  Note the batch maxima are
    biased low relative to the full-run maximum.  Batches without records are
    left out.
    """
    B = _check_batches(n_batches)
    packet = _packets(escapes)
    md = _column(escapes, "max_depth", 1, None, packet.shape[0]).astype(np.float64)
    if md.size == 0:
        raise ValueError("escapes['max_depth']: no records")
    batch, _ = batch_index(packet, B, n_packets)
    mx = np.full(B, -np.inf)
    np.maximum.at(mx, batch, md)
    mx = np.where(np.isfinite(mx), mx, np.nan)
    good = mx[np.isfinite(mx)]
    mean = float(good.mean())
    sd = float(good.std(ddof=1)) if good.size > 1 else float("nan")
    return (mean, sd, mx) if return_batches else (mean, sd)
