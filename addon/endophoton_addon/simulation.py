# SPDX-License-Identifier: MIT
"""One simulation run: collect and validate inputs (main thread), run the
engine in a worker thread, hand the result to :mod:`results` (main thread).

The worker thread never touches ``bpy``: it gets numpy arrays and plain
Python values in :class:`RunInputs`, the engine objects built from them, and
returns the engine's Result.  The modal operator (operators.py), the blocking
``execute`` path and the tests all drive the same :class:`SimulationJob`.
"""

import contextlib
import math
import os
import re
import threading
import time
import traceback
from dataclasses import dataclass, field
from datetime import datetime
from typing import Optional

import numpy as np

from . import export, guards, live_view, package_finder, preferences, presets, rig, sweep_blend, volumes
from .errors import InputError

_ACTIVE_JOBS = set()
_ACTIVE_LOCK = threading.Lock()


@dataclass
class RunInputs:
    """Everything a run needs, as plain values (no bpy objects)."""

    scene_name: str
    regions: list
    rig_name: str
    rig_matrix: np.ndarray  # 4x4 float64, head frame -> world, metres
    rig_params: dict  # head_diameter_mm, ... (engine keyword units)
    beta_deg: float  # the rig's tilt from its surface normal, for naming
    kind: str  # "photons", "store" or "target"
    count: int  # packets, records, or the packet cap of a target run
    seed: int
    threads: int
    fluorescent_only: bool
    fluorescence_rule: str
    output_points: bool
    grid_voxel_m: Optional[float]  # None = no grids
    grid_path: Optional[str]
    grid_per_fluorophore: bool
    scale_length: float  # metres per Blender unit
    target_error: Optional[float] = None  # "target" runs: relative stderr goal of the diffuse reflectance
    endoscope_view: bool = False  # render the rig camera's images from the records (ep.render_view)
    live_view: bool = False  # ... and refresh them while the run is in flight (live_view.py)
    view_estimator: str = (
        "exitance"  # ep.render_view's: "exitance", "kernel", "knn" or "nee" (the run tallies the camera)
    )
    timestamp: str = field(default_factory=lambda: datetime.now().strftime("%Y%m%d-%H%M%S"))
    # The grids' quantities, ep.GridRequest's switches of the same names (check_grid_quantities); empty without grids.
    grid_quantities: dict = field(default_factory=dict)


def grid_folder(settings, who="Scene"):
    """The .vdb folder of the grid_dir field, checked writable (guards.resolve_folder)."""
    return guards.resolve_folder(settings.grid_dir, f"{who}: simulation.grid_dir", "endophoton_cache")


def _pick_rig(scene):
    chosen = scene.endophoton.rig
    if chosen is not None:
        if chosen.name not in scene.objects or not rig.is_rig(chosen):
            raise InputError(
                f"Scene '{scene.name}': simulation.rig '{chosen.name}' is not an endoscope rig "
                "in this scene; pick another or use Add Endoscope"
            )
        return chosen
    rigs = rig.find_rigs(scene)
    if not rigs:
        raise InputError(
            f"Scene '{scene.name}': simulation.rig is not set and the scene has no endoscope rig; " "use Add Endoscope"
        )
    if len(rigs) > 1:
        raise InputError(
            f"Scene '{scene.name}': simulation.rig is not set and the scene has {len(rigs)} rigs; "
            "choose one in the Simulation panel"
        )
    return rigs[0]


