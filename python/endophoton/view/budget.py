"""The render's memory budget: what a view of width x height pixels will hold, checked before anything is allocated.

A view keeps per-pixel, per-batch sums (radiance, X, Y, Z, camera R, G, each for the white and the
fluorescence image) besides its images and per-pixel spectra, so its memory grows with
pixels x batches: about 4.3 kB a pixel at the default 20 batches, 4.5 GB at 1024 x 1024 and 290 GB at the
largest side the sources accept (8192, ``sources.MAX_IMAGE_SIDE``). :func:`render_memory_bytes` states that
cost from the sizes alone; :func:`check_render_memory` refuses, naming width and height, a render that would
need more than the budget (``RENDER_MEMORY_BUDGET_BYTES``, or the caller's ``memory_budget_bytes``).
``render_view``, the run's camera tally (``ep.run(..., view=...)``) and ``render`` on the command line check
it before they trace or allocate anything (docs/numerics.md, "Limits"; docs/render.md, "Memory").
"""
from __future__ import annotations

import math

from . import colour
from .camera import DEFAULT_VIEW_BATCHES

__all__ = ["RENDER_MEMORY_BUDGET_BYTES", "render_memory_bytes", "check_render_memory"]

#: The default memory budget of one render (bytes): 4 GiB.
RENDER_MEMORY_BUDGET_BYTES = 4 * 2**30

# Doubles a pixel holds (measured with tracemalloc at 192^2, 2 to 100 batches, kernel, aperture and nee
# estimators; docs/render.md "Memory"): 20 per batch (the accumulated sums and the View's per-batch copies)
# plus 2.5 per spectrum bin plus 110 (rays, hit points, images); an aperture image adds 2 per batch and one
# per bin. Each term is an upper bound of the measured peak (10-14 % above it).
_PER_BATCH, _PER_BIN, _PER_PIXEL = 20, 2.5, 110
_APERTURE_PER_BATCH, _APERTURE_PER_BIN = 2, 1
_PER_RECORD = 32  # doubles per escape record: positions, directions, colour tables, batch, filters
# The exitance estimate's extra doubles per record (normals, regions, bands, its angular tables' Legendre rows and
# calibration sums): measured 35 a record in all at 1.4 M records (tracemalloc, colon, 128^2), the kernel's 23.
_EXITANCE_PER_RECORD = 8
#: The most pixel-record pairs the kernel gather holds at once (render._pixel_chunks splits a chunk of pixels
#: below it), so the pairs in flight take at most MAX_PAIRS_PER_CHUNK x _PAIR_BYTES whatever the kernel's size
#: or the records' density.
MAX_PAIRS_PER_CHUNK = 2**16
_PAIR_BYTES = 256
_TALLY_CHANNELS = 12  # the run's camera tally: (pixels, batches, 12) sums and (pixels, 2, bins) spectra


def render_memory_bytes(
    width, height, n_batches=DEFAULT_VIEW_BATCHES, records=0, aperture=False, tally=False, exitance=False
) -> int:
    """Bytes a render of ``width`` x ``height`` pixels with ``n_batches`` batches will need at its peak,
    over ``records`` escape records (0 when not yet known), with an ``aperture`` image, with ``tally`` the
    run's next-event camera tally (ep.run(..., view=...)) it reads, and with ``exitance`` the exitance
    estimate. An upper bound of the measured peak, not counting the run's own photon records."""
    pixels = int(width) * int(height)
    B = int(n_batches)
    nbins = colour.spectrum_bins().size - 1
    per_pixel = _PER_BATCH * B + _PER_BIN * nbins + _PER_PIXEL
    if aperture:
        per_pixel += _APERTURE_PER_BATCH * B + _APERTURE_PER_BIN * nbins
    if tally:
        per_pixel += _TALLY_CHANNELS * B + 2 * nbins
    pairs = min(MAX_PAIRS_PER_CHUNK, pixels * int(records))
    per_record = _PER_RECORD + (_EXITANCE_PER_RECORD if exitance else 0)
    return int(math.ceil(8 * (pixels * per_pixel + int(records) * per_record) + pairs * _PAIR_BYTES))


def check_render_memory(
    width: int,
    height: int,
    n_batches: int = DEFAULT_VIEW_BATCHES,
    records: int = 0,
    aperture: bool = False,
    tally: bool = False,
    memory_budget_bytes=None,
    names=("width", "height", "memory_budget_bytes"),
    exitance: bool = False,
) -> int:
    """ValueError naming width and height (``names``: the API's or the command line's spelling) when
    :func:`render_memory_bytes` exceeds the budget (``memory_budget_bytes``, None: RENDER_MEMORY_BUDGET_BYTES);
    also when the budget is not a positive number. Returns the estimate (bytes)."""
    wn, hn, bn = names
    budget = RENDER_MEMORY_BUDGET_BYTES if memory_budget_bytes is None else memory_budget_bytes
    if isinstance(budget, bool) or not isinstance(budget, (int, float)) or not (math.isfinite(budget) and budget > 0):
        raise ValueError(f"{bn} = {memory_budget_bytes!r} must be a positive number of bytes")
    need = render_memory_bytes(width, height, n_batches, records, aperture, tally, exitance)
    if need > budget:
        raise ValueError(
            f"{wn} = {width}, {hn} = {height}: the render needs about {need / 2**30:.3g} GiB ({n_batches} batches"
            f"{', the camera tally' if tally else ''}), more than the memory budget of {budget / 2**30:.3g} GiB; "
            f"render fewer pixels or batches, or raise {bn} (default RENDER_MEMORY_BUDGET_BYTES = "
            f"{RENDER_MEMORY_BUDGET_BYTES / 2**30:g} GiB)"
        )
    return need
