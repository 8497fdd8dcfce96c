# SPDX-License-Identifier: MIT
"""The β sweep from Blender: collect and validate inputs (main thread), run
``endophoton.sweep`` in a worker thread, load its plots as images (main thread).

The scene is exported once (the same regions and ``ep.Scene(unit="m")`` as the
Run operator builds) and the rig's geometry is read from the rig's properties:
for every β the package rebuilds the head with ``ep.EndoscopeRig.from_beta``
about the rig's target, normal and tilt axis at its distance, with its tip
dimensions — exactly what ``endophoton_addon.sweep_blend`` does, so both paths give
the same numbers for the same seed.

The worker thread never touches ``bpy``: it gets the engine scene and plain
values in :class:`SweepInputs`, runs the sweep, writes the output files with
``write_outputs`` (atomic writes) and reduces the result to a plain summary.
"""

import argparse
import contextlib
import math
import os
import threading
import time
import uuid
from dataclasses import dataclass
from typing import Optional

import numpy as np

from . import export, guards, live_view, package_finder, preferences, rig, simulation, sweep_answer, sweep_blend
from .errors import InputError
from .keys import SWEEP_PLOT_KEY

IMAGE_PREFIX = "EndoPhoton Sweep: "  # + the plot's file name, e.g. "EndoPhoton Sweep: energy.png"
IMAGE_KEY = SWEEP_PLOT_KEY  # ID property on every image the sweep loaded
SUMMARY_KEY = "endophoton_sweep"  # ID property on the scene: the last finished sweep
DEFAULT_DIR_NAME = "endophoton_sweep"
# keep_runs "AUTO": per-β collections up to β values × Store N records; a kept escape
# record costs 100 bytes (17 columns, measured on the engine's records): 2e6 -> 200 MB.
KEEP_AUTO_RECORDS = 2_000_000
SWEEP_ID_KEY = "sweep_id"  # in a β collection's parameters (results.PARAMS_KEY): the sweep it belongs to


@dataclass
class SweepInputs:
    """Everything a sweep needs, as plain values (no bpy objects)."""

    scene_name: str
    regions: list
    rig_name: str
    betas: list  # degrees
    store: int
    seed: int
    threads: int
    n_batches: int
    fluorescent_only: bool
    fluorescence_rule: str
    distance_m: float  # head distance from the target, metres (the engine unit)
    point_m: tuple  # target point, metres
    normal: tuple
    tilt_axis: tuple
    rig_params: dict  # head_diameter_mm, ... (EndoscopeRig keywords)
    out_dir: str
    scale_length: float
    seed_per_beta: bool = True  # β k runs with its own seed (endophoton.sweep.schema.beta_seed)
    keep_runs: bool = False  # every β becomes a results collection (its records kept until the end)
    endoscope_view: bool = False  # ... with the rig camera's images (ep.render_view)
    live_view: bool = False  # each β's images refresh while it runs (live_view.py), with endoscope_view
    timestamp: str = ""
    sweep_id: str = ""  # tags the sweep's β collections (SWEEP_ID_KEY); unique per sweep
    visibility: Optional[dict] = None  # endophoton.sweep's visibility request (sweep_answer.visibility_request)

    def sweep_kwargs(self):
        """Keyword arguments of ``endophoton.sweep`` (all but the scene, progress and cancel)."""
        visibility = {} if self.visibility is None else {"visibility": dict(self.visibility)}
        return dict(
            **visibility,
            betas=list(self.betas),
            store=self.store,
            seed=self.seed,
            threads=self.threads,
            fluorescent_only=self.fluorescent_only,
            fluorescence_rule=self.fluorescence_rule,
            distance=self.distance_m,
            point=self.point_m,
            normal=self.normal,
            tilt_axis=self.tilt_axis,
            rig_kwargs=dict(self.rig_params),
            n_batches=self.n_batches,
            seed_per_beta=self.seed_per_beta,
        )


