"""One run across the workers of a Dask cluster, bit-identical to a local run.

The engine traces packets in work units of consecutive packet indices whose
size depends only on the request, and every packet's random numbers depend
only on (seed, packet index). A unit traced on any machine therefore gives the
same bytes. This module cuts the unit range into chunks, runs each chunk as a
Dask task (``_core.trace_units``: a pure function of scene, seed and unit
range) and feeds the returned units, in unit order, to ``_core.UnitReducer``,
which is the very object ``ep.run`` merges its own threads' units with: the
same merge, the same stop rule, the same estimates and grid writer. So for a
fixed count, a "store N" run and a target-accuracy run the result is the same
bits as ``ep.run`` on one machine. For store and target runs the client keeps a
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

import contextlib
import math
import os
import sys
import uuid
from collections import OrderedDict

from . import _core

#: Chunks of a store/target run kept in flight per worker thread.
WINDOW_PER_THREAD = 2
#: Chunks of a fixed-count run per worker thread (more chunks balance better,
#: fewer cost less overhead: docs/distributed.md measures both).
CHUNKS_PER_THREAD = 4
#: Packets per chunk aimed at in store/target runs (whose length is unknown).
OPEN_CHUNK_PACKETS = 16384

# Per worker process: native scenes built for recent runs, by scatter key.
_NATIVE_SCENES: "OrderedDict[str, object]" = OrderedDict()
_NATIVE_SCENES_KEPT = 4


def _native_scene(scene, key: str):
    native = _NATIVE_SCENES.get(key)
    if native is None:
        native = scene.to_native()
        _NATIVE_SCENES[key] = native
        while len(_NATIVE_SCENES) > _NATIVE_SCENES_KEPT:
            _NATIVE_SCENES.popitem(last=False)
    return native


def trace_chunk(scene, scene_key: str, lights: list, body, options: dict, first_unit: int, count: int):
    """A Dask task: trace units first_unit .. first_unit+count-1 of a run.

    Returns (engine version, unit bytes); pure in (scene, options, unit range)."""
    native = _native_scene(scene, scene_key)
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


def _wait_unless_cancelled(future, cancel) -> bool:
    """Blocks until ``future`` is done (True) or ``cancel`` is set (False)."""
    from distributed import wait

    while not (cancel is not None and cancel.cancelled):
        try:
            wait(future, timeout=0.1)
            return True
        except TimeoutError:
            pass
    return False


def run(scene, source, options: dict, client, *, chunk_units: int = 0, progress=None, cancel=None) -> dict:
    """Run the request ``options`` (as endophoton.run builds it) on ``client``'s
    workers; returns the engine's raw result dict (what ``_core.run`` returns)."""
    if isinstance(chunk_units, bool) or not isinstance(chunk_units, int) or chunk_units < 0:
        raise ValueError(f"chunk_units = {chunk_units!r} must be a non-negative integer (0 = automatic)")
    native_scene = scene.to_native()
    lights = source.native_lights(scene.unit_cm)
    body = source.native_body(scene.unit_cm)
    native_source = _core.Source(lights, body=body)
    config = _core.RunConfig(**options)
    reducer = _core.UnitReducer(native_scene, native_source, config)  # validates like run()
    unit_size, n_units = _core.unit_plan(native_scene, native_source, config)
    fixed = "photons" in options
    threads = _worker_threads(client)
    chunk = chunk_units or default_chunk_units(n_units, unit_size, fixed, threads)
    n_chunks = math.ceil(n_units / chunk)
    window = n_chunks if fixed else WINDOW_PER_THREAD * threads
    total = int(options["photons"]) if fixed else 0

    run_id = uuid.uuid4().hex[:12]
    scene_future = client.scatter(scene, broadcast=True, hash=False)
    futures: dict[int, object] = {}
    next_submit = next_merge = 0
    done_packets = 0
    try:
        while not reducer.stopped and next_merge < n_chunks:
            while next_submit < n_chunks and next_submit - next_merge < window:
                first = next_submit * chunk
                futures[next_submit] = client.submit(
                    trace_chunk,
                    scene_future,
                    scene_future.key,
                    lights,
                    body,
                    options,
                    first,
                    min(chunk, n_units - first),
                    key=f"endophoton-units-{run_id}-{first}",
                    pure=False,
                )
                next_submit += 1
            fut = futures[next_merge]
            if not _wait_unless_cancelled(fut, cancel):
                break
            version, data = fut.result()
            if version != _core.__version__:
                raise RuntimeError(
                    f"a worker runs endophoton engine {version!r}, this client {_core.__version__!r}: "
                    "install the same build on every worker (docs/distributed.md)"
                )
            first = next_merge * chunk
            _, got = reducer.add(data)
            expected = min(chunk, n_units - first)
            if got != expected:
                raise RuntimeError(f"chunk of units {first}..{first + expected - 1} came back with {got} units")
            del futures[next_merge]
            next_merge += 1
            done_packets = min(reducer.merged_units * unit_size, total) if fixed else reducer.merged_units * unit_size
            if progress is not None and progress(done_packets, total) is False:
                break
    finally:
        client.cancel(list(futures.values()))
        client.cancel([scene_future])
    return reducer.finish(threads)


@contextlib.contextmanager
def connect(address: str, timeout_s: float = 10.0):
    """A Dask client for ``address``: ``tcp://host:port`` of a running
    scheduler, or ``local:N`` for a LocalCluster of N single-threaded worker
    processes that import this very package. Closes what it opened.

    An unreachable scheduler raises ValueError naming the address."""
    from distributed import Client, LocalCluster

    if not isinstance(address, str) or not address:
        raise ValueError(f"scheduler = {address!r} must be tcp://host:port or local:N")
    if address.startswith("local:"):
        n = address[len("local:") :]
        if not n.isdigit() or int(n) < 1:
            raise ValueError(f"scheduler = {address!r}: N in local:N must be a positive integer")
        package_parent = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
        path = os.pathsep.join(p for p in (package_parent, os.environ.get("PYTHONPATH", "")) if p)
        cluster = LocalCluster(
            n_workers=int(n), threads_per_worker=1, processes=True, dashboard_address=":0", env={"PYTHONPATH": path}
        )
        try:
            with Client(cluster) as client:
                yield client
        finally:
            cluster.close()
        return
    try:
        client = Client(address, timeout=timeout_s)
    except (OSError, TimeoutError, ValueError) as e:
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
