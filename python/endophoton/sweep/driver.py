"""The seed paper's beta sweep (§5, Figs. 4-9): tilt the endoscope head, store N photons, analyse.

For each tilt angle beta (degrees from the surface normal) the sweep builds the
endoscope rig with :meth:`endophoton.EndoscopeRig.from_beta`, runs the engine in
store-N mode (``ep.run(scene, rig, store=N, fluorescent_only=...)``) and reduces
the surface photon map with :mod:`endophoton.sweep.reduce`:

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

The sweep is split along its seams: the data (:mod:`endophoton.sweep.schema`),
the paper's constants (:mod:`endophoton.paper`), the reduction of one run
(:mod:`endophoton.sweep.reduce`), this driver, and the command line
(:mod:`endophoton.sweep.cli`).  Inside Blender the add-on's
``endophoton_addon.sweep_blend`` exports a Blender scene and calls :func:`sweep`.
"""
from __future__ import annotations

import argparse
import functools
import inspect
import itertools
import math
import os
import sys
import time
from typing import Any, Callable, Iterable, Mapping, Sequence

import numpy as np

from .. import _core, meshes, placement
from ..analysis import DEFAULT_BATCHES
from ..callbacks import notification_done, progress_verdict
from ..io import atomic_write_text, check_bool, check_int, check_output_files, check_path, check_real, jsonable
from ..live import run_live
from ..medium import Medium
from ..paper import DISTANCE_CM, FLUOROPHORES, IMPORTANT_ANGLE_DEG, TISSUE
from ..run import check_client, run
from ..scene import Scene
from ..sources import EndoscopeRig
from ..spectra import Fluorophore
from .reduce import analyse_run, finish_relative, rig_geometry
from .schema import (
    region_cells,
    CSV_COLUMNS,
    MAX_BETAS,
    VISIBILITY_COLUMNS,
    SweepResult,
    beta_seed,
    beta_text,
    check_beta_spacing,
    output_file_names,
    parse_betas,
)
from ..units import UNIT_CM

__all__ = [
    "SweepResult",
    "sweep",
    "analyse_run",
    "write_outputs",
    "default_flat_scene",
    "rig_geometry",
    "CSV_COLUMNS",
    "parse_betas",
    "check_placements",
]


def default_flat_scene(
    unit: str = "cm",
    polyp: str | None = "dome",
    polyp_radius_cm: float = 0.3,
    polyp_height_cm: float = 0.15,
    half_width_cm: float = 50.0,
    thickness_cm: float = 10.0,
    mesh_resolution: tuple[int, int] = (24, 48),
):
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
    if unit not in UNIT_CM:
        raise ValueError(f"unit = {unit!r} must be one of {sorted(UNIT_CM)}")
    if polyp not in ("dome", "embedded", None):
        raise ValueError(f"polyp = {polyp!r} must be 'dome', 'embedded' or None")
    s = 1.0 / UNIT_CM[unit]  # scene units per cm
    scene = Scene(unit=unit, ambient_n=1.0)
    medium = Medium(**TISSUE)
    tissue_fl = [Fluorophore(name, d, c) for name, d, c in FLUOROPHORES["tissue"]]
    polyp_fl = [Fluorophore(name, d, c) for name, d, c in FLUOROPHORES["polyp"]]
    w, t = half_width_cm * s, thickness_cm * s
    scene.add_box("tissue", min=(-w, -w, -t), max=(w, w, 0.0), medium=medium, priority=0, fluorophores=tissue_fl)
    if polyp is not None:
        n_lat, n_lon = mesh_resolution
        radii = (polyp_radius_cm * s, polyp_radius_cm * s, polyp_height_cm * s)
        if polyp == "dome":
            v, tri = meshes.ellipsoid((0.0, 0.0, 0.0), radii, n_lat=n_lat, n_lon=n_lon)
        else:
            v, tri = meshes.half_ellipsoid(
                (0.0, 0.0, -1e-4 * s), radii, n_lat=max(1, n_lat // 2), n_lon=n_lon, upper=False
            )
        scene.add_mesh("polyp", v, tri, medium, priority=1, fluorophores=polyp_fl)
    return scene


def _call_builder(builder: Callable, beta: float):
    try:
        n_params = len(
            [
                p
                for p in inspect.signature(builder).parameters.values()
                if p.default is inspect.Parameter.empty and p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD)
            ]
        )
    except (TypeError, ValueError):
        n_params = 1
    return builder(beta) if n_params >= 1 else builder()


