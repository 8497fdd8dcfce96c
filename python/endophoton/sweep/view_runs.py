"""The endoscope's view of one β of a sweep: which records make each image, and how many packets.

* **The white-light image holds all the light.** A fluorescent-only run (the paper's store N) keeps only
  the fluorescent exits, so with a record-based estimator (the exitance estimate, ``estimator``
  "exitance", "auto" or none given, or the kernel estimate, "kernel") its white image would be made of the
  very records of its fluorescence image. The sweep then runs a **white pass**: a run of the same scene and rig that records every exit (``fluorescent_only=False``),
  with a seed of its own (:func:`piece_seed`), ``white_packets`` packets (default: as many as the store run
  traced). ``white_*`` comes from the white pass's records, ``fluorescence_*`` and ``red_green_*`` from the
  fluorescent records: never the same records, by construction. A run that kept every exit
  (``--all-photons``) gives both images itself (the white image all its records, the fluorescence image its
  fluorescent ones). An estimator that tallies all the light itself (``estimator="nee"``) needs no pass.
* **The next-event estimate in a sweep** (``estimator="nee"``): a store run has no camera tally (the tally
  needs a fixed packet count), so each β's view comes from runs of its own with ``ep.run(..., view=...)``:
  a first run of ``white_packets`` packets (default: as many as the store run traced), then the top-ups. Their
  tallies are added batch by batch (:class:`_Tally`): batch b of the sum holds batch b of every run, so the
  batches stay independent and equal within a packet, and both images (white and fluorescence) come from
  the same tally of all the light.
* **Sweeps to a target accuracy on the answer** (:class:`ContrastTarget`, ``ep.sweep(target=("red_green",
  0.05))``): after the store run, the image the criterion reads is topped up with runs of its own seed
  (:func:`piece_seed`; packet indices continue after the packets before them, so the batches stay contiguous
  packet blocks) until the contrast's standard error is at most the requested error, or the cap
  ``max_packets`` is reached. :func:`next_packets` is the stopping rule.
* With the kernel estimate, records it cannot use are dropped from the top-ups as they arrive
  (``render.kernel_candidates``, the kernel's own pre-filter), so a β of millions of packets keeps only the
  records that head for the camera. The exitance estimate uses every record of a region, so its top-ups keep
  them all.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Mapping

import numpy as np

from ..analysis.batches import batch_index
from ..io import check_int, check_real, no_nan
from ..view.nee import view_request
from ..view.render import _resolve_camera, kernel_candidates, render_view
from ..view.visibility import SURROUND_PX, contrast

__all__ = [
    "CRITERIA",
    "DEFAULT_MAX_PACKETS",
    "ContrastTarget",
    "contrast_target",
    "next_packets",
    "grow_to_target",
    "piece_seed",
    "view_of_beta",
]

#: criterion -> (the sweep column it reads, the image it comes from)
CRITERIA = {
    "red_green": ("red_green_contrast", "fluorescence"),
    "red_green_camera": ("red_green_camera_contrast", "fluorescence"),
    "fluorescence": ("fluorescence_contrast", "fluorescence"),
    "white": ("white_contrast", "white"),
}

#: Default cap on the packets behind one β's image in a target sweep (the store run's included).
DEFAULT_MAX_PACKETS = 20_000_000

#: Packets of one top-up run at most (bounds the memory of its records before they are pruned).
PIECE_PACKETS = 1_000_000

#: Odd step between the seeds of a β's top-up runs and white pass (2^64 / the plastic number), distinct from
#: the step between β (schema.SEED_STEP).
PIECE_STEP = 0xD1B54A32D192ED03

#: The packets a top-up adds are those the projection asks for times this margin (as a store run's chunks:
#: +10 %), and at most GROWTH - 1 times the packets already traced (a noisy first error cannot ask for 100x).
MARGIN, GROWTH = 1.1, 8.0


@dataclass(frozen=True)
class ContrastTarget:
    """Run each β until the standard error of the criterion's contrast is at most ``stderr``, or until the
    image behind it holds ``max_packets`` packets (the cap). ``criterion``: a key of :data:`CRITERIA`."""

    criterion: str
    stderr: float
    max_packets: int = DEFAULT_MAX_PACKETS

    @property
    def column(self) -> str:
        return CRITERIA[self.criterion][0]

    @property
    def image(self) -> str:
        return CRITERIA[self.criterion][1]

    def to_dict(self) -> dict:
        return {"criterion": self.criterion, "stderr": self.stderr, "max_packets": self.max_packets}


def contrast_target(value: Any, field: str = "target") -> ContrastTarget | None:
    """``value`` as a :class:`ContrastTarget`: None, a ContrastTarget, ``(criterion, stderr[, max_packets])``,
    a dict of those fields, or the command line's ``"CRITERION:ERR"``. ValueError naming ``field``."""
    if value is None or isinstance(value, ContrastTarget):
        return value
    if isinstance(value, str):
        parts = value.split(":")
        if len(parts) != 2:
            raise ValueError(f"{field} {value!r}: use CRITERION:ERR, e.g. red_green:0.05")
        try:
            err = float(parts[1])
        except ValueError:
            raise ValueError(f"{field} {value!r}: ERR = {parts[1]!r} must be a number") from None
        value = (parts[0], err)
    if isinstance(value, Mapping):
        value = (value.get("criterion"), value.get("stderr"), value.get("max_packets", DEFAULT_MAX_PACKETS))
    if not isinstance(value, (tuple, list)) or len(value) not in (2, 3):
        raise ValueError(f"{field} = {value!r} must be (criterion, stderr) or (criterion, stderr, max_packets)")
    criterion = value[0]
    if criterion not in CRITERIA:
        raise ValueError(f"{field}: criterion = {criterion!r} must be one of {', '.join(CRITERIA)}")
    err = check_real(f"{field}: stderr", value[1], 0.0, math.inf, lo_open=True)
    cap = check_int(f"{field}: max_packets", value[2], 1, 2**62) if len(value) == 3 else DEFAULT_MAX_PACKETS
    return ContrastTarget(str(criterion), float(err), int(cap))