# --- validation (main thread) ---------------------------------------------------
def parse_betas(ep, text, who):
    """The β list of the ``betas`` field, with the command line's grammar
    (``endophoton.sweep.driver.parse_betas``); raises InputError naming the field."""
    field = f"{who}: sweep.betas = '{text}'"
    if not text.strip():
        raise InputError(f"{field} is empty; give angles in degrees, e.g. '0,10,20' or '0:60:5'")
    from endophoton.sweep import driver, schema

    try:
        values = driver.parse_betas(text, spacing=False)  # spacing: below, worded for this field
    except (ValueError, argparse.ArgumentTypeError) as e:
        raise InputError(
            f"{field} must be a list '0,10,20' or a range 'start:stop:step' "
            f"(degrees, stop excluded) giving at least one angle: {e}"
        ) from None
    for beta in values:
        if not math.isfinite(beta) or not -90.0 < beta < 90.0:
            raise InputError(f"{field}: β = {schema.beta_text(beta)}° must be a finite angle in (-90, 90) degrees")
    try:  # the package's own rule: no two β closer than its resolution (sweep_schema.BETA_RESOLUTION_DEG)
        schema.check_beta_spacing(values, field)
    except ValueError as e:
        raise InputError(str(e)) from None
    return [float(b) for b in values]


def _rig_geometry(rig_obj, scale_length):
    """Target (m), normal, tilt axis, distance (m) and tip of the rig; raises InputError."""
    simulation._check_rig(rig_obj, scale_length)  # finite values, light guides inside the head
    s = rig_obj.endophoton_rig
    who = f"Object '{rig_obj.name}'"
    if not s.distance > 0.0:
        raise InputError(f"{who}: endophoton_rig.distance = {s.distance:g} must be > 0 for the sweep")
    normal = np.array(s.normal, dtype=np.float64)
    tilt = np.array(s.tilt_axis, dtype=np.float64)
    if np.linalg.norm(tilt) < 1e-12:
        raise InputError(f"{who}: endophoton_rig.tilt_axis has zero length; the sweep tilts about it")
    n = normal / np.linalg.norm(normal)
    if np.linalg.norm(tilt - (tilt @ n) * n) < 1e-9 * np.linalg.norm(tilt):
        raise InputError(
            f"{who}: endophoton_rig.tilt_axis is parallel to endophoton_rig.normal; " "the sweep tilts about it"
        )
    return sweep_blend.rig_sweep_geometry(rig_obj, scale_length)


def keeps_runs(mode, n_betas, store):
    """Whether the sweep keeps every β's records (``keep_runs`` mode AUTO / ON / OFF)."""
    return mode == "ON" or (mode == "AUTO" and n_betas * store <= KEEP_AUTO_RECORDS)