def _rig_from_beta(beta: float, distance: float, point, normal, tilt_axis, rig_kwargs: Mapping[str, Any]):
    """``EndoscopeRig.from_beta(...)`` for one tilt angle (lengths in scene units)."""
    return EndoscopeRig.from_beta(
        beta_deg=float(beta),
        distance=float(distance),
        point=tuple(map(float, point)),
        normal=tuple(map(float, normal)),
        tilt_axis=tuple(map(float, tilt_axis)),
        **rig_kwargs,
    )


def _scene_unit(scene: Any) -> str:
    unit = getattr(scene, "unit", None)
    if unit not in UNIT_CM:
        raise ValueError(f"scene.unit = {unit!r} must be one of {sorted(UNIT_CM)}")
    return unit


class _Progress:
    """tqdm bar over beta, with the engine's done/total shown as postfix (terminal only)."""

    def __init__(self, betas: Sequence[float], enabled: bool, user: Callable | None, chunks: bool = False):
        self.user = user
        self.bar = None
        self._last = 0.0
        self._i = 0
        self._n = len(betas)
        self._chunks = chunks  # on a cluster: one bar over the chunks of all angles
        if enabled:
            try:
                from tqdm import tqdm

                total, unit = (None, "chunk") if chunks else (len(betas), "beta")
                self.bar = tqdm(total=total, desc="beta sweep", unit=unit, file=sys.stderr, dynamic_ncols=True)
            except ImportError:  # pragma: no cover - tqdm is a dependency
                self.bar = None

    def start(self, i: int, beta: float) -> None:
        self._i = i
        if self.bar is not None:
            self.bar.set_description(f"beta = {beta:g} deg")

    def engine(self, done: int, total: int):
        """Engine progress callback; returns the user callback's value (False stops the run)."""
        now = time.monotonic()
        if self.bar is not None and not self._chunks and now - self._last > 0.5:
            self._last = now
            self.bar.set_postfix_str(f"{done:,}/{total:,}" if total else f"{done:,} packets")
        if self.user is not None:  # its value by type (endophoton.callbacks): None/True go on, False stops
            return progress_verdict("progress", self.user(self._i, self._n, done, total))
        return None

    def engine_of(self, i: int, done: int, total: int):
        """Progress of beta ``i``'s run on a cluster (the runs advance together)."""
        self._i = i
        return self.engine(done, total)

    def chunks(self, done: int, total: int) -> None:
        """Chunks merged over all angles against their estimated total (cluster sweeps)."""
        if self.bar is not None:
            self.bar.total = max(total, done)
            self.bar.update(done - self.bar.n)

    def step(self) -> None:
        if self.bar is not None and not self._chunks:
            self.bar.update(1)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _sweep_meta(a: dict, static_scene: Any) -> dict:
    """The run settings recorded in ``SweepResult.meta``, from :func:`sweep`'s arguments ``a`` (by name)."""
    rig_kwargs = dict(a["rig_kwargs"] or {})
    return {
        "seed": int(a["seed"]),
        "store": int(a["store"]),
        "threads": int(a["threads"]),
        "n_batches": int(a["n_batches"]),
        "fluorescent_only": bool(a["fluorescent_only"]),
        "fluorescence_rule": a["fluorescence_rule"],
        "max_angle_deg": float(a["max_angle_deg"]),
        "point": list(map(float, a["point"])),
        "normal": list(map(float, a["normal"])),
        "tilt_axis": list(map(float, a["tilt_axis"])),
        "rig_kwargs": {k: v for k, v in rig_kwargs.items() if isinstance(v, (int, float, str, tuple, list))},
        "scene": "default_flat_scene(unit='cm', polyp='dome')"
        if a["scene_or_builder"] is None
        else ("builder" if static_scene is None else "user scene"),
        "engine_version": _core.__version__,
        "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "n_elev": 10,
        "n_azim": 36,
    }


