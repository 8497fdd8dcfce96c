"""``python3 -m endophoton render SCENE.json ... --out DIR``: run a scene and render the endoscope's view.

Writes DIR/white.png, DIR/fluorescence.png (W x H) and DIR/view.npz (float arrays), and prints one JSON
object: width, height, regions, kernel, photons and, with --target/--background, contrast.
"""
from __future__ import annotations

import argparse
import json
import math
import os


#: The render command's camera estimator unless --estimator names one: the most efficient estimate that passes
#: the cross-checks (issue 34; docs/render.md, "Exitance estimate").
DEFAULT_ESTIMATOR = "exitance"


def add_render_arguments(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
    p.add_argument(
        "scene",
        help="SCENE.json (an optional top-level 'camera' object: position, look_at, up, "
        "fov_deg, aperture_radius; default: the endoscope source's camera)",
    )
    p.add_argument("--photons", type=int, default=None, help="packets to launch (default: run.photons or 1e6)")
    p.add_argument("--seed", type=int, default=None)
    p.add_argument("--threads", type=int, default=None, help="0 = all cores")
    p.add_argument("--width", type=int, default=None, help="pixels (default: the camera's, else 128)")
    p.add_argument("--height", type=int, default=None, help="pixels (default: the camera's, else 128)")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--target", default=None, help="target region (e.g. the polyp); needs --background")
    p.add_argument("--background", default=None, help="background region (e.g. the wall)")
    p.add_argument(
        "--surround",
        type=float,
        default=None,
        metavar="PIXELS",
        help="the background is the wall seen in a ring of PIXELS pixels around --target (of --background's "
        "region, if given); the contrast object then also has the Michelson contrasts (docs/render.md)",
    )
    p.add_argument("--excitation", default="white", help="white (default, flat 400-700 nm) or blue (405 nm)")
    p.add_argument(
        "--emission-filter",
        type=float,
        default=None,
        help="long-pass cut-on of the fluorescence image's filter, nm (default: auto)",
    )
    p.add_argument("--kernel-radius", type=float, default=None, help="scene units (default: 2 pixel footprints)")
    p.add_argument("--kernel-angle", type=float, default=15.0, help="degrees (default 15)")
    p.add_argument(
        "--memory-budget-gib",
        type=float,
        default=None,
        metavar="GIB",
        help="the most memory the render may need, GiB (default 4: view.budget.RENDER_MEMORY_BUDGET_BYTES); a "
        "larger --width x --height is refused before the run",
    )
    p.add_argument(
        "--estimator",
        choices=("exitance", "nee", "kernel", "knn"),
        default=DEFAULT_ESTIMATOR,
        help="exitance (default: every escape record near the pixel times its region's calibrated angular "
        "share toward the camera, the most efficient estimate that passes the cross-checks; docs/render.md), "
        "nee (next-event estimation toward the camera during the run, unbiased), kernel (kernel estimate over "
        "the escape records) or knn (k-nearest estimate over the escape records: each pixel's kernel grows to "
        "hold --knn-k records)",
    )
    p.add_argument(
        "--no-look-back",
        dest="look_back",
        action="store_false",
        help="with --estimator nee: plain next-event estimation instead of the default look-back next event "
        "(which costs about 1.2x the run's CPU for 1.1-2.5x the polyp contrast's efficiency on the colon view: "
        "docs/render.md, docs/performance.md section 17)",
    )
    p.add_argument(
        "--knn-k",
        type=int,
        default=None,
        metavar="K",
        help="with --estimator knn: the nearest records that set each pixel's kernel (default 32)",
    )
    return p


def _load(path: str):
    from .camera import Camera
    from ..scene import Scene
    from ..sources import source_from_dict

    from ..cli_files import load_scene_file

    data = load_scene_file(path)  # errors name the file
    if not isinstance(data, dict):
        raise ValueError(f"scene = {type(data).__name__} must be a JSON object")
    scene = Scene.from_dict(data, base_dir=os.path.dirname(os.path.abspath(path)))
    if "source" not in data:
        raise ValueError("scene: missing key 'source'")
    source = source_from_dict(data["source"])
    camera = Camera.from_dict(data["camera"]) if "camera" in data else None
    defaults = data.get("run", {})
    if not isinstance(defaults, dict):
        raise ValueError(f"scene.run = {defaults!r} must be an object")
    allowed = {"photons", "seed", "threads", "roulette_threshold", "roulette_chance", "max_steps", "max_path_cm"}
    for k in defaults:
        if k not in allowed:
            raise ValueError(f"scene.run: unknown key {k!r} (allowed: {', '.join(sorted(allowed))})")
    return scene, source, camera, defaults


def _check_int(name, v, lo):
    if v is not None and v < lo:
        raise ValueError(f"--{name} = {v} must be >= {lo}")


def _check_before_the_run(args, scene, source, camera) -> int | None:
    """The render inputs a run would only meet after tracing, checked first: --width/--height in
    [1, MAX_IMAGE_SIDE], --target/--background naming regions of the scene, a camera to render from, and
    the image's memory (view.budget: the render and, with --estimator nee, the run's camera tally) within
    --memory-budget-gib; with --estimator kernel also the emission filter and the camera outside tissue (the
    nee run's view request checks those before tracing). ValueError naming the option (an unknown --target
    used to be refused after the whole run, 8192 x 8192 died in a MemoryError, a camera inside tissue was
    found after the kernel run). Returns the budget in bytes (None: the default)."""
    from .budget import check_render_memory
    from .nee import _check_camera_outside
    from .render import _resolve_camera, emission_filter_function, excitation_spectrum
    from ..sources import MAX_IMAGE_SIDE, is_image_side

    for name in ("width", "height"):
        v = getattr(args, name)
        if v is not None and not is_image_side(v):
            raise ValueError(f"--{name} = {v} must be an integer in [1, {MAX_IMAGE_SIDE}] (pixels)")
    names = [r.name for r in scene.regions]
    for option in ("target", "background"):
        v = getattr(args, option)
        if v is not None and v not in names:
            raise ValueError(f"--{option} = {v!r} is not a region of the scene (regions: {', '.join(names)})")
    if camera is None and not hasattr(source, "camera"):
        raise ValueError(
            f"camera: SCENE.json has no 'camera' object and source.type = "
            f"{type(source).__name__} has no camera of its own"
        )
    gib = getattr(args, "memory_budget_gib", None)
    if gib is not None and not (math.isfinite(gib) and gib > 0):
        raise ValueError(f"--memory-budget-gib = {gib!r} must be a positive number of GiB")
    budget = None if gib is None else gib * 2**30
    cam, W, H = _resolve_camera(source, camera, args.width, args.height)
    nee = getattr(args, "estimator", DEFAULT_ESTIMATOR) == "nee"
    aperture = camera is not None and camera.aperture_radius > 0
    check_render_memory(W, H, tally=nee, aperture=aperture, memory_budget_bytes=budget, names=_BUDGET_NAMES)
    if not nee:
        light = excitation_spectrum(args.excitation)
        emission_filter_function("auto" if args.emission_filter is None else args.emission_filter, light)
        _check_camera_outside(scene, cam)
    return budget


def _check_knn_k(args):
    """--knn-k: only with --estimator knn, an integer in [2, render.MAX_KNN_K] (checked before the run)."""
    from .render import MAX_KNN_K

    k = getattr(args, "knn_k", None)
    if k is None:
        return
    if getattr(args, "estimator", None) != "knn":
        raise ValueError(f"--knn-k = {k}: give --estimator knn too (the other estimators have no k)")
    if not 2 <= k <= MAX_KNN_K:
        raise ValueError(f"--knn-k = {k} must be an integer in [2, {MAX_KNN_K}] (records)")


_BUDGET_NAMES = ("--width", "--height", "--memory-budget-gib")


#: The keys of the printed ``contrast`` object against a whole --background region (the render CLI's contract).
CONTRAST_KEYS = (
    "target",
    "background",
    "fluorescence",
    "fluorescence_stderr",
    "white",
    "white_stderr",
    "red_green",
    "red_green_stderr",
)


def render_main(args) -> int:
    from ..cli_files import check_out_dir, out_dir_errors
    from ..io import check_output_files
    from .render import check_kernel, excitation_spectrum, render_view, view_file_names
    from ..run import run

    for name, lo in (("photons", 1), ("seed", 0), ("threads", 0), ("width", 1), ("height", 1)):
        _check_int(name, getattr(args, name), lo)
    _check_knn_k(args)
    if not getattr(args, "look_back", True) and getattr(args, "estimator", None) != "nee":
        raise ValueError(
            f"--no-look-back: give --estimator nee (it is a way of the next-event estimate), not {args.estimator}"
        )
    surround = getattr(args, "surround", None)
    if args.target is not None and args.background is None and surround is None:
        raise ValueError(f"--target = {args.target!r}: give --background REGION or --surround PIXELS")
    if args.target is None and (args.background is not None or surround is not None):
        raise ValueError(f"--background = {args.background!r}, --surround = {surround!r}: give --target too")
    if surround is not None and not surround >= 1:
        raise ValueError(f"--surround = {surround!r} must be a number of pixels >= 1")
    scene, source, camera, defaults = _load(args.scene)
    budget = _check_before_the_run(args, scene, source, camera)
    # before the run: the kernel's size against the scene's unit, the output folder and every output file
    check_kernel(args.kernel_radius, args.kernel_angle, scene.unit_cm, names=("--kernel-radius", "--kernel-angle"))
    check_out_dir(args.out)
    aperture = camera is not None and camera.aperture_radius > 0  # the rig's own camera is a pinhole
    check_output_files(args.out, view_file_names("", aperture).values())
    source.spectrum = excitation_spectrum(args.excitation)
    kwargs = {k: v for k, v in defaults.items() if k != "photons"}
    photons = args.photons if args.photons is not None else int(defaults.get("photons", 1_000_000))
    if args.seed is not None:
        kwargs["seed"] = args.seed
    if args.threads is not None:
        kwargs["threads"] = args.threads
    estimator = getattr(args, "estimator", DEFAULT_ESTIMATOR)
    emission_filter = "auto" if args.emission_filter is None else args.emission_filter
    if estimator == "nee":
        kwargs["view"] = dict(
            camera=camera,
            width=args.width,
            height=args.height,
            emission_filter=emission_filter,
            memory_budget_bytes=budget,
            look_back=bool(getattr(args, "look_back", True)),
        )
    # the next-event image needs no escape records, but for its aperture image (a camera with an aperture)
    records = estimator != "nee" or aperture
    res = run(scene, source, photons=photons, record_escapes=records, spectral=True, **kwargs)
    knn = {} if getattr(args, "knn_k", None) is None else {"knn_k": args.knn_k}
    view = render_view(
        res,
        camera,
        args.width,
        args.height,
        kernel_radius=args.kernel_radius,
        kernel_angle_deg=args.kernel_angle,
        threads=kwargs.get("threads", 0),
        emission_filter=emission_filter,
        estimator=estimator,
        memory_budget_bytes=budget,
        **knn,
    )
    out = {
        "width": view.width,
        "height": view.height,
        "regions": view.regions(),
        "photons": view.packets,
        "kernel": view.kernel_summary(),
        "estimator": view.estimator,
    }
    if view.nee is not None:  # the next-event tally's counters (events, scored, looked_back, ...)
        out["nee"] = view.nee
    if args.target is not None and surround is None:  # the contract's object, exactly as before
        c = view.contrast(args.target, args.background)
        out["contrast"] = {k: v for k, v in c.items() if k in CONTRAST_KEYS}
    elif args.target is not None:
        out["contrast"] = view.contrast(args.target, args.background, surround_px=surround)
    with out_dir_errors(args.out):
        view.save(args.out)
    print(json.dumps(out, sort_keys=True, allow_nan=False))
    return 0
