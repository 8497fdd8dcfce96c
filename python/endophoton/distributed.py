"""One run across the workers of a Dask cluster, bit-identical to a local run.

The engine traces packets in work units of consecutive packet indices whose
size depends only on the request, and every packet's random numbers depend
only on (seed, packet index). A unit traced on any machine therefore gives the
same bytes. This module cuts the unit range into chunks, runs each chunk as a
Dask task (``_core.trace_units``: a pure function of scene, seed and unit
range) and feeds the returned units, in unit order, to ``_core.UnitReducer``,
which is the very object ``ep.run`` merges its own threads' units with: the
same merge, the same stop rule, the same estimates and grid writer. A chunk
ships one grid set for all its units (store, target and time-budget runs: one
per unit, so that units past the stop point take their deposits with them);
grid voxels are exact fixed-point sums, so the sets add up to the same bits in
any order and grouping. So for a fixed count, a "store N" run and a
target-accuracy run the result is the same bits as ``ep.run`` on one machine. For store and target runs the client keeps a
window of chunks in flight ahead of the merge point, stops at the same unit the
local engine stops at, cancels the chunks beyond it and discards the surplus
units the way the local engine discards its threads' surplus.

The scene (meshes included) is sent to every worker once with
``client.scatter(..., broadcast=True)``; each worker process builds the native
scene once per run and keeps it for the run's other chunks.

A worker that dies mid-run loses nothing: Dask reruns its chunks elsewhere,
and a rerun chunk gives the same bytes.
"""
from __future__ import annotations

import collections
import contextlib
import math
import os
import sys
import uuid

from . import _core
from .callbacks import checked_notification, progress_verdict

#: Chunks of a store/target run kept in flight per worker thread.
WINDOW_PER_THREAD = 2
#: Chunks of a fixed-count run per worker thread (more chunks balance better,
#: fewer cost less overhead: docs/distributed.md measures both).
CHUNKS_PER_THREAD = 4
#: Packets per chunk aimed at in store/target runs (whose length is unknown).
OPEN_CHUNK_PACKETS = 16384
#: Most worker processes ``local:N`` starts: each is a Python process with the engine loaded, far
#: dearer than a thread (endophoton.run.MAX_THREADS = 4096); more is refused before any starts.
MAX_LOCAL_WORKERS = 256
#: Memory one ``local:N`` worker process takes, for the check before any starts: ~100 MB measured
#: idle with the engine loaded (issue 38), and room for its copy of the scene and its chunk's units.
LOCAL_WORKER_BYTES = 160 * 2**20
#: Share of the memory available when the cluster starts that its workers may take together.
LOCAL_MEMORY_SHARE = 0.75
#: Address schemes ``--scheduler`` / :func:`connect` accept, besides ``local:N``.
REMOTE_SCHEMES = ("tcp://",)


def trace_chunk(scene, lights: list, body, options: dict, first_unit: int, count: int):
    """A Dask task: trace units first_unit .. first_unit+count-1 of a run.

    Returns (engine version, unit bytes); pure in (scene, options, unit range)."""
    native = scene.to_native()  # kept on the worker's copy of the scene (Scene.to_native)
    source = _core.Source(lights, body=body)
    return _core.__version__, _core.trace_units(native, source, _core.RunConfig(**options), first_unit, count)


def _worker_threads(client) -> int:
    return max(1, sum(client.nthreads().values()))