def _checked_betas(betas: Iterable[float], store: int, n_batches: int) -> list[float]:
    """``betas`` as floats, after checking the arguments every sweep needs (clear errors).

    A string is parsed with the command line's grammar (:func:`parse_betas`); at most
    :data:`MAX_BETAS` angles are taken from any iterable (an endless one is an error, not a hang);
    no two closer than ``sweep_schema.BETA_RESOLUTION_DEG`` (:func:`check_beta_spacing`)."""
    if isinstance(betas, str):
        try:
            return _checked_betas(parse_betas(betas, field="betas ="), store, n_batches)
        except argparse.ArgumentTypeError as e:
            raise ValueError(str(e)) from None
    if betas is None or not isinstance(betas, Iterable):
        raise ValueError(f"betas = {betas!r} must be a list of angles in degrees or a string such as '0:60:5'")
    betas = list(itertools.islice(betas, MAX_BETAS + 1))
    if len(betas) > MAX_BETAS:
        raise ValueError(f"betas: more than {MAX_BETAS} angles (each is a full run)")
    betas = [check_real(f"betas[{i}]", b, -math.inf, math.inf) for i, b in enumerate(betas)]
    if not betas:
        raise ValueError("betas: empty")
    check_beta_spacing(betas, "betas")
    if int(store) < n_batches:
        raise ValueError(f"store = {store} must be >= n_batches = {n_batches}")
    return betas


# ep.run's keyword arguments (all but scene and source), the keys run_kwargs may hold.
_RUN_KEYWORDS = tuple(inspect.signature(run).parameters)[2:]
# ep.run_live's own keyword arguments (those ep.run lacks), the keys ``live`` may hold.
_LIVE_KEYWORDS = tuple(
    p for p in inspect.signature(run_live).parameters if p not in ("scene", "source", "kwargs", *_RUN_KEYWORDS)
)


def _keywords_of(name: str, value, accepted: Iterable[str], of: str) -> dict:
    """``value`` (None or a mapping whose keys are among ``accepted``) as a dict; ValueError naming ``name``."""
    if value is None:
        return {}
    if not isinstance(value, Mapping):
        raise ValueError(f"{name} = {value!r} must be None or a dict of {of}'s keyword arguments")
    accepted = set(accepted)
    unknown = sorted(str(k) for k in value if k not in accepted)
    if unknown:
        raise ValueError(f"{name}: {', '.join(map(repr, unknown))} is not a keyword argument of {of}")
    return dict(value)


def _check_sweep_arguments(a: dict) -> None:
    """The types of :func:`sweep`'s arguments ``a`` (by name), before anything runs: ValueError naming
    the argument and its value (the betas: :func:`_checked_betas`; seed, threads and the rest of
    ``run_kwargs``: ep.run's own checks, before the first run)."""
    check_int("store", a["store"], 1, 2**62)
    check_int("n_batches", a["n_batches"], 2, 1_000_000)
    for name in ("fluorescent_only", "plots", "report", "seed_per_beta"):
        check_bool(name, a[name])
    if a["distance"] is not None:
        check_real("distance", a["distance"], 0.0, math.inf, lo_open=True)
    check_real("max_angle_deg", a["max_angle_deg"], 0.0, 180.0)
    if not isinstance(a["progress"], bool) and not callable(a["progress"]):
        raise ValueError(f"progress = {a['progress']!r} must be True, False or a callable")
    for name in ("rig_builder", "on_beta", "on_chunks", "on_run"):
        if a[name] is not None and not callable(a[name]):
            raise ValueError(f"{name} = {a[name]!r} must be None or a callable")
    if a["out_dir"] is not None:
        out = check_path("out_dir", a["out_dir"])
        if os.path.exists(out) and not os.path.isdir(out):
            raise ValueError(f"out_dir = {out!r} exists and is not a folder")
    rig_params = [p for p in inspect.signature(EndoscopeRig.__init__).parameters if p != "self"]
    _keywords_of("rig_kwargs", a["rig_kwargs"], rig_params, "EndoscopeRig")
    run_kwargs = _keywords_of("run_kwargs", a["run_kwargs"], _RUN_KEYWORDS, "ep.run")
    check_client("client", a["client"])
    check_client("run_kwargs['client']", run_kwargs.get("client"))
    _check_live(a["live"], a["client"], run_kwargs)


def _check_live(live, client, run_kwargs: dict) -> None:
    """:func:`sweep`'s ``live``: None, or ep.run_live's own keywords with a callable ``on_snapshot``; only
    for a local sweep (the Dask path and the camera tally have no snapshots: ep.run_live refuses them)."""
    live = _keywords_of("live", live, _LIVE_KEYWORDS, "ep.run_live")
    if not live:
        return
    if not callable(live.get("on_snapshot")):
        raise ValueError(
            f"live['on_snapshot'] = {live.get('on_snapshot')!r} must be a callable "
            "on_snapshot(i_beta, beta_deg, result)"
        )
    for name, value in (("client", client), ("run_kwargs['client']", run_kwargs.get("client"))):
        if value is not None:
            raise ValueError(
                f"live with {name} = {value!r}: a live sweep runs each β on this machine through ep.run_live "
                "(the unit path carries no Dask client); give live or a client, not both"
            )
    if run_kwargs.get("view") not in (None, False):
        raise ValueError(f"live with run_kwargs['view'] = {run_kwargs['view']!r}: a live run has no camera tally")


