"""Running the engine and reading its results."""
from __future__ import annotations

import dataclasses
import inspect
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np

from . import _core, placement
from .quality import quality_preset
from .scene import Scene
from .callbacks import checked_progress
from .io import check_bool, check_int, check_path, check_real
from .tallies import FRACTIONS, TARGET_TALLIES, Target  # noqa: F401  (re-exported: endophoton.run.Target)
from .io import MAX_THREADS  # noqa: F401  (largest thread count a run accepts; owner: io)

CancelToken = _core.CancelToken
#: Largest packet count a request may name (photons, store, max_photons): 2^62.
MAX_PACKETS = int(_core.MAX_PACKET_REQUEST)
#: Packet cap of a target run without max_photons (2^30; the engine's kDefaultTargetMaxPackets). Such a
#: run also stops early, as "target_unreachable" with a warning, once the packets its error so far
#: projects exceed ten times this cap (docs/numerics.md, "Unreachable targets").
DEFAULT_TARGET_MAX_PHOTONS = int(_core.DEFAULT_TARGET_MAX_PACKETS)


#: GridRequest's switches of the quantities it tallies (RunConfig's ``grid_<name>``).
GRID_QUANTITY_FIELDS = ("absorbed", "fluorescent_light", "emission")


@dataclass
class GridRequest:
    """Volume grids to accumulate and write as one OpenVDB file.

    voxel_size : edge of a voxel in scene units
    path : the .vdb file to write (atomically)
    absorbed, fluorescent_light, emission : which quantities to tally (all three by default): the
        ``absorbed`` grid, the ``fluorescent_light`` grid, and one ``emission_<name>`` grid per
        fluorophore of a scene that has any (where and how much it converts into fluorescence).
        What each grid holds, with its unit: ``endophoton.vdb.GRID_QUANTITIES``. A grid not asked
        for costs nothing: a run without ``absorbed`` and ``fluorescent_light`` deposits nothing at
        its interactions (only at its fluorescence events), and traces at the speed of a run
        without grids.
    per_fluorophore : also one ``fluorescent_light_<name>`` grid per fluorophore (where its light
        goes); needs ``fluorescent_light``.
    max_memory_mb : the most memory (MiB) the run's voxel tables may take, and
        again the most the file's OpenVDB trees may take while it is written; None:
        three quarters of the memory available when the run starts (the tables) and
        when the file is written (the trees). Deposits scattered at a tiny voxel size
        need a new voxel each, and a tree node (2 kB to 270 kB) for a few voxels: a
        run or write that would pass the limit stops with an error naming
        ``grids.voxel_size`` and leaves no file.
    """

    voxel_size: float
    path: str
    per_fluorophore: bool = False
    max_memory_mb: float | None = None
    absorbed: bool = True
    fluorescent_light: bool = True
    emission: bool = True

    def __post_init__(self):
        check_real("grids.voxel_size", self.voxel_size, 0.0, math.inf, lo_open=True)
        check_path("grids.path", self.path)
        for name in ("per_fluorophore",) + GRID_QUANTITY_FIELDS:
            check_bool(f"grids.{name}", getattr(self, name))
        if not any(getattr(self, name) for name in GRID_QUANTITY_FIELDS):
            raise ValueError(
                "grids.absorbed, grids.fluorescent_light and grids.emission are all False: no grid to write"
            )
        if self.per_fluorophore and not self.fluorescent_light:
            raise ValueError(
                "grids.per_fluorophore = True needs grids.fluorescent_light = True (its grids split that one)"
            )
        if self.max_memory_mb is not None:
            self.max_memory_mb = check_real("grids.max_memory_mb", self.max_memory_mb, 1.0, 2.0**40)