def collect_sweep_inputs(context, ep):
    """Read and validate the scene, the rig and the sweep settings; export once.

    Returns ``(SweepInputs, ep.Scene)``.  Creates no datablock and no file.
    Raises InputError (message names the object/scene and field).
    """
    scene = context.scene
    settings = scene.endophoton.sweep
    who = f"Scene '{scene.name}'"
    scale = scene.unit_settings.scale_length
    if not math.isfinite(scale) or scale <= 0.0:
        raise InputError(f"{who}: unit_settings.scale_length = {scale:g} must be > 0")

    betas = parse_betas(ep, settings.betas, who)
    if settings.store <= 0:
        raise InputError(f"{who}: sweep.store = {settings.store} must be > 0")
    if settings.batches < 2:
        raise InputError(f"{who}: sweep.batches = {settings.batches} must be >= 2")
    if settings.store < settings.batches:
        raise InputError(
            f"{who}: sweep.store = {settings.store} must be >= sweep.batches = "
            f"{settings.batches} (one record per batch at least)"
        )
    if settings.threads < 0:
        raise InputError(f"{who}: sweep.threads = {settings.threads} must be >= 0")
    guards.check_display(scene.endophoton, who)
    out_dir = guards.resolve_folder(settings.output_dir, f"{who}: sweep.output_dir", DEFAULT_DIR_NAME)

    depsgraph = context.evaluated_depsgraph_get()
    regions = export.export_regions(scene, context.view_layer, depsgraph)
    if not scene.endophoton.allow_unusual_scale:
        guards.check_unit_scale(regions, scale, who)
    guards.check_overlaps(regions)
    rig_obj = simulation._pick_rig(scene)
    geometry = _rig_geometry(rig_obj, scale)
    visibility = sweep_answer.visibility_request(settings, [r.name for r in regions], who)
    if visibility is not None and not rig.has_camera(rig_obj):
        raise InputError(f"{who}: sweep.visibility needs the rig's camera; rig '{rig_obj.name}' has none")

    inputs = SweepInputs(
        scene_name=scene.name,
        regions=regions,
        rig_name=rig_obj.name,
        betas=betas,
        store=int(settings.store),
        seed=int(settings.seed),
        seed_per_beta=bool(settings.seed_per_beta),
        threads=int(settings.threads),
        n_batches=int(settings.batches),
        fluorescent_only=bool(settings.fluorescent_only),
        fluorescence_rule=settings.fluorescence_rule,
        out_dir=out_dir,
        scale_length=float(scale),
        keep_runs=keeps_runs(settings.keep_runs, len(betas), int(settings.store)),
        endoscope_view=bool(scene.endophoton.output_views) and rig.has_camera(rig_obj),
        live_view=bool(scene.endophoton.live_view),
        timestamp=time.strftime("%Y%m%d-%H%M%S"),
        sweep_id=f"sweep-{time.strftime('%Y%m%d-%H%M%S')}-{uuid.uuid4().hex[:8]}",
        visibility=visibility,
        **geometry,
    )
    try:
        engine_scene = simulation.build_engine_scene(ep, regions)
    except ValueError as exc:
        raise simulation.engine_rejected(exc, "sweep") from exc
    # The head for every β, as the sweep will build it, and its placement in the
    # scene: the package's own check (ep.sweep makes it too), before anything starts.
    from endophoton.sweep import driver

    try:
        driver.check_placements(
            engine_scene,
            betas,
            distance=inputs.distance_m,
            point=inputs.point_m,
            normal=inputs.normal,
            tilt_axis=inputs.tilt_axis,
            rig_kwargs=inputs.rig_params,
        )
    except ValueError as exc:
        raise InputError(f"{who}: sweep.betas = '{settings.betas}' with rig '{rig_obj.name}': {exc}") from None
    return inputs, engine_scene


# --- the job ----------------------------------------------------------------------
@dataclass
class SweepProgress:
    index: int  # β being run (0-based)
    n: int
    beta: float
    done: int  # packets of the current β so far
    fraction: float  # of the whole sweep
    elapsed: float
    eta: Optional[float]  # seconds, None when unknown (first β in store-N mode)
    phase: str  # "running" or "writing"

    def text(self):
        if self.phase == "writing":
            return f"Sweep: all {self.n} β done, writing CSV, JSON, plots and report…"
        eta = "--" if self.eta is None else simulation.format_seconds(self.eta)
        return (
            f"Sweep β={self.beta:g}° ({self.index + 1}/{self.n}), ETA {eta} · " f"{self.done:,} packets · Esc to cancel"
        )

    def panel_lines(self):
        if self.phase == "writing":
            return [f"Sweep: {self.n}/{self.n} β done", "Writing outputs…"]
        eta = "--" if self.eta is None else simulation.format_seconds(self.eta)
        return [f"Sweep β={self.beta:g}° ({self.index + 1}/{self.n})", f"{self.done:,} packets · ETA {eta}"]