def _contrast_target(target, visibility):
    """:func:`sweep`'s ``target`` as a ``view_runs.ContrastTarget`` (None without one); a target needs a view.
    Checks the view's estimator and ``white_packets`` (a count of at least the view's batches) before any run."""
    from ..view.render import DEFAULT_VIEW_BATCHES
    from .view_runs import SWEEP_ESTIMATORS, contrast_target

    checked = contrast_target(target, "target")
    white_packets = (visibility or {}).get("white_packets")
    if white_packets is not None:
        batches = (visibility or {}).get("n_batches", DEFAULT_VIEW_BATCHES)
        lo = batches if isinstance(batches, int) and not isinstance(batches, bool) and batches > 0 else 1
        check_int("visibility['white_packets']", white_packets, lo, 2**62)
    estimator = (visibility or {}).get("estimator")
    if estimator not in (None, "auto") + SWEEP_ESTIMATORS:
        raise ValueError(
            f"visibility['estimator'] = {estimator!r}: a sweep renders each β with the exitance estimate "
            "('exitance', from its records; 'auto' is the same there), the kernel estimate ('kernel', from its "
            "records) or the next-event estimate ('nee', from runs of its own with the camera tally)"
        )
    if checked is not None and visibility is None:
        raise ValueError(f"target = {target!r} needs a view: give visibility={{'target': ..., 'background': ...}}")
    return checked


def _engine_kwargs(store, fluorescent_only, fluorescence_rule, seed, threads, progress, cancel, run_kwargs) -> dict:
    """The keyword arguments of every beta's ``ep.run`` (``run_kwargs`` last, so they win)."""
    kw = dict(
        store=int(store),
        fluorescent_only=bool(fluorescent_only),
        fluorescence_rule=fluorescence_rule,
        seed=int(seed),
        threads=int(threads),
        progress=progress,
    )
    if cancel is not None:
        kw["cancel"] = cancel
    kw.update(run_kwargs)
    return kw


def _static_scene(scene_or_builder: Any):
    """The scene used at every beta, or ``None`` when ``scene_or_builder`` builds one per beta."""
    if scene_or_builder is None:
        return default_flat_scene()
    if not callable(scene_or_builder) or hasattr(scene_or_builder, "add_mesh"):
        return scene_or_builder
    return None


def _setup_beta(
    beta: float,
    *,
    static_scene: Any,
    builder: Any,
    distance: float | None,
    point,
    normal,
    tilt_axis,
    rig_kwargs: Mapping[str, Any],
    rig_builder: Callable | None,
    meta: dict,
):
    """``(scene, unit, rig)`` of one beta; records the scene unit and head distance in ``meta``."""
    scene = static_scene if static_scene is not None else _call_builder(builder, beta)
    unit = _scene_unit(scene)
    dist = DISTANCE_CM / UNIT_CM[unit] if distance is None else float(distance)
    meta.setdefault("unit", unit)
    meta.setdefault("distance", dist)
    if rig_builder is not None:
        return scene, unit, rig_builder(beta, scene)
    return scene, unit, _rig_from_beta(beta, dist, point, normal, tilt_axis, rig_kwargs)


def _setup_of(static_scene, builder, distance, point, normal, tilt_axis, rig_kwargs, rig_builder, meta) -> Callable:
    """``setup(beta) -> (scene, unit, rig)``: :func:`_setup_beta` with a sweep's arguments."""
    return functools.partial(
        _setup_beta,
        static_scene=static_scene,
        builder=builder,
        distance=distance,
        point=point,
        normal=normal,
        tilt_axis=tilt_axis,
        rig_kwargs=rig_kwargs,
        rig_builder=rig_builder,
        meta=meta,
    )