class Result:
    """What a run produced. Fractions are per launched packet, each with ``<name>_stderr``
    from batch means over consecutive blocks of packets."""

    def __init__(self, raw: dict, scene: Scene, source, options: dict, view_request: dict | None = None):
        # The camera tally (ep.run(..., view=...)): arrays for render_view, not part of the summary.
        self.camera_image = raw.pop("camera_view", None)
        self.view_request = view_request
        if self.camera_image is not None:
            for k in ("sums", "spectrum"):
                if not np.all(np.isfinite(self.camera_image[k])):
                    raise ValueError(f"result.camera_view.{k} holds a non-finite value (engine bug)")
        _require_finite(raw)
        self._raw = raw
        self.scene = scene
        self.source = source
        self.options = options
        for k, v in raw.items():
            if k != "escapes":
                setattr(self, k, v)
        self.escapes = raw.get("escapes")

    @property
    def fluorophore_names(self) -> list[str]:
        return self.scene.fluorophore_names()

    def to_dict(self) -> dict:
        """JSON-able summary (no per-record arrays)."""
        out = {k: v for k, v in self._raw.items() if k != "escapes"}
        out["unit"] = self.scene.unit
        out["escape_records"] = 0 if self.escapes is None else int(len(self.escapes["weight"]))
        return out

    def __repr__(self):
        parts = [f"photons={self.photons}"]
        for k in FRACTIONS[:4]:
            parts.append(f"{k}={getattr(self, k):.6f}±{getattr(self, k + '_stderr'):.6f}")
        return "Result(" + ", ".join(parts) + ")"


def _require_finite(raw: dict, path: str = "result") -> None:
    """Every number of a result, nested ones included, is finite (no NaN ever reaches a
    result): an engine bug is reported here, naming the field, rather than passed on."""
    for k, v in raw.items():
        if k != "escapes":
            _require_finite_value(v, f"{path}.{k}")


def _require_finite_value(v, path: str) -> None:
    """:func:`_require_finite` of one value: a dict, a list or tuple (each item, ``path[i]``) or a number."""
    if isinstance(v, dict):
        _require_finite(v, path)
    elif isinstance(v, (list, tuple)):
        for i, x in enumerate(v):
            _require_finite_value(x, f"{path}[{i}]")
    elif isinstance(v, float) and not math.isfinite(v):
        raise RuntimeError(f"{path} = {v!r} is not finite (engine bug: please report)")


def _check_arguments(a: SimpleNamespace) -> None:
    """The checks of :func:`run`'s arguments ``a``: types, ranges and exclusive modes (ValueError names the field)."""
    if not isinstance(a.scene, Scene):
        raise ValueError(f"scene = {a.scene!r} must be an endophoton.Scene")
    modes = [m for m in ("photons", "store", "target") if getattr(a, m) is not None]
    if not modes:
        raise ValueError("photons = None: give photons > 0, store > 0 or a target")
    if len(modes) > 1 and not (modes == ["photons", "target"]):
        raise ValueError(f"{' and '.join(modes)} are exclusive: give one")
    for name in ("photons", "store"):
        if getattr(a, name) is not None:
            check_int(name, getattr(a, name), 1, MAX_PACKETS)
    check_int("seed", a.seed, 0, 2**64 - 1)
    check_int("threads", a.threads, 0, MAX_THREADS)
    for name in ("max_steps", "max_photons", "unit_size"):
        check_int(name, getattr(a, name), 0, MAX_PACKETS)
    check_int("batches", a.batches, 2, 1_000_000)
    check_real("roulette_threshold", a.roulette_threshold, 0.0, 1.0)
    check_real("roulette_chance", a.roulette_chance, 0.0, 1.0, lo_open=True)
    check_real("max_path_cm", a.max_path_cm, 0.0, math.inf)
    check_real("time_budget_s", a.time_budget_s, 0.0, math.inf)
    for name in ("record_escapes", "fluorescent_only", "safe_distance", "lanes", "stats"):
        check_bool(name, getattr(a, name))
    if a.stats and a.client is not None:
        raise ValueError("stats = True counts the events of a local run; a run on a Dask client (client=) has none")
    if a.spectral is not None:
        check_bool("spectral", a.spectral)
    if a.fluorescence_rule not in ("paper", "eem"):
        raise ValueError(f"fluorescence_rule = {a.fluorescence_rule!r} must be 'paper' or 'eem'")
    if not isinstance(a.lumen, bool):
        raise ValueError(f"lumen = {a.lumen!r} must be True or False")
    _check_source_and_callbacks(a)


