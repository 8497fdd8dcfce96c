"""``python3 -m endophoton sweep``: the β sweep from the command line.

Without ``--blend`` the sweep runs here on the paper's scene
(:func:`endophoton.sweep.driver.default_flat_scene`).  With ``--blend FILE`` it
starts ``blender -b FILE`` and runs the add-on's module
``endophoton_addon.sweep_blend`` inside it, which exports the Blender scene and
calls :func:`endophoton.sweep`; the package itself never imports ``bpy`` or the
add-on.  Outputs (sweep.csv, sweep.json, the plots, report.md) go to ``--out``.
"""
from __future__ import annotations

import argparse
import contextlib
import os
import shutil
import subprocess

from ..analysis import DEFAULT_BATCHES
from .driver import default_flat_scene, sweep, write_outputs
from ..io import check_output_files
from .schema import beta_text, output_file_names, parse_betas
from .view_runs import SWEEP_ESTIMATORS, contrast_target
from ..view.visibility import SURROUND_PX

__all__ = ["add_sweep_arguments", "sweep_main", "sweep_kwargs", "addon_folder", "scheduler_client"]

#: Environment variable naming the folder that holds the ``endophoton_addon`` package.
ADDON_PATH_VAR = "ENDOPHOTON_ADDON_PATH"

#: What Blender prints when it cannot import the add-on (%s: the ImportError).
NO_ADDON = (
    "sweep --blend: the EndoPhoton add-on is not found (%s); set $ENDOPHOTON_ADDON_PATH to the folder that holds "
    "endophoton_addon (the source tree's addon/), or install the add-on in Blender"
)