class _Rows:
    """The sweep's rows, histograms and batch values, accepted in beta order."""

    def __init__(self, betas: Sequence[float], meta: dict, bar: _Progress, on_beta: Callable | None):
        self.betas, self.meta, self.bar, self.on_beta = betas, meta, bar, on_beta
        self.rows, self.hists, self.batches = [], [], []

    def stop_at(self, i: int) -> None:
        """The sweep ends at beta ``i`` (a cancel)."""
        self.meta["cancelled_at_beta"] = self.betas[i]

    def accept(self, i: int, one) -> bool:
        """Adds beta i's outcome (from :func:`_beta_outcome`); False once the sweep ends there."""
        if one is None:  # cancelled before the first record: no row
            self.stop_at(i)
            return False
        row, hist, bt, cancelled = one
        self.rows.append(row)
        self.hists.append(hist)
        self.batches.append(bt)
        self.bar.step()
        if self.on_beta is not None:
            notification_done("on_beta", self.on_beta(i, len(self.betas), row))
        if cancelled:
            self.stop_at(i)
        return not cancelled

    def result(self) -> SweepResult:
        """The finished sweep: relative columns filled in, end state recorded in ``meta``."""
        finish_relative(self.rows)
        self.meta["cancelled"] = "cancelled_at_beta" in self.meta
        self.meta["finished"] = time.strftime("%Y-%m-%dT%H:%M:%S%z")
        return SweepResult(rows=self.rows, histograms=self.hists, batches=self.batches, meta=self.meta)


def _check_placements(betas, setup: Callable) -> None:
    """Every beta's rig in the ambient (:func:`placement.check_rig`) before the first run: one
    ValueError naming every refused beta, instead of failing after the runs before it."""
    bad = []
    for beta in betas:
        scene, _, rig = setup(beta)
        try:
            placement.check_rig(scene, rig)
        except ValueError as e:
            bad.append((beta, str(e)))
    if bad:
        angles = ", ".join(beta_text(b) for b, _ in bad)
        raise ValueError(
            f"betas: at rig.beta_deg = {angles} the endoscope head enters the tissue; drop them. {bad[0][1]}"
        )


def check_placements(
    scene: Any,
    betas: Iterable[float],
    distance: float | None = None,
    point: Sequence[float] = (0.0, 0.0, 0.0),
    normal: Sequence[float] = (0.0, 0.0, 1.0),
    tilt_axis: Sequence[float] = (0.0, 1.0, 0.0),
    rig_kwargs: Mapping[str, Any] | None = None,
    rig_builder: Callable | None = None,
) -> None:
    """The check :func:`sweep` makes before its first run, on its own: the head of every beta, built
    as the sweep builds it (``EndoscopeRig.from_beta``, or ``rig_builder(beta, scene)``), must lie in
    the ambient of ``scene`` (an ``ep.Scene``; arguments as :func:`sweep`'s). Raises ValueError naming
    the refused betas, or the rig's own error; returns None when every head fits. The add-on calls it
    on the main thread before its sweep starts."""
    setup = _setup_of(scene, scene, distance, point, normal, tilt_axis, dict(rig_kwargs or {}), rig_builder, {})
    _check_placements([float(b) for b in betas], setup)


def _run_beta(scene, rig, kw: dict, live: Mapping[str, Any] | None, chunk_units: int, i: int, beta: float):
    """Beta ``i``'s run on this machine: ``ep.run``, or with ``live`` ``ep.run_live`` (the same bits;
    ``chunk_units`` units per traced chunk, 0: its own choice) handing each snapshot to
    ``live['on_snapshot'](i, beta, result)``."""
    if not live:
        return run(scene, rig, **kw)
    user = live["on_snapshot"]

    def on_snapshot(result):
        return user(i, beta, result)

    return run_live(scene, rig, **kw, **dict(live, on_snapshot=on_snapshot, chunk_units=chunk_units))


def _sweep_locally(
    betas, seeds, setup: Callable, kw: dict, outcome: Callable, rows: _Rows, bar: _Progress, cancel, live=None, chunks=0
) -> None:
    """One beta after the other on this machine (beta i with seeds[i]; through ep.run_live with
    ``live``, ``chunks`` units per chunk); a cancel ends the sweep at the cancelled run."""
    for i, beta in enumerate(betas):
        if cancel is not None and getattr(cancel, "cancelled", False):
            rows.stop_at(i)  # cancelled between two runs: nothing to analyse
            break
        bar.start(i, beta)
        scene, unit, rig = setup(beta)
        t0 = time.perf_counter()
        res = _run_beta(scene, rig, dict(kw, seed=seeds[i]), live, chunks, i, beta)
        seconds = float(getattr(res, "seconds", time.perf_counter() - t0))
        if not rows.accept(i, outcome(i, res, seconds, beta, rig, unit)):
            break