def next_packets(packets: int, stderr: float | None, target_stderr: float, max_packets: int) -> int:
    """The stopping rule: how many packets to add to an image of ``packets`` packets whose contrast has
    standard error ``stderr`` (None: undefined) to reach ``target_stderr``; 0 = stop.

    Stop when the error is reached or the cap is. An error falls as 1/sqrt(packets), so the packets
    needed are packets x (stderr / target)^2; the step adds them with a 10 % margin (:data:`MARGIN`), at
    least 1 % of the packets so far, at most (:data:`GROWTH` - 1) x packets, never past the cap. An
    undefined error (a contrast with no spread yet) doubles the packets."""
    if packets >= max_packets:
        return 0
    if stderr is not None and stderr <= target_stderr:
        return 0
    if stderr is None or not math.isfinite(stderr):
        want = packets
    else:
        want = math.ceil(packets * (stderr / target_stderr) ** 2 * MARGIN) - packets
    want = max(want, math.ceil(0.01 * packets), 1)
    want = min(want, math.ceil((GROWTH - 1.0) * packets))
    return int(min(want, max_packets - packets))


def grow_to_target(packets: Callable, stderr: Callable, grow: Callable, target: ContrastTarget) -> bool:
    """The target loop: while :func:`next_packets` asks for more, ``grow(n)`` adds n packets (False: it was
    cancelled, stop). ``packets()`` and ``stderr()`` read the image's packets and its contrast's standard
    error (None: undefined). Returns whether the error reached ``target.stderr``."""
    while True:
        add = next_packets(packets(), stderr(), target.stderr, target.max_packets)
        if add == 0 or not grow(add):
            break
    se = stderr()
    return se is not None and se <= target.stderr


def piece_seed(seed: int, image: str, piece: int) -> int:
    """The seed of a β's ``piece``-th extra run (0, 1, ...) for ``image`` ("fluorescence": top-ups;
    "white": the white pass and its top-ups): ``(seed + (2 piece + 1 + [white]) x PIECE_STEP) mod 2^64``,
    a stream of its own (the β's store run has ``seed``)."""
    k = 2 * int(piece) + 1 + (1 if image == "white" else 0)
    return (int(seed) + k * PIECE_STEP) % 2**64


