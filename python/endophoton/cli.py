"""Command line: ``python3 -m endophoton run SCENE.json`` and ``... sweep``."""
from __future__ import annotations

import argparse
import json
import math
import sys


def _run_main(args) -> int:
    from .scene import Scene
    from .sources import source_from_dict
    from .run import run
    import os

    with open(args.scene, "r", encoding="utf-8") as fh:
        data = json.load(fh)
    scene = Scene.from_dict(data, base_dir=os.path.dirname(os.path.abspath(args.scene)))
    if "source" not in data:
        raise ValueError("scene: missing key 'source'")
    source = source_from_dict(data["source"])
    defaults = data.get("run", {})
    if not isinstance(defaults, dict):
        raise ValueError(f"scene.run = {defaults!r} must be an object")
    allowed = {"photons", "seed", "threads", "roulette_threshold", "roulette_chance", "max_steps", "max_path_cm"}
    for k in defaults:
        if k not in allowed:
            raise ValueError(f"scene.run: unknown key {k!r} (allowed: {', '.join(sorted(allowed))})")
    photons = args.photons if args.photons is not None else int(defaults.get("photons", 100000))
    kwargs = {k: v for k, v in defaults.items() if k != "photons"}
    if args.seed is not None:
        kwargs["seed"] = args.seed
    if args.threads is not None:
        kwargs["threads"] = args.threads
    if args.target_rel_error is not None:
        from .run import Target
        kwargs["target"] = Target(tally=args.target_tally, rel_error=args.target_rel_error)
        kwargs["max_photons"] = args.max_photons
        photons = None
    if args.quality is not None:
        kwargs["quality"] = args.quality
        photons = None
    if args.time_budget is not None:
        kwargs["time_budget_s"] = args.time_budget
    if args.scheduler is not None:  # the same result, traced on a Dask cluster
        from .distributed import run_on_scheduler
        res = run_on_scheduler(args.scheduler, run, scene, source, photons=photons, record_escapes=False, **kwargs)
    else:
        res = run(scene, source, photons=photons, record_escapes=False, **kwargs)
    out = res.to_dict()
    print(json.dumps(out, indent=None, sort_keys=True, allow_nan=False))
    return 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python3 -m endophoton", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    p_run = sub.add_parser("run", help="run one scene file and print the totals as JSON")
    p_run.add_argument("scene", help="SCENE.json")
    p_run.add_argument("--photons", type=int, default=None, help="packets to launch (default: run.photons or 1e5)")
    p_run.add_argument("--seed", type=int, default=None)
    p_run.add_argument("--threads", type=int, default=None, help="0 = all cores")
    p_run.add_argument("--target-rel-error", type=float, default=None,
                       help="target-accuracy mode: run until stderr/mean of --target-tally is at most this")
    p_run.add_argument("--target-tally", default="diffuse_reflectance",
                       help="tally for --target-rel-error (default diffuse_reflectance)")
    p_run.add_argument("--max-photons", type=int, default=0, help="upper bound in target mode (0 = none)")
    p_run.add_argument("--quality", choices=("preview", "standard", "reference"), default=None,
                       help="run to a preset accuracy: 5 %%, 1 %% or 0.2 %% relative error on the diffuse reflectance")
    p_run.add_argument("--time-budget", type=float, default=None, help="stop after this many seconds")
    p_run.add_argument("--scheduler", default=None, metavar="ADDRESS",
                       help="trace on a Dask cluster: tcp://host:port, or local:N for N local worker processes "
                            "(docs/distributed.md); the result is bit-identical to a local run")
    p_run.set_defaults(func=_run_main)
    try:
        from .beta_sweep import add_sweep_arguments, sweep_main
    except ImportError:  # pragma: no cover - the sweep module is part of the package
        add_sweep_arguments = None
    if add_sweep_arguments is not None:
        p_sweep = sub.add_parser("sweep", help="sweep the endoscope angle beta (the seed's experiment)")
        add_sweep_arguments(p_sweep)
        p_sweep.set_defaults(func=sweep_main)
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (ValueError, FileNotFoundError, json.JSONDecodeError) as e:
        print(f"endophoton: error: {e}", file=sys.stderr)
        return 2