def _check_rig(obj, scale_length):
    s = obj.endophoton_rig
    who = f"Object '{obj.name}'"
    for name in ("beta", "distance", "head_diameter", "light_diameter", "light_offset", "cone_angle", "camera_fov"):
        value = getattr(s, name)
        if not math.isfinite(value):
            raise InputError(f"{who}: endophoton_rig.{name} = {value:g} must be a finite number")
    for name in ("target", "normal", "tilt_axis"):
        value = tuple(getattr(s, name))
        if not all(math.isfinite(v) for v in value):
            raise InputError(f"{who}: endophoton_rig.{name} = {value} must be finite")
    if np.linalg.norm(tuple(s.normal)) < 1e-12:
        raise InputError(f"{who}: endophoton_rig.normal has zero length")
    matrix = np.array(obj.matrix_world, dtype=np.float64)
    if not np.all(np.isfinite(matrix)):
        raise InputError(f"{who}: matrix_world is not finite")
    if abs(np.linalg.det(matrix[:3, :3])) < 1e-12:
        raise InputError(f"{who}: matrix_world is singular (zero scale)")
    params = rig.rig_parameters(obj, scale_length)
    if params["light_offset_mm"] + 0.5 * params["light_diameter_mm"] > 0.5 * params["head_diameter_mm"] + 1e-9:
        raise InputError(
            f"{who}: endophoton_rig.light_offset + light_diameter / 2 puts the light guides "
            "outside the head (head_diameter / 2)"
        )
    # β as placed: angle between the viewing direction and −normal, signed like the property.
    axis = np.array(rig.light_axis_world(obj))
    normal = np.array(s.normal, dtype=np.float64)
    normal /= np.linalg.norm(normal)
    beta = math.degrees(math.acos(max(-1.0, min(1.0, float(-axis @ normal)))))
    beta = math.copysign(beta, s.beta) if s.beta != 0.0 else beta
    return rig.rigid_world_matrix(obj, scale_length), params, beta


def collect_inputs(context):
    """Read and validate everything from the scene.  Creates no datablock.

    Raises InputError (message names the object/scene and field).
    """
    scene = context.scene
    settings = scene.endophoton
    who = f"Scene '{scene.name}'"
    scale = scene.unit_settings.scale_length
    if not math.isfinite(scale) or scale <= 0.0:
        raise InputError(f"{who}: unit_settings.scale_length = {scale:g} must be > 0")

    depsgraph = context.evaluated_depsgraph_get()
    regions = export.export_regions(scene, context.view_layer, depsgraph)

    rig_obj = _pick_rig(scene)
    rig_matrix, rig_params, beta_deg = _check_rig(rig_obj, scale)

    kind, count, target_error = presets.resolve_budget(
        settings.quality, settings.mode, settings.photons, settings.store
    )
    if count <= 0:
        field_name = "store" if kind == "store" else "photons"
        raise InputError(f"{who}: simulation.{field_name} = {count} must be > 0")
    if settings.threads < 0:
        raise InputError(f"{who}: simulation.threads = {settings.threads} must be >= 0")
    guards.check_display(settings, who)

    views = bool(settings.output_views) and rig.has_camera(rig_obj)
    if not settings.output_points and not settings.output_grids and not views:
        raise InputError(
            f"{who}: simulation outputs are all off; enable the point cloud, the grids "
            "or the endoscope-view images (the rig needs a camera)"
        )

    estimator = view_estimator(settings, who, kind, views)
    voxel_m = grid_path = None
    grid_quantities = {}
    if settings.output_grids:
        voxel = settings.voxel_size
        if not math.isfinite(voxel) or voxel <= 0.0:
            raise InputError(f"{who}: simulation.voxel_size = {voxel:g} must be a finite number > 0")
        voxel_m = voxel * scale
        grid_quantities = check_grid_quantities(settings, who, regions)
        inputs_stamp = datetime.now().strftime("%Y%m%d-%H%M%S-%f")
        grid_path = os.path.join(grid_folder(settings, who), f"endophoton_{inputs_stamp}.vdb")

    inputs = RunInputs(
        scene_name=scene.name,
        regions=regions,
        rig_name=rig_obj.name,
        rig_matrix=rig_matrix,
        rig_params=rig_params,
        beta_deg=beta_deg,
        kind=kind,
        count=int(count),
        seed=int(settings.seed),
        threads=int(settings.threads),
        fluorescent_only=bool(settings.fluorescent_only),
        fluorescence_rule=settings.fluorescence_rule,
        output_points=bool(settings.output_points),
        grid_voxel_m=voxel_m,
        grid_path=grid_path,
        grid_per_fluorophore=bool(settings.grid_per_fluorophore),
        scale_length=float(scale),
        target_error=target_error,
        endoscope_view=views,
        live_view=bool(settings.live_view),
        view_estimator=estimator,
        grid_quantities=grid_quantities,
    )
    check_before_run(scene, inputs)
    return inputs


