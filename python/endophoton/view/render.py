"""The endoscope's view: camera images from a run's surface photon map.

``render_view(result, camera=None, width=None, height=None, ...)`` returns a
:class:`View`. Estimators of the radiance each pixel records:

**Kernel estimate** (the seed paper's; ``render_view``'s default is the exitance estimate,
:mod:`endophoton.view.exitance`). A primary ray per pixel centre (Embree, through
``_core.first_surfaces``) finds the surface point x_p the pixel sees, its
region and outward normal n_p; w_p is the unit direction from x_p to the
camera. The escape records r that left within ``kernel_radius`` of x_p
(3-D distance) in a direction within ``kernel_angle_deg`` of w_p (the paper's
"important" photons, generalised) estimate the exitant radiance

    L_p = sum_r e_r / (P * A * Omega * cos theta_p),
    A = pi r_k^2 (cm^2),  Omega = 2 pi (1 - cos theta_k),  cos theta_p = w_p . n_p,

per launched packet (P packets traced), with e_r the record's energy
(weight x 500/lambda) times the image's spectral weight (1 for the white
image; fluorescent flag x emission-filter transmission for the fluorescence
image). Units: energy of a 500 nm photon per launched packet per cm^2 per sr.
The gather uses scipy's cKDTree (6-D points (x / r_k, w / chord(theta_k)), a
ball of radius sqrt 2 holds the product kernel; the exact kernel is then
applied). The kernel is the speed/accuracy knob: its bias is reported by
halving both sizes in the same pass (bias ~ c r^2 + c' theta^2 for a smooth
radiance, so bias(h) ~ 4/3 (L_h - L_{h/2})).

**k-nearest estimate** (``estimator="knn"``). The same sum with a kernel of each pixel's own size: in the
6-D metric D = max(|x - x_p| / r_k, chord(w, w_p) / chord(theta_k)) the k-th nearest record (k = ``knn_k``)
at D = s_p sets the product kernel (radius s_p r_k, chord s_p chord(theta_k)), and the k - 1 records inside
it are summed over its exact volume, (k - 1) / V_k being the unbiased k-NN density for a uniform density.
Each image's scale comes from its own records; the scale is fixed across the batches.

**Aperture image (unbiased).** With ``camera.aperture_radius`` > 0, records
whose exit ray passes, unoccluded, through the lens disk are imaged through a
thin lens focused at ``focus_distance``: the ray meets the plane of focus at
F, and F projects through the lens centre onto the sensor. The pixel's
radiance is sum e_r / (P * A_lens * cos theta_r * Omega_pixel).

Noise: every per-pixel and per-region figure has a batch-means standard
error over ``n_batches`` contiguous packet-index blocks (records carry
``packet``). Colour: ``endophoton.view.colour``.
"""
from __future__ import annotations

import io
import math
import numbers
import os

import numpy as np

from .. import _core, det

from . import colour, exitance
from ..analysis import batch_index
from .budget import MAX_PAIRS_PER_CHUNK, check_render_memory
from .camera import DEFAULT_VIEW_BATCHES, Camera
from ..io import MAX_THREADS, check_int, shown
from ..sources import MAX_IMAGE_SIDE, is_image_side
from ..spectra import Spectrum

__all__ = ["render_view", "View", "excitation_spectrum", "emission_filter_function", "kernel_candidates"]

_CHUNK_PIXELS = 4096
#: The k-nearest estimate's default k (render_view's ``knn_k``), chosen by measurement (docs/render.md,
#: "k-nearest estimate"), and its largest allowed value.
KNN_K = 32
MAX_KNN_K = 4096
#: The two images of a view: all the light that leaves, and the fluorescence through the emission filter.
VIEW_IMAGES = ("white", "fluorescence")
#: The most pixel-record pairs one block of the k-nearest search holds (~80 bytes each: ~40 MiB).
_KNN_BLOCK_PAIRS = 2**19


# --------------------------------------------------------------------------
# light and filter
# --------------------------------------------------------------------------


def excitation_spectrum(kind) -> Spectrum | None:
    """The excitation light as a source spectrum (photon counts per nm, relative).

    ``"white"`` (or None): flat 400-700 nm, the paper's light (returned as None, the sources' default);
    ``"blue"``/``"405"``/405: narrow-band blue, Gaussian centred at 405 nm with 10 nm FWHM (photofrin's
    Soret band, as in photodynamic diagnosis); an ``ep.Spectrum`` or (wavelength_nm, values): a table.
    """
    if kind is None or (isinstance(kind, str) and kind.lower() == "white"):
        return None
    if isinstance(kind, Spectrum):
        return kind
    if (isinstance(kind, str) and kind.lower() in ("blue", "405", "blue405")) or (
        isinstance(kind, (int, float)) and not isinstance(kind, bool) and float(kind) == 405.0
    ):
        # endophoton.det's log and exp: the light shapes the channel tables a run with view= hands the engine
        lam = np.arange(385.0, 425.5, 1.0)
        sigma = 10.0 / (2 * math.sqrt(2 * det.log(2.0)))
        z = (lam - 405.0) / sigma
        return Spectrum(lam, det.exp(-0.5 * (z * z)), name="blue405")
    if isinstance(kind, (tuple, list)) and len(kind) == 2:
        return Spectrum(kind[0], kind[1], name="excitation")
    raise ValueError(
        f"excitation = {kind!r} must be 'white', 'blue' (405 nm), an ep.Spectrum or " "(wavelength_nm, values)"
    )


def emission_filter_function(emission_filter, excitation: Spectrum | None):
    """Transmission T(lambda) in [0, 1] of the fluorescence image's emission filter, and its description.

    ``"auto"``: a long-pass filter whose cut-on is 10 nm above the upper edge of the excitation band
    (where the light falls below 1 % of its peak) if that band is narrower than 100 nm, so it blocks the
    excitation; for a broad (white) light, which no long-pass filter can block without blocking the
    visible fluorescence, all-pass (the image then holds the fluorescent records only, which a real
    camera could not separate). None: all-pass. A number: long-pass cut-on in nm. An ``ep.Spectrum``:
    the transmission table (values in [0, 1], 0 outside it).
    """
    if isinstance(emission_filter, str) and emission_filter == "auto":
        if excitation is not None:
            lam = np.arange(250.0, 900.0, 0.5)
            s = excitation(lam)
            band = lam[s >= 0.01 * s.max()]
            if band.size and band[-1] - band[0] < 100.0:
                return emission_filter_function(float(band[-1]) + 10.0, excitation)
        emission_filter = None
    if emission_filter is None:
        return (lambda lam: np.ones_like(np.asarray(lam, dtype=np.float64))), "all-pass"
    if isinstance(emission_filter, (int, float)) and not isinstance(emission_filter, bool):
        cut = float(emission_filter)
        if not (math.isfinite(cut) and 200.0 <= cut <= 1000.0):
            raise ValueError(f"emission_filter = {emission_filter!r} must be a cut-on wavelength in [200, 1000] nm")
        return (lambda lam: (np.asarray(lam, dtype=np.float64) >= cut).astype(np.float64)), f"long-pass {cut:g} nm"
    if isinstance(emission_filter, Spectrum):
        if emission_filter.values.max() > 1.0:
            raise ValueError(f"emission_filter: transmission max {emission_filter.values.max():g} must be <= 1")
        return emission_filter, f"table '{emission_filter.name}'"
    raise ValueError(
        f"emission_filter = {emission_filter!r} must be 'auto', None, a cut-on wavelength (nm) "
        "or an ep.Spectrum of transmission"
    )


# --------------------------------------------------------------------------
# the view
# --------------------------------------------------------------------------


