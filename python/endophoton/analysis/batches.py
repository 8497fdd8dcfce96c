"""Batch means over the escape records: the record columns checked by name, each record's
packet batch, and the standard errors of mean, ratio and sum statistics (the rules in
:mod:`endophoton.analysis`'s docstring)."""

from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np

DEFAULT_BATCHES = 20


# --------------------------------------------------------------------------
# validation helpers
# --------------------------------------------------------------------------


def _column(
    escapes: Mapping[str, Any], key: str, ndim: int, width: int | None = None, n: int | None = None
) -> np.ndarray:
    """Return ``escapes[key]`` as a numpy array after checking its shape.

    Raises ``ValueError`` naming ``key`` when it is missing, has the wrong shape,
    the wrong row count, or contains non-finite values.
    """
    if not isinstance(escapes, Mapping):
        raise ValueError(f"escapes must be a dict of numpy arrays, got {type(escapes).__name__}")
    if key not in escapes or escapes[key] is None:
        raise ValueError(f"escapes: missing key '{key}'")
    a = np.asarray(escapes[key])
    if a.ndim != ndim or (width is not None and a.shape[1] != width):
        want = f"(K,{width})" if width is not None else "(K,)"
        raise ValueError(f"escapes['{key}']: shape {a.shape} must be {want}")
    if n is not None and a.shape[0] != n:
        raise ValueError(f"escapes['{key}']: {a.shape[0]} rows, expected {n} (same as 'packet')")
    if a.dtype.kind not in "biuf":
        raise ValueError(f"escapes['{key}']: dtype {a.dtype} is not numeric")
    if a.dtype.kind == "f" and a.size and not np.all(np.isfinite(a)):
        raise ValueError(f"escapes['{key}']: contains non-finite values")
    return a


def _packets(escapes: Mapping[str, Any]) -> np.ndarray:
    p = _column(escapes, "packet", 1)
    if p.dtype.kind == "f":
        raise ValueError(f"escapes['packet']: dtype {p.dtype} must be an integer type")
    if p.size and p.dtype.kind == "i" and p.min() < 0:
        raise ValueError("escapes['packet']: negative packet index")
    return p.astype(np.int64)


def _unit_rows(a: np.ndarray, key: str) -> np.ndarray:
    a = a.astype(np.float64)
    norm = np.linalg.norm(a, axis=1)
    if a.shape[0] and np.any(norm < 1e-12):
        raise ValueError(f"escapes['{key}']: zero-length vector in row {int(np.argmax(norm < 1e-12))}")
    return a / norm[:, None]


def _check_batches(n_batches: int) -> int:
    if isinstance(n_batches, bool) or not isinstance(n_batches, (int, np.integer)) or n_batches < 2:
        raise ValueError(f"n_batches = {n_batches!r} must be an integer >= 2")
    return int(n_batches)


# --------------------------------------------------------------------------
# batch means
# --------------------------------------------------------------------------


def batch_index(
    packet: np.ndarray, n_batches: int = DEFAULT_BATCHES, n_packets: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Assign each record to a contiguous packet-index batch.

    Parameters
    ----------
    packet : (K,) integer array of packet indices.
    n_batches : number of batches B (>= 2).
    n_packets : number of packets traced P (default ``max(packet) + 1``).

    Returns
    -------
    batch : (K,) int array, batch id of each record in ``[0, B)``.
    packets_per_batch : (B,) int array, number of *packets* (not records) in
        each batch; batch ``b`` covers ``[floor(b P/B), floor((b+1) P/B))``.
    """
    B = _check_batches(n_batches)
    packet = np.asarray(packet).astype(np.int64)
    if n_packets is None:
        P = int(packet.max()) + 1 if packet.size else 0
    else:
        P = int(n_packets)
        if packet.size and int(packet.max()) >= P:
            raise ValueError(f"escapes['packet']: index {int(packet.max())} >= n_packets = {P}")
    if P < B:
        raise ValueError(f"n_packets = {P} must be >= n_batches = {B} for batch means")
    edges = (np.arange(B + 1, dtype=np.int64) * P) // B
    batch = np.searchsorted(edges, packet, side="right") - 1
    return batch.astype(np.int64), np.diff(edges)


def batch_se(values: np.ndarray) -> float:
    """Standard error of the mean of independent batch values: sd(ddof=1)/sqrt(B).

    Non-finite batch values (e.g. a ratio with an empty denominator) are left
    out; with fewer than two finite values the result is ``nan``.
    """
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    if v.size < 2:
        return float("nan")
    return float(np.std(v, ddof=1) / math.sqrt(v.size))


def _batch_sums(batch: np.ndarray, values: np.ndarray, B: int) -> np.ndarray:
    return np.bincount(batch, weights=np.asarray(values, dtype=np.float64), minlength=B)[:B]


def _ratio_with_se(num_b: np.ndarray, den_b: np.ndarray) -> tuple[float, float, np.ndarray]:
    """Overall ratio sum(num)/sum(den) and the batch-means stderr of per-batch ratios."""
    den_tot = float(np.sum(den_b))
    value = float(np.sum(num_b)) / den_tot if den_tot > 0 else float("nan")
    with np.errstate(divide="ignore", invalid="ignore"):
        ratios = np.where(den_b > 0, num_b / np.where(den_b > 0, den_b, 1.0), np.nan)
    return value, batch_se(ratios), ratios