def check_grid_quantities(settings, who, regions):
    """The grids' quantities of the panel (simulation.grid_absorbed, grid_fluorescent_light,
    grid_emission) as ep.GridRequest's switches; refused, naming the fields, when none is on, when
    the per-fluorophore grids lack the fluorescent-light grid they split, or when the emission grids
    alone are on and no exported region has a fluorophore (no grid to write)."""
    asked = {q: bool(getattr(settings, f"grid_{q}")) for q in ("absorbed", "fluorescent_light", "emission")}
    if not any(asked.values()):
        raise InputError(
            f"{who}: simulation.grid_absorbed, grid_fluorescent_light and grid_emission are all off; "
            "turn one on, or turn Volume Grids off"
        )
    if settings.grid_per_fluorophore and not asked["fluorescent_light"]:
        raise InputError(
            f"{who}: simulation.grid_per_fluorophore needs simulation.grid_fluorescent_light on "
            "(its grids split that one)"
        )
    if not asked["absorbed"] and not asked["fluorescent_light"] and not any(r.fluorophores for r in regions):
        raise InputError(
            f"{who}: simulation.grid_emission is the only grid on, and no object has a fluorophore: "
            "no grid to write; turn on Absorbed or Fluorescent Light"
        )
    return asked


def view_estimator(settings, who, kind, views):
    """simulation.view_estimator as ep.render_view's estimator name; the next-event camera tally is
    refused, naming the field, where the engine cannot make it (it needs a fixed packet count and a
    local run: the Dask unit path does not carry it)."""
    estimator = str(settings.view_estimator).lower()
    if estimator != "nee" or not views:
        return estimator
    if kind != "photons":
        raise InputError(
            f"{who}: simulation.view_estimator = 'NEE' needs a fixed packet count (Mode: Photons, "
            f"Quality: Custom), not a {kind} run; or choose the Exitance, Kernel or k-Nearest estimator"
        )
    if preferences.scheduler_address():
        raise InputError(
            f"{who}: simulation.view_estimator = 'NEE' runs locally only: clear the add-on preferences' "
            "Dask scheduler or choose the Exitance, Kernel or k-Nearest estimator"
        )
    return estimator


def last_rate(scene):
    """Packets per second of the active result (a measured rate for estimates), or None."""
    collection = scene.endophoton.result_collection
    summary = collection.get("endophoton_summary") if collection is not None else None
    if summary is None or not summary.get("seconds"):
        return None
    return summary.get("packets_traced", 0) / summary["seconds"] or None


def check_before_run(scene, inputs):
    """The guards (guards.py): unit scale, overlaps, voxel count, size of the run."""
    settings = scene.endophoton
    who = f"Scene '{scene.name}'"
    if not settings.allow_unusual_scale:
        guards.check_unit_scale(inputs.regions, inputs.scale_length, who)
    guards.check_overlaps(inputs.regions)
    if inputs.grid_voxel_m is not None:
        guards.check_voxels(inputs.regions, inputs.grid_voxel_m, who)
    if not settings.allow_large_runs:
        guards.check_budget(inputs, who, last_rate(scene))


def build_engine_scene(ep, regions):
    """``ep.Scene(unit="m")`` holding the exported regions; see sweep_blend.blender_regions_to_scene."""
    return sweep_blend.blender_regions_to_scene(ep, regions)


def needs_records(inputs):
    """Whether the run needs the engine's escape records: the point cloud, the endoscope-view
    images and a "store N" run use them; a grids-only run does not pay for them, nor do images of the
    next-event estimate, which the run tallies itself."""
    view_records = inputs.endoscope_view and inputs.view_estimator != "nee"
    return inputs.kind == "store" or inputs.output_points or view_records


# ep.run's keywords that are fields of the scene's simulation settings (simulation.<name>).
_RUN_FIELDS = ("photons", "store", "seed", "threads", "fluorescent_only", "fluorescence_rule")


def engine_rejected(exc, panel="simulation"):
    """The InputError for the engine's (or the package's) ValueError ``exc`` about a run's input:
    "Engine rejected the input: ...", its keywords named as the fields of the add-on's ``panel``
    settings (``fluorescent_only = True`` -> ``simulation.fluorescent_only = True``)."""
    text = re.sub(r"(?<![\w.])(%s) = " % "|".join(_RUN_FIELDS), panel + r".\1 = ", str(exc))
    return InputError(f"Engine rejected the input: {text}")