def _beta_outcome(
    res: Any,
    seconds: float,
    beta: float,
    rig: Any,
    unit: str,
    seed: int,
    normal,
    run_kwargs: Mapping[str, Any],
    meta: dict,
    n_batches: int,
    max_angle_deg: float,
    visibility: Mapping[str, Any] | None,
    out_dir: str | os.PathLike | None,
    contrast_target: Any = None,
):
    """Reduce one beta's run ``res`` (wherever it ran); returns ``(row, hist, batches, cancelled)``
    or ``None`` when a cancel landed before the first record (no row)."""
    geo = rig_geometry(rig, unit, normal)
    esc = res.escapes
    if esc is None:
        raise ValueError("ep.run returned no escape records (record_escapes off?)")
    cancelled = bool(getattr(res, "cancelled", False))
    if cancelled and np.asarray(esc.get("packet", ())).size == 0:
        return None
    P = int(getattr(res, "packets_traced", 0) or 0)
    if P <= 0:
        P = int(np.asarray(esc["packet"]).max()) + 1
    row, hist, bt = analyse_run(
        esc, P, geo["light_positions"], geo["camera"], n_batches, max_angle_deg, reference=geo["reference"]
    )
    full = {
        "beta_deg": beta,
        "store": int(run_kwargs["store"]),
        **row,
        "seconds": seconds,
        "seed": int(seed),
        "cancelled": int(cancelled),
        **region_cells(res),
    }
    if visibility is not None:  # the endoscope's view of this run (docs/render.md)
        from .view_sweep import add_visibility, rerun_of

        more = rerun_of(res, **{k: v for k, v in run_kwargs.items() if k not in _NOT_FOR_TOP_UPS})
        add_visibility(full, res, beta, visibility, out_dir, run_more=more, contrast_target=contrast_target)
        cancelled = cancelled or bool(full["cancelled"])
    else:
        full.update({k: None for k in VISIBILITY_COLUMNS})  # undefined without a view
    meta.setdefault("light_positions", {})[f"{beta:g}"] = geo["light_positions"].tolist()
    meta.setdefault("camera", {})[f"{beta:g}"] = jsonable(geo["camera"])
    meta.setdefault("azimuth_reference", {})[f"{beta:g}"] = jsonable(geo["reference"])
    return full, hist, bt, cancelled


# ep.run keywords of a beta's store run that its view's extra runs (white pass, top-ups: a fixed packet
# count, a seed of their own, sweep.view_runs) do not take: they choose these themselves, write no grids
# over the store run's, and run on this machine.
_NOT_FOR_TOP_UPS = (
    "store",
    "photons",
    "target",
    "quality",
    "max_photons",
    "time_budget_s",
    "seed",
    "fluorescent_only",
    "grids",
    "client",
    "chunk_units",
)


def _sweep_on_cluster(client, chunk_units, betas, seeds, setup, kw, outcome, rows, bar, on_chunks, cancel) -> None:
    """Every beta's run at once on ``client``'s workers (:func:`endophoton.distributed.run_many`:
    the same requests, reducer and stop rule as ``ep.run``). A run is analysed and accepted in
    beta order as soon as it and every run before it have ended; after a cancel the sweep ends
    at the first unfinished beta, as a local sweep ends at its cancelled run."""
    from .. import distributed
    from ..run import Result, run_request, with_warnings

    setups = [setup(beta) for beta in betas]
    notes = [placement.check_rig(scene, rig) for scene, _, rig in setups]  # as ep.run checks each run
    request_kw = {k: v for k, v in kw.items() if k not in ("progress", "cancel")}
    requests = [
        (scene, rig, run_request(scene, rig, **dict(request_kw, seed=seeds[i])), functools.partial(bar.engine_of, i))
        for i, (scene, _, rig) in enumerate(setups)
    ]
    results = [None] * len(setups)
    state = {"next": 0, "open": True}

    def finished(i, raw):
        scene, _, rig = setups[i]
        results[i] = Result(with_warnings(raw, notes[i]), scene, rig, requests[i][2])
        while state["open"] and state["next"] < len(setups) and results[state["next"]] is not None:
            j = state["next"]
            _, unit, rig = setups[j]
            res = results[j]
            state["open"] = rows.accept(j, outcome(j, res, float(res.seconds), betas[j], rig, unit))
            results[j] = None  # analysed: its records are no longer needed
            state["next"] += 1

    def chunks(done, total):
        bar.chunks(done, total)
        if on_chunks is not None:
            notification_done("on_chunks", on_chunks(done, total))

    distributed.run_many(
        client, requests, chunk_units=chunk_units, cancel=cancel, on_chunk=chunks, on_finished=finished
    )