class SweepJob(simulation.BackgroundJob):
    """A β sweep in a worker thread.  The main thread calls ``start``, ``cancel``,
    ``progress``, ``done``; the worker writes ``result``/``paths``/``summary``
    or ``error`` (or sets ``cancelled``) and then the finished event."""

    thread_name = "endophoton-sweep"

    def __init__(self, ep, inputs, engine_scene):
        self.ep = ep
        self.inputs = inputs
        self.engine_scene = engine_scene
        self.scheduler = preferences.scheduler_address()  # read here: the worker thread has no bpy
        # the current β's view while it runs, as a Run's (the rig's camera, Live View on, no Dask)
        self.live = live_view.LiveView(ep, inputs.threads) if live_view.wanted(inputs, self.scheduler) else None
        self.collections = []  # the β collections finish_sweep made (main thread)
        self.token = ep.CancelToken()
        self.result = None
        self.paths = None
        self.summary = None
        self.runs = {}  # β index -> engine Result, while inputs.keep_runs (worker thread)
        self.beta_runs = []  # finished, not cancelled: [(simulation.RunInputs, Result, view, view error)]
        self.cancelled = False
        self.error = None
        self.error_traceback = None
        self._lock = threading.Lock()
        self._finished_betas = 0  # β values run and analysed
        self._engine_index = 0  # β of the engine's last progress report
        self._done = 0  # packets of that β so far
        self._packets_per_beta = 0  # packets the last finished β needed (estimate for the current one)
        self._chunks = None  # on a Dask cluster: (chunks merged, estimated chunks) over all β
        self._phase = "running"
        self._t0 = None
        self._finished = threading.Event()
        self._thread = None

    # --- main thread: start(), cancel(), done and wait() from BackgroundJob ---
    def progress(self):
        """Overall fraction = (finished β + fraction of the current β) / n.  In store-N
        mode the current β's packet total is unknown: it is estimated by the packets
        the previous β needed (none during the first β: its fraction stays 0).
        On a Dask cluster all β run at once: the fraction is that of their chunks."""
        with self._lock:
            finished, phase = self._finished_betas, self._phase
            done = self._done if self._engine_index == finished else 0
            per_beta, chunks = self._packets_per_beta, self._chunks
        n = len(self.inputs.betas)
        index = min(finished, n - 1)
        current = min(done / per_beta, 0.99) if per_beta > 0 else 0.0
        fraction = min(1.0, (finished + current) / n)
        if chunks is not None and chunks[1] > 0:
            fraction = min(chunks[0] / chunks[1], 0.99)
        fraction = 1.0 if phase == "writing" else fraction
        elapsed = time.monotonic() - self._t0 if self._t0 else 0.0
        eta = elapsed * (1.0 - fraction) / fraction if 0.0 < fraction < 1.0 else None
        return SweepProgress(index, n, self.inputs.betas[index], done, fraction, elapsed, eta, phase)

    def panel_lines(self):
        return self.progress().panel_lines()

    # --- worker thread (no bpy here) ----------------------------------------
    def _on_progress(self, index, _n, done, _total):
        with self._lock:
            self._engine_index = index
            self._done = int(done)

    def _on_chunks(self, merged, total):
        with self._lock:
            self._chunks = (int(merged), int(total))

    def _on_beta(self, index, _n, row):
        if row["cancelled"]:  # a cancelled partial run: the sweep ends here
            return
        with self._lock:
            self._finished_betas = index + 1
            self._packets_per_beta = int(row["packets_traced"])

    def _on_run(self, index, _beta, result):
        if not getattr(result, "cancelled", False):
            self.runs[index] = result

    def _body(self):
        from endophoton.sweep import driver as bs

        if self.inputs.keep_runs:
            extra_keep = {"on_run": self._on_run}
        else:
            extra_keep = {}
        with contextlib.ExitStack() as stack:
            client = simulation.cluster_client(stack, self.ep, self.scheduler)
            # on a cluster all β run at once and cancel cancels their tasks
            extra = {"client": client, "on_chunks": self._on_chunks} if client is not None else {}
            if client is None and self.live is not None:  # each β through ep.run_live: the same bits
                extra = self.live.sweep_kwargs()
            result = bs.sweep(
                self.engine_scene,
                progress=self._on_progress,
                on_beta=self._on_beta,
                cancel=self.token,
                out_dir=None,
                **self.inputs.sweep_kwargs(),
                **extra,
                **extra_keep,
            )
        if self.token.cancelled or result.meta.get("cancelled") or any(row["cancelled"] for row in result.rows):
            self.cancelled = True  # nothing is written, nothing will be added
            self.runs = {}
            return
        self.beta_runs = [self._beta_run(i, self.runs.pop(i)) for i in sorted(self.runs) if not self.token.cancelled]
        if self.token.cancelled:  # Esc while the kept runs' views were rendered (each stops within a block)
            self.cancelled, self.runs, self.beta_runs = True, {}, []
            return
        with self._lock:
            self._phase = "writing"
        paths = bs.write_outputs(result, self.inputs.out_dir)
        self.summary = sweep_summary(self.ep, result, paths, self.inputs.out_dir)
        self.paths = paths
        self.result = result

    def _beta_run(self, index, result):
        """(RunInputs, Result, view, view error) of β ``index``: what a single Run of
        that β in store-N mode would hand to simulation.collection_from_run (worker thread)."""
        inputs = beta_run_inputs(self.inputs, index, result, self.ep)
        view, view_error = simulation.endoscope_view(self.ep, inputs, result, self.token)
        return inputs, result, view, view_error