def build_engine_call(ep, inputs):
    """Engine scene, rig and ep.run keyword arguments for ``inputs`` (main thread; cheap: the
    engine scene's build and the engine's checks, ep.check_run, run first thing in the worker,
    SimulationJob._body, and its errors end the job as an InputError too)."""
    try:
        scene = build_engine_scene(ep, inputs.regions)
        # The rig transform is in scene units (metres here, the engine scene's unit).
        endoscope = ep.EndoscopeRig(transform=inputs.rig_matrix, **inputs.rig_params)
        if inputs.kind == "target":
            budget = {"target": ep.Target("diffuse_reflectance", inputs.target_error), "max_photons": inputs.count}
        else:
            budget = {inputs.kind: inputs.count}
        kwargs = {
            **budget,
            "fluorescent_only": inputs.fluorescent_only,
            "fluorescence_rule": inputs.fluorescence_rule,
            "seed": inputs.seed,
            "threads": inputs.threads,
            "record_escapes": needs_records(inputs),
        }
        if inputs.endoscope_view and inputs.view_estimator == "nee":
            kwargs["view"] = True  # the camera tally: the rig's camera, ep.render_view(estimator="nee")
        if inputs.grid_path is not None:
            kwargs["grids"] = ep.GridRequest(
                voxel_size=inputs.grid_voxel_m,
                path=inputs.grid_path,
                per_fluorophore=inputs.grid_per_fluorophore,
                **inputs.grid_quantities,
            )
    except ValueError as exc:
        raise engine_rejected(exc) from exc
    return scene, endoscope, kwargs


@dataclass
class Progress:
    done: int
    total: int
    elapsed: float
    rate: float  # packets (or records) per second
    eta: Optional[float]  # seconds, None when unknown
    target_error: Optional[float] = None  # a quality preset: the diffuse reflectance's relative error goal
    cap: int = 0  # ... and its packet cap
    stage: Optional[str] = None  # after the tracing: what the worker does now (the endoscope view's render)

    @property
    def fraction(self):
        return min(1.0, self.done / self.total) if self.total > 0 else 0.0

    def goal(self):
        """What ends a run without a fixed packet count, with the ETA that can be given."""
        if self.target_error is None:  # "store N" runs: the packet count is open-ended
            return "ETA -- (until N records are stored)"
        bound = ""
        if self.cap > self.done and self.rate > 0:
            bound = f", ETA ≤ {format_seconds((self.cap - self.done) / self.rate)}"
        return f"until Rd ±{100 * self.target_error:g} % (≤ {self.cap:,} packets{bound})"

    def text(self):
        if self.stage is not None:  # the packets are traced; the worker renders (seconds), Esc still stops it
            return f"EndoPhoton: {self.done:,} packets traced · {self.stage} · Esc to cancel"
        if self.total <= 0:
            return f"EndoPhoton: {self.done:,} packets · {self.rate:,.0f} packets/s · {self.goal()} · Esc to cancel"
        eta = "--" if self.eta is None else format_seconds(self.eta)
        return (
            f"EndoPhoton: {self.done:,}/{self.total:,} packets · {self.rate:,.0f} packets/s · "
            f"ETA {eta} · Esc to cancel"
        )


def format_seconds(seconds):
    seconds = int(round(seconds))
    if seconds >= 3600:
        return f"{seconds // 3600}h{(seconds % 3600) // 60:02d}m"
    if seconds >= 60:
        return f"{seconds // 60}m{seconds % 60:02d}s"
    return f"{seconds}s"