def _view_meta(meta: dict, seed_per_beta: bool, rig_kwargs: dict, visibility, contrast_target) -> None:
    """Adds to ``meta`` the sweep's seeds rule, its light, and its view request and target, if any."""
    meta["seed_per_beta"] = seed_per_beta
    light = rig_kwargs.get("spectrum")  # the rig's light: None = flat white 400-700 nm
    meta["light"] = "white" if light is None else str(getattr(light, "name", "") or "table")
    if visibility is not None:
        meta["visibility"] = jsonable(dict(visibility))
    if contrast_target is not None:
        meta["contrast_target"] = contrast_target.to_dict()


def sweep(
    scene_or_builder: Any = None,
    betas: Iterable[float] = range(0, 60, 5),
    store: int = 500_000,
    seed: int = 1,
    threads: int = 0,
    fluorescent_only: bool = True,
    fluorescence_rule: str = "paper",
    distance: float | None = None,
    point: Sequence[float] = (0.0, 0.0, 0.0),
    normal: Sequence[float] = (0.0, 0.0, 1.0),
    tilt_axis: Sequence[float] = (0.0, 1.0, 0.0),
    progress: bool | Callable = True,
    out_dir: str | os.PathLike | None = None,
    n_batches: int = DEFAULT_BATCHES,
    max_angle_deg: float = IMPORTANT_ANGLE_DEG,
    rig_kwargs: Mapping[str, Any] | None = None,
    rig_builder: Callable | None = None,
    run_kwargs: Mapping[str, Any] | None = None,
    cancel: Any = None,
    plots: bool = True,
    report: bool = True,
    on_beta: Callable | None = None,
    visibility: Mapping[str, Any] | None = None,
    client: Any = None,
    chunk_units: int = 0,
    on_chunks: Callable | None = None,
    on_run: Callable | None = None,
    seed_per_beta: bool = True,
    target: Any = None,
    live: Mapping[str, Any] | None = None,
) -> SweepResult:
    """Run the seed's beta sweep and analyse every run; returns a :class:`SweepResult`
    (rows in the order of ``betas``).

    The arguments are described once, in ``docs/sweep.md`` ("Running it": ``scene_or_builder``,
    the rig from ``distance``/``point``/``normal``/``tilt_axis`` and ``rig_kwargs`` or
    ``rig_builder(beta, scene)``, ``run_kwargs``, the same ``seed`` at every beta, ``cancel``,
    ``progress``, ``on_beta``), ``docs/render.md`` ("In a β sweep": ``visibility``) and
    ``docs/distributed.md`` ("Sweeps on a cluster": ``client``, ``chunk_units``, ``on_chunks``;
    ``run_kwargs={"client": c}`` does the same). Besides those:

    store : N, escape records stored per beta; threads : engine threads (0 = all cores).
    out_dir : if given, write ``sweep.csv``, ``sweep.json``, the plots and ``report.md``
        there (``plots``/``report`` switch the last two; :func:`write_outputs`).
    n_batches : B for the batch-means standard errors.
    max_angle_deg : angle criterion of the important fraction (seed: 15 deg).
    seed_per_beta : True (default): beta k runs with its own seed, :func:`beta_seed` (independent
        runs: the report's test of "varies with beta" holds its level, docs/sweep.md); False: ``seed``
        at every beta (common random numbers).
    target : None, or an accuracy on the answer: ``(criterion, stderr[, max_packets])`` (criterion
        "red_green", "red_green_camera", "fluorescence" or "white"; ``sweep.view_runs.ContrastTarget``):
        after its store run, each beta's view is topped up until that contrast's standard error is at
        most ``stderr``, or until ``max_packets`` (default 2e7) packets are behind the image
        (docs/sweep.md, "Sweeps to a target accuracy"). Needs ``visibility``.
    on_run : ``on_run(i_beta, beta_deg, result)`` is given each beta's engine ``Result``
        (records, totals, rig; also a cancelled one) before it is analysed. The sweep keeps
        only the reduced rows; a caller that wants every beta's records (the add-on's per-beta
        collections) keeps them here, at about 100 bytes per record.
    live : None, or ``ep.run_live``'s own keywords (docs/sweep.md): each beta runs through ``ep.run_live``
        (the same bits) and ``on_snapshot(i_beta, beta_deg, result)`` gets its snapshots. Not with ``client``.
    """
    arguments = dict(locals())
    _check_sweep_arguments(arguments)
    betas = _checked_betas(betas, store, n_batches)
    contrast_target = _contrast_target(target, visibility)
    seeds = [beta_seed(seed, k, seed_per_beta) for k in range(len(betas))]
    rig_kwargs = dict(rig_kwargs or {})
    run_kwargs = dict(run_kwargs or {})
    client = run_kwargs.pop("client", None) if client is None else client
    chunk_units = run_kwargs.pop("chunk_units", chunk_units)
    bar = _Progress(
        betas, enabled=(progress is True), user=progress if callable(progress) else None, chunks=client is not None
    )
    static_scene = _static_scene(scene_or_builder)
    kw = _engine_kwargs(store, fluorescent_only, fluorescence_rule, seed, threads, bar.engine, cancel, run_kwargs)
    meta = _sweep_meta(arguments, static_scene)
    _view_meta(meta, seed_per_beta, rig_kwargs, visibility, contrast_target)
    setup = _setup_of(static_scene, scene_or_builder, distance, point, normal, tilt_axis, rig_kwargs, rig_builder, meta)
    analyse = functools.partial(
        _beta_outcome,
        normal=normal,
        run_kwargs=kw,
        meta=meta,
        n_batches=n_batches,
        max_angle_deg=max_angle_deg,
        visibility=visibility,
        out_dir=out_dir,
        contrast_target=contrast_target,
    )

    def outcome(i, res, seconds, beta, rig, unit):
        if on_run is not None:
            notification_done("on_run", on_run(i, beta, res))
        return analyse(res, seconds, beta, rig, unit, seeds[i])

    if static_scene is not None:
        _check_placements(betas, setup)
    rows = _Rows(betas, meta, bar, on_beta)
    try:
        if client is not None:
            _sweep_on_cluster(client, chunk_units, betas, seeds, setup, kw, outcome, rows, bar, on_chunks, cancel)
        else:
            _sweep_locally(betas, seeds, setup, kw, outcome, rows, bar, cancel, live, chunk_units)
    finally:
        bar.close()
    result = rows.result()
    if out_dir is not None:
        write_outputs(result, out_dir, plots=plots, report=report)
    return result