def beta_run_inputs(inputs, index, result, ep):
    """simulation.RunInputs of the sweep ``inputs``' β number ``index`` (plain values, no bpy):
    a store-N run of that β with its seed (``endophoton.sweep.schema.beta_seed``), no grids (the sweep
    asks for none)."""
    from endophoton.sweep.schema import beta_seed

    beta = inputs.betas[index]
    source = getattr(result, "source", None)
    matrix = getattr(source, "transform", None)
    return simulation.RunInputs(
        scene_name=inputs.scene_name,
        regions=inputs.regions,
        rig_name=inputs.rig_name,
        rig_matrix=np.eye(4) if matrix is None else np.asarray(matrix, dtype=np.float64),
        rig_params=dict(inputs.rig_params),
        beta_deg=float(beta),
        kind="store",
        count=int(inputs.store),
        seed=beta_seed(inputs.seed, index, inputs.seed_per_beta),
        threads=int(inputs.threads),
        fluorescent_only=inputs.fluorescent_only,
        fluorescence_rule=inputs.fluorescence_rule,
        output_points=True,
        grid_voxel_m=None,
        grid_path=None,
        grid_per_fluorophore=False,
        scale_length=inputs.scale_length,
        endoscope_view=inputs.endoscope_view,
        timestamp=inputs.timestamp,
    )


def min_fit_points(ep):
    """Angles the panel needs before it shows a best β: the paper's fit degree + 3, so that the
    fit keeps >= 2 degrees of freedom (a degree-6 polynomial through fewer points interpolates
    the noise)."""
    from endophoton.paper import PAPER_TRENDS

    return int(PAPER_TRENDS["energy_fit_degree"]) + 3


def sweep_summary(ep, result, paths, out_dir):
    """Plain-value summary of a finished sweep (no bpy): the β of the energy
    maximum by the paper's degree-6 fit (sum over stored records, and per packet
    traced) with its standard error when there are enough angles, the range of
    packets traced, times and where the files are.  The fit and its error are the
    written report's (``ep.report.compute_trends``: the fit's maximum computed again
    from every batch of packets, one rule in one place), so the panel shows the
    numbers of report.md.  A β without a fit (too few angles) is None, never NaN; the scene's copy
    leaves it out (Blender's ID properties hold no None), which :func:`summary_rows`
    shows as "needs ≥ N β values"."""
    from endophoton.io import no_nan
    from endophoton.report import compute_trends

    betas = result.betas
    trends = compute_trends(result)
    enough = len(result.rows) >= min_fit_points(ep)
    best = {}
    for key in ("energy_total", "energy_per_packet"):
        fit = trends.get(key + "_fit") or {}
        found = enough and trends.get(key + "_peak") is not None
        best.update(
            {
                f"best_beta_{key}": trends[key + "_peak"] if found else None,
                f"best_beta_{key}_se": trends.get(key + "_peak_se") if found else None,
                f"best_beta_{key}_interior": bool(found and fit.get("interior")),
            }
        )
    best_total = best["best_beta_energy_total"]
    degree = int(trends["energy_total_fit"]["deg"]) if best_total is not None else 0
    packets = result.column("packets_traced")
    return no_nan(
        {
            "out_dir": out_dir,
            "csv": paths["csv"],
            "n_betas": len(result.rows),
            "beta_min": float(betas.min()),
            "beta_max": float(betas.max()),
            "store": int(result.meta.get("store", 0)),
            "seed": int(result.meta.get("seed", 0)),
            "seed_per_beta": bool(result.meta.get("seed_per_beta", False)),
            **best,
            "fit_degree": degree,
            "fit_min_betas": min_fit_points(ep),
            "packets_min": float(np.nanmin(packets)),
            "packets_max": float(np.nanmax(packets)),
            "seconds": float(np.nansum(result.column("seconds"))),
            "plots": len(paths.get("plots", [])),
            **sweep_answer.visibility_summary(result),
        }
    )