class BackgroundJob:
    """Life cycle shared by the engine jobs: a daemon worker thread running
    ``self._work`` (no bpy there), a CancelToken in ``self.token`` and a
    ``self._finished`` event the worker sets when it ends."""

    thread_name = "endophoton-job"
    cancelled_at = None  # time.monotonic() of the first cancel (Esc): cancel latency figures
    finished_at = None  # time.monotonic() when the worker ended

    def start(self):
        self._t0 = time.monotonic()
        self._thread = threading.Thread(target=self._work, name=self.thread_name, daemon=True)
        track_job(self)
        self._thread.start()

    def cancel(self):
        if self.cancelled_at is None:
            self.cancelled_at = time.monotonic()
        self.token.cancel()

    @property
    def done(self):
        return self._finished.is_set()

    def wait(self, timeout=None):
        return self._finished.wait(timeout)

    def _work(self):
        """Worker thread: ``self._body()`` (no bpy); any error is kept for the main thread,
        with its traceback unless it is an InputError (bad input: its message says it all)."""
        try:
            self._body()
        except BaseException as exc:  # reported by the main thread
            self.error = exc
            self.error_traceback = None if isinstance(exc, InputError) else traceback.format_exc()
        finally:
            untrack_job(self)
            self.finished_at = time.monotonic()
            self._finished.set()


class SimulationJob(BackgroundJob):
    """A run of the engine in a worker thread.  Only ``start``/``cancel``/``progress``
    /``done`` are called from the main thread while it runs; the worker writes
    ``result``/``error`` and sets the finished event."""

    thread_name = "endophoton-run"

    def __init__(self, ep, inputs):
        self.ep = ep
        self.inputs = inputs
        self.engine_scene, self.engine_rig, self.run_kwargs = build_engine_call(ep, inputs)
        self.scheduler = preferences.scheduler_address()  # read here: the worker thread has no bpy
        self.token = ep.CancelToken()
        self.live = live_view.LiveView(ep, inputs.threads) if live_view.wanted(inputs, self.scheduler) else None
        self.result = None
        self.error = None
        self.error_traceback = None
        self.grid_info = []  # [(name, active voxel count, max value)] read in the worker
        self.render_grids = {}  # volumes.write_render_grids: {grid name: index -> metres matrix}
        self.view = None  # ep.View of the rig camera (inputs.endoscope_view), computed in the worker
        self.view_error = None  # why there is no view although one was asked for
        self.created_folders = []  # folders this run made for its files, deepest first
        self._lock = threading.Lock()
        self._progress = (0, inputs.count if inputs.kind == "photons" else 0)
        self._stage = None  # Progress.stage: set by the worker once the tracing is done
        self._t0 = None
        self._finished = threading.Event()
        self._thread = None

    # --- main thread: start(), cancel(), done and wait() from BackgroundJob ---
    @property
    def cancelled(self):
        """Whether the run was cancelled (Esc, Cancel, Ctrl-C), also after the engine's end: its result,
        complete or not, is not kept (SweepJob.cancelled says the same of a sweep)."""
        return self.token.cancelled or getattr(self.result, "cancelled", False)

    def progress(self):
        with self._lock:
            done, total, stage = *self._progress, self._stage
        elapsed = time.monotonic() - self._t0 if self._t0 else 0.0
        rate = done / elapsed if elapsed > 0 else 0.0
        eta = (total - done) / rate if rate > 0 and total >= done > 0 else None
        target = self.inputs.target_error if self.inputs.kind == "target" else None
        total = 0 if target is not None else total  # a preset's count is a cap, not a total
        eta = None if target is not None else eta
        return Progress(done, total, elapsed, rate, eta, target, self.inputs.count, stage)

    def panel_lines(self):
        """Lines for the sidebar's progress box (the panel wraps them to its width)."""
        progress = self.progress()
        if progress.stage is not None:
            return [f"Traced: {progress.done:,} packets", progress.stage[0].upper() + progress.stage[1:]]
        lines = [f"Running: {progress.done:,} packets"]
        if progress.total > 0:
            eta = "--" if progress.eta is None else format_seconds(progress.eta)
            lines.append(f"of {progress.total:,}, ETA {eta}")
        else:
            lines.append(progress.goal())
        return lines + [f"{progress.rate:,.0f} packets/s"]

    # --- worker thread (no bpy here) ----------------------------------------
    def _on_progress(self, done, total):
        with self._lock:
            self._progress = (int(done), int(total))

    def _body(self):
        # The grid's folder first (the engine checks that it can write there), then the engine's
        # checks (~0.1 s on colon_polyp.blend: kept off the main thread); a rejected or failed run
        # removes the folders it made.
        if self.inputs.grid_path:
            folder = os.path.dirname(self.inputs.grid_path)
            try:
                self.created_folders = make_folders(folder)
            except OSError as exc:  # checked before the run (guards.resolve_folder); the disk may change
                raise InputError(
                    f"Scene '{self.inputs.scene_name}': simulation.grid_dir: cannot create '{folder}': "
                    f"{exc.strerror or exc}; choose another Grid Folder"
                ) from None
        try:
            try:
                self.ep.check_run(self.engine_scene, self.engine_rig, **self.run_kwargs)
            except ValueError as exc:  # _core.InvalidArgument is a ValueError
                raise engine_rejected(exc) from exc
            self._run()
        except BaseException:
            remove_empty_folders(self.created_folders)
            raise

    def _run(self):
        with contextlib.ExitStack() as stack:
            kwargs = dict(self.run_kwargs)
            client = cluster_client(stack, self.ep, self.scheduler)
            if client is not None:  # trace on the Dask cluster; cancel stops its tasks
                kwargs["client"] = client
            run = self.ep.run
            if self.live is not None:  # the same bits, with snapshots shown while it runs
                run, kwargs = self.ep.run_live, {**kwargs, **self.live.run_kwargs()}
            self.result = run(
                self.engine_scene,
                self.engine_rig,
                progress=self._on_progress,
                cancel=self.token,
                **kwargs,
            )
        # After Esc the result is discarded (finish_job): the work below, for the result's objects,
        # is skipped, and the view (seconds of kernel gather) stops within a block of pixels.
        grid_path = getattr(self.result, "grid_path", None)
        if grid_path and not self.cancelled:
            self.grid_info = read_grid_info(grid_path)
            self.render_grids = volumes.write_render_grids(grid_path)
        if not self.cancelled:
            if self.inputs.endoscope_view:
                with self._lock:
                    self._stage = f"rendering the endoscope view ({self.inputs.view_estimator} estimate)"
            self.view, self.view_error = endoscope_view(self.ep, self.inputs, self.result, self.token)


