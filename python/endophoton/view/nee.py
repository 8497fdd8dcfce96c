"""The next-event camera estimate (issue 34): the request a run takes, and the image it gives back.

``ep.run(scene, rig, photons, view=True)`` (or ``view=dict(...)``, keys as :func:`view_request`) asks the
engine to score, at every scattering event inside tissue, the light that would leave it unscattered
through the refracting surface into the pinhole camera (native/camera_tally.h, docs/render.md "The
next-event estimate"). Each score is split into colour channels while the run merges its units, so the
run hands back per pixel, per batch sums of:

    0..5   white image: energy, X, Y, Z, camera R, camera G
    6..11  fluorescence image: the same for fluorescent packets, times the emission filter T(lambda)

and per-pixel spectra. :func:`render_view` (``estimator="nee"``, render._nee_sums) turns them into a :class:`View`.
"""
from __future__ import annotations

import math

import numpy as np

from . import colour
from .camera import DEFAULT_VIEW_BATCHES

__all__ = ["view_request", "camera_view", "camera_view_options", "CHANNELS"]

CHANNELS = ("energy", "x", "y", "z", "camera_r", "camera_g")
_LAMBDA0_NM, _LAMBDA1_NM, _DLAMBDA_NM = 200.0, 1100.0, 0.1
_KEYS = {
    "camera",
    "width",
    "height",
    "n_batches",
    "excitation",
    "emission_filter",
    "white_balance",
    "tau_cut",
    "memory_budget_bytes",
    "look_back",
    "look_back_alpha",
    "look_back_g",
}
DEFAULT_TAU_CUT = 3.0
#: The look-back next event (docs/render.md "Look-back next event"): on by default (more efficient than plain
#: next-event estimation on every measured seed, equally unbiased); its proposal's share aimed at the camera and
#: that lobe's HG asymmetry (chosen by docs/performance.md §17).
DEFAULT_LOOK_BACK = True
DEFAULT_LOOK_BACK_ALPHA = 0.5
DEFAULT_LOOK_BACK_G = 0.9


def view_request(
    camera=None,
    width: int | None = None,
    height: int | None = None,
    n_batches: int = DEFAULT_VIEW_BATCHES,
    excitation=None,
    emission_filter="auto",
    white_balance="white",
    tau_cut: float = DEFAULT_TAU_CUT,
    memory_budget_bytes: float | None = None,
    look_back: bool = DEFAULT_LOOK_BACK,
    look_back_alpha: float = DEFAULT_LOOK_BACK_ALPHA,
    look_back_g: float = DEFAULT_LOOK_BACK_G,
) -> dict:
    """The keys of ``ep.run(..., view=dict(...))``; the same names and defaults as :func:`render_view`'s.

    camera : None (the rig's camera), an ep.Camera or its dict; width, height : pixels (default: the rig
    camera's resolution, else 128); n_batches : batches of the batch-means standard errors; excitation,
    emission_filter, white_balance : as render_view's (they set the colour channels); tau_cut : optical
    depth (mu_t x path to the exit point) beyond which scores are thinned by an unbiased roulette;
    memory_budget_bytes : the most memory the tally and its render may need (None: 4 GiB,
    ``view.budget.RENDER_MEMORY_BUDGET_BYTES``): a larger image is refused before the run; look_back : score an
    event reached by a clear free flight by a virtual event drawn at the scattering before it (docs/render.md
    "Look-back next event"), whose direction comes from the mixture (1 - look_back_alpha) p_HG(g) about the
    packet's direction + look_back_alpha p_HG(look_back_g) about the camera's (look_back_alpha in [0, 1),
    look_back_g in (-1, 1)).
    """
    return dict(
        camera=camera,
        width=width,
        height=height,
        n_batches=n_batches,
        excitation=excitation,
        emission_filter=emission_filter,
        white_balance=white_balance,
        tau_cut=tau_cut,
        memory_budget_bytes=memory_budget_bytes,
        look_back=look_back,
        look_back_alpha=look_back_alpha,
        look_back_g=look_back_g,
    )


def _as_request(view) -> dict:
    if view is True:
        return view_request()
    if isinstance(view, dict):
        unknown = sorted(set(view) - _KEYS)
        if unknown:
            raise ValueError(f"view: unknown key {unknown[0]!r} (keys: {', '.join(sorted(_KEYS))})")
        return view_request(**view)
    raise ValueError(f"view = {view!r} must be True (the rig's camera) or a dict (keys: {', '.join(sorted(_KEYS))})")


def channel_tables(light, T, gains):
    """Tables over the wavelength grid: (lambda_nm (L,), table (L, 12), fluorescent_only (12,),
    spectrum_bin (L,), fluorescent spectrum weight (L,), bins)."""
    lam = np.arange(_LAMBDA0_NM, _LAMBDA1_NM + _DLAMBDA_NM / 2, _DLAMBDA_NM)
    cmf = colour.cmf_xyz(lam)
    cam = np.maximum(colour.xyz_to_linear_srgb(cmf, gains)[:, :2], 0.0)
    base = np.column_stack([np.ones_like(lam), cmf, cam])
    t = np.clip(np.asarray(T(lam), dtype=np.float64), 0.0, 1.0)
    table = np.hstack([base, base * t[:, None]])
    fl_only = np.array([0] * 6 + [1] * 6, dtype=np.uint8)
    edges = colour.spectrum_bins()
    sbin = np.searchsorted(edges, lam, side="right") - 1
    sbin = np.where((sbin >= 0) & (sbin < edges.size - 1), sbin, -1).astype(np.int32)
    return lam, table, fl_only, sbin, t, edges.size - 1