class View:
    """A rendered endoscope view. Images are (height, width[, 3]) arrays, row 0 at the top.

    Attributes: ``width``, ``height``, ``camera`` (:class:`Camera`), ``region_names``, ``region_map``
    (int32, region index each pixel sees, -1 none), ``depth`` (distance to the surface, scene units,
    0 where none), ``packets``, ``packets_per_batch``, ``kernel`` (radius, angle_deg), ``knn`` (the k-nearest
    estimate's k and per-image (H, W) scale maps, :func:`_knn_info`; None for the other estimators),
    ``images[name]`` for name in ("white", "fluorescence") with keys ``radiance``, ``radiance_stderr``,
    ``bias``, ``bias_stderr``, ``xyz``, ``rgb`` (linear sRGB, white balanced, unclipped), ``srgb8``,
    ``exposure``, ``spectrum`` (H, W, bins); ``aperture`` (same radiance/rgb keys, or None without an
    aperture); ``region_pixels``; ``region_batches`` (per-region, per-batch pixel-mean sums);
    ``pixel_batches[name]`` (H, W, B) per-batch radiance estimates and ``pixel_colour_sums[name]`` (``xyz``:
    H, W, 3, B; ``camera_rg``: H, W, 2, B) per-batch colour sums (not saved); ``gains`` (white balance).
    """

    def __init__(self, **kw):
        self.__dict__.update(kw)

    def pixels_of(self, name: str, field: str = "region") -> int:
        """How many pixels see region ``name`` (0 if none); ValueError naming ``field`` if the scene has no such region."""
        if name not in self.region_names:
            raise ValueError(
                f"{field} = {name!r} is not a region of the scene " f"(regions: {', '.join(self.region_names)})"
            )
        return int(self.region_pixels[self.region_names.index(name)])

    def region_index(self, name: str, field: str = "region") -> int:
        """Index of region ``name``; ValueError naming ``field`` if the scene has no such region or the camera
        sees none of it."""
        if self.pixels_of(name, field) == 0:
            raise ValueError(f"{field} = {name!r}: the camera sees no pixel of this region")
        return self.region_names.index(name)

    def regions(self) -> dict:
        """Mean radiance of each region's pixels: {name: {pixels, white_radiance, white_radiance_stderr,
        fluorescence_radiance, fluorescence_radiance_stderr}} (regions the camera sees)."""
        Pb = self.packets_per_batch
        out = {}
        for i, name in enumerate(self.region_names):
            if self.region_pixels[i] == 0:
                continue
            d = {"pixels": int(self.region_pixels[i])}
            for key in VIEW_IMAGES:
                per_batch = self.region_batches[key + "_radiance"][i] / Pb
                d[key + "_radiance"] = float(self.region_batches[key + "_radiance"][i].sum() / Pb.sum())
                d[key + "_radiance_stderr"] = float(np.std(per_batch, ddof=1) / math.sqrt(Pb.size))
            out[name] = d
        return out

    def kernel_summary(self) -> dict:
        """The kernel (radius in scene units, angle_deg) and its estimated bias in each region's mean radiance:
        bias = 4/3 (L(r, theta) - L(r/2, theta/2)), with its batch-means stderr, per image. The k-nearest
        estimate adds ``knn_k`` and ``knn_median_scale`` (the white image's median scale s over the pixels that
        see tissue: its kernels' radius is s x radius, their chord s x chord(angle))."""
        Pb = self.packets_per_batch
        bias = {}
        for i, name in enumerate(self.region_names):
            if self.region_pixels[i] == 0:
                continue
            d = {}
            for key in VIEW_IMAGES:
                rb = self.region_batches
                b = 4.0 / 3.0 * (rb[key + "_radiance"][i] - rb[key + "_half_radiance"][i])
                d[key + "_bias"] = float(b.sum() / Pb.sum())
                d[key + "_bias_stderr"] = float(np.std(b / Pb, ddof=1) / math.sqrt(Pb.size))
            bias[name] = d
        out = {"radius": self.kernel["radius"], "angle_deg": self.kernel["angle_deg"], "bias": bias}
        if getattr(self, "knn", None) is not None:  # the k-nearest estimate: k, and the median scale of its kernels
            s = self.knn["scale"]["white"][self.region_map >= 0]
            out.update(knn_k=self.knn["k"], knn_median_scale=float(np.median(s)) if s.size else None)
        return out

    def contrast(self, target: str, background: str | None, channels: str = "srgb", surround_px=None) -> dict:
        """:func:`endophoton.view.visibility.contrast` of this view."""
        from .visibility import contrast

        return contrast(self, target, background, channels, surround_px)

    def save(self, out_dir, prefix: str = "") -> dict:
        """Write ``white.png``, ``fluorescence.png`` (and ``aperture_*.png``) and ``view.npz`` (float arrays)
        atomically into ``out_dir``; returns {name: path}. Every path is checked before any file is written
        (:func:`endophoton.io.check_output_files`: ValueError naming a path that is a directory)."""
        from ..io import atomic_write_bytes, check_output_files

        files = view_file_names(prefix, self.aperture is not None)
        targets = dict(zip(files, check_output_files(out_dir, files.values())))
        os.makedirs(out_dir, exist_ok=True)
        paths = {}
        for key in (k for k in files if k != "arrays"):  # the PNGs (the .npz follows)
            images = self.aperture if key.startswith("aperture_") else self.images
            paths[key] = atomic_write_bytes(targets[key], _png_bytes(images[key.removeprefix("aperture_")]["srgb8"]))
        arrays = {
            "region_map": self.region_map,
            "depth": self.depth,
            "region_names": np.array(self.region_names),
            "spectrum_bin_edges_nm": self.spectrum_bin_edges_nm,
            "kernel_radius": self.kernel["radius"],
            "kernel_angle_deg": self.kernel["angle_deg"],
        }
        for key, img in self.images.items():
            for k, v in img.items():
                arrays[f"{key}_{k}"] = v
        if self.aperture is not None:
            for key, img in self.aperture.items():
                for k, v in img.items():
                    arrays[f"aperture_{key}_{k}"] = v
        buf = io.BytesIO()
        np.savez_compressed(buf, **arrays)
        paths["arrays"] = atomic_write_bytes(targets["arrays"], buf.getvalue())
        return paths


def view_file_names(prefix: str = "", aperture: bool = False) -> dict:
    """The files :meth:`View.save` writes, {key: file name}: ``white``, ``fluorescence`` (PNG), with an
    aperture image also ``aperture_white``, ``aperture_fluorescence``, and ``arrays`` (``view.npz``)."""
    keys = ["white", "fluorescence"] + (["aperture_white", "aperture_fluorescence"] if aperture else [])
    names = {k: f"{prefix}{k}.png" for k in keys}
    names["arrays"] = f"{prefix}view.npz"
    return names


def _png_bytes(srgb8: np.ndarray) -> bytes:
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.image as mpimg

    buf = io.BytesIO()
    mpimg.imsave(buf, srgb8, format="png")
    return buf.getvalue()


# --------------------------------------------------------------------------
# rendering
# --------------------------------------------------------------------------


def _resolve_camera(src, camera, width, height):
    """(Camera, width, height) of a render from the run's source ``src``: the rig's camera and resolution
    when ``camera`` is None, else 128 x 128 unless given. ValueError naming the camera, width or height."""
    if camera is None:
        if src is None or not hasattr(src, "camera"):
            raise ValueError(
                "camera = None: the run's source has no camera (only an EndoscopeRig has one); "
                "give camera=ep.Camera.look_at(...)"
            )
        camera = Camera.from_rig(src)
        res = tuple(src.camera_resolution)
    elif isinstance(camera, dict):
        camera = Camera.from_dict(camera)
        res = (128, 128)
    elif isinstance(camera, Camera):
        res = (128, 128)
    else:
        raise ValueError(f"camera = {camera!r} must be None (the rig's camera), an ep.Camera or a dict")
    w = res[0] if width is None else width
    h = res[1] if height is None else height
    for name, v in (("width", w), ("height", h)):
        if not is_image_side(v):
            raise ValueError(f"{name} = {v!r} must be an integer in [1, {MAX_IMAGE_SIDE}] (pixels)")
    return camera, int(w), int(h)


def check_kernel(kernel_radius, kernel_angle_deg, unit_cm=None, names=("kernel_radius", "kernel_angle_deg")):
    """Check the kernel's size: radius None (the default, resolved later) or a positive finite number
    (scene units), angle in (0, 90] degrees, and, with ``unit_cm``, both such that the kernel's
    normalisations 1 / (A Omega) at full and half size are finite and nonzero in double precision.
    ValueError naming the knob (``names``: the API's or the command line's spelling) and its value."""
    rn, an = names
    r, a = kernel_radius, kernel_angle_deg
    if r is not None and (isinstance(r, bool) or not isinstance(r, (int, float)) or not math.isfinite(r) or r <= 0):
        raise ValueError(f"{rn} = {r!r} must be a positive number (scene units) or None")
    if isinstance(a, bool) or not isinstance(a, (int, float)) or not math.isfinite(a) or not 0 < a <= 90:
        raise ValueError(f"{an} = {a!r} must be in (0, 90] degrees")
    theta = math.radians(a)
    omega, omega_h = (2.0 * math.pi * (1.0 - math.cos(t)) for t in (theta, theta / 2))
    if not omega_h > 0 or not math.isfinite(1.0 / (2.0 * math.sin(theta / 2))):
        raise ValueError(f"{an} = {a!r} is too small: the kernel's solid angle 2 pi (1 - cos) is 0 in double precision")
    if r is None or unit_cm is None:
        return
    rc = float(r) * float(unit_cm)
    area, area_h = math.pi * rc * rc, math.pi * (0.5 * rc) * (0.5 * rc)  # x * x: inf, never OverflowError
    if not area_h > 0 or not math.isfinite(1.0 / r):
        raise ValueError(f"{rn} = {r!r} is too small: the kernel's area pi r^2 is 0 in double precision")
    if not math.isfinite(area):
        raise ValueError(f"{rn} = {r!r} is too large: the kernel's area pi r^2 overflows double precision")
    for x in (area * omega, area_h * omega_h):
        if not (x > 0 and math.isfinite(x) and math.isfinite(1.0 / x)):
            raise ValueError(
                f"{rn} = {r!r} with {an} = {a!r}: the kernel's normalisation 1 / (pi r^2 x 2 pi (1 - cos)) "
                "is not a finite nonzero number in double precision"
            )


def _whole(v, lo: int, hi: int):
    """``v`` as an int when it is an integer (a Python or numpy one, not a bool) in [lo, hi], else None."""
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, numbers.Integral) or not lo <= int(v) <= hi:
        return None
    return int(v)


def _check_knobs(kernel_radius, kernel_angle_deg, n_batches, knn_k=KNN_K, exit_k=exitance.EXIT_K):
    """The render's knobs checked; returns (n_batches, knn_k, exit_k) as ints (a sweep script's np.int64 is
    fine)."""
    check_kernel(kernel_radius, kernel_angle_deg)
    k, b, x = _whole(knn_k, 2, MAX_KNN_K), _whole(n_batches, 2, 1000), _whole(exit_k, 2, MAX_KNN_K)
    if k is None:
        raise ValueError(f"knn_k = {knn_k!r} must be an integer in [2, {MAX_KNN_K}] (records)")
    if x is None:
        raise ValueError(f"exit_k = {exit_k!r} must be an integer in [2, {MAX_KNN_K}] (records)")
    if b is None:
        raise ValueError(f"n_batches = {n_batches!r} must be an integer in [2, 1000]")
    return b, k, x