# --- main thread: start, finish ----------------------------------------------------
def prepare_job(context, interactive=False):
    """Validate, export once and build the job; raises InputError / EngineMissing.

    ``interactive``: the modal operator's run; threads = 0 then leaves one core
    to the UI (simulation.interactive_threads; the numbers do not depend on it).
    """
    ep = package_finder.require()
    if not hasattr(ep, "sweep"):
        raise package_finder.EngineMissing(
            f"EndoPhoton package at '{getattr(ep, '__file__', '?')}' is too old: "
            "it has no β sweep (endophoton.sweep.driver)"
        )
    inputs, engine_scene = collect_sweep_inputs(context, ep)
    if interactive:
        inputs.threads = simulation.interactive_threads(inputs.threads)
    return SweepJob(ep, inputs, engine_scene)


def plot_paths(paths):
    """The PNGs of a finished sweep to load: its plots, and with visibility the contrast-against-β
    plot (``visibility.png``) and the contact sheet of the views when it was made."""
    return list(paths.get("plots", [])) + [paths[key] for key in ("plot", "contact_sheet") if key in paths]


def image_name(path):
    return IMAGE_PREFIX + os.path.basename(path)


def sweep_images():
    """The images loaded by sweeps (tagged with IMAGE_KEY)."""
    import bpy

    return [img for img in bpy.data.images if img.get(IMAGE_KEY)]


def load_plot_images(paths):
    """Load the plot PNGs as images named ``"EndoPhoton Sweep: <file>"``.

    An image of that name from an earlier sweep is pointed at the new file and
    reloaded; other images are loaded with ``check_existing=True`` (a file
    already open is reused and reloaded).  Plot images of an earlier sweep that
    this one did not produce (other β values) are removed.  Each has a fake user
    (the sweep's files stay external, in its output folder), so the plots are still
    there when the .blend is saved and reopened.
    """
    import bpy

    from . import blend_paths

    wanted = {image_name(path): os.path.abspath(path) for path in paths}
    for img in sweep_images():
        if img.name not in wanted:
            bpy.data.images.remove(img)
    images = []
    for name, path in wanted.items():
        img = bpy.data.images.get(name)
        if img is not None and img.get(IMAGE_KEY):
            if os.path.normpath(bpy.path.abspath(img.filepath)) != os.path.normpath(path):
                img.filepath = blend_paths.stored_path(path)
        else:
            try:
                img = bpy.data.images.load(path, check_existing=True)
            except RuntimeError as exc:
                raise RuntimeError(f"Sweep plot '{path}' could not be loaded: {exc}") from exc
            img.name = name
            img[IMAGE_KEY] = True
            img.filepath = blend_paths.stored_path(img.filepath)
        img.use_fake_user = True  # nothing else uses a plot: kept when the .blend is saved and reopened
        img.reload()
        images.append(img)
    return images


def finish_sweep(context, job):
    """Load the plots and store the summary (main thread).

    Returns the list of images, or None when the sweep was cancelled (then
    nothing is added).  Raises RuntimeError if the worker failed.
    """
    import bpy

    if not job.done:
        raise RuntimeError("finish_sweep called before the sweep finished")
    if job.error is not None:
        raise RuntimeError(f"EndoPhoton sweep failed: {type(job.error).__name__}: {job.error}")
    if job.cancelled or job.result is None:
        return None
    collections = job.collections = make_beta_collections(context, job)
    images = load_plot_images(plot_paths(job.paths))
    scene = bpy.data.scenes.get(job.inputs.scene_name) or context.scene
    summary = {k: v for k, v in job.summary.items() if v is not None}  # ID properties hold no None
    scene[SUMMARY_KEY] = dict(summary, images=len(images), collections=[c.name for c in collections])
    return images


def discard_job(job):
    """A cancelled sweep leaves nothing to discard: it writes its files only after its last β
    (and not at all once cancelled), and adds nothing to the scene until finish_sweep."""
    job.beta_runs = []
    job.runs = {}


def sweep_id(inputs):
    return inputs.sweep_id


