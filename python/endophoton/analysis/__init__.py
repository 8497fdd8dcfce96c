"""Analysis of the surface photon map (escape records) of an EndoPhoton run.

Everything here is pure numpy and works on the ``escapes`` dict described in
``docs/design.md`` (one row per escaped packet, in packet order).  Only the
keys a function needs are validated; malformed input raises ``ValueError``
whose message names the offending key.

Units
-----
* positions (``position``, light and camera positions): scene units;
* ``max_depth``: cm (as recorded by the engine);
* ``energy``: weight x 500 nm / wavelength (dimensionless, see design.md);
* angles: degrees unless a name ends in ``_rad``.

Standard errors: batch means
----------------------------
Every statistic carries a standard error computed by *batch means*.  The packet
index range ``[0, P)`` (``P`` = number of packets traced, default
``max(packet) + 1``) is split into ``B`` contiguous batches (``B = 20`` by
default); batch ``b`` holds the packets ``[floor(b P / B), floor((b+1) P / B))``
and therefore every record of those packets.  Packets are independent, so the
batches are independent replicas of the experiment.

* mean-type statistic per packet (e.g. energy per packet traced): evaluated per
  batch (batch sum / packets in the batch); value = overall estimate;
  stderr = sd(batch values, ddof=1) / sqrt(B);
* ratio statistic (e.g. important fraction = important / stored, mean energy per
  stored record): the ratio is computed per batch; value = overall ratio;
  stderr = sd(batch ratios, ddof=1) / sqrt(B) (batches whose denominator is 0 are
  left out and B is reduced accordingly);
* sum-type statistic (a histogram count = sum of the B batch counts):
  stderr = sqrt(B) * sd(batch counts, ddof=1), i.e. B times the standard error
  of the batch mean;
* maximum (``max_depth``): the maximum has no batch-means standard error; we
  report the per-batch maxima's mean and sd as a spread measure
  (:func:`max_depth_spread`).

Undefined values: these are numeric helpers, and an undefined statistic (a ratio
over nothing, a fit through fewer than two points) is ``nan`` here, the working
value of numpy arithmetic.  A result the package returns turns it into ``None``
(:func:`endophoton.io.no_nan`: the sweep rows, ``report.compute_trends``).

Modules (one concept each): :mod:`.batches` (record columns, batch means), :mod:`.reductions`
(energy, record rate, depth), :mod:`.directions` (exit angles and their histogram, azimuthal
uniformity), :mod:`.chi_square`, :mod:`.importance` (what the camera sees), :mod:`.trends` (fits over a
sweep). This package re-exports their public names.
"""

from __future__ import annotations

from .batches import DEFAULT_BATCHES, batch_index, batch_se
from .chi_square import chi2_sf
from .directions import (
    azimuth_asymmetry,
    azimuthal_uniformity_test,
    exit_angles,
    exit_direction_histogram,
    ring_bin_edges,
)
from .importance import important_fraction, important_mask
from .reductions import max_depth, max_depth_spread, mean_energy_per_record, record_rate, total_energy
from .trends import linear_fit, pearson_r, poly_peak, polyfit_ready

__all__ = [
    "DEFAULT_BATCHES",
    "batch_index",
    "batch_se",
    "exit_direction_histogram",
    "exit_angles",
    "important_mask",
    "important_fraction",
    "total_energy",
    "mean_energy_per_record",
    "record_rate",
    "max_depth",
    "max_depth_spread",
    "azimuthal_uniformity_test",
    "chi2_sf",
    "azimuth_asymmetry",
    "ring_bin_edges",
    "linear_fit",
    "pearson_r",
    "poly_peak",
    "polyfit_ready",
]