def default_chunk_units(n_units: int, unit_size: int, fixed: bool, threads: int) -> int:
    """Units per chunk: CHUNKS_PER_THREAD chunks per worker thread for a fixed
    count, about OPEN_CHUNK_PACKETS packets for store/target runs."""
    if fixed:
        return max(1, math.ceil(n_units / (CHUNKS_PER_THREAD * threads)))
    return max(1, OPEN_CHUNK_PACKETS // unit_size)


def _wait_any(futures: list, cancel) -> bool:
    """Blocks until one of ``futures`` is done (True) or ``cancel`` is set (False)."""
    from distributed import wait

    while not (cancel is not None and cancel.cancelled):
        try:
            wait(futures, timeout=0.1, return_when="FIRST_COMPLETED")
            return True
        except TimeoutError:
            pass
    return False


def _check_chunk_units(chunk_units) -> None:
    if isinstance(chunk_units, bool) or not isinstance(chunk_units, int) or chunk_units < 0:
        raise ValueError(f"chunk_units = {chunk_units!r} must be a non-negative integer (0 = automatic)")


class _ChunkedRun:
    """One run on the cluster: its chunks are submitted in a window ahead of the
    merge point and merged, in unit order, by the engine's own UnitReducer.

    Chunk sizes do not change any result (units do), so a run whose length is
    unknown ("store N", target) sizes its chunks as it goes: they double from one
    unit up to about OPEN_CHUNK_PACKETS packets; a store run sends one unit first
    and then only what its record rate says it still needs (+10 %) beyond the
    units in flight, so a short store run does not trace a window of large
    chunks it would discard."""

    def __init__(self, client, native_scene, scene_future, lights, body, options, chunk_units, threads, progress):
        self.client, self.scene_future = client, scene_future
        self.lights, self.body, self.options = lights, body, options
        native_source = _core.Source(lights, body=body)
        config = _core.RunConfig(**options)
        self.reducer = _core.UnitReducer(native_scene, native_source, config)  # validates like run()
        self.unit_size, self.n_units = _core.unit_plan(native_scene, native_source, config)
        self.fixed = "photons" in options
        self.chunk = chunk_units or default_chunk_units(self.n_units, self.unit_size, self.fixed, threads)
        self.adaptive = not (self.fixed or chunk_units)
        self.window = math.ceil(self.n_units / self.chunk) if self.fixed else WINDOW_PER_THREAD * threads
        self.total = int(options["photons"]) if self.fixed else 0
        self.progress = progress
        self.threads = threads
        self.key = f"endophoton-units-{uuid.uuid4().hex[:12]}"
        self.pending: collections.deque = collections.deque()  # (first unit, units, future), in unit order
        self.next_unit = self.merged_to = self.merged_chunks = self.submitted_chunks = 0  # merged_to: merge point
        self.halted = False  # its progress callback returned False

    @property
    def done(self) -> bool:
        return self.halted or self.reducer.stopped or self.merged_to >= self.n_units

    @property
    def front(self):
        """The future of the next chunk to merge."""
        return self.pending[0][2]

    def _units_needed(self) -> int | None:
        """Units a store run still needs beyond those in flight (+10 %), from its record
        rate so far; None while unknown (other runs, or no record merged yet)."""
        store, records, merged = self.options.get("store", 0), self.reducer.records, self.reducer.merged_units
        if not (store and records and merged):
            return None
        return math.ceil(1.1 * (store - records) * merged / records) - (self.next_unit - self.merged_to)

    def _next_count(self) -> int:
        """Units of the next chunk (0: none needed now)."""
        if not self.adaptive:
            return self.chunk
        size = min(self.chunk, 2**self.submitted_chunks)
        needed = self._units_needed()
        if needed is None and self.options.get("store") and self.merged_to == 0 and self.pending:
            return 0  # a store run's first unit measures its record rate before more are sent
        if needed is not None:
            if needed <= 0:
                return 0 if self.pending else 1
            size = min(self.chunk, max(1, math.ceil(needed / self.window)))
        return size

    def submit(self) -> None:
        """Keeps up to ``window`` chunks in flight ahead of the merge point."""
        while not self.done and self.next_unit < self.n_units and len(self.pending) < self.window:
            count = min(self._next_count(), self.n_units - self.next_unit)
            if count <= 0:
                return
            first = self.next_unit
            future = self.client.submit(
                trace_chunk,
                self.scene_future,
                self.lights,
                self.body,
                self.options,
                first,
                count,
                key=f"{self.key}-{first}",
                pure=False,
            )
            self.pending.append((first, count, future))
            self.next_unit += count
            self.submitted_chunks += 1

    def merge_ready(self, cancel) -> int:
        """Merges the finished chunks at the merge point, in order, until ``cancel``
        is set; returns how many. Once the run is done its outstanding chunks are
        cancelled."""
        merged = 0
        while not self.done and not (cancel is not None and cancel.cancelled) and self.front.done():
            first, expected, future = self.pending.popleft()
            version, data = future.result()
            if version != _core.__version__:
                raise RuntimeError(
                    f"a worker runs endophoton engine {version!r}, this client {_core.__version__!r}: "
                    "install the same build on every worker (docs/distributed.md)"
                )
            _, got = self.reducer.add(data)
            if got != expected:
                raise RuntimeError(f"chunk of units {first}..{first + expected - 1} came back with {got} units")
            self.merged_to += expected
            self.merged_chunks += 1
            merged += 1
            done = self.reducer.merged_units * self.unit_size
            done = min(done, self.total) if self.fixed else done
            if self.progress is not None and not progress_verdict("progress", self.progress(done, self.total)):
                self.halted = True
            self.submit()  # refill the window: the next chunk to merge is then in flight too
        if self.done:
            self.cancel()
        return merged

    def chunks_estimate(self) -> int:
        """Chunks this run will merge: exact for a fixed count or once done; for a
        "store N" run extrapolated from its record rate so far."""
        if self.done:
            return self.merged_chunks
        known = self.merged_chunks + len(self.pending)
        if self.fixed:
            return known + math.ceil((self.n_units - self.next_unit) / self.chunk)
        needed = self._units_needed()
        if needed is None or needed <= 0:
            return known
        return known + math.ceil(needed / max(1, self._next_count() if self.adaptive else self.chunk))

    def cancel(self) -> None:
        self.client.cancel([future for _, _, future in self.pending])
        self.pending.clear()

    def finish(self) -> dict:
        return self.reducer.finish(self.threads)


def run_many(client, requests, *, chunk_units: int = 0, cancel=None, on_chunk=None, on_finished=None) -> list:
    """Several runs on ``client``'s workers at once: the chunks of all of them are
    tasks in flight together, and each run is merged in its own unit order by
    its own UnitReducer, so each gives the bits of ``ep.run`` on one machine.

    ``requests``: (scene, source, options, progress) per run (options as
    :func:`endophoton.run.run_request` builds them; progress(done, total) or None; False
    from it stops every run). Each distinct scene object is scattered to the
    workers once. ``on_chunk(merged_chunks, estimated_chunks)`` (over all runs)
    is called after each merge, ``on_finished(i, raw)`` once run i has ended.
    Returns the engine's raw result dict per run (what ``_core.run`` returns);
    after a cancel the unfinished runs give their merged prefixes, marked
    cancelled."""
    _check_chunk_units(chunk_units)
    on_chunk, on_finished = checked_notification("on_chunk", on_chunk), checked_notification("on_finished", on_finished)
    threads = _worker_threads(client)
    scattered: dict[int, tuple] = {}  # id(scene) -> (native scene, its future)
    runs, raws = [], [None] * len(requests)

    def finish(i):
        if raws[i] is None:
            raws[i] = runs[i].finish()
            if on_finished is not None:
                on_finished(i, raws[i])

    try:
        for scene, source, options, progress in requests:
            if id(scene) not in scattered:
                scattered[id(scene)] = (scene.to_native(), client.scatter(scene, broadcast=True, hash=False))
            native, future = scattered[id(scene)]
            lights, body = source.native_lights(scene.unit_cm), source.native_body(scene.unit_cm)
            runs.append(_ChunkedRun(client, native, future, lights, body, options, chunk_units, threads, progress))
        merged = 0
        while not all(r.done for r in runs):
            live = [r for r in runs if not r.done]
            for r in live:
                r.submit()
            if not _wait_any([r.front for r in live], cancel):
                break
            for r in live:
                merged += r.merge_ready(cancel)
            if on_chunk is not None:
                on_chunk(merged, sum(r.chunks_estimate() for r in runs))
            if any(r.halted for r in runs):
                break
            for i, r in enumerate(runs):
                if r.done:
                    finish(i)
    finally:
        for r in runs:
            r.cancel()
        client.cancel([future for _, future in scattered.values()])
    for i in range(len(runs)):
        finish(i)
    return raws


def run(scene, source, options: dict, client, *, chunk_units: int = 0, progress=None, cancel=None) -> dict:
    """Run the request ``options`` (as endophoton.run builds it) on ``client``'s
    workers; returns the engine's raw result dict (what ``_core.run`` returns)."""
    return run_many(client, [(scene, source, options, progress)], chunk_units=chunk_units, cancel=cancel)[0]


def local_workers(address: str) -> int | None:
    """N of a ``local:N`` address (1 <= N <= MAX_LOCAL_WORKERS, else ValueError naming the
    address), or None for any other address."""
    if not address.startswith("local:"):
        return None
    n = address[len("local:") :]
    digits = n.lstrip("0")
    if not (n.isascii() and n.isdigit()) or not digits:
        raise ValueError(f"scheduler = {address!r}: N in local:N must be a positive integer")
    if len(digits) > 9 or int(digits) > MAX_LOCAL_WORKERS:
        shown = digits if len(digits) <= 30 else f"{digits[:30]}... ({len(digits)} digits)"
        raise ValueError(
            f"scheduler = {address[:40]!r}: N = {shown} local worker processes is more than {MAX_LOCAL_WORKERS} "
            "(for more, start a scheduler and its workers and give tcp://host:port)"
        )
    return int(digits)


def available_memory_bytes() -> int | None:
    """Memory available to new processes now (Linux: MemAvailable of /proc/meminfo; elsewhere the
    free physical pages), or None where it cannot be read."""
    try:
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def check_local_memory(address: str, n_workers: int, available: int | None = None) -> None:
    """``local:N``'s N workers fit in :data:`LOCAL_MEMORY_SHARE` of the memory available (each
    :data:`LOCAL_WORKER_BYTES`), else ValueError naming the address, the need and the memory: checked
    before any worker starts (256 workers took ~25 GB)."""
    available = available_memory_bytes() if available is None else available
    need = n_workers * LOCAL_WORKER_BYTES
    if available is not None and need > LOCAL_MEMORY_SHARE * available:
        fit = max(1, int(LOCAL_MEMORY_SHARE * available // LOCAL_WORKER_BYTES))
        raise ValueError(
            f"scheduler = {address!r}: {n_workers} local worker processes need about {need / 2**30:.1f} GiB "
            f"({LOCAL_WORKER_BYTES // 2**20} MiB each), more than {LOCAL_MEMORY_SHARE:.0%} of the "
            f"{available / 2**30:.1f} GiB available: give local:{fit} or fewer"
        )


def check_address(address) -> int | None:
    """A scheduler address, accepted or refused by name before anything is imported or started:
    ``local:N`` (N workers that fit in memory: returns N) or ``tcp://host[:port]`` (returns None).
    ``tls://`` (it needs certificates, a distributed.Security the command line does not take),
    ``inproc://`` (a scheduler inside this very process, which the command line has not) and any
    other text are ValueErrors naming the address."""
    if not isinstance(address, str) or not address:
        raise ValueError(f"scheduler = {address!r} must be tcp://host:port or local:N")
    n_workers = local_workers(address)
    if n_workers is not None:
        check_local_memory(address, n_workers)
        return n_workers
    shown = repr(address) if len(address) <= 80 else repr(address[:77] + "...")
    if address.startswith("tls://"):
        raise ValueError(
            f"scheduler = {shown}: tls:// needs TLS certificates (a distributed.Security), which are not "
            "taken here: connect a dask.distributed.Client yourself and pass it as client= (docs/distributed.md)"
        )
    if address.startswith("inproc://"):
        raise ValueError(
            f"scheduler = {shown}: inproc:// names a scheduler inside this process: pass its "
            "dask.distributed.Client as client= instead, or give tcp://host:port or local:N"
        )
    scheme = next((s for s in REMOTE_SCHEMES if address.startswith(s)), None)
    host = address[len(scheme) :] if scheme else ""
    if not host or any(c.isspace() for c in host) or "/" in host.rstrip("/"):
        raise ValueError(f"scheduler = {shown} must be tcp://host:port or local:N")
    return None


@contextlib.contextmanager
def connect(address: str, timeout_s: float = 10.0):
    """A Dask client for ``address``: ``tcp://host:port`` of a running
    scheduler, or ``local:N`` for a LocalCluster of N single-threaded worker
    processes that import this very package. Closes what it opened.

    An unreachable scheduler raises ValueError naming the address."""
    n_workers = check_address(address)  # checked before anything is imported or started
    from distributed import Client, LocalCluster

    if n_workers is not None:
        package_parent = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
        path = os.pathsep.join(p for p in (package_parent, os.environ.get("PYTHONPATH", "")) if p)
        cluster = LocalCluster(
            n_workers=n_workers, threads_per_worker=1, processes=True, dashboard_address=":0", env={"PYTHONPATH": path}
        )
        try:
            with Client(cluster) as client:
                yield client
        finally:
            cluster.close()
        return
    try:
        client = Client(address, timeout=timeout_s)
    except (OSError, TimeoutError, ValueError, TypeError) as e:
        raise ValueError(f"scheduler = {address!r}: cannot connect ({type(e).__name__}: {e})") from None
    try:
        yield client
    finally:
        client.close()


def run_on_scheduler(address: str, run_fn, scene, source, progress=None, **kwargs):
    """``run_fn(scene, source, client=..., **kwargs)`` (endophoton.run, passed in
    so that this module does not import the one that imports it) on the cluster
    at ``address`` (see connect). Without a ``progress`` callback a tqdm bar on
    stderr shows the merged packets."""
    from tqdm import tqdm

    with connect(address) as client, tqdm(
        unit="packet", unit_scale=True, file=sys.stderr, disable=None if progress is None else True, desc="endophoton"
    ) as bar:

        def show(done, total):
            bar.total = total or None
            bar.update(done - bar.n)

        return run_fn(scene, source, client=client, progress=progress or show, **kwargs)
