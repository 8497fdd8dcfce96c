"""A local run that shows its records while it runs: :func:`run_live`.

The engine's own ``_core.run`` hands back nothing before the run ends. The unit path of a Dask
run (endophoton.distributed, docs/distributed.md) does: ``_core.trace_units`` traces a range of
work units (GIL released) as bytes and ``_core.UnitReducer`` merges them in unit order through the
engine's own reducer, so the result is the same bits as ``ep.run``'s. :func:`run_live` drives that
path on this machine's threads: ``threads`` Python threads each trace chunks of consecutive units,
the calling thread merges them in unit order into the run's reducer (its stop rule decides where a
"store N" or target run ends, as in ``ep.run``) and, every ``every_s`` seconds, finishes a second
reducer fed the same batches so far: a snapshot :class:`Result` of the units merged so far (a
partial run, ``cancelled`` True), handed to ``on_snapshot(result)`` (e.g. to render it with
``ep.render_view`` and watch the noise fall). The snapshot and its callback run in a thread of
their own, so the merge and the tracing go on meanwhile; one snapshot at a time.

Cost: a snapshot re-merges every batch so far (the reducer cannot be finished twice) and the
callback typically renders all the records so far, so its cost grows with the run. The next snapshot
starts at least ``every_s`` after the last one ended; when the run's threads take every core (the
snapshot then competes with them) also only while the snapshots' seconds so far, with this one's
predicted from the last one's cost per merged unit, stay within ``overhead_share`` of the time since
the run began. The batches are kept in memory until the run ends (about the
size of its records). A run with grids writes each snapshot's grids to a scratch file (removed).
"""
from __future__ import annotations

import inspect
import math
import os
import tempfile
import threading
import time
from types import SimpleNamespace

from . import _core
from .callbacks import checked_notification, checked_progress, progress_verdict
from .io import check_int, check_real
from .run import MAX_PACKETS, Result, _prepare, run, with_warnings

#: Seconds of tracing a chunk of units aims at: the cancel latency and the merge granularity.
CHUNK_SECONDS = 0.25
#: Chunks each thread may trace ahead of the merge point (a store or target run discards those past its stop).
CHUNKS_AHEAD_PER_THREAD = 2


class _Tracing:
    """The tracer threads' shared state: which units go next, and the traced chunks not merged yet."""

    def __init__(self, native_scene, native_source, config, n_units: int, threads: int, chunk_units: int):
        self.scene, self.source, self.config = native_scene, native_source, config
        self.n_units, self.threads, self.fixed_chunk = n_units, threads, chunk_units
        self.cond = threading.Condition()
        self.next_unit = 0
        self.merge_point = 0
        self.done: dict[int, tuple[int, bytes]] = {}  # first unit -> (units, bytes)
        self.unit_seconds = None  # thread-seconds per unit, from the chunks traced so far
        self.stop = False
        self.error: BaseException | None = None
        self.limit = n_units  # units beyond this one are not traced yet (a store run's need so far)

    def set_limit(self, unit: int) -> None:
        with self.cond:
            self.limit = min(self.n_units, unit)
            self.cond.notify_all()

    def _chunk_units(self) -> int:
        """Units of the next chunk: ``chunk_units`` if given, else one until a unit's cost is known,
        then about CHUNK_SECONDS."""
        if self.fixed_chunk:
            return self.fixed_chunk
        if self.unit_seconds is None:
            return 1
        return max(1, min(4096, int(CHUNK_SECONDS / max(self.unit_seconds, 1e-9))))

    def _take(self):
        """(first unit, units) of the next chunk, or None when the run needs no more (waits for room)."""
        with self.cond:
            ahead = CHUNKS_AHEAD_PER_THREAD * self.threads
            while (
                not self.stop
                and self.next_unit < self.n_units
                and (len(self.done) >= ahead or self.next_unit >= self.limit)
            ):
                self.cond.wait()
            if self.stop or self.next_unit >= self.n_units:
                return None
            first, count = self.next_unit, min(self._chunk_units(), self.limit - self.next_unit)
            self.next_unit += count
            return first, count

    def trace(self) -> None:
        """A tracer thread: chunks until the run stops; an engine error stops the run and is kept."""
        try:
            while (chunk := self._take()) is not None:
                first, count = chunk
                t0 = time.perf_counter()
                data = _core.trace_units(self.scene, self.source, self.config, first, count)
                with self.cond:
                    self.unit_seconds = (time.perf_counter() - t0) / count
                    self.done[first] = (count, data)
                    self.cond.notify_all()
        except BaseException as exc:  # handed to the calling thread
            with self.cond:
                self.error, self.stop = exc, True
                self.cond.notify_all()

    def next_ready(self, timeout_s: float):
        """(units, bytes) of the chunk at the merge point, or None if it is not traced after ``timeout_s``."""
        with self.cond:
            if self.merge_point not in self.done and self.error is None:
                self.cond.wait(timeout_s)
            if self.error is not None:
                raise self.error
            got = self.done.pop(self.merge_point, None)
            if got is not None:
                self.merge_point += got[0]
                self.cond.notify_all()
            return got

    def halt(self) -> None:
        with self.cond:
            self.stop = True
            self.cond.notify_all()