def _check_source_and_callbacks(a: SimpleNamespace) -> None:
    """``source`` is an endophoton source; ``progress`` None or a callable; ``cancel`` None or a
    CancelToken (on a cluster, anything with a ``cancelled`` flag, as endophoton.distributed reads it)."""
    if not all(callable(getattr(a.source, m, None)) for m in ("native_lights", "native_body")):
        raise ValueError(
            f"source = {a.source!r} must be an endophoton source (PencilSource, DiskSource, ConeSource or EndoscopeRig)"
        )
    if a.progress is not None and not (callable(a.progress) and _takes_two(a.progress)):
        raise ValueError(f"progress = {a.progress!r} must be None or a callable progress(done, total)")
    check_client("client", a.client)
    duck = a.client is not None and hasattr(a.cancel, "cancelled")
    if a.cancel is not None and not isinstance(a.cancel, CancelToken) and not duck:
        raise ValueError(f"cancel = {a.cancel!r} must be None or an endophoton.CancelToken")


def check_client(name: str, client) -> None:
    """``client`` is None or a dask.distributed.Client (anything with its ``submit``); ValueError naming ``name``."""
    if client is not None and not callable(getattr(client, "submit", None)):
        raise ValueError(
            f"{name} = {client!r} must be a dask.distributed.Client (endophoton.distributed.connect(address))"
        )


def _takes_two(f) -> bool:
    """Whether ``f(done, total)`` binds (True where Python cannot tell, e.g. some builtins)."""
    try:
        inspect.signature(f).bind(0, 0)
    except TypeError:
        return False
    except ValueError:  # no signature to read
        return True
    return True


def _as_field_object(name: str, value, cls):
    """``value`` as a ``cls`` (GridRequest, Target): itself, or built from a dict of its fields
    (JSON-style configs). Anything else, an unknown or a missing field is a ValueError naming ``name``."""
    if value is None or isinstance(value, cls):
        return value
    if not isinstance(value, Mapping):
        raise ValueError(f"{name} = {value!r} must be an endophoton.{cls.__name__} or a dict of its fields")
    fields = [f.name for f in dataclasses.fields(cls)]
    unknown = [k for k in value if k not in fields]
    if unknown:
        raise ValueError(f"{name}.{unknown[0]} is not a field of {cls.__name__} (fields: {', '.join(fields)})")
    missing = [
        f.name
        for f in dataclasses.fields(cls)
        if f.name not in value and f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
    ]
    if missing:
        raise ValueError(f"{name}.{missing[0]} is missing (fields: {', '.join(fields)})")
    return cls(**value)


def _apply_quality(a: SimpleNamespace) -> None:
    """``quality`` (a preset name) stands for a target and a packet cap; it excludes the other modes."""
    if a.quality is None:
        return
    if a.photons is not None or a.store is not None or a.target is not None:
        raise ValueError(f"quality = {a.quality!r} replaces photons, store and target: give only one")
    preset = quality_preset(a.quality)
    if a.max_photons:
        raise ValueError(
            f"quality = {a.quality!r} brings its own packet cap ({preset.max_photons:,}); max_photons = "
            f"{a.max_photons!r} would not change it: bound a run to an accuracy with target= and max_photons="
        )
    a.target, a.max_photons = preset.target, preset.max_photons


def _request(a: SimpleNamespace) -> dict:
    """The checked options of :func:`run`'s arguments ``a`` as the engine's RunConfig takes them."""
    a.grids = _as_field_object("grids", a.grids, GridRequest)
    a.target = _as_field_object("target", a.target, Target)
    _apply_quality(a)
    _check_arguments(a)
    return _native_options(a)


def _arguments(scene, source, kwargs: dict) -> SimpleNamespace:
    """``run(scene, source, **kwargs)``'s arguments by name, defaults filled in (unknown keywords: TypeError)."""
    bound = inspect.signature(run).bind(scene, source, **kwargs)
    bound.apply_defaults()
    return SimpleNamespace(**bound.arguments)


def run_request(scene: Scene, source, **kwargs) -> dict:
    """The engine request (checked) that ``run(scene, source, **kwargs)`` would make, without
    running it: the sweep on a cluster (endophoton.distributed.run_many) starts all its runs from
    these. Unknown keywords raise TypeError, as run() does."""
    return _request(_arguments(scene, source, kwargs))