def add_sweep_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add the ``sweep`` subcommand's arguments to ``parser``."""
    parser.add_argument(
        "--betas",
        type=parse_betas,
        default=parse_betas("0:60:5"),
        help="tilt angles in degrees: '0,5,10' or 'start:stop:step' (default 0:60:5)",
    )
    parser.add_argument("--store", type=int, default=500_000, help="records stored per beta (default 500000)")
    parser.add_argument("--seed", type=int, default=1, help="engine seed of the first beta (default 1)")
    seeds = parser.add_mutually_exclusive_group()
    seeds.add_argument(
        "--seed-per-beta",
        dest="seed_per_beta",
        action="store_true",
        default=True,
        help="(the default) beta k runs with seed + k * 0x9E3779B97F4A7C15 (mod 2^64): independent runs, so "
        "the report's test of whether a contrast depends on beta holds its level (docs/render.md)",
    )
    seeds.add_argument(
        "--common-seed",
        dest="seed_per_beta",
        action="store_false",
        help="every beta runs with --seed (common random numbers: correlated betas, a conservative flatness test)",
    )
    parser.add_argument("--threads", type=int, default=0, help="engine threads, 0 = all cores")
    parser.add_argument("--out", default="sweep_out", help="output folder (default ./sweep_out)")
    parser.add_argument(
        "--blend",
        default=None,
        help=".blend file: run the sweep on it inside 'blender -b' (default: the paper's scene)",
    )
    parser.add_argument(
        "--distance", type=float, default=None, help="head distance from the target point, scene units (default 1 cm)"
    )
    parser.add_argument(
        "--batches", type=int, default=DEFAULT_BATCHES, help="batches for batch-means standard errors (default 20)"
    )
    parser.add_argument("--fluorescence-rule", choices=("paper", "eem"), default="paper")
    parser.add_argument(
        "--all-photons", action="store_true", help="store every escaping packet, not only fluorescent ones"
    )
    parser.add_argument(
        "--polyp",
        choices=("dome", "embedded", "none"),
        default="dome",
        help="polyp of the default scene (default dome)",
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument(
        "--target",
        default=None,
        help="render the endoscope's view per beta and add the visibility of this region "
        "(e.g. polyp) against --background (docs/render.md)",
    )
    parser.add_argument(
        "--background",
        default=None,
        help="background region for --target (e.g. tissue): the contrast against the whole region; with "
        "--surround, only its pixels in the ring",
    )
    parser.add_argument(
        "--surround",
        type=float,
        default=None,
        metavar="PIXELS",
        help="the background is the wall seen in a ring of PIXELS pixels around --target (the default, 8 "
        "pixels, when --target comes without --background; docs/render.md)",
    )
    parser.add_argument(
        "--target-contrast",
        default=None,
        metavar="CRITERION:ERR",
        help="run each beta until the contrast CRITERION (red_green, red_green_camera, fluorescence, white) has "
        "a standard error <= ERR, or until --max-packets packets (docs/sweep.md); needs --target",
    )
    parser.add_argument(
        "--max-packets",
        type=int,
        default=None,
        help="cap of --target-contrast: packets behind one beta's image (default 20000000)",
    )
    parser.add_argument(
        "--light",
        choices=("white", "blue"),
        default="white",
        help="the endoscope's light: white (flat 400-700 nm, default) or blue (405 nm, photodynamic diagnosis; "
        "the fluorescence image then has the long-pass filter 10 nm above the band)",
    )
    parser.add_argument(
        "--estimator",
        default=None,
        choices=SWEEP_ESTIMATORS,
        help="the view's camera estimator: exitance (default: every record near each pixel times its region's "
        "calibrated angular share toward the camera: no more packets, about 6x the kernel's efficiency on the "
        "colour contrast; docs/render.md), kernel (the records' kernel estimate, the paper's: its colour "
        "contrast reads about 22 %% low on the colon) or nee (the "
        "next-event estimate, unbiased: each beta's view from runs of its own with the camera tally, "
        "as many packets as the store run, topped up by --target-contrast; about 6x their time)",
    )
    parser.add_argument("--view-size", type=int, default=128, help="view width = height in pixels (default 128)")
    parser.add_argument(
        "--scheduler",
        default=None,
        metavar="ADDRESS",
        help="trace every angle's run on a Dask cluster, all at once: tcp://host:port, or local:N for N local "
        "worker processes (docs/distributed.md); the CSV is bit-identical to a local sweep's",
    )
    return parser


def sweep_kwargs(args: argparse.Namespace) -> dict:
    """Keyword arguments of :func:`endophoton.sweep` from the parsed ``sweep`` arguments."""
    kw = dict(
        betas=args.betas,
        store=args.store,
        seed=args.seed,
        threads=args.threads,
        fluorescent_only=not args.all_photons,
        fluorescence_rule=args.fluorescence_rule,
        distance=args.distance,
        progress=not args.no_progress,
        n_batches=args.batches,
        seed_per_beta=bool(getattr(args, "seed_per_beta", True)),
    )
    target, background = getattr(args, "target", None), getattr(args, "background", None)
    surround = getattr(args, "surround", None)
    if target is None and (background is not None or surround is not None):
        what = "--background" if background is not None else "--surround"
        raise ValueError(f"{what} needs --target (the region whose visibility is measured)")
    if getattr(args, "light", "white") == "blue":
        from ..view.render import excitation_spectrum

        kw["rig_kwargs"] = {"spectrum": excitation_spectrum("blue")}
    if target is not None:
        if args.view_size < 1:
            raise ValueError(f"--view-size = {args.view_size} must be >= 1")
        if surround is not None and not surround >= 1:
            raise ValueError(f"--surround = {surround!r} must be a number of pixels >= 1")
        kw["visibility"] = {
            "target": target,
            "background": background,
            "surround_px": SURROUND_PX if background is None and surround is None else surround,
            "width": args.view_size,
            "height": args.view_size,
            "images_dir": os.path.join(os.path.abspath(args.out), "views"),
        }
        if getattr(args, "estimator", None) is not None:
            kw["visibility"]["estimator"] = args.estimator
    tc = getattr(args, "target_contrast", None)
    if tc is None and getattr(args, "max_packets", None) is not None:
        raise ValueError("--max-packets is the cap of --target-contrast: give --target-contrast too")
    if tc is not None:
        if target is None:
            raise ValueError(f"--target-contrast {tc!r} needs --target (the view whose contrast it reads)")
        t = contrast_target(tc, "--target-contrast")
        if args.max_packets is not None:
            t = contrast_target((t.criterion, t.stderr, args.max_packets), "--target-contrast (--max-packets)")
        kw["target"] = t
    return kw


def forward_argv(args: argparse.Namespace) -> list:
    """The ``sweep`` arguments, as a list the add-on's ``sweep_blend.main`` parses again inside Blender."""
    argv = [
        "--betas",
        ",".join(beta_text(b) for b in args.betas),  # as given: :g would turn 89.9999999 into 90
        "--store",
        str(args.store),
        "--seed",
        str(args.seed),
        "--threads",
        str(args.threads),
        "--out",
        os.path.abspath(args.out),
        "--batches",
        str(args.batches),
        "--fluorescence-rule",
        args.fluorescence_rule,
    ]
    if args.distance is not None:
        argv += ["--distance", str(args.distance)]
    if not getattr(args, "seed_per_beta", True):
        argv.append("--common-seed")
    if args.all_photons:
        argv.append("--all-photons")
    if args.no_progress:
        argv.append("--no-progress")
    if getattr(args, "target", None) is not None:
        argv += ["--target", args.target, "--view-size", str(args.view_size)]
        if args.background is not None:
            argv += ["--background", args.background]
        if args.surround is not None:
            argv += ["--surround", repr(float(args.surround))]
        if args.estimator is not None:
            argv += ["--estimator", args.estimator]
    if getattr(args, "target_contrast", None) is not None:
        argv += ["--target-contrast", args.target_contrast]
    if getattr(args, "max_packets", None) is not None:
        argv += ["--max-packets", str(args.max_packets)]
    if getattr(args, "light", "white") != "white":
        argv += ["--light", args.light]
    if getattr(args, "scheduler", None) is not None:
        argv += ["--scheduler", args.scheduler]
    return argv


@contextlib.contextmanager
def scheduler_client(args: argparse.Namespace):
    """A Dask client for ``--scheduler`` (endophoton.distributed.connect: an unreachable
    scheduler is a ValueError naming the address), or None without it."""
    address = getattr(args, "scheduler", None)
    if address is None:
        yield None
        return
    from ..distributed import connect

    with connect(address) as client:
        yield client


def _package_parent() -> str:
    """The folder that holds the ``endophoton`` package (python/ in the source tree): this file is
    <parent>/endophoton/sweep/cli.py."""
    return os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def addon_folder() -> str | None:
    """The folder holding ``endophoton_addon``: ``$ENDOPHOTON_ADDON_PATH``, else the source tree's
    ``addon/`` beside ``python/``, else None (Blender then uses its installed add-on)."""
    folder = os.environ.get(ADDON_PATH_VAR)
    if not folder:
        folder = os.path.join(os.path.dirname(_package_parent()), "addon")
    return folder if os.path.isdir(os.path.join(folder, "endophoton_addon")) else None


def _blender() -> str:
    """The Blender executable (``$BLENDER``, else ``blender`` on PATH); ValueError if there is none."""
    blender = shutil.which(os.environ.get("BLENDER", "blender"))
    if blender is None:
        raise ValueError(f"blender not found (set $BLENDER; BLENDER = {os.environ.get('BLENDER', 'blender')!r})")
    return blender


def _check_blend(path) -> None:
    """``--blend FILE`` names an existing regular file (checked before Blender or a cluster starts)."""
    try:
        ok = os.path.isfile(path)
    except (TypeError, ValueError):  # an embedded NUL
        ok = False
    if not ok:
        why = "not a regular file" if os.path.lexists(path) else "no such file"
        raise ValueError(f"--blend {path!r}: {why}")


def run_in_blender(args: argparse.Namespace) -> int:
    """Start ``blender -b FILE`` and run ``endophoton_addon.sweep_blend.main`` inside it."""
    blender = _blender()
    paths = [_package_parent()] + [p for p in (addon_folder(),) if p]
    # Without the add-on (no addon/ beside the package, no $ENDOPHOTON_ADDON_PATH, none installed in Blender)
    # Blender says so in one line and exits 2, instead of a traceback of the import.
    expr = (
        "import sys; sys.path[:0] = %r\n"
        "try:\n    from endophoton_addon import sweep_blend\n"
        "except ImportError as e:\n    print(%r %% e, file=sys.stderr); sys.exit(2)\n"
        "sys.exit(sweep_blend.main(%r))" % (paths, NO_ADDON, forward_argv(args))
    )
    # blender opens the .blend itself; sweep_blend.main registers the add-on first
    cmd = [blender, "-b", os.fspath(args.blend), "--python-exit-code", "1", "--python-expr", expr]
    env = dict(os.environ)
    env.setdefault("ENDOPHOTON_PYTHONPATH", paths[0])
    return subprocess.call(cmd, env=env)


def sweep_main(args: argparse.Namespace) -> int:
    """Entry point of ``python -m endophoton sweep``; returns the exit code.

    Writes sweep.csv, sweep.json, the PNG plots and report.md into ``--out``.
    """
    from ..cli_files import check_out_dir, out_dir_errors

    if getattr(args, "blend", None):
        _check_blend(args.blend)
        _blender()
        check_out_dir(args.out)
        with scheduler_client(args) as client:
            if client is not None:  # Blender connects to it: a local:N cluster lives in this process
                args.scheduler = client.scheduler.address
            return run_in_blender(args)
    polyp = None if args.polyp == "none" else args.polyp
    scene = default_flat_scene(polyp=polyp)
    kwargs = sweep_kwargs(args)
    check_out_dir(args.out)
    check_output_files(args.out, output_file_names(args.betas, visibility=bool(kwargs.get("visibility"))))
    # Ctrl-C cancels the sweep (local or on a cluster): the finished angles' rows, the cancelled
    # one's partial row, their images and the report are written, marked cancelled; exit 130.
    from ..interrupts import sigint_cancels

    with sigint_cancels() as token:
        with scheduler_client(args) as client:
            res = sweep(scene, client=client, cancel=token, **kwargs)
        res.meta["scene"] = f"default_flat_scene(unit='cm', polyp={polyp!r})"
        with out_dir_errors(args.out):
            paths = write_outputs(res, args.out)
    print(
        f"sweep: {len(res.rows)} angle(s); wrote {paths['csv']}, {paths['json']}, "
        f"{len(paths.get('plots', []))} plot(s), {paths.get('report')}"
    )
    return 130 if res.meta.get("cancelled") or any(r["cancelled"] for r in res.rows) else 0