def make_beta_collections(context, job):
    """One results collection per kept β (simulation.collection_from_run, the single
    Run's path), tagged with the sweep id, its β and the sweep's parameters, inside one
    parent collection per sweep ("EP Sweep <id>", tagged results.SWEEP_KEY).  All or
    nothing: a failure removes the β collections made so far and the parent."""
    import bpy

    from . import results

    if not job.beta_runs:
        return []
    parent = bpy.data.collections.new(f"EP Sweep {sweep_id(job.inputs).removeprefix('sweep-')}")
    parent[results.SWEEP_KEY] = sweep_id(job.inputs)
    bpy_scene(context, job).collection.children.link(parent)
    tags = {
        SWEEP_ID_KEY: sweep_id(job.inputs),
        "sweep_betas": [float(b) for b in job.inputs.betas],
        "sweep_store": int(job.inputs.store),
        "sweep_out_dir": job.inputs.out_dir,
    }
    made = []
    try:
        for index, (inputs, result, view, view_error) in enumerate(job.beta_runs):
            made.append(
                simulation.collection_from_run(
                    context,
                    inputs,
                    result,
                    view=view,
                    view_error=view_error,
                    tags=dict(tags, sweep_index=index),
                    parent=parent,
                )
            )
    except Exception:
        for collection in made:
            results.remove_run(collection)
        if parent.name in bpy.data.collections:
            bpy.data.collections.remove(parent)
        raise
    job.beta_runs = []  # the records now live in the meshes
    return made


def sweep_collections(scene, sweep=None):
    """The scene's β result collections (of the sweep id ``sweep``, or of any sweep)."""
    from . import results

    found = []
    for collection in results.result_collections(scene):
        params = collection.get(results.PARAMS_KEY)
        tag = params.get(SWEEP_ID_KEY) if params is not None else None
        if tag is not None and (sweep is None or tag == sweep):
            found.append(collection)
    return found


def report_finished(context, job):
    """Finish the sweep (main thread) and say what happened: ``(level, message)``."""
    images = finish_sweep(context, job)
    if images is None:
        return "WARNING", "EndoPhoton sweep cancelled; nothing was written or added"
    kept = len(sweep_collections(bpy_scene(context, job), sweep_id(job.inputs)))
    return "INFO", (
        f"EndoPhoton sweep: {len(job.inputs.betas)} β values, {kept} result collections, "
        f"{len(images)} plots loaded; files in '{job.inputs.out_dir}'"
    )


def bpy_scene(context, job):
    import bpy

    return bpy.data.scenes.get(job.inputs.scene_name) or context.scene


def summary_rows(scene):
    """(label, value) rows of the last sweep's summary for the panel; [] if none."""
    summary = scene.get(SUMMARY_KEY)
    if summary is None:
        return []
    s = summary.to_dict() if hasattr(summary, "to_dict") else dict(summary)

    def angle(key):
        value, se = s.get(f"best_beta_{key}"), s.get(f"best_beta_{key}_se")
        if value is None or not math.isfinite(value):
            return f"– (needs ≥ {s.get('fit_min_betas', '?')} β values)"
        edge = "" if s.get(f"best_beta_{key}_interior") else " at range edge"
        error = f"{se:.1f}" if se is not None and math.isfinite(se) else "n/a"
        return f"{value:.1f} ± {error}°{edge}"

    degree = s.get("fit_degree", 0)
    rows = sweep_answer.answer_rows(s) + [
        ("β", f"{s.get('beta_min', 0):g}…{s.get('beta_max', 0):g}° ({s.get('n_betas', 0)} values)"),
        (
            "Store N",
            f"{s.get('store', 0):,} · seed {s.get('seed', 0)}" + (" (+ one per β)" if s.get("seed_per_beta") else ""),
        ),
        ("Energy max β (sum)", angle("energy_total") + (f" deg-{degree} fit" if degree else "")),
        ("Energy max β (/packet)", angle("energy_per_packet")),
        ("Packets", f"{s.get('packets_min', 0):,.0f} – {s.get('packets_max', 0):,.0f}"),
        ("Time", f"{s.get('seconds', 0.0):.1f} s"),
        ("Plots", f"{s.get('images', 0)} images '{IMAGE_PREFIX}…'"),
        ("Per β", f"{len(s.get('collections', []))} result collections (Results)"),
        ("Folder", s.get("out_dir", "")),
    ]
    return rows