def check_run(scene: Scene, source, **kwargs) -> list[str]:
    """Every check ``run(scene, source, **kwargs)`` makes before it traces a packet, without
    tracing: its arguments, the rig's placement, the engine scene's build (mesh checks; kept on
    ``scene``, so the run that follows does not build it again), the source and the engine's own
    validation of the request. Raises ValueError naming the field or region (the engine's own
    errors are ``_core.InvalidArgument``, a ValueError); returns the notes the run would add to
    its warnings. Writes no file."""
    return _prepare(_arguments(scene, source, kwargs), engine_check=True)[1]


def _prepare(a: SimpleNamespace, engine_check: bool) -> tuple[dict, list[str], object, object]:
    """:func:`check_run` of :func:`run`'s arguments ``a``: (engine options, notes, native scene,
    native source). ``engine_check``: also the engine's validation of the request (``_core.check_run``);
    a run leaves it to the engine call that traces (``_core.run``, or ``_core.unit_plan`` on a cluster),
    which validates first, so that a run crosses into the engine once."""
    opts = _request(a)
    notes = placement.check_rig(a.scene, a.source)  # the endoscope head in the ambient (ValueError), its body
    native_scene = a.scene.to_native()
    native_source = _core.Source(a.source.native_lights(a.scene.unit_cm), body=a.source.native_body(a.scene.unit_cm))
    if engine_check:
        _core.check_run(native_scene, native_source, _core.RunConfig(**opts))  # the engine's validation, no tracing
    return opts, notes, native_scene, native_source


def _native_options(a: SimpleNamespace) -> dict:
    """The keyword arguments of the engine's RunConfig for :func:`run`'s checked arguments ``a``."""
    opts = dict(
        seed=a.seed,
        threads=a.threads,
        roulette_threshold=float(a.roulette_threshold),
        roulette_chance=float(a.roulette_chance),
        max_steps=a.max_steps,
        max_path_cm=float(a.max_path_cm),
        record_escapes=bool(a.record_escapes),
        fluorescent_only=bool(a.fluorescent_only),
        fluorescence_rule=a.fluorescence_rule,
        batches=a.batches,
        safe_distance=bool(a.safe_distance),
        unit_size=a.unit_size,
    )
    if a.photons is not None and a.target is None:
        opts["photons"] = a.photons
    if a.store is not None:
        opts["store"] = a.store
    if a.target is not None:
        opts["target_tally"] = a.target.tally
        opts["target_rel_error"] = float(a.target.rel_error)
        opts["max_photons"] = a.photons if a.photons is not None else a.max_photons
    elif a.max_photons:
        opts["max_photons"] = a.max_photons
    if a.time_budget_s:
        opts["time_budget_s"] = float(a.time_budget_s)
    if not a.lumen:
        opts["lumen"] = False
    if a.lanes:
        opts["lanes"] = True
    if a.stats:
        opts["stats"] = True
    if a.spectral:
        opts["force_spectral"] = True
    if a.grids is not None:
        opts["grid_voxel_size"] = float(a.grids.voxel_size)
        opts["grid_path"] = os.fspath(a.grids.path)
        opts["grid_per_fluorophore"] = bool(a.grids.per_fluorophore)
        for name in GRID_QUANTITY_FIELDS:
            opts[f"grid_{name}"] = bool(getattr(a.grids, name))
        if a.grids.max_memory_mb is not None:
            opts["grid_max_tree_bytes"] = int(a.grids.max_memory_mb * 2**20)
    return opts