def write_outputs(result: SweepResult, out_dir: str | os.PathLike, plots: bool = True, report: bool = True) -> dict:
    """Write sweep.csv, sweep.json, the plots and report.md into ``out_dir``; returns the paths.
    Every file's path is checked before any is written (a directory named like one of them is
    refused by name, ValueError), so a refused write leaves the folder as it was. So are betas
    closer than ``sweep_schema.BETA_RESOLUTION_DEG`` (a result read from a JSON file not written by
    :func:`sweep`): no fit over them is posed."""
    check_beta_spacing(result.betas, "result.betas")
    os.makedirs(out_dir, exist_ok=True)
    vis = bool(result.meta.get("visibility"))
    check_output_files(out_dir, output_file_names(result.betas, visibility=vis, plots=plots, report=report))
    paths = {
        "csv": result.to_csv(os.path.join(out_dir, "sweep.csv")),
        "json": result.to_json(os.path.join(out_dir, "sweep.json")),
    }
    # plots and report load matplotlib: imported here so that ``import endophoton`` does not
    # (neither imports this module, so this is no hidden cycle)
    if plots and result.rows:  # a sweep cancelled before its first record has no rows to plot
        from ..plots import plot_all

        paths["plots"] = plot_all(result, out_dir)
    if report and result.rows:
        from ..report import write_report

        paths["report"] = write_report(result, out_dir)
    vis = result.meta.get("visibility")
    if vis and plots and result.rows:
        from .view_sweep import write_visibility_outputs

        extra = write_visibility_outputs(
            result.betas,
            result.rows,
            out_dir,
            vis["target"],
            vis["background"],
            seed_per_beta=bool(result.meta.get("seed_per_beta", False)),
            surround_px=vis.get("surround_px"),
            meta=result.meta,
        )
        paths.update({k: v for k, v in extra.items() if k != "report"})
        if "report" in paths:
            with open(paths["report"], encoding="utf-8") as fh:
                atomic_write_text(paths["report"], fh.read().rstrip("\n") + "\n\n" + extra["report"])
    return paths
