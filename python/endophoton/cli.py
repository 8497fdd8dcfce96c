"""Command line: ``python3 -m endophoton run SCENE.json`` and ``... sweep``.

Exit status: 0 success; 2 bad input (the message names the field and the value);
1 a failure of the run itself (e.g. a grid file that could not be written);
130 interrupted (Ctrl-C: the partial result, marked ``cancelled``, is printed; no grid).
Every subcommand runs through :func:`run_guarded`, which maps errors to these codes.
"""
from __future__ import annotations

import argparse
import functools
import json
import math
import signal
import sys
import time

from .cli_files import load_scene_file as _load_scene_file
from .interrupts import sigint_cancels
from .sweep.cli import add_sweep_arguments, sweep_main

#: Errors of the input: exit 2 with the message (which names the field and value).
INPUT_ERRORS = (ValueError, OSError, RecursionError, UnicodeError, OverflowError)
EXIT_INPUT, EXIT_FAILURE, EXIT_INTERRUPTED = 2, 1, 130


def run_guarded(func, args) -> int:
    """Run a subcommand: bad input -> exit 2, a failed run -> exit 1, Ctrl-C -> 130; never a
    traceback for either. Other exceptions are bugs and keep their traceback."""
    try:
        return int(func(args) or 0)
    except KeyboardInterrupt:
        print("endophoton: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except RecursionError:
        print("endophoton: error: input nested too deeply", file=sys.stderr)
        return EXIT_INPUT
    except INPUT_ERRORS as e:
        print(f"endophoton: error: {e}", file=sys.stderr)
        return EXIT_INPUT
    except RuntimeError as e:
        print(f"endophoton: error: {e}", file=sys.stderr)
        return EXIT_FAILURE


def int_arg(lo: int, hi: int):
    """argparse type: an integer in [lo, hi] (argparse names the option in its error)."""

    def parse(text: str) -> int:
        try:
            v = int(text, 10)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
        if not lo <= v <= hi:
            raise argparse.ArgumentTypeError(f"{text} must be in [{lo}, {hi}]")
        return v

    return parse


def real_arg(lo: float, hi: float = math.inf, lo_open: bool = False):
    """argparse type: a finite number in [lo, hi] (or (lo, hi])."""

    def parse(text: str) -> float:
        try:
            v = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
        if not math.isfinite(v) or not (lo < v if lo_open else lo <= v) or v > hi:
            raise argparse.ArgumentTypeError(f"{text} must be a finite number {'>' if lo_open else '>='} {lo}")
        return v

    return parse


def _run_main(args) -> int:
    import os

    from .run import Target, run
    from .scene import Scene
    from .sources import source_from_dict

    data = _load_scene_file(args.scene)
    scene = Scene.from_dict(data, base_dir=os.path.dirname(os.path.abspath(args.scene)))
    if "source" not in data:
        raise ValueError("scene: missing key 'source'")
    source = source_from_dict(data["source"])
    if "camera" in data:  # render's camera: run does not use it, but checks it as render does
        from .view.camera import Camera

        Camera.from_dict(data["camera"])
    defaults = dict(data.get("run", {}))
    _check_one_budget(args)
    photons = args.photons if args.photons is not None else defaults.pop("photons", 100000)
    defaults.pop("photons", None)
    kwargs = dict(defaults)
    if args.seed is not None:
        kwargs["seed"] = args.seed
    if args.threads is not None:
        kwargs["threads"] = args.threads
    if args.target_rel_error is not None:
        kwargs["target"] = Target(tally=args.target_tally or "diffuse_reflectance", rel_error=args.target_rel_error)
        kwargs["max_photons"] = args.max_photons
        photons = None
    if args.quality is not None:
        kwargs["quality"] = args.quality
        photons = None
    if args.time_budget is not None:
        kwargs["time_budget_s"] = args.time_budget
    if args.progress:
        kwargs["progress"] = lambda done, total: print(f"progress {done} {total}", file=sys.stderr, flush=True)
    if args.stats:
        kwargs["stats"] = True
    if args.scheduler is not None:  # the same result, traced on a Dask cluster
        from .distributed import run_on_scheduler

        run = functools.partial(run_on_scheduler, args.scheduler, run)
    cpu_s = time.process_time()
    res = _run_interruptible(run, scene, source, photons=photons, record_escapes=False, **kwargs)
    cpu_s = time.process_time() - cpu_s
    out = res.to_dict()
    if args.stats:
        out["stats"] = stats_summary(out.get("stats"), res.photons)
        out["stats"]["process"] = {"run_cpu_seconds": cpu_s, "peak_rss_mb": _peak_rss_mb()}
    print(json.dumps(out, indent=None, sort_keys=True, allow_nan=False))
    return EXIT_INTERRUPTED if res.cancelled else 0


#: The engine counters of a run with stats (native/stats.h), in the order --stats prints them.
STAT_COUNTERS = ("interactions", "crossings", "cache_hits", "cache_misses", "full_queries")


def stats_summary(stats: dict | None, photons: int) -> dict:
    """``--stats``' block: each counter's total, its mean per packet, and its smallest, mean and
    largest count per work unit (the engine's ``stats``; None when no unit was merged)."""
    stats = stats or {"units": 0, "per_unit": {name: [] for name in STAT_COUNTERS}}
    out = {"units": int(stats["units"]), "total": {}, "per_packet": {}, "per_unit": {}}
    for name in STAT_COUNTERS:
        column = stats["per_unit"][name]
        total = int(sum(column))
        out["total"][name] = total
        out["per_packet"][name] = total / photons if photons else 0.0
        out["per_unit"][name] = {
            "min": int(min(column, default=0)),
            "mean": total / len(column) if column else 0.0,
            "max": int(max(column, default=0)),
        }
    return out


def _peak_rss_mb() -> float:
    """This process's peak resident set (VmHWM, MiB; 0 where /proc is missing). Not ru_maxrss: Linux
    carries a parent's peak over fork + exec into the child's ru_maxrss."""
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            return next((int(line.split()[1]) / 1024 for line in fh if line.startswith("VmHWM:")), 0.0)
    except OSError:
        return 0.0


def _check_one_budget(args) -> None:
    """A fixed --photons count and a run to an accuracy (--quality, --target-rel-error)
    exclude each other, as in ep.run (which also refuses --quality with a target), and a
    preset's packet cap is its own: refused by name instead of dropping --photons or
    --max-photons."""
    others = [(f, v) for f, v in (("--quality", args.quality), ("--target-rel-error", args.target_rel_error)) if v]
    if args.photons is not None and others:
        given = " and ".join(f"{f} {v}" for f, v in others)
        raise ValueError(
            f"--photons {args.photons} and {given}: a fixed count and a run to an accuracy exclude each other; "
            "give one (--max-photons bounds a --target-rel-error run)"
        )
    if args.quality and args.max_photons:
        raise ValueError(
            f"--quality {args.quality} brings its own packet cap; --max-photons {args.max_photons} would not change "
            "it (--max-photons bounds a --target-rel-error run)"
        )
    if args.target_rel_error is None:
        for flag, value in (("--target-tally", args.target_tally), ("--max-photons", args.max_photons)):
            if value:
                raise ValueError(f"{flag} {value} belongs to a --target-rel-error run, and none was given")


#: SIGINTs received while the CLI was still loading modules or reading the scene.
_early_interrupts: list = []


def _run_interruptible(run, *a, **kw):
    """Ctrl-C cancels the run (:func:`sigint_cancels`); the partial result, marked cancelled, is returned."""
    with sigint_cancels() as token:
        return run(*a, cancel=token, **kw)


def main(argv=None) -> int:
    # Until a run installs its own handler, Ctrl-C is only noted (an interrupt inside a
    # module import would otherwise surface as a traceback or an ImportError).
    previous = signal.signal(signal.SIGINT, lambda signum, frame: _early_interrupts.append(signum))
    try:
        return _main(argv)
    finally:
        signal.signal(signal.SIGINT, previous)
        if _early_interrupts:
            _early_interrupts.clear()


def _main(argv) -> int:
    from .run import MAX_PACKETS, MAX_THREADS

    parser = argparse.ArgumentParser(
        prog="python3 -m endophoton", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    sub = parser.add_subparsers(dest="command", required=True)
    p_run = sub.add_parser("run", help="run one scene file and print the totals as JSON")
    p_run.add_argument("scene", help="SCENE.json")
    p_run.add_argument(
        "--photons", type=int_arg(1, MAX_PACKETS), default=None, help="packets to launch (default: run.photons or 1e5)"
    )
    p_run.add_argument("--seed", type=int_arg(0, 2**64 - 1), default=None)
    p_run.add_argument("--threads", type=int_arg(0, MAX_THREADS), default=None, help="0 = all cores")
    p_run.add_argument(
        "--target-rel-error",
        type=real_arg(0.0, lo_open=True),
        default=None,
        help="target-accuracy mode: run until stderr/mean of --target-tally is at most this",
    )
    p_run.add_argument(
        "--target-tally",
        default=None,
        help="tally for --target-rel-error (default diffuse_reflectance)",
    )
    p_run.add_argument(
        "--max-photons",
        type=int_arg(0, MAX_PACKETS),
        default=0,
        help="upper bound in target mode (0 = the default cap, 2^30; an unreachable target then stops early "
        "with a warning)",
    )
    p_run.add_argument(
        "--quality",
        choices=("preview", "standard", "reference"),
        default=None,
        help="run to a preset accuracy: 5 %%, 1 %% or 0.2 %% relative error on the diffuse reflectance",
    )
    p_run.add_argument("--time-budget", type=real_arg(0.0), default=None, help="stop after this many seconds")
    p_run.add_argument(
        "--progress", action="store_true", help="print 'progress DONE TOTAL' lines to stderr about 10 times a second"
    )
    p_run.add_argument(
        "--scheduler",
        default=None,
        metavar="ADDRESS",
        help="trace on a Dask cluster: tcp://host:port, or local:N for N local worker processes "
        "(docs/distributed.md); the result is bit-identical to a local run",
    )
    p_run.add_argument(
        "--stats",
        action="store_true",
        help="count the engine's events (interactions, boundary crossings, triangle-cache hits/misses, full ray "
        "queries) and add their totals, means per packet and per-unit spread to the JSON as 'stats', with the "
        "run's CPU seconds and the process's peak memory (stats.process)",
    )
    p_run.set_defaults(func=_run_main)
    p_sweep = sub.add_parser("sweep", help="sweep the endoscope angle beta (the seed's experiment)")
    add_sweep_arguments(p_sweep)
    p_sweep.set_defaults(func=sweep_main)
    from .view.render_cli import add_render_arguments, render_main

    p_render = sub.add_parser("render", help="run a scene and render the endoscope's view (PNG + arrays + JSON)")
    add_render_arguments(p_render)
    p_render.set_defaults(func=render_main)
    args = parser.parse_args(argv)
    # From here Ctrl-C raises KeyboardInterrupt again (run_guarded: exit 130); `run`
    # replaces that with a cancel of the engine while it runs.
    signal.signal(signal.SIGINT, signal.default_int_handler)
    if _early_interrupts:
        print("endophoton: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    return run_guarded(args.func, args)