class _Records:
    """The records behind one image, as ``render_view`` reads a result: the first run's records, then
    top-ups appended with their packet indices shifted past the packets before them."""

    def __init__(self, res):
        self.scene, self.source, self.options = res.scene, res.source, getattr(res, "options", {})
        self.escapes = {k: np.asarray(v) for k, v in res.escapes.items()}
        self.packets_traced = self.photons = _packets_of(res)
        self.cancelled = bool(getattr(res, "cancelled", False))

    def keep(self, mask) -> None:
        self.escapes = {k: v[mask] for k, v in self.escapes.items()}

    def add(self, res, keep: Callable | None) -> None:
        esc = {k: np.asarray(v) for k, v in res.escapes.items()}
        if keep is not None:
            m = keep(esc)
            esc = {k: v[m] for k, v in esc.items()}
        esc["packet"] = esc["packet"].astype(np.uint64) + np.uint64(self.packets_traced)
        self.escapes = {k: np.concatenate([self.escapes[k], esc[k]]) for k in self.escapes}
        self.packets_traced = self.photons = self.packets_traced + _packets_of(res)
        self.cancelled = self.cancelled or bool(getattr(res, "cancelled", False))


class _Tally:
    """The camera tallies behind one image of the next-event estimate, as ``render_view`` reads a result: the
    runs' per-pixel, per-batch sums, spectra and counters added, with the packets of each batch
    (``camera_packets_per_batch``: batch b holds batch b of every run). An aperture camera's records (its
    reference images) are appended as :class:`_Records` appends them."""

    _ARRAYS = ("sums", "spectrum")

    def __init__(self, res):
        self.scene, self.source, self.options = res.scene, res.source, getattr(res, "options", {})
        self.spectral, self.view_request = getattr(res, "spectral", True), res.view_request
        self.camera_image = {k: (np.array(v) if k in self._ARRAYS else int(v)) for k, v in res.camera_image.items()}
        self.escapes = None if res.escapes is None else {k: np.asarray(v) for k, v in res.escapes.items()}
        self.packets_traced = self.photons = _packets_of(res)
        self.camera_packets_per_batch = self._batches(res)
        self.cancelled = bool(getattr(res, "cancelled", False))

    def _batches(self, res) -> np.ndarray:
        return batch_index(np.zeros(0, dtype=np.int64), self.view_request["n_batches"], _packets_of(res))[1]

    def add(self, res, keep=None) -> None:
        for k, v in res.camera_image.items():
            if k in self._ARRAYS:
                self.camera_image[k] += v
            else:
                self.camera_image[k] += int(v)
        if self.escapes is not None:
            esc = {k: np.asarray(v) for k, v in res.escapes.items()}
            esc["packet"] = esc["packet"].astype(np.uint64) + np.uint64(self.packets_traced)
            self.escapes = {k: np.concatenate([self.escapes[k], esc[k]]) for k in self.escapes}
        self.camera_packets_per_batch = self.camera_packets_per_batch + self._batches(res)
        self.packets_traced = self.photons = self.packets_traced + _packets_of(res)
        self.cancelled = self.cancelled or bool(getattr(res, "cancelled", False))


def _nee_request(source, render_kwargs: Mapping) -> tuple[dict, bool]:
    """The ``view=`` request of a next-event run that ``render_view(**render_kwargs)`` can render (the camera,
    size, batches, light and filter it names), and whether the run must record escapes (an aperture camera's
    reference images read them)."""
    keys = ("camera", "width", "height", "n_batches", "excitation", "emission_filter", "white_balance")
    req = view_request(**{k: render_kwargs[k] for k in keys if k in render_kwargs})
    if "memory_budget_bytes" in render_kwargs:
        req["memory_budget_bytes"] = render_kwargs["memory_budget_bytes"]
    camera, _, _ = _resolve_camera(source, req["camera"], req["width"], req["height"])
    return req, camera.aperture_radius > 0


def _packets_of(res) -> int:
    p = int(getattr(res, "packets_traced", 0) or 0)
    return p if p > 0 else int(res.photons)


#: The camera estimators a sweep renders each β with (``visibility["estimator"]``, ``sweep --estimator``; "auto"
#: and None are the exitance estimate): from its records, or from next-event runs of its own.
SWEEP_ESTIMATORS = ("exitance", "kernel", "nee")


def _kernel_estimator(render_kwargs: Mapping) -> bool:
    """Whether the view's estimator is the kernel estimate (asked for by name)."""
    return render_kwargs.get("estimator") == "kernel"


