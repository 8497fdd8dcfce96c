"""Running the engine and reading its results."""
from __future__ import annotations

import inspect
import math
import os
from dataclasses import dataclass


from . import _core
from .quality import quality_preset
from .scene import Scene
from .io import check_bool, check_int, check_real
from .tallies import FRACTIONS, TARGET_TALLIES, Target  # noqa: F401  (re-exported: endophoton.run.Target)

CancelToken = _core.CancelToken
#: Largest packet count a request may name (photons, store, max_photons): 2^62.
MAX_PACKETS = int(_core.MAX_PACKET_REQUEST)
#: Largest thread count a run accepts (a count the system cannot start is a named error too).
MAX_THREADS = 4096


@dataclass
class GridRequest:
    """Volume grids to accumulate and write as one OpenVDB file.

    voxel_size : edge of a voxel in scene units
    path : the .vdb file to write (atomically)
    per_fluorophore : also one fluorescence grid per fluorophore
    """

    voxel_size: float
    path: str
    per_fluorophore: bool = False

    def __post_init__(self):
        check_real("grids.voxel_size", self.voxel_size, 0.0, math.inf, lo_open=True)
        if not isinstance(self.path, (str, os.PathLike)) or not str(self.path):
            raise ValueError(f"grids.path = {self.path!r} must be a file path")
        check_bool("grids.per_fluorophore", self.per_fluorophore)


class Result:
    """What a run produced. Fractions are per launched packet, each with ``<name>_stderr``
    from batch means over consecutive blocks of packets."""

    def __init__(self, raw: dict, scene: Scene, source, options: dict):
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
        if k == "escapes":
            continue
        if isinstance(v, dict):
            _require_finite(v, f"{path}.{k}")
        elif isinstance(v, float) and not math.isfinite(v):
            raise RuntimeError(f"{path}.{k} = {v!r} is not finite (engine bug: please report)")


def _check_arguments(
    scene,
    photons,
    store,
    target,
    seed,
    threads,
    max_steps,
    max_photons,
    unit_size,
    batches,
    roulette_threshold,
    roulette_chance,
    max_path_cm,
    time_budget_s,
    record_escapes,
    fluorescent_only,
    safe_distance,
    spectral,
    fluorescence_rule,
    lumen,
) -> None:
    """The checks of :func:`run`'s arguments: types, ranges and exclusive modes (ValueError names the field)."""
    if not isinstance(scene, Scene):
        raise ValueError(f"scene = {scene!r} must be an endophoton.Scene")
    modes = [m for m, v in (("photons", photons), ("store", store), ("target", target)) if v is not None]
    if not modes:
        raise ValueError("photons = None: give photons > 0, store > 0 or a target")
    if len(modes) > 1 and not (modes == ["photons", "target"]):
        raise ValueError(f"{' and '.join(modes)} are exclusive: give one")
    for name, v in (("photons", photons), ("store", store)):
        if v is not None:
            check_int(name, v, 1, MAX_PACKETS)
    check_int("seed", seed, 0, 2**64 - 1)
    check_int("threads", threads, 0, MAX_THREADS)
    for name, v in (("max_steps", max_steps), ("max_photons", max_photons), ("unit_size", unit_size)):
        check_int(name, v, 0, MAX_PACKETS)
    check_int("batches", batches, 2, 1_000_000)
    check_real("roulette_threshold", roulette_threshold, 0.0, 1.0)
    check_real("roulette_chance", roulette_chance, 0.0, 1.0, lo_open=True)
    check_real("max_path_cm", max_path_cm, 0.0, math.inf)
    check_real("time_budget_s", time_budget_s, 0.0, math.inf)
    for name, v in (
        ("record_escapes", record_escapes),
        ("fluorescent_only", fluorescent_only),
        ("safe_distance", safe_distance),
    ):
        check_bool(name, v)
    if spectral is not None:
        check_bool("spectral", spectral)
    if fluorescence_rule not in ("paper", "eem"):
        raise ValueError(f"fluorescence_rule = {fluorescence_rule!r} must be 'paper' or 'eem'")
    if not isinstance(lumen, bool):
        raise ValueError(f"lumen = {lumen!r} must be True or False")


#: run()'s parameters that say how to run, not what: not part of the engine request.
_NOT_REQUEST = ("source", "progress", "cancel", "client", "chunk_units")