def make_folders(path):
    """``os.makedirs(path)``; returns the folders it created, deepest first."""
    made, folder = [], os.path.abspath(path)
    while not os.path.lexists(folder) and os.path.dirname(folder) != folder:
        made.append(folder)
        folder = os.path.dirname(folder)
    os.makedirs(path, exist_ok=True)
    return made


def remove_empty_folders(folders):
    """Remove those of ``folders`` (deepest first) that are empty; leave the others."""
    for folder in folders:
        with contextlib.suppress(OSError):
            os.rmdir(folder)


def endoscope_view(ep, inputs, result, cancel=None):
    """(ep.View of the rig's camera, None) from the run's escape records (worker thread),
    or (None, reason) when the scene does not ask for one or the run left no records;
    (None, None) once ``cancel`` (the job's CancelToken) is cancelled."""
    if not inputs.endoscope_view or result is None or getattr(result, "cancelled", False):
        return None, None
    estimator = inputs.view_estimator
    escapes = getattr(result, "escapes", None)
    if estimator != "nee" and (escapes is None or len(escapes.get("weight", ())) == 0):
        return None, "the run left no escape records to image"
    try:
        return ep.render_view(result, threads=inputs.threads, cancel=cancel, estimator=estimator), None
    except ValueError as exc:  # e.g. the camera inside tissue: keep the run, say why there is no view
        return None, f"endoscope view not rendered: {exc}"


def cluster_client(stack, ep, address):
    """A Dask client for the preferences' scheduler ``address`` (worker thread),
    closed by ``stack``; None when the address is empty (run locally)."""
    if not address:
        return None
    from endophoton.distributed import connect

    return stack.enter_context(connect(address))


def read_grid_info(path):
    """[(grid name, active voxel count, max value)] of a .vdb, via pyopenvdb if present."""
    try:
        import pyopenvdb
    except ImportError:
        return []
    info = []
    for grid in pyopenvdb.readAllGridMetadata(path):
        full = pyopenvdb.read(path, grid.name)
        _lo, hi = full.evalMinMax()
        info.append((grid.name, int(full.activeVoxelCount()), float(hi)))
    return info