def _records_estimator(render_kwargs: Mapping) -> bool:
    """Whether the view's estimator makes its images from the run's records: the kernel or the exitance estimate
    (also "auto" and none given: the exitance estimate in a sweep, whose store runs have no camera tally)."""
    return render_kwargs.get("estimator") in ("kernel", "exitance", "auto", None)


def _nee_estimator(render_kwargs: Mapping) -> bool:
    """Whether the view's estimator is the next-event camera tally (runs of its own, :class:`_Tally`)."""
    return render_kwargs.get("estimator") == "nee"


class _Image:
    """One image's records, its view, and the extra runs that grow it."""

    def __init__(self, name, records, render_kwargs, run_more, seed, pieces=0, nee=None):
        self.name, self.records, self.kw, self.run_more, self.seed = name, records, dict(render_kwargs), run_more, seed
        self.pieces, self.nee = pieces, nee  # nee: the next-event runs' (view request, record_escapes)
        self.view = render_view(records, **self.kw)
        self.keep = None
        if _kernel_estimator(self.kw) and self.view.aperture is None:
            # fix the kernel (its default depends on the geometry only) and keep what it can use
            self.kw.setdefault("kernel_radius", self.view.kernel["radius"])
            r, a, cam = self.view.kernel["radius"], self.view.kernel["angle_deg"], self.view.camera.position
            self.keep = lambda esc: kernel_candidates(esc["position"], esc["direction"], cam, r, a)

    def grow(self, packets: int, fluorescent_only: bool) -> None:
        """Adds ``packets`` packets in runs of at most :data:`PIECE_PACKETS`, then renders again."""
        left = int(packets)
        while left > 0 and not self.records.cancelled:
            n = min(left, PIECE_PACKETS)
            seed = piece_seed(self.seed, self.name, self.pieces)
            if self.nee is not None:
                res = self.run_more(n, seed, False, view=self.nee[0], record_escapes=self.nee[1])
            else:
                res = self.run_more(n, seed, fluorescent_only)
            self.pieces += 1
            if self.keep is not None and self.pieces == 1:
                self.records.keep(self.keep(self.records.escapes))
            self.records.add(res, self.keep)
            left -= n
        self.view = render_view(self.records, **self.kw)


def _columns(fl: _Image, wh: _Image, target, background, surround_px) -> dict:
    """The visibility columns from the two images' views (None where undefined)."""
    cols = {}
    c = contrast(fl.view, target, background, "srgb", surround_px)
    cam = contrast(fl.view, target, background, "camera", surround_px)
    w = c if wh is fl else contrast(wh.view, target, background, "srgb", surround_px)
    for key, src in (("fluorescence", c), ("white", w)):
        cols[key + "_contrast"], cols[key + "_contrast_stderr"] = src[key], src[key + "_stderr"]
        cols[key + "_michelson"], cols[key + "_michelson_stderr"] = (
            src[key + "_michelson"],
            src[key + "_michelson_stderr"],
        )
    cols["red_green_contrast"], cols["red_green_contrast_stderr"] = c["red_green"], c["red_green_stderr"]
    cols["red_green_camera_contrast"], cols["red_green_camera_contrast_stderr"] = (
        cam["red_green"],
        cam["red_green_stderr"],
    )
    cols["background_pixels"] = c["background_pixels"]
    if surround_px is not None and background is not None:  # the whole region, for comparison
        rc = contrast(fl.view, target, background)
        rw = rc if wh is fl else contrast(wh.view, target, background)
        cols["region_fluorescence_contrast"], cols["region_fluorescence_contrast_stderr"] = (
            rc["fluorescence"],
            rc["fluorescence_stderr"],
        )
        cols["region_white_contrast"], cols["region_white_contrast_stderr"] = rw["white"], rw["white_stderr"]
        cols["region_red_green_contrast"], cols["region_red_green_contrast_stderr"] = (
            rc["red_green"],
            rc["red_green_stderr"],
        )
    return cols


def _in_view(view, target, background, surround_px) -> bool:
    """Whether the camera sees the target and a background pixel (the region's, or the ring's)."""
    return view.pixels_of(target, "target") > 0 and _background_pixels(view, target, background, surround_px) > 0