def _snapshot_raw(native_scene, native_source, opts: dict, batches: list, threads: int) -> dict:
    """The raw result of the batches merged so far: a second reducer fed the same bytes, finished
    (a run with grids writes them to a scratch file, removed)."""
    with tempfile.TemporaryDirectory(prefix="endophoton-live-") as tmp:
        snap = dict(opts)
        if "grid_path" in snap:
            snap["grid_path"] = os.path.join(tmp, "snapshot.vdb")
        reducer = _core.UnitReducer(native_scene, native_source, _core.RunConfig(**snap))
        for data in batches:
            reducer.add(data)
        return reducer.finish(threads)


def run_live(
    scene,
    source,
    photons: int | None = None,
    *,
    on_snapshot,
    every_s: float = 3.0,
    overhead_share: float = 0.05,
    snapshot_after_chunks: int = 0,
    progress=None,
    cancel=None,
    **kwargs,
) -> Result:
    """``ep.run(scene, source, photons, **kwargs)`` that hands ``on_snapshot(result)`` a snapshot
    :class:`Result` of the units merged so far every ``every_s`` seconds (wall clock, > 0), at most
    ``overhead_share`` (0 < share <= 1) of the run's time spent on snapshots when its threads take
    every core (module docstring); ``on_snapshot`` runs in a thread of its own, one call at a time,
    and is not called once the run has ended (a call under way then ends in the background). The
    final result is the same bits as ``ep.run``'s with the same arguments (its ``seconds`` and
    ``threads`` aside); each snapshot is a partial run (``cancelled`` True) whose ``photons`` never
    decrease. ``snapshot_after_chunks`` (N > 0) also makes a snapshot after each of the first N
    merged chunks, whatever the clock says, in the calling thread (tests; a deterministic refresh). ``chunk_units`` (K > 0)
    traces K units per chunk (0: about :data:`CHUNK_SECONDS` of work each); chunks never change a
    result, units do.

    ``progress(done, total)`` and ``cancel`` (a CancelToken) as in ``ep.run``: after a cancel the
    run returns its merged units as a partial result (``cancelled`` True), within about
    :data:`CHUNK_SECONDS`. Not with ``client`` (a Dask run) or ``view`` (the camera tally): the
    unit path carries neither.
    """
    check_real("every_s", every_s, 0.0, math.inf, lo_open=True)
    check_real("overhead_share", overhead_share, 0.0, 1.0, lo_open=True)
    check_int("snapshot_after_chunks", snapshot_after_chunks, 0, MAX_PACKETS)
    if not callable(on_snapshot):
        raise ValueError(f"on_snapshot = {on_snapshot!r} must be a callable on_snapshot(result) (or use ep.run)")
    on_snapshot = checked_notification("on_snapshot", on_snapshot)
    for name in ("client", "view"):
        if kwargs.get(name) not in (None, False):
            raise ValueError(f"{name} = {kwargs[name]!r}: a live run traces locally without the camera tally")
    bound = inspect.signature(run).bind(scene, source, photons, progress=progress, cancel=cancel, **kwargs)
    bound.apply_defaults()
    opts, notes, native_scene, native_source = _prepare(SimpleNamespace(**bound.arguments), engine_check=False)
    progress = checked_progress("progress", progress)
    live = SimpleNamespace(
        on_snapshot=on_snapshot, every_s=float(every_s), share=float(overhead_share), forced=snapshot_after_chunks
    )
    chunk_units = check_int("chunk_units", bound.arguments["chunk_units"], 0, MAX_PACKETS)
    raw = _LiveRun(scene, source, opts, native_scene, native_source, chunk_units).run(progress, cancel, live)
    return Result(with_warnings(raw, notes), scene, source, opts)