def _packets(result) -> int:
    p = int(getattr(result, "packets_traced", 0) or 0)
    return p if p > 0 else int(result.photons)


def _records(result, n_batches, P, T):
    esc = result.escapes
    if esc is None:
        raise ValueError("result.escapes = None: render a run made with record_escapes=True")
    n = len(esc["weight"])
    if n == 0:
        raise ValueError("result.escapes holds no records: nothing left the tissue")
    batch, Pb = batch_index(esc["packet"], n_batches, P)
    wl = np.asarray(esc["wavelength"], dtype=np.float64)
    e = np.asarray(esc["energy"], dtype=np.float64)
    ef = e * (np.asarray(esc["fluorescent"]) > 0) * np.clip(T(wl), 0.0, 1.0)
    edges = colour.spectrum_bins()
    sbin = np.searchsorted(edges, wl, side="right") - 1
    sbin = np.where((sbin >= 0) & (sbin < edges.size - 1), sbin, -1)
    return dict(
        pos=np.asarray(esc["position"], dtype=np.float64),
        dir=np.asarray(esc["direction"], dtype=np.float64),
        normal=np.asarray(esc["normal"], dtype=np.float64),
        region=np.asarray(esc["region"], dtype=np.int64),
        band=exitance.bands(wl),
        batch=batch,
        Pb=Pb,
        wl=wl,
        cmf=colour.cmf_xyz(wl),
        energy={"white": e, "fluorescence": ef},
        sbin=sbin,
        nbins=edges.size - 1,
    )


def _cancelled(cancel):
    """Whether render_view's ``cancel`` (None or a CancelToken) is cancelled."""
    return cancel is not None and cancel.cancelled


def _accumulate(acc, key, index, weights, size):
    """acc[key] (float64, ``size``) += the sums of ``weights`` by ``index``: a whole-size bincount, for sums
    that are small (per region and batch) or made once (the aperture image)."""
    acc[key] = acc.get(key, 0) + np.bincount(index, weights=weights, minlength=size)[:size]


def _bins(index):
    """The bins of ``index`` and each entry's place among them: what :func:`_accumulate_sparse` adds by. The
    distinct bins (a sort), or, where the entries outnumber the span of their bins (the exitance estimate's
    millions of pairs a chunk), every bin of the span (no sort; the bins no entry reaches receive +0)."""
    if index.size == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    lo, hi = int(index.min()), int(index.max()) + 1
    if hi - lo <= index.size:
        return np.arange(lo, hi), index - lo
    return np.unique(index, return_inverse=True)


def _accumulate_sparse(acc, key, bins, weights, size):
    """:func:`_accumulate` of the entries grouped by ``bins`` (:func:`_bins` of their indices): only the bins
    that receive something are touched, so a chunk of pixels costs its entries, not the image's size.
    Each bin receives the same sum, in the same order, as from :func:`_accumulate` (bit-identical)."""
    a = acc.get(key)
    if a is None:
        a = acc[key] = np.zeros(size)
    u, inv = bins
    a[u] += np.bincount(inv, weights=weights, minlength=u.size)