def _background_pixels(view, target, background, surround_px) -> int:
    """Pixels of the background: the ring's (0 without a target pixel), or the whole region's."""
    if surround_px is None:
        return view.pixels_of(background, "background")
    from ..view.visibility import surround_mask

    bi = None if background is None else view.region_names.index(background)
    return int(surround_mask(view.region_map, view.region_names.index(target), surround_px, bi).sum())


def view_of_beta(
    result,
    target: str,
    background: str | None,
    surround_px: float | None,
    run_more: Callable,
    seed: int,
    contrast_target: ContrastTarget | None = None,
    white_packets: int | None = None,
    **render_kwargs,
) -> tuple[dict, Any]:
    """The visibility columns of one β's run ``result`` and the view to save (its white image from the
    white-light records). ``run_more(packets, seed, fluorescent_only, view=None, record_escapes=True)`` runs the
    same scene and rig again (the white pass, the next-event runs, the top-ups). Returns ``(columns, view)``;
    columns None where undefined."""
    if render_kwargs.get("estimator") in ("auto", None):  # named: render_view's "auto" rule cannot change it
        render_kwargs["estimator"] = "exitance"
    fluorescent_only = bool(dict(getattr(result, "options", {}) or {}).get("fluorescent_only", False))
    # a white pass of its own: each run's records are rendered for the one image read from them
    white_pass = fluorescent_only and _records_estimator(render_kwargs)
    if _nee_estimator(render_kwargs):
        fl = _nee_image(result, render_kwargs, run_more, seed, white_packets)
    else:
        kw = dict(render_kwargs, images=("fluorescence",)) if white_pass else render_kwargs
        fl = _Image("fluorescence", _Records(result), kw, run_more, seed)
    cols = {"target_pixels": fl.view.pixels_of(target, "target"), "view_packets": fl.records.packets_traced}
    if background is not None:
        fl.view.pixels_of(background, "background")  # an unknown region is an error, out of view is not
    wh = fl
    if white_pass:
        n = _packets_of(result) if white_packets is None else int(white_packets)
        white = run_more(n, piece_seed(seed, "white", 0), False)
        wh = _Image("white", _Records(white), dict(render_kwargs, images=("white",)), run_more, seed)
        wh.pieces = 1
    cols["white_packets"] = wh.records.packets_traced
    if not (_in_view(fl.view, target, background, surround_px) and _in_view(wh.view, target, background, surround_px)):
        cols["background_pixels"] = _background_pixels(fl.view, target, background, surround_px)
        return cols, _saved_view(fl, wh)
    cols.update(_columns(fl, wh, target, background, surround_px))
    if contrast_target is not None:
        img = wh if contrast_target.image == "white" else fl

        def grow(packets):
            img.grow(packets, fluorescent_only and img is fl)
            cols.update(_columns(fl, wh, target, background, surround_px))
            return not img.records.cancelled

        cols["target_reached"] = int(
            grow_to_target(
                lambda: img.records.packets_traced,
                lambda: cols.get(contrast_target.column + "_stderr"),
                grow,
                contrast_target,
            )
        )
        cols["view_packets"], cols["white_packets"] = fl.records.packets_traced, wh.records.packets_traced
    cols["cancelled"] = int(fl.records.cancelled or wh.records.cancelled)
    return no_nan(cols), _saved_view(fl, wh)


def _nee_image(result, render_kwargs, run_more, seed, white_packets) -> _Image:
    """The next-event image of one β: a run of ``white_packets`` packets (None: as many as ``result``, the
    store run, traced) with the camera tally, the first piece of the fluorescence image's stream."""
    req, with_records = _nee_request(result.source, render_kwargs)
    n = _packets_of(result) if white_packets is None else int(white_packets)
    first = run_more(n, piece_seed(seed, "fluorescence", 0), False, view=req, record_escapes=with_records)
    return _Image("fluorescence", _Tally(first), render_kwargs, run_more, seed, pieces=1, nee=(req, with_records))


def _saved_view(fl: _Image, wh: _Image):
    """The fluorescence image's view with the white image of the white-light records, for View.save (which
    writes the images; the view's region and pixel batches stay the fluorescence run's, whose white image a
    sweep with a white pass does not compute)."""
    view = fl.view
    if wh is not fl:
        view.images = dict(view.images, white=wh.view.images["white"])
    return view