def interactive_threads(threads):
    """Threads for a run behind a live UI: 0 ("all cores") becomes all cores but
    one, so Blender's own drawing keeps a core and the UI stays responsive."""
    if threads > 0:
        return threads
    return max(1, (os.cpu_count() or 1) - 1)


def prepare_job(context, interactive=False):
    """Validate the scene and build the engine call; raises InputError / EngineMissing.

    ``interactive``: the modal operator's run; threads = 0 then leaves one core
    to the UI (see interactive_threads).
    """
    inputs = collect_inputs(context)
    if interactive:
        inputs.threads = interactive_threads(inputs.threads)
    ep = package_finder.require()
    return SimulationJob(ep, inputs)


def finish_job(context, job):
    """Turn a finished job into the result collection (main thread).

    Returns the collection, or None when the run was cancelled (then nothing
    is created).  Raises RuntimeError if the worker failed.
    """

    if not job.done:
        raise RuntimeError("finish_job called before the run finished")
    if isinstance(job.error, InputError):  # the engine rejected the input: no run, nothing added
        raise job.error
    if job.error is not None:
        raise RuntimeError(f"EndoPhoton run failed: {type(job.error).__name__}: {job.error}")
    if job.result is None or job.cancelled:  # a cancel that came after the engine's end too
        _discard_partial_grid(job)
        return None
    return collection_from_run(
        context, job.inputs, job.result, job.grid_info, job.render_grids, job.view, job.view_error
    )


def collection_from_run(
    context, inputs, result, grid_info=(), render_grids=None, view=None, view_error=None, tags=None, parent=None
):
    """One finished engine run -> its tagged results collection (main thread): the path
    of a single Run and of every β of a sweep.  ``tags``: extra parameters (e.g. the sweep);
    ``parent``: the collection that holds it (a sweep's), else the scene's."""
    from . import results

    collection = results.apply_result(context, inputs, result, grid_info, render_grids, view, tags=tags, parent=parent)
    if view_error:
        collection["endophoton_view_error"] = view_error
        print(f"EndoPhoton: {view_error}")
    return collection


def discard_job(job):
    """A cancelled job's leftovers, whatever the engine returned: its grid files (fresh names,
    nothing refers to them) and the folders it made, if empty."""
    _discard_partial_grid(job)


def _discard_partial_grid(job):
    """A cancelled run may still have written its (partial) grid file: remove
    it, it is ours (a fresh name per run) and nothing refers to it; and the
    folders the run made for it, if they are empty now."""

    path = job.inputs.grid_path
    for name in (path, volumes.render_grid_path(path)) if path else ():
        if os.path.isfile(name):
            os.remove(name)
    remove_empty_folders(job.created_folders)


def report_finished(context, job):
    """Finish the job (main thread) and say what happened: ``(level, message)``
    for the operator's report, level "INFO" when a collection was added."""
    from . import results

    collection = finish_job(context, job)
    if collection is None:
        return "WARNING", "EndoPhoton run cancelled; nothing was added"
    summary = collection.get(results.SUMMARY_KEY, {})
    return "INFO", (
        f"EndoPhoton: {summary.get('packets_traced', 0):,} packets traced "
        f"in {summary.get('seconds', 0.0):.1f} s -> '{collection.name}'"
    )


def track_job(job):
    """Note a job whose worker thread is starting (cancelled on unregister)."""
    with _ACTIVE_LOCK:
        _ACTIVE_JOBS.add(job)


def untrack_job(job):
    with _ACTIVE_LOCK:
        _ACTIVE_JOBS.discard(job)


def forget_engine_scenes():
    """Free the engine scene the package keeps for the next run of the same scene
    (endophoton.forget_native_scenes; ~100 MB with warm caches on colon_polyp).
    Called when another file is loaded and on unregister; a no-op while the
    engine was never imported."""
    ep = package_finder.loaded()
    if ep is not None:
        ep.forget_native_scenes()


def cancel_all_jobs(timeout=10.0):
    """Cancel running jobs and wait for their threads (add-on unregister)."""
    with _ACTIVE_LOCK:
        jobs = list(_ACTIVE_JOBS)
    for job in jobs:
        job.cancel()
    for job in jobs:
        job.wait(timeout)