class _LiveRun:
    """One live run: tracer threads, the merge in unit order, the snapshots."""

    def __init__(self, scene, source, opts: dict, native_scene, native_source, chunk_units: int):
        self.scene, self.source, self.opts = scene, source, opts
        self.native_scene, self.native_source = native_scene, native_source
        config = _core.RunConfig(**opts)
        self.reducer = _core.UnitReducer(native_scene, native_source, config)  # validates like run()
        self.unit_size, self.n_units = _core.unit_plan(native_scene, native_source, config)
        self.threads = opts["threads"] or (os.cpu_count() or 1)
        self.tracing = _Tracing(native_scene, native_source, config, self.n_units, self.threads, chunk_units)
        self.batches: list[bytes] = []
        self.total = int(opts["photons"]) if "photons" in opts else 0
        self.store = int(opts.get("store", 0))
        if self.store:  # the first unit measures the record rate (endophoton.distributed does the same)
            self.tracing.set_limit(1)

    def _store_limit(self) -> None:
        """A store run traces only the units its record rate so far says it still needs (+10 %)."""
        records, merged = self.reducer.records, self.reducer.merged_units
        need = math.ceil(1.1 * (self.store - records) * merged / records) if records else merged + 1
        self.tracing.set_limit(merged + max(1, need))

    def _merge_one(self, progress) -> bool:
        """Merges the chunk at the merge point if it is ready; False once the run must stop."""
        got = self.tracing.next_ready(0.05)
        if got is None:
            return True
        units, data = got
        self.reducer.add(data)
        self.batches.append(data)
        self.merged_chunks += 1
        if self.store:
            self._store_limit()
        done = self.reducer.merged_units * self.unit_size
        done = min(done, self.total) if self.total else done
        if progress is not None and not progress_verdict("progress", progress(done, self.total)):
            return False
        return not (self.reducer.stopped or self.reducer.merged_units >= self.n_units)

    def _snapshot(self, live, batches: list, units: int, learn: bool = True) -> None:
        """A snapshot of ``batches`` (``units`` merged units) handed to ``on_snapshot`` (none once the run
        has ended); its cost is kept for :meth:`_due` (its cost per unit only if ``learn``: a forced
        snapshot of the first chunks is mostly the callback's fixed cost)."""
        t0 = time.perf_counter()
        try:
            raw = _snapshot_raw(self.native_scene, self.native_source, self.opts, batches, self.threads)
            if not self.ended:
                live.on_snapshot(Result(raw, self.scene, self.source, self.opts))
        except BaseException as exc:  # raised by the merging thread
            self.snapshot_error = exc
        took = time.perf_counter() - t0
        self.snapshot_seconds += took
        if learn:
            self.seconds_per_unit = took / max(1, units)
        self.next_snapshot = time.monotonic() + live.every_s

    def _due(self, live) -> bool:
        """Whether a clock snapshot starts now: ``every_s`` after the last one ended, none under way and,
        when the run's threads take every core (a snapshot then competes with them), the snapshots so far
        and this one (its cost predicted from the last one's per merged unit: it re-merges and renders all
        the records so far) within ``share`` of the time since the run began."""
        now = time.monotonic()
        if now < self.next_snapshot or self.snapshotting.is_alive():
            return False
        if self.threads < (os.cpu_count() or 1):
            return True  # a core of its own
        predicted = self.seconds_per_unit * self.reducer.merged_units
        return self.snapshot_seconds + predicted <= live.share * (now - self.t_start)

    def _maybe_snapshot(self, live, merged_now: bool) -> None:
        """After a merge: a forced snapshot (the first ``live.forced`` chunks) in this thread, or a
        due one in the snapshot thread, which renders while the merge and the tracing go on."""
        units = self.reducer.merged_units
        if merged_now and self.merged_chunks <= live.forced:
            self._snapshot(live, list(self.batches), units, learn=False)
        elif merged_now and self._due(live):
            args = (live, list(self.batches), units)
            self.snapshotting = threading.Thread(target=self._snapshot, args=args, daemon=True)
            self.snapshotting.start()
        if self.snapshot_error is not None:
            raise self.snapshot_error

    def run(self, progress, cancel, live) -> dict:
        tracers = [threading.Thread(target=self.tracing.trace, daemon=True) for _ in range(self.threads)]
        for t in tracers:
            t.start()
        self.t_start = time.monotonic()
        self.merged_chunks, self.next_snapshot = 0, self.t_start + live.every_s
        self.snapshot_seconds, self.seconds_per_unit = 0.0, 0.0
        self.snapshotting, self.snapshot_error, self.ended = threading.Thread(), None, False
        try:
            going = True
            while going and not (cancel is not None and cancel.cancelled):
                before = self.merged_chunks
                going = self._merge_one(progress)
                if going:
                    self._maybe_snapshot(live, self.merged_chunks > before)
        finally:
            self.ended = True  # a snapshot still being made is not handed on
            self.tracing.halt()
            for t in tracers:
                t.join()
        return self.reducer.finish(self.threads)