def kernel_candidates(positions, directions, camera_position, kernel_radius: float, kernel_angle_deg: float):
    """Which records (positions, directions: (N, 3), scene units) can enter the kernel of some pixel of a
    camera at ``camera_position``: those whose exit direction lies within kernel_angle_deg + arcsin(2 r /
    distance) of the direction to the camera (a kernel centre lies on a ray through the camera, at most r
    from the record). A boolean (N,) mask; the kernel estimate's pre-filter, and the one rule by which a
    caller may drop records the kernel estimate cannot use (sweep.view_runs keeps top-up records this way)."""
    pos = np.asarray(positions, dtype=np.float64)
    to_cam = np.asarray(camera_position, dtype=np.float64) - pos
    dist = np.linalg.norm(to_cam, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        cosc = np.einsum("ij,ij->i", np.asarray(directions, dtype=np.float64), to_cam) / dist
        slack = np.arcsin(np.minimum(1.0, 2.0 * kernel_radius / np.maximum(dist, 1e-300)))
    return (dist > 0) & (cosc >= np.cos(np.minimum(math.pi, math.radians(kernel_angle_deg) + slack)))


def _pixel_chunks(cum):
    """The kernel gather's chunks [p0, p1) of pixels, given ``cum`` (pixels + 1,), the running count of the
    pairs in their balls: _CHUNK_PIXELS pixels, split where a chunk would hold more than MAX_PAIRS_PER_CHUNK
    pairs (one pixel at least); chunks without a pair are skipped."""
    n_pix, p0 = cum.size - 1, 0
    while p0 < n_pix:
        p1 = min(n_pix, p0 + _CHUNK_PIXELS)
        if cum[p1] - cum[p0] > MAX_PAIRS_PER_CHUNK:
            p1 = max(p0 + 1, int(np.searchsorted(cum, cum[p0] + MAX_PAIRS_PER_CHUNK, side="right")) - 1)
        if cum[p1] > cum[p0]:
            yield p0, p1
        p0 = p1


def _fixed_kernel_rule(rec, px, pw, pk, r, theta, unit_cm):
    """The kernel estimate's pair rule: a record is in pixel p's kernel when it left within ``r`` (scene units)
    of x_p, in a direction within ``theta`` (radians) of w_p; the half kernel halves both. ``rule(p, j)`` of
    the candidate pairs returns (p, j, weight factor per image, half mask, half factors per image): the pair's
    sum is e_j x factor, its half-kernel sum e_j x f1 x f2."""
    cos_t, cos_h = math.cos(theta), math.cos(theta / 2)
    norm = 1.0 / (math.pi * (r * unit_cm) ** 2 * 2 * math.pi * (1 - cos_t))
    norm_h = 1.0 / (math.pi * (0.5 * r * unit_cm) ** 2 * 2 * math.pi * (1 - cos_h))

    def rule(p, j):
        d2 = np.sum((rec["pos"][j] - px[p]) ** 2, axis=1)
        cw = np.einsum("ij,ij->i", rec["dir"][j], pw[p])
        inside = (d2 <= r * r) & (cw >= cos_t)
        half = inside & (d2 <= 0.25 * r * r) & (cw >= cos_h)
        p, j, half = p[inside], j[inside], half[inside]
        k, kh = pk[p] * norm, pk[p][half]
        return p, j, {name: k for name in rec["energy"]}, half, {name: (kh, norm_h) for name in rec["energy"]}

    return rule


def _knn_distance(dp, dw, r0, c0):
    """The k-nearest estimate's distance of position and direction differences dp, dw (..., 3):
    D = max(|dp| / r0, |dw| / c0), r0 in scene units, c0 a chord of the unit sphere. The product kernel of
    scale s (position radius s r0, direction chord s c0) holds exactly the records with D <= s. Written per
    component, so that a pair has the same bits wherever it is computed (the k-th record is then excluded
    exactly: D < s)."""
    a = np.sqrt(dp[..., 0] * dp[..., 0] + dp[..., 1] * dp[..., 1] + dp[..., 2] * dp[..., 2]) / r0
    b = np.sqrt(dw[..., 0] * dw[..., 0] + dw[..., 1] * dw[..., 1] + dw[..., 2] * dw[..., 2]) / c0
    return np.maximum(a, b)


def _knn_scales(pos, dirs, masks, px, pw, k, r0, c0, threads, cancel):
    """Per pixel (px, pw: (n, 3)) and per record set (``masks``: boolean (N,) over the records pos, dirs), the
    k-th smallest :func:`_knn_distance` to the set's records: the scale s_p of the pixel's product kernel
    (0 for an empty set; k is min(k, the set's size)). A list of (n,) arrays, or None once ``cancel`` is
    cancelled. Sets of at least 3/4 of the records share one search over all of them; a smaller set (the
    fluorescent records under blue light) gets its own, so that no search has to reach past many records of
    other sets."""
    out = [None] * len(masks)
    shared = [i for i, m in enumerate(masks) if 4 * int(m.sum()) >= 3 * m.size]
    groups = [(pos, dirs, [masks[i] for i in shared], shared)] if shared else []
    groups += [
        (pos[m], dirs[m], [np.ones(int(m.sum()), dtype=bool)], [i]) for i, m in enumerate(masks) if i not in shared
    ]
    for gpos, gdirs, gmasks, index in groups:
        found = _knn_search(gpos, gdirs, gmasks, px, pw, k, r0, c0, threads, cancel)
        if found is None:
            return None
        for i, f in zip(index, found):
            out[i] = f
    return out


def _knn_search(pos, dirs, masks, px, pw, k, r0, c0, threads, cancel):
    """:func:`_knn_scales` of record sets (``masks``) within one cKDTree of ``pos``, ``dirs``, in the 6-D Euclidean
    metric of (x / r0, w / c0), E <= sqrt 2 D: the m Euclidean-nearest records hold every record with D <= d_k
    when sqrt 2 d_k < E_m, else the pixel is searched again with 4m (m = 4k first); the pixels
    :func:`_knn_by_position` decided skip it. Pixels are searched in blocks of at most _KNN_BLOCK_PAIRS
    pixel-record pairs (~80 bytes each), so a large k or m cannot exhaust memory."""
    from scipy.spatial import cKDTree

    n, out = pos.shape[0], [np.zeros(px.shape[0]) for _ in masks]
    sizes = [int(m.sum()) for m in masks]
    if max(sizes, default=0) == 0:
        return out
    first = _knn_by_position(pos, dirs, masks, sizes, px, pw, k, r0, c0, threads, cancel)
    if first is None:
        return None
    out = [np.nan_to_num(f, nan=0.0) for f in first]
    rows_6d = np.flatnonzero(np.logical_or.reduce([np.isnan(f) for f in first]))
    if rows_6d.size == 0:
        return out
    tree = cKDTree(np.hstack([pos / r0, dirs / c0]))
    query = np.hstack([px / r0, pw / c0])
    pending = [(rows_6d, min(n, 4 * k))]
    while pending:
        rows_all, m = pending.pop()
        again = []
        for b in range(0, rows_all.size, max(1, _KNN_BLOCK_PAIRS // m)):
            if _cancelled(cancel):
                return None
            rows = rows_all[b : b + max(1, _KNN_BLOCK_PAIRS // m)]
            e, j = tree.query(query[rows], k=m, workers=threads or -1)
            e, j = e.reshape(rows.size, m), j.reshape(rows.size, m)
            d = _knn_distance(pos[j] - px[rows, None], dirs[j] - pw[rows, None], r0, c0)
            ok, dks = np.ones(rows.size, dtype=bool), []
            for mask, size in zip(masks, sizes):
                ki = min(int(k), size)
                dk = (
                    np.partition(np.where(mask[j], d, np.inf), ki - 1, axis=1)[:, ki - 1] if ki else np.zeros(rows.size)
                )
                ok &= (m >= n) | (math.sqrt(2.0) * (1 + 1e-9) * dk < e[:, -1])
                dks.append(dk)
            for o, dk in zip(out, dks):
                o[rows[ok]] = dk[ok]
            again.append(rows[~ok])
        if sum(a.size for a in again):
            pending.append((np.concatenate(again), min(n, 4 * m)))
    return out


def _knn_by_position(pos, dirs, masks, sizes, px, pw, k, r0, c0, threads, cancel):
    """:func:`_knn_search`'s first pass: per record set, the k-th smallest D among the m = k + 8 records nearest
    in position (a 3-D cKDTree of pos / r0). It is the set's k-th D where the m-th position distance exceeds
    it, since every other record has D >= |dp| / r0 >= that distance; else NaN (the 6-D search decides). Where
    the kernels outgrow the direction cone (few records: s c0 >= 2, the whole sphere) nearly every pixel is
    decided here, with k + 8 records a pixel instead of the 6-D search's hundreds. None once cancelled."""
    from scipy.spatial import cKDTree

    out = []
    for mask, size in zip(masks, sizes):
        ki, dk = min(int(k), size), np.full(px.shape[0], np.nan)
        out.append(dk)
        if ki == 0:
            dk[:] = 0.0
            continue
        idx, m = np.flatnonzero(mask), min(size, ki + 8)
        tree, step = cKDTree(pos[idx] / r0), max(1, _KNN_BLOCK_PAIRS // m)
        for b in range(0, px.shape[0], step):
            if _cancelled(cancel):
                return None
            rows = np.arange(b, min(b + step, px.shape[0]))
            a, j = tree.query(px[rows] / r0, k=m, workers=threads or -1)
            a, j = a.reshape(rows.size, m), idx[j.reshape(rows.size, m)]
            d = _knn_distance(pos[j] - px[rows, None], dirs[j] - pw[rows, None], r0, c0)
            d_k = np.partition(d, ki - 1, axis=1)[:, ki - 1]
            ok = (m >= size) | (a[:, -1] * (1 - 1e-9) > d_k)
            dk[rows[ok]] = d_k[ok]
    return out


def _knn_rule(rec, px, pw, pk, r0, c0, unit_cm, scales):
    """The k-nearest estimate's pair rule (as :func:`_fixed_kernel_rule`'s): a record is in pixel p's kernel
    of image m when D < s_m(p) (:func:`_knn_distance`; the k-th record itself, at D = s, is left out), with
    the product kernel's exact volume V = pi (s r0)^2 [cm^2] x pi min(s c0, 2)^2 [sr] (a cap of chord c has
    solid angle pi c^2); the half kernel is the scale s / 2. ``scales``: {image: s (pixels,)}."""

    def norm(s):
        v = math.pi * (s * r0 * unit_cm) ** 2 * math.pi * np.minimum(s * c0, 2.0) ** 2
        return np.where(v > 0, 1.0 / np.where(v > 0, v, 1.0), 0.0)

    norms = {name: (norm(s), norm(0.5 * s)) for name, s in scales.items()}

    def rule(p, j):
        d = _knn_distance(rec["pos"][j] - px[p], rec["dir"][j] - pw[p], r0, c0)
        ins = {name: d < s[p] for name, s in scales.items()}
        inside = np.logical_or.reduce(list(ins.values()))
        p, j, d = p[inside], j[inside], d[inside]
        hs = {name: d < 0.5 * s[p] for name, s in scales.items()}
        half = np.logical_or.reduce(list(hs.values()))
        k = {name: pk[p] * norms[name][0][p] * ins[name][inside] for name in scales}
        kh = {name: (pk[p][half], (norms[name][1][p] * hs[name])[half]) for name in scales}
        return p, j, k, half, kh

    return rule


def _knn_setup(rec, px, pw, pk, r0, c0, k, unit_cm, threads, cancel):
    """The k-nearest estimate's records (those with energy in some image), the pixels' ball radii in the
    tree's metric (at most sqrt 2 x the largest scale) and its pair rule; the scales per image go into rec["knn_scale"].
    Each image's scale comes from its own records (e > 0: the fluorescence image's are the fluorescent ones).
    None once ``cancel`` is cancelled."""
    keep = np.flatnonzero(np.logical_or.reduce([e > 0 for e in rec["energy"].values()]))
    masks = [e[keep] > 0 for e in rec["energy"].values()]
    found = _knn_scales(rec["pos"][keep], rec["dir"][keep], masks, px, pw, k, r0, c0, threads, cancel)
    if found is None:
        return None
    scales = rec["knn_scale"] = dict(zip(rec["energy"], found))
    # D < s means |dp| / r0 < s and |dw| / c0 < min(s, 2 / c0) (unit directions: |dw| <= 2), so the tree's
    # Euclidean distance is below sqrt(s^2 + min(s, 2 / c0)^2): at most sqrt 2 s, and s once the kernels
    # outgrow the direction cone (few records), where a ball of sqrt 2 s would hold twice the records.
    b_max = 2.0 * (1 + 1e-9) / c0
    ball = (1 + 1e-9) * np.maximum.reduce([np.sqrt(f * f + np.minimum(f, b_max) ** 2) for f in found])
    return keep, ball, _knn_rule(rec, px, pw, pk, r0, c0, unit_cm, scales)


def _add_pairs(acc, rec, p, j, k, half, kh, names, preg, hit, n_regions):
    """Adds the pixel-record pairs (p, j) of one chunk into the gather's sums ``acc``, for the images ``names``:
    pair weight e_j x k[name] (per pair), the half kernel's e_j x kh[name][0] x kh[name][1] over the pairs
    ``half``. The sums are those :func:`_image_from_sums`, :func:`_region_batches` and the View read (pixels are
    the hit pixels, in order; image pixels are the (H W,) indices of ``hit``)."""
    if p.size == 0:
        return
    B, n_pix = rec["Pb"].size, int(hit.sum())
    image_pixel, n_image = np.flatnonzero(hit), hit.size
    pb = p * B + rec["batch"][j]
    rb = preg[p] * B + rec["batch"][j]
    # Only the bins the chunk's pairs reach are touched (a dense block per chunk cost the image's size).
    nb = rec["nbins"]
    sb = rec["sbin"][j]
    ok = sb >= 0
    g_p, g_pb, g_half, g_spec = _bins(p), _bins(pb), _bins(pb[half]), _bins(p[ok] * nb + sb[ok])
    # (image pixel, channel, batch) of channel 0 of the XYZ (3 channels) and camera R, G (2) sums
    g_xyz, g_cam = (_bins(image_pixel[p] * (n * B) + rec["batch"][j]) for n in (3, 2))
    for name in names:
        e = rec["energy"][name]
        w = e[j] * k[name]
        _accumulate_sparse(acc, name + "_pix_batch", g_pb, w, n_pix * B)
        _accumulate_sparse(acc, name + "_half_pix_batch", g_half, e[j][half] * kh[name][0] * kh[name][1], n_pix * B)
        for c in range(3):
            wc = w * rec["cmf"][j, c]
            _accumulate_sparse(acc, f"{name}_xyz{c}_pix", g_p, wc, n_pix)
            _accumulate(acc, f"{name}_xyz{c}_reg_batch", rb, wc, n_regions * B)
            _accumulate_sparse(acc, f"{name}_xyz_image", (g_xyz[0] + c * B, g_xyz[1]), wc, n_image * 3 * B)
        for c in range(2):
            wc = w * rec["cam_rg"][j, c]
            _accumulate(acc, f"{name}_cam{c}_reg_batch", rb, wc, n_regions * B)
            _accumulate_sparse(acc, f"{name}_cam_image", (g_cam[0] + c * B, g_cam[1]), wc, n_image * 2 * B)
        _accumulate_sparse(acc, name + "_spec_pix", g_spec, w[ok], n_pix * nb)


def _kernel_gather(px, pw, pk, preg, n_regions, rec, r, theta_deg, threads, unit_cm, hit, cancel=None, knn_k=None):
    """Sums over the kernel of each hit pixel (see the module docstring): (a dict of arrays, the candidate
    count). ``hit`` (image pixels,): the pixels that see a surface (``px``'s); the colour sums are laid out as
    View.pixel_colour_sums holds them, (image pixels, channels, B), so the View takes them without a copy.
    ``knn_k``: None (the fixed kernel of radius ``r``, angle ``theta_deg``) or k (the k-nearest estimate: r and
    theta set the metric's scales, the k-th nearest record each pixel's size; :func:`_knn_rule`).
    Returns (None, 0) once ``cancel`` (a CancelToken or None) is cancelled: it is checked before and in the
    middle of every chunk."""
    from scipy.spatial import cKDTree

    theta = math.radians(theta_deg)
    chord = 2.0 * math.sin(theta / 2.0)
    n_pix = px.shape[0]
    if knn_k is None:
        keep = np.flatnonzero(kernel_candidates(rec["pos"], rec["dir"], rec["cam"], r, theta_deg))
        ball, rule = math.sqrt(2.0) * (1 + 1e-9), _fixed_kernel_rule(rec, px, pw, pk, r, theta, unit_cm)
    else:
        setup = _knn_setup(rec, px, pw, pk, r, chord, knn_k, unit_cm, threads, cancel)
        if setup is None:
            return None, 0
        keep, ball, rule = setup
    acc = {}
    if keep.size == 0 or n_pix == 0:
        return acc, keep.size
    tree = cKDTree(np.hstack([rec["pos"][keep] / r, rec["dir"][keep] / chord]))
    query = np.hstack([px / r, pw / chord])
    # the pairs each pixel's ball holds, counted first: chunks of _CHUNK_PIXELS pixels, split where they would
    # hold more than MAX_PAIRS_PER_CHUNK pairs (a pixel's own pairs are at most the records)
    n_ball = tree.query_ball_point(query, ball, workers=threads or -1, return_length=True)
    for p0, p1 in _pixel_chunks(np.concatenate([[0], np.cumsum(n_ball)])):
        if _cancelled(cancel):
            return None, 0
        lists = tree.query_ball_point(
            query[p0:p1], ball if np.isscalar(ball) else ball[p0:p1], workers=threads or -1, return_sorted=False
        )
        if _cancelled(cancel):  # again before the chunk's sums (half its time)
            return None, 0
        counts = np.fromiter((len(x) for x in lists), dtype=np.int64, count=p1 - p0)
        j = keep[np.concatenate([np.asarray(x, dtype=np.int64) for x in lists])]
        _add_pairs(acc, rec, *rule(np.repeat(np.arange(p0, p1), counts), j), rec["energy"], preg, hit, n_regions)
    return acc, keep.size


def _exitance_gather(px, pk, preg, n_regions, rec, r0, theta_deg, threads, unit_cm, hit, cancel, k):
    """:func:`_kernel_gather`'s sums for the exitance estimate (:mod:`endophoton.view.exitance`): each pixel's
    ball over its own region's records, radius r_p = max(r0, d_k) per image, each pair weighted by the angular
    table of the record's batch, region and band at the pixel's view cosine and by the calibration. The pairs
    are searched and summed natively (``_core.ExitIndex``: one search per pixel at the larger of the images'
    radii).
    Returns (acc, the records used, {image: (pixels,) ball radii}), or (None, 0, None) once cancelled."""
    mu_rows = exitance.legendre_rows(np.clip(1.0 / pk, 0.0, 1.0))
    mu = np.clip(np.abs(np.einsum("ij,ij->i", rec["normal"], rec["dir"])), 0.0, 1.0)
    B, names = rec["Pb"].size, list(rec["energy"])
    s0 = 8.0 * float(np.median(r0)) if np.size(r0) else 0.0  # no pixel sees a surface: no cell is made
    anything = np.logical_or.reduce([e > 0 for e in rec["energy"].values()])
    index = _core.ExitIndex(rec["pos"], rec["region"].astype(np.int32), anything.astype(np.uint8), n_regions)
    token = cancel if isinstance(cancel, _core.CancelToken) else None  # what the native searches poll
    setup = {}
    for name, e in rec["energy"].items():
        if _cancelled(cancel):
            return None, 0, None
        coef = exitance.angular_tables(mu, rec["region"], rec["band"], rec["batch"], e, n_regions, B)
        cal = exitance.calibration(rec, e, coef, px, preg, n_regions, theta_deg, s0)
        radii = exitance.pixel_radii(index, e, px, preg, r0, k, threads, token)
        if radii is None:
            return None, 0, None
        r_p, grown = radii
        f_p = exitance.region_share(px, preg, r_p, threads)  # A_p = f_p pi r_p^2: the ball's own-region part
        base = pk / (2.0 * math.pi * math.pi * f_p * (r_p * unit_cm) ** 2)  # 1 / (2 pi mu_p A_p): 0 where r_p is inf
        setup[name] = (coef, cal * base[:, None], r_p, grown)
    if _cancelled(cancel):
        return None, 0, None
    sums = _exitance_sums(index, rec, [setup[name] for name in names], px, preg, mu_rows, hit, threads, token)
    if sums is None or _cancelled(cancel):
        return None, 0, None
    acc = _exitance_acc(sums, names, preg, n_regions, hit)
    seen = np.unique(preg[np.max([np.where(np.isfinite(v[2]), v[2], 0.0) for v in setup.values()], axis=0) > 0])
    used = int(np.count_nonzero(anything & np.isin(rec["region"], seen)))
    return acc, used, {name: v[2] for name, v in setup.items()}


def _exitance_sums(index, rec, setups, px, preg, mu_rows, hit, threads, cancel):
    """``index.gather`` (``_core.ExitIndex``) of the images whose (coef, scale, r_p, grown) are ``setups``, in the
    order of ``rec["energy"]``: the native sums, or None once ``cancel`` (a CancelToken or None) is set."""
    return index.gather(
        rec["batch"].astype(np.int32),
        rec["band"].astype(np.int32),
        rec["sbin"].astype(np.int32),
        rec["cmf"],
        rec["cam_rg"],
        np.stack(list(rec["energy"].values())),
        np.stack([v[0] for v in setups]),
        px,
        preg.astype(np.int32),
        mu_rows,
        np.stack([v[2] for v in setups]),
        np.stack([v[3] for v in setups]).astype(np.uint8),
        np.stack([v[1] for v in setups]),
        np.flatnonzero(hit),
        hit.size,
        spectrum_bins=int(rec["nbins"]),
        threads=int(threads),
        cancel=cancel,
    )


def _exitance_acc(sums, names, preg, n_regions, hit) -> dict:
    """The native exitance sums (W, W_half (images, pixels, B), XYZ (images, image pixels, 3, B), CAM (images,
    image pixels, 2, B), SPEC (images, pixels, bins)) laid out as :func:`_add_pairs` leaves the gathers' (``acc``),
    without copies of the per-batch colour sums."""
    W, Wh, XYZ, CAM, SPEC = sums
    image_pixel = np.flatnonzero(hit)
    acc = {}
    for m, name in enumerate(names):
        acc[name + "_pix_batch"] = W[m].reshape(-1)
        acc[name + "_half_pix_batch"] = Wh[m].reshape(-1)
        acc[name + "_spec_pix"] = SPEC[m].reshape(-1)
        for tag, a in (("xyz", XYZ[m]), ("cam", CAM[m])):
            acc[f"{name}_{tag}_image"] = a.reshape(-1)
            for c in range(a.shape[1]):
                per_batch = a[image_pixel, c, :]
                acc[f"{name}_{tag}{c}_reg_batch"] = _region_sums(preg, per_batch, n_regions).reshape(-1)
                if tag == "xyz":
                    acc[f"{name}_xyz{c}_pix"] = per_batch.sum(axis=1)
    return acc


def _image_from_sums(acc, name, P, Pb, hit, shape, nbins, gains, exposure, prefix=""):
    """Per-pixel radiance (+ batch-means stderr), XYZ, linear sRGB, 8-bit sRGB and spectrum of one image."""
    H, W = shape
    B = Pb.size
    n_hit = int(hit.sum())
    zero_pb = np.zeros(n_hit * B)
    sums = acc.get(f"{prefix}{name}_pix_batch", zero_pb).reshape(n_hit, B)
    per_batch = sums / Pb
    img = {}

    def full(a, extra=()):
        out = np.zeros((H * W,) + tuple(extra))
        out[hit] = a
        return out.reshape((H, W) + tuple(extra))

    img["radiance"] = full(sums.sum(axis=1) / P)
    img["radiance_stderr"] = full(np.std(per_batch, axis=1, ddof=1) / math.sqrt(B))
    if prefix == "":
        half = acc.get(f"{name}_half_pix_batch", zero_pb).reshape(n_hit, B) / Pb
        bias_b = 4.0 / 3.0 * (per_batch - half)
        img["bias"] = full(4.0 / 3.0 * (sums.sum(axis=1) / P - half @ Pb / P))
        img["bias_stderr"] = full(np.std(bias_b, axis=1, ddof=1) / math.sqrt(B))
    xyz = np.stack([acc.get(f"{prefix}{name}_xyz{c}_pix", np.zeros(n_hit)) for c in range(3)], axis=1) / P
    img["xyz"] = full(xyz, (3,))
    rgb = colour.xyz_to_linear_srgb(img["xyz"], gains)
    img["rgb"] = rgb
    k = colour.auto_exposure(rgb.max(axis=-1), hit.reshape(H, W)) if exposure == "auto" else float(exposure)
    img["exposure"] = np.float64(k)
    img["srgb8"] = colour.to_srgb8(rgb, k)
    spec = np.zeros((H * W, nbins), dtype=np.float32)  # float32 directly: no full-size float64 copy
    spec[hit] = acc.pop(f"{prefix}{name}_spec_pix", np.zeros(n_hit * nbins)).reshape(n_hit, nbins) / P
    img["spectrum"] = spec.reshape(H, W, nbins)
    return img


def _gains(white_balance, light):
    if white_balance is None:
        return None
    if white_balance == "white":
        return colour.white_balance_gains(None)
    if white_balance == "excitation":
        return colour.white_balance_gains(light)
    raise ValueError(f"white_balance = {white_balance!r} must be 'white', 'excitation' or None")


def render_view(
    result,
    camera=None,
    width: int | None = None,
    height: int | None = None,
    *,
    kernel_radius: float | None = None,
    kernel_angle_deg: float = 15.0,
    excitation=None,
    emission_filter="auto",
    white_balance="white",
    exposure="auto",
    n_batches: int = DEFAULT_VIEW_BATCHES,
    threads: int = 0,
    estimator: str = "auto",
    knn_k: int = KNN_K,
    exit_k: int = exitance.EXIT_K,
    memory_budget_bytes: float | None = None,
    cancel=None,
    images=VIEW_IMAGES,
) -> View | None:
    """Render the image the camera records from ``result``'s escape records (surface photon map).

    result : an ``ep.Result`` with escape records (``record_escapes=True``); a spectral run gives colour
    camera : None = the run's EndoscopeRig camera; an :class:`ep.Camera`; or a dict with position,
        look_at, up, fov_deg and optional aperture_radius (scene units), as in SCENE.json
    width, height : pixels (default: the rig camera's resolution, else 128 x 128)
    kernel_radius : kernel radius on the surface, scene units (default: 2 pixel footprints at the median
        depth); kernel_angle_deg : half angle of the direction cone (default 15, the paper's)
    excitation : the light the run used, for white balance and the auto emission filter
        (default: the run source's spectrum; see :func:`excitation_spectrum`)
    emission_filter : the fluorescence image's filter (:func:`emission_filter_function`)
    white_balance : "white" (von Kries for the flat 400-700 nm white light), "excitation" (for the run's
        light) or None (no balance, D65 assumed)
    exposure : "auto" (99th percentile of the largest linear channel -> 0.5, per image) or a fixed factor
    n_batches : packet-index blocks for the batch-means standard errors
    threads : for the primary rays and the gather (0 = all cores)
    estimator : "nee" (the run's next-event camera tally, from ``ep.run(..., view=...)``; unbiased:
        docs/render.md), "kernel" (the kernel estimate over the escape records), "knn" (the k-nearest estimate
        over them: each pixel's kernel grows until it holds ``knn_k`` records, so every pixel that sees tissue
        is nonzero; docs/render.md), "exitance" (every record near the pixel times its region's calibrated angular
        share toward the camera: :mod:`endophoton.view.exitance`) or "auto" (nee with a tally, else exitance)
    knn_k : with estimator "knn", the number of nearest records (in the 6-D metric of position / kernel_radius
        and direction / chord(kernel_angle_deg)) that sets each pixel's kernel: the k-th sets its size, the
        k - 1 inside it are summed ((k - 1) / V_k: unbiased for a uniform density). Larger k: less noise
        (relative stderr ~ 1 / sqrt(k - 1)), larger kernels and more bias. Default ``KNN_K`` (32)
    exit_k : estimator "exitance": the records of its region each pixel's ball holds at least (default 256)
    memory_budget_bytes : the most memory the render may need (None: ``view.budget.RENDER_MEMORY_BUDGET_BYTES``,
        4 GiB); a size that needs more (:func:`endophoton.view.budget.render_memory_bytes`) is refused before
        anything is allocated, with a ValueError naming width and height
    cancel : None or an ``ep.CancelToken``: once cancelled, render_view stops at its next check (twice per
        block of pixels of the kernel gather, and between the steps after it) and returns None (the add-on's Esc)
    images : the images the records' estimators compute (default both); one left out is all zeros and costs
        nothing (a sweep reads one image of each of its two runs). The next-event tally keeps both.
    """
    n_batches, knn_k, exit_k = _check_knobs(kernel_radius, kernel_angle_deg, n_batches, knn_k, exit_k)
    wanted = _check_call(result, estimator, threads, cancel, images)
    if estimator == "auto":
        estimator = "nee" if getattr(result, "camera_image", None) is not None else "exitance"
    camera, W, H = _resolve_camera(result.source, camera, width, height)
    _check_memory(result, camera, W, H, n_batches, estimator, memory_budget_bytes)
    light = excitation_spectrum(excitation) if excitation is not None else getattr(result.source, "spectrum", None)
    T, filter_desc = emission_filter_function(emission_filter, light)
    gains = _gains(white_balance, light)
    _check_exposure(exposure)
    scene = result.scene
    native = scene.to_native()
    region, hit, px, pw, pk, depth = _surface_pixels(native, camera, W, H, threads)
    radius_given = kernel_radius
    kernel_radius = _kernel_radius(kernel_radius, kernel_angle_deg, camera, W, H, depth, hit, scene.unit_cm)
    P = _packets(result)
    n_regions = len(scene.regions)
    preg = region[hit].astype(np.int64)
    nee_counters, exit_radii = None, None
    if estimator == "nee":
        acc, rec, nee_counters = _nee_estimate(result, camera, W, H, n_batches, filter_desc, white_balance, P)
        acc = _nee_acc(*acc, hit, preg, n_regions)
        n_candidates = int(nee_counters["scored"])
    else:
        rec = _camera_records(result, n_batches, P, T, camera, gains, wanted)
        surface = (px, pw, pk, preg, n_regions, hit)
        kernel = (radius_given, float(kernel_radius), float(kernel_angle_deg))
        acc, n_candidates, exit_radii = _records_estimate(
            estimator, rec, surface, camera, (W, H), kernel, int(threads), scene.unit_cm, cancel, knn_k, exit_k
        )
    if acc is None or _cancelled(cancel):  # also between the steps after the gather (~0.5 s each)
        return None
    Pb, shape, nbins = rec["Pb"], (H, W), rec["nbins"]
    images = {name: _image_from_sums(acc, name, P, Pb, hit, shape, nbins, gains, exposure) for name in VIEW_IMAGES}
    if _cancelled(cancel):
        return None
    region_pixels = np.bincount(preg, minlength=n_regions)[:n_regions]
    region_batches = _region_batches(acc, preg, region_pixels, Pb.size, gains)
    knobs = (W, H, n_batches, P, T, gains, exposure)
    aperture = _aperture(result, estimator, rec, native, camera, depth, hit, knobs, threads)
    return View(
        width=W,
        height=H,
        camera=camera,
        region_names=[r.name for r in scene.regions],
        region_map=np.where(hit, region, -1).reshape(H, W).astype(np.int32),
        depth=depth.reshape(H, W),
        packets=P,
        packets_per_batch=Pb,
        kernel=dict(radius=float(kernel_radius), angle_deg=float(kernel_angle_deg)),
        knn=_knn_info(rec, knn_k, hit, (H, W)) if estimator == "knn" else None,
        exitance=_exitance_info(exit_radii, exit_k, hit, (H, W)) if estimator == "exitance" else None,
        candidates=int(n_candidates),
        estimator=estimator,
        nee=nee_counters,
        emission_filter=filter_desc,
        white_balance=white_balance,
        images=images,
        aperture=aperture,
        region_pixels=region_pixels,
        region_batches=region_batches,
        **_pixel_arrays(acc, hit, (H, W), Pb),
        gains=gains,
        spectrum_bin_edges_nm=colour.spectrum_bins(),
    )


def _aperture(result, estimator, rec, native, camera, depth, hit, knobs, threads):
    """The aperture images (None without a lens, or for a next-event run without records). ``knobs``:
    (W, H, n_batches, P, T, gains, exposure)."""
    W, H, n_batches, P, T, gains, exposure = knobs
    if not (camera.aperture_radius > 0 and (estimator != "nee" or result.escapes is not None)):
        return None
    rec = _records(result, n_batches, P, T) if estimator == "nee" else rec
    focus = camera.focus_distance or _autofocus(depth, hit, W, H)
    return _aperture_images(native, camera, focus, rec, P, hit, (H, W), gains, exposure, result.scene.unit_cm, threads)


def _pixel_arrays(acc, hit, shape, Pb) -> dict:
    """The View's ``pixel_batches`` and ``pixel_colour_sums`` of both images, taken out of ``acc``."""
    return dict(
        pixel_batches={name: _pixel_batches(acc, name, hit, shape, Pb) for name in VIEW_IMAGES},
        pixel_colour_sums={name: _pixel_colour_sums(acc, name, hit, shape, Pb.size) for name in VIEW_IMAGES},
    )


def _nee_estimate(result, camera, W, H, n_batches, filter_desc, white_balance, P):
    """The run's camera tally as render_view reads it: ((sums, spectrum), the records' stand-in {nbins, energy,
    Pb}, the counters); ValueErrors as :func:`_nee_sums` and :func:`_nee_packets_per_batch`."""
    sums, spectrum, counters = _nee_sums(result, camera, W, H, n_batches, filter_desc, white_balance)
    Pb = _nee_packets_per_batch(result, n_batches, P)
    return (sums, spectrum), dict(nbins=spectrum.shape[2], energy={}, Pb=Pb), counters


def _records_estimate(estimator, rec, surface, camera, size, kernel, threads, unit_cm, cancel, knn_k, exit_k):
    """The kernel, k-nearest or exitance estimate's sums from the records ``rec``: (acc, candidates, the exitance
    estimate's ball radii or None). ``surface``: (px, pw, pk, preg, n_regions, hit) of the pixels; ``kernel``:
    (the kernel_radius given or None, the radius used, the angle in degrees)."""
    px, pw, pk, preg, n_regions, hit = surface
    given, r, angle = kernel
    if estimator == "exitance":
        r0 = _exitance_radius(camera, *size, px, pk, hit, r) if given is None else r
        return _exitance_gather(px, pk, preg, n_regions, rec, r0, angle, threads, unit_cm, hit, cancel, exit_k)
    gather = (px, pw, pk, preg, n_regions, rec, r, angle, threads, unit_cm, hit, cancel)
    acc, n = _kernel_gather(*gather, knn_k if estimator == "knn" else None)
    return acc, n, None


def _camera_records(result, n_batches, P, T, camera, gains, images=VIEW_IMAGES) -> dict:
    """The escape records as the kernel and k-nearest gathers read them (:func:`_records`), with the camera's
    position and the camera-like R and G sensitivities: each record's linear-sRGB channels, negative parts
    clipped (docs/render.md, "Visibility"); their energies for ``images`` only (the gathers compute those)."""
    rec = _records(result, n_batches, P, T)
    rec["energy"] = {name: e for name, e in rec["energy"].items() if name in images}
    rec["cam"] = camera.position
    rec["cam_rg"] = np.maximum(colour.xyz_to_linear_srgb(rec["cmf"], gains)[:, :2], 0.0)
    return rec


def _check_call(result, estimator, threads, cancel, images=VIEW_IMAGES) -> tuple:
    """render_view's checks of its result, estimator, threads, cancel token and images (named ValueErrors);
    returns the images' names."""
    if estimator not in ESTIMATORS:
        raise ValueError(f"estimator = {estimator!r} must be one of {', '.join(map(repr, ESTIMATORS))}")
    if not all(hasattr(result, k) for k in ("scene", "escapes", "source", "photons")):
        raise ValueError(
            f"result = {shown(result)}: render_view's first argument must be an ep.Result "
            "(from ep.run(..., record_escapes=True))"
        )
    check_int("threads", threads, 0, MAX_THREADS)  # the rule of ep.run
    if cancel is not None and not hasattr(cancel, "cancelled"):
        raise ValueError(f"cancel = {shown(cancel)} must be None or an endophoton.CancelToken")
    check_spectral(result)
    return _check_images(images)


def _check_images(images) -> tuple:
    """render_view's ``images``: a non-empty subset of :data:`VIEW_IMAGES` (a str is one name), else a ValueError
    naming it."""
    names = (images,) if isinstance(images, str) else images
    try:
        names = tuple(names)
    except TypeError:
        names = None
    if not names or not all(isinstance(n, str) and n in VIEW_IMAGES for n in names):
        raise ValueError(f"images = {shown(images)} must be a non-empty subset of {VIEW_IMAGES}")
    return names


def _check_exposure(exposure) -> None:
    """exposure is "auto" or a finite positive number (not a bool), else a ValueError naming it."""
    number = isinstance(exposure, (int, float)) and not isinstance(exposure, bool)
    if not (exposure == "auto" or (number and math.isfinite(exposure) and exposure > 0)):
        raise ValueError(f"exposure = {exposure!r} must be 'auto' or a positive number")


def _surface_pixels(native, camera, W, H, threads):
    """The surface each pixel sees (one primary ray per pixel centre, docs/render.md): per pixel the region
    (-1: none) and whether it sees tissue (``hit``, (H W,)); per hit pixel its surface point px, the unit
    direction pw toward the camera and 1 / cos of the view angle to the normal pk (cos clamped at 1e-3); and the
    depth along the camera's forward axis per pixel (0 where no tissue), scene units."""
    dirs = camera.primary_rays(W, H)
    origins = np.broadcast_to(camera.position, dirs.shape)
    t, region, _, normal = _core.first_surfaces(native, origins, dirs, None, 0.0, int(threads))
    if np.any(region == -2):
        raise ValueError(
            f"camera.position = {camera.position.tolist()} lies inside a region: put the camera in "
            "the ambient medium"
        )
    hit = region >= 0
    px = camera.position + t[hit, None] * dirs[hit]
    pw = -dirs[hit]
    pk = 1.0 / np.clip(np.einsum("ij,ij->i", pw, normal[hit]), 1e-3, 1.0)
    depth = np.zeros(H * W)
    depth[hit] = t[hit] * (dirs[hit] @ camera.frame(W, H)["forward"])
    return region, hit, px, pw, pk, depth


def _kernel_radius(kernel_radius, kernel_angle_deg, camera, W, H, depth, hit, unit_cm) -> float:
    """The kernel radius in scene units: the one given, or 2 pixel footprints at the median surface depth
    (docs/render.md, "The kernel is the speed/accuracy knob"); checked by check_kernel, with the default's
    error naming the field of view and the width that made it."""
    if kernel_radius is None:
        med = float(np.median(depth[hit])) if hit.any() else 1.0
        default = 2.0 * (2.0 * camera.frame(W, H)["tan_x"] / W) * med
        try:
            check_kernel(default, kernel_angle_deg, unit_cm)
        except ValueError as e:  # name what the user gave: the field of view and the width
            raise ValueError(
                f"camera.fov_deg = {camera.fov_deg!r} with width = {W}: the default kernel_radius (2 pixel "
                f"footprints, {default:.3g} scene units) is unusable ({e}); give kernel_radius"
            ) from None
        kernel_radius = default
    check_kernel(kernel_radius, kernel_angle_deg, unit_cm)
    return kernel_radius


ESTIMATORS = ("auto", "nee", "kernel", "knn", "exitance")


def _exitance_radius(camera, W, H, px, pk, hit, cap) -> np.ndarray:
    """The exitance estimate's smallest ball radius per hit pixel, scene units: the radius of the disc of the
    pixel's own footprint area on the surface, Omega_pixel t^2 / cos theta_p (t the distance from the pinhole),
    so that the ball averages the light over what the pixel sees; at most ``cap`` (the kernel's default radius,
    where grazing views stretch the footprint)."""
    omega = camera.pixel_solid_angles(W, H)[hit]
    t2 = np.sum((px - camera.position) ** 2, axis=1)
    return np.minimum(np.sqrt(omega * t2 * pk / math.pi), cap)


def _exitance_info(radii, k, hit, shape):
    """The exitance estimate's size: {k, radius: {image: (H, W) ball radius r_p in scene units, 0 where no
    surface, inf where the region has too few records}}."""
    out = {}
    for name, r in radii.items():
        full = np.zeros(hit.size)
        full[hit] = r
        out[name] = full.reshape(shape)
    return dict(k=int(k), radius=out)


def _knn_info(rec, k, hit, shape):
    """The k-nearest estimate's size: {k, scale: {image: (H, W) scale s of each pixel's product kernel (radius
    s x kernel_radius, chord s x chord(kernel_angle_deg)), 0 where no surface}}."""
    scale = {}
    for name, s in rec["knn_scale"].items():
        full = np.zeros(hit.size)
        full[hit] = s
        scale[name] = full.reshape(shape)
    return dict(k=int(k), scale=scale)


def _check_memory(result, camera, W, H, n_batches, estimator, memory_budget_bytes):
    """:func:`endophoton.view.budget.check_render_memory` of this render, records counted, before anything
    is allocated."""
    esc = result.escapes
    check_render_memory(
        W,
        H,
        n_batches,
        records=len(esc["weight"]) if isinstance(esc, dict) and "weight" in esc else 0,
        aperture=camera.aperture_radius > 0 and (estimator == "kernel" or esc is not None),
        memory_budget_bytes=memory_budget_bytes,
        exitance=estimator == "exitance",
    )


def check_spectral(result):
    """ValueError naming ``result`` when its run traced no wavelengths (``spectral=None`` without fluorophores or
    spectral media): its records and tallies are at wavelength 0, which has no colour."""
    if getattr(result, "spectral", True) is False:
        raise ValueError(
            "result: the run was not spectral (spectral=None and no fluorophores or spectral media), so its light "
            "has no wavelength and no colour; run ep.run(..., spectral=True) to render it"
        )


def _nee_sums(result, camera, W, H, n_batches, filter_desc, white_balance):
    """The run's camera tally, checked against the render's arguments: (sums (pixels, B, 12), spectrum
    (pixels, 2, bins), counters). ValueError naming the argument that differs from the run's request."""
    img = getattr(result, "camera_image", None)
    desc = getattr(result, "view_request", None)
    if img is None or desc is None:
        raise ValueError(
            "estimator = 'nee': the run has no camera tally; run it with ep.run(..., view=True) "
            "(or view=dict(camera=..., width=..., height=...))"
        )
    want = dict(
        camera=camera.to_dict(),
        width=W,
        height=H,
        n_batches=n_batches,
        emission_filter=filter_desc,
        white_balance=white_balance,
    )
    for k, v in want.items():
        if desc[k] != v:
            raise ValueError(
                f"{k} = {v!r} differs from the run's camera tally ({desc[k]!r}): render with the run's "
                f"view settings or run again with view=dict({k}=...)"
            )
    counters = {
        k: int(img[k])
        for k in ("events", "thinned", "scored", "occluded", "unresolved", "crossing", "looked_back", "covered")
    }
    return img["sums"], img["spectrum"], counters


def _nee_packets_per_batch(result, n_batches, P) -> np.ndarray:
    """The packets of each of the camera tally's batches: a run's contiguous blocks (``batch_index``), or,
    for tallies of several runs added batch by batch (a sweep's next-event view), their own
    ``camera_packets_per_batch``."""
    Pb = getattr(result, "camera_packets_per_batch", None)
    if Pb is None:
        return batch_index(np.zeros(0, dtype=np.int64), n_batches, P)[1]
    Pb = np.asarray(Pb, dtype=np.int64)
    if Pb.shape != (n_batches,) or int(Pb.sum()) != P:
        raise ValueError(
            f"result.camera_packets_per_batch = {Pb.tolist()} must hold n_batches = {n_batches} counts summing to {P}"
        )
    return Pb


def _nee_acc(sums, spectrum, hit, preg, n_regions):
    """The next-event tally's sums (pixels, B, 12) and spectra (pixels, 2, bins) as the sums
    :func:`_image_from_sums` and :func:`_region_batches` take (hit pixels; regions by the pixel's region).
    The estimate is unbiased: its 'half kernel' sums equal the full ones, so every bias reads 0."""
    hp = np.flatnonzero(hit)
    s = sums[hp]  # (n_hit, B, 12)
    B = s.shape[1]
    acc = {}
    for j, name in enumerate(VIEW_IMAGES):
        o = 6 * j
        acc[name + "_pix_batch"] = s[:, :, o].ravel()
        acc[name + "_half_pix_batch"] = acc[name + "_pix_batch"]
        for c in range(3):
            acc[f"{name}_xyz{c}_pix"] = s[:, :, o + 1 + c].sum(axis=1)
        for key, first, n in (("xyz", o + 1, 3), ("cam", o + 4, 2)):
            image = np.zeros((hit.size, n, B))  # View.pixel_colour_sums' layout
            for c in range(n):
                acc[f"{name}_{key}{c}_reg_batch"] = _region_sums(preg, s[:, :, first + c], n_regions).ravel()
                image[hp, c] = s[:, :, first + c]
            acc[f"{name}_{key}_image"] = image.ravel()
        acc[name + "_spec_pix"] = spectrum[hp, j, :].ravel()
    return acc


def _pixel_batches(acc, name, hit, shape, Pb):
    """Per-pixel, per-batch radiance estimates (H, W, B): batch sums / packets in the batch. Takes the sums
    out of ``acc`` (their last use: the render's memory peak holds one copy)."""
    B = Pb.size
    out = np.zeros((hit.size, B))
    out[hit] = acc.pop(name + "_pix_batch", np.zeros(int(hit.sum()) * B)).reshape(-1, B) / Pb
    return out.reshape(shape + (B,))


def _pixel_colour_sums(acc, name, hit, shape, B):
    """Per-pixel, per-batch sums (not divided by the batch's packets) of the image's XYZ (H, W, 3, B) and
    camera R, G (H, W, 2, B): what a contrast over any group of pixels (visibility.pixel_group_batches) needs.
    The sums are accumulated in this layout (image pixel, channel, batch): the View takes them out of ``acc``
    without a copy."""
    out = {}
    for key, tag, k in (("xyz", "xyz", 3), ("camera_rg", "cam", 2)):
        a = acc.pop(f"{name}_{tag}_image", None)
        out[key] = (np.zeros(hit.size * k * B) if a is None else a).reshape(shape + (k, B))
    return out


def _region_sums(preg, values, n_regions):
    """Sums (n_regions, B) of the rows of ``values`` (pixels, B) by the pixels' regions ``preg``: one bincount,
    adding each region's pixels in order (as np.add.at did, bit-identical, in time linear in the pixels)."""
    B = values.shape[1]
    index = (preg[:, None] * B + np.arange(B)).ravel()
    return np.bincount(index, weights=np.ravel(values), minlength=n_regions * B)[: n_regions * B].reshape(n_regions, B)


def _region_batches(acc, preg, region_pixels, B, gains):
    """Per-region, per-batch sums of pixel values divided by the region's pixel count."""
    n_regions = region_pixels.size
    n_hit = preg.size
    inv = np.where(region_pixels > 0, 1.0 / np.maximum(region_pixels, 1), 0.0)
    out = {}
    for name in VIEW_IMAGES:
        pb = acc.get(name + "_pix_batch", np.zeros(n_hit * B)).reshape(n_hit, B)
        out[name + "_radiance"] = _region_sums(preg, pb, n_regions) * inv[:, None]
        half = acc.pop(name + "_half_pix_batch", np.zeros(n_hit * B)).reshape(n_hit, B)  # its last use
        out[name + "_half_radiance"] = _region_sums(preg, half, n_regions) * inv[:, None]
        xyz = (
            np.stack(
                [acc.get(f"{name}_xyz{c}_reg_batch", np.zeros(n_regions * B)).reshape(n_regions, B) for c in range(3)],
                axis=1,
            )
            * inv[:, None, None]
        )
        out[name + "_xyz"] = xyz
        g = np.ones(3) if gains is None else np.asarray(gains)
        out[name + "_rgb"] = np.einsum("ck,rkb->rcb", colour.XYZ_TO_SRGB, xyz * g[None, :, None])
        out[name + "_camera_rg"] = (
            np.stack(
                [acc.get(f"{name}_cam{c}_reg_batch", np.zeros(n_regions * B)).reshape(n_regions, B) for c in range(2)],
                axis=1,
            )
            * inv[:, None, None]
        )
    return out


def _autofocus(depth, hit, W, H):
    """Focus on the surface at the image centre; else on the median surface depth."""
    d = depth.reshape(H, W)
    c = d[H // 2, W // 2]
    if c > 0:
        return float(c)
    return float(np.median(depth[hit])) if hit.any() else 1.0


def _aperture_images(native, camera, focus, rec, P, hit, shape, gains, exposure, unit_cm, threads):
    """The physical camera: records through the lens disk, imaged by a thin lens focused at ``focus``."""
    H, W, threads = shape[0], shape[1], int(threads)
    fr = camera.frame(W, H)
    c, f = camera.position, fr["forward"]
    pos, d = rec["pos"], rec["dir"]
    depth = (pos - c) @ f
    df = d @ f
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(df < 0, depth / -df, -1.0)
    cand = np.flatnonzero((depth > 0) & (df < 0) & (t > 0))
    q = pos[cand] + t[cand, None] * d[cand]
    through = np.sum((q - c) ** 2, axis=1) <= camera.aperture_radius**2
    cand, q = cand[through], q[through]
    # Occlusion: the exit ray must reach the lens without entering tissue again.
    scale = np.max(np.abs(pos[cand]), axis=1) + 1.0 if cand.size else np.zeros(0)
    eps = 1e-6 * scale
    _, reg, _, _ = _core.first_surfaces(
        native, pos[cand] + eps[:, None] * d[cand], d[cand], t[cand] - eps, 0.0, threads
    )
    cand, q = cand[reg < 0], q[reg < 0]
    # Thin lens: the ray meets the plane of focus at F; F's image is its projection through the lens centre.
    s = focus / (d[cand] @ f)
    F = q + s[:, None] * d[cand]
    pix = camera.project(F, W, H)
    ok = pix >= 0
    cand, pix = cand[ok], pix[ok]
    omega = camera.pixel_solid_angles(W, H)
    k = 1.0 / (math.pi * (camera.aperture_radius * unit_cm) ** 2 * (-(d[cand] @ f)) * omega[pix])
    B = rec["Pb"].size
    n = H * W
    acc = {}
    allpix = np.ones(n, dtype=bool)
    for name, e in rec["energy"].items():
        w = e[cand] * k
        _accumulate(acc, "ap_" + name + "_pix_batch", pix * B + rec["batch"][cand], w, n * B)
        for ch in range(3):
            _accumulate(acc, f"ap_{name}_xyz{ch}_pix", pix, w * rec["cmf"][cand, ch], n)
        sb = rec["sbin"][cand]
        okb = sb >= 0
        _accumulate(acc, f"ap_{name}_spec_pix", pix[okb] * rec["nbins"] + sb[okb], w[okb], n * rec["nbins"])
    out = {
        name: _image_from_sums(acc, name, P, rec["Pb"], allpix, shape, rec["nbins"], gains, exposure, prefix="ap_")
        for name in VIEW_IMAGES
    }
    for img in out.values():
        img["focus_distance"] = np.float64(focus)
        img["records"] = np.int64(cand.size)
    return out