def run_request(scene: Scene, source, **kwargs) -> dict:
    """The engine request (checked) that ``run(scene, source, **kwargs)`` would make, without
    running it: the sweep on a cluster (endophoton.distributed.run_many) starts all its runs from
    these. Unknown keywords raise TypeError, as run() does."""
    bound = inspect.signature(run).bind(scene, source, **kwargs)
    bound.apply_defaults()
    return _request(**{k: v for k, v in bound.arguments.items() if k not in _NOT_REQUEST})


def _request(
    *,
    scene,
    photons,
    store,
    seed,
    threads,
    roulette_threshold,
    roulette_chance,
    max_steps,
    max_path_cm,
    record_escapes,
    fluorescent_only,
    fluorescence_rule,
    grids,
    target,
    time_budget_s,
    max_photons,
    batches,
    spectral,
    safe_distance,
    unit_size,
    quality,
    lumen,
) -> dict:
    """The checked options of run() as the engine's RunConfig takes them."""
    if quality is not None:
        if photons is not None or store is not None or target is not None:
            raise ValueError(f"quality = {quality!r} replaces photons, store and target: give only one")
        preset = quality_preset(quality)
        target, max_photons = preset.target, preset.max_photons
    _check_arguments(
        scene,
        photons,
        store,
        target,
        seed,
        threads,
        max_steps,
        max_photons,
        unit_size,
        batches,
        roulette_threshold,
        roulette_chance,
        max_path_cm,
        time_budget_s,
        record_escapes,
        fluorescent_only,
        safe_distance,
        spectral,
        fluorescence_rule,
        lumen,
    )
    opts = dict(
        seed=seed,
        threads=threads,
        roulette_threshold=float(roulette_threshold),
        roulette_chance=float(roulette_chance),
        max_steps=max_steps,
        max_path_cm=float(max_path_cm),
        record_escapes=bool(record_escapes),
        fluorescent_only=bool(fluorescent_only),
        fluorescence_rule=fluorescence_rule,
        batches=batches,
        safe_distance=bool(safe_distance),
        unit_size=unit_size,
    )
    if photons is not None and target is None:
        opts["photons"] = photons
    if store is not None:
        opts["store"] = store
    if target is not None:
        opts["target_tally"] = target.tally
        opts["target_rel_error"] = float(target.rel_error)
        opts["max_photons"] = photons if photons is not None else max_photons
    elif max_photons:
        opts["max_photons"] = max_photons
    if time_budget_s:
        opts["time_budget_s"] = float(time_budget_s)
    if not lumen:
        opts["lumen"] = False
    if spectral:
        opts["force_spectral"] = True
    if grids is not None:
        opts["grid_voxel_size"] = float(grids.voxel_size)
        opts["grid_path"] = os.fspath(grids.path)
        opts["grid_per_fluorophore"] = bool(grids.per_fluorophore)
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
    unit_size: int = 0,
    quality: str | None = None,
    progress=None,
    cancel=None,
    lumen: bool = True,
    client=None,
    chunk_units: int = 0,
) -> Result:
    """Trace photon packets through ``scene`` from ``source``.

    Exactly one of ``photons`` (launch that many packets), ``store`` (launch
    until that many escape records are stored; the seed's "store N") or
    ``target`` (until the relative standard error of a tally reaches the target)
    chooses when to stop. The run releases the GIL; ``progress(done, total)`` is
    called about 10 times a second from the calling thread and may return False
    to stop; ``cancel`` (a CancelToken) can stop it from any thread, and the
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

    Lengths in scene units; ``max_path_cm`` in cm; mua/mus in cm^-1.
    """
    opts = _request(**{k: v for k, v in locals().items() if k not in _NOT_REQUEST})
    if client is not None:  # a dask.distributed.Client: the same result, traced on its workers
        from . import distributed

        raw = distributed.run(scene, source, opts, client, chunk_units=chunk_units, progress=progress, cancel=cancel)
        return Result(raw, scene, source, opts)
    native_scene = scene.to_native()
    native_source = _core.Source(source.native_lights(scene.unit_cm), body=source.native_body(scene.unit_cm))
    raw = _core.run(native_scene, native_source, _core.RunConfig(**opts), progress, cancel)
    return Result(raw, scene, source, opts)