def run(
    scene: Scene,
    source,
    photons: int | None = None,
    *,
    store: int | None = None,
    seed: int = 1,
    threads: int = 0,
    roulette_threshold: float = 1e-4,
    roulette_chance: float = 0.1,
    max_steps: int = 0,
    max_path_cm: float = 0.0,
    record_escapes: bool = True,
    fluorescent_only: bool = False,
    fluorescence_rule: str = "paper",
    grids: GridRequest | None = None,
    target: Target | None = None,
    time_budget_s: float = 0.0,
    max_photons: int = 0,
    batches: int = 50,
    spectral: bool | None = None,
    safe_distance: bool = True,
    lanes: bool = True,
    unit_size: int = 0,
    quality: str | None = None,
    progress=None,
    cancel=None,
    lumen: bool = True,
    client=None,
    chunk_units: int = 0,
    stats: bool = False,
    view=None,
) -> Result:
    """Trace photon packets through ``scene`` from ``source``.

    Exactly one of ``photons`` (launch that many packets), ``store`` (launch
    until that many escape records are stored; the seed's "store N") or
    ``target`` (until the relative standard error of a tally reaches the target)
    chooses when to stop. A target run without ``max_photons`` is capped at
    :data:`DEFAULT_TARGET_MAX_PHOTONS` and stops early (``stop_reason``
    "target_unreachable", a warning naming the packets it would need) once its
    error so far projects more than ten times that cap. The run releases the GIL; ``progress(done, total)`` is
    called about 10 times a second from the calling thread and may return False
    to stop (None or True go on; any other value is a TypeError naming ``progress``,
    endophoton.callbacks); ``cancel`` (a CancelToken) can stop it from any thread, and the
    partial result then has ``cancelled=True``.

    ``client`` (a dask.distributed.Client) traces the packets on its workers in
    chunks of ``chunk_units`` units (0 = automatic) and gives bit-for-bit the
    result of a local run with the same seed (endophoton.distributed).

    ``quality`` ("preview", "standard", "reference") is a shortcut for a target
    accuracy with a packet cap (endophoton.quality); it cannot be combined with
    ``photons``, ``store`` or ``target``.

    ``lumen`` (default True): packets that leave the tissue go on through the
    ambient and land on the region or rig head they meet (docs/design.md,
    "Light crosses the lumen"); False ends every packet at its first exit, as
    the engine did before (for comparisons and benchmarks).

    ``stats`` (default False): count the engine's events (interactions, boundary
    crossings, triangle-cache hits and misses, full ray queries) per work unit;
    the result's ``stats`` holds the totals and ``stats["per_unit"]`` the counts
    of each merged unit (native/stats.h). Local runs only.
    ``lanes`` (default True): the plain interior steps -- deep in one scattering region, crossing
    nothing -- in float32 vector lanes, 16 packets at once (native/lane_block.h), fluorescence trials
    included. They serve runs without a camera tally, a path cap or grids taking a deposit at every
    interaction (``absorbed``, ``fluorescent_light``: the ``emission`` grids alone are served);
    ``result.lanes`` names the lanes' instruction set where they served the run ("sse2", "avx2",
    "avx512"), else None. The result is another sample of the same
    physics, the same bits for a seed on any processor, thread count or cluster, but not the bits of
    the double walk that ``lanes=False`` gives (docs/numerics.md, "Float32 lanes").
    ``view`` (None: off): True or a dict (endophoton.view.nee.view_request) makes the run tally the
    camera's image by next-event estimation (docs/render.md), which ``ep.render_view(result)`` then
    renders (estimator "nee"). It needs a fixed ``photons`` count, a spectral run and no ``client``.

    Lengths in scene units; ``max_path_cm`` in cm; mua/mus in cm^-1.
    """
    # every argument of this call, captured once by name, checked as check_run() checks them
    opts, notes, native_scene, native_source = _prepare(SimpleNamespace(**locals()), engine_check=False)
    progress = checked_progress("progress", progress)  # a value other than None/True/False: TypeError naming it
    config, view_desc = _core.RunConfig(**opts), None
    if view is not None and view is not False:
        from .view import nee

        if client is not None:
            raise ValueError(
                "view: the camera tally is not carried through the Dask unit path yet; run it locally (client=None)"
            )
        if "photons" not in opts or "store" in opts:
            raise ValueError("view: the camera tally needs a fixed photon count (photons=N, no store or target)")
        config.camera_view, view_desc = nee.camera_view(scene, source, opts["photons"], view)
    if client is not None:  # a dask.distributed.Client: the same result, traced on its workers
        from . import distributed

        raw = distributed.run(scene, source, opts, client, chunk_units=chunk_units, progress=progress, cancel=cancel)
    else:
        raw = _core.run(native_scene, native_source, config, progress, cancel)
    return Result(with_warnings(raw, notes), scene, source, opts, view_desc)


def with_warnings(raw: dict, notes: list[str]) -> dict:
    """The engine's result ``raw`` with the run's own ``notes`` (e.g. :func:`placement.check_rig`'s)
    appended to its ``warnings``."""
    if notes:
        raw["warnings"] = list(raw.get("warnings", [])) + list(notes)
    return raw