def camera_view(scene, source, photons, view):
    """The engine's CameraView for ``ep.run(scene, source, photons, view=view)`` and its description
    (a dict :func:`render_view` checks its own arguments against). ValueError naming the field."""
    from .. import _core

    options, desc = camera_view_options(scene, source, photons, view)
    return _core.CameraView(**options), desc


def camera_view_options(scene, source, photons, view):
    """The keyword arguments of the engine's CameraView (everything the camera tally receives: the
    pinhole frame, the pixels' solid angles in sr, the channel tables over the wavelength grid in nm)
    and the view's description. Camera.frame, Camera.pixel_solid_angles and colour's tables compute
    them with endophoton.det's arithmetic, so that they have the same bits on every x86-64 machine
    (tests/python/test_det_inputs.py)."""
    from .render import _gains, _resolve_camera, emission_filter_function, excitation_spectrum
    from ..analysis.batches import _check_batches
    from .budget import check_render_memory

    req = _as_request(view)
    if photons is None:
        raise ValueError("view: the camera tally needs a fixed photon count (photons=N, no store or target)")
    camera, W, H = _resolve_camera(source, req["camera"], req["width"], req["height"])
    B = _check_batches(req["n_batches"])
    if photons < B:
        raise ValueError(f"photons = {photons} must be >= view n_batches = {B}")
    # the tally (pixels x batches x 12 sums) and the render that reads it, before the engine allocates it
    check_render_memory(
        W,
        H,
        B,
        tally=True,
        aperture=camera.aperture_radius > 0,
        memory_budget_bytes=req["memory_budget_bytes"],
        names=("view width", "view height", "view memory_budget_bytes"),
    )
    tau = req["tau_cut"]
    if isinstance(tau, bool) or not isinstance(tau, (int, float)) or not (math.isfinite(tau) and tau >= 0):
        raise ValueError(f"view tau_cut = {tau!r} must be a finite number >= 0 (optical depth)")
    look_back = _look_back(req)
    light = (
        excitation_spectrum(req["excitation"]) if req["excitation"] is not None else getattr(source, "spectrum", None)
    )
    T, filter_desc = emission_filter_function(req["emission_filter"], light)
    gains = _gains(req["white_balance"], light)
    _check_camera_outside(scene, camera)
    fr = camera.frame(W, H)
    lam, table, fl_only, sbin, t, nbins = channel_tables(light, T, gains)
    options = dict(
        position=fr["position"].tolist(),
        forward=fr["forward"].tolist(),
        right=fr["right"].tolist(),
        up=fr["up"].tolist(),
        tan_x=float(fr["tan_x"]),
        tan_y=float(fr["tan_y"]),
        width=W,
        height=H,
        pixel_solid_angle=camera.pixel_solid_angles(W, H),
        batches=B,
        packets=int(photons),
        tau_cut=float(tau),
        **look_back,
        lambda0_nm=_LAMBDA0_NM,
        dlambda_nm=_DLAMBDA_NM,
        table=table,
        fluorescent_only=fl_only,
        spectrum_bins=int(nbins),
        spectrum_bin=sbin,
        spectrum_fluorescent_weight=t,
    )
    desc = dict(
        camera=camera.to_dict(),
        width=W,
        height=H,
        n_batches=B,
        emission_filter=filter_desc,
        white_balance=req["white_balance"],
        tau_cut=float(tau),
        **look_back,
    )
    return options, desc


def _look_back(req) -> dict:
    """The look-back's switch and parameters, checked (ValueError naming the field and the value)."""
    on, alpha, g = req["look_back"], req["look_back_alpha"], req["look_back_g"]
    if not isinstance(on, bool):
        raise ValueError(f"view look_back = {on!r} must be True or False")
    for name, x, lo, ok in (
        ("look_back_alpha", alpha, "[0, 1)", lambda v: 0 <= v < 1),
        ("look_back_g", g, "(-1, 1)", lambda v: -1 < v < 1),
    ):
        if isinstance(x, bool) or not isinstance(x, (int, float)) or not (math.isfinite(x) and ok(x)):
            raise ValueError(f"view {name} = {x!r} must be a finite number in {lo}")
    return dict(look_back=on, look_back_alpha=float(alpha), look_back_g=float(g))


def _check_camera_outside(scene, camera):
    """ValueError naming camera.position when the pinhole lies inside a region (tissue)."""
    from .. import _core

    d = np.array([camera.forward])
    _, region, _, _ = _core.first_surfaces(scene.to_native(), np.array([camera.position]), d, None, 0.0, 1)
    if region[0] == -2:
        raise ValueError(
            f"camera.position = {camera.position.tolist()} lies inside a region: put the camera in the ambient medium"
        )
