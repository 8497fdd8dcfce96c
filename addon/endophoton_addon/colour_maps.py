# SPDX-License-Identifier: MIT
"""Colour by any record attribute (no bpy): wavelength as its physical colour,
categories (fluorescent or not, fluorophore, region) and continuous values
(depth, energy, scatterings, exit order), with the filters and the legend
each mapping shows.

The point cloud stores the engine's record columns as named attributes
(points.POINT_ATTRIBUTES); :func:`colour_records` turns them into one linear
RGB colour and one "shown" flag per point, which results.py writes back as the
named attributes ``ep_colour`` and ``ep_show`` with ``foreach_set`` — the way
Molecular Nodes colours atoms.  Nothing here depends on Blender, so the tests
recompute every colour independently.

Wavelength colour (:func:`wavelength_rgb`): the package's own rules
(``endophoton.view.colour``, the endoscope-view images' conversion, one owner):
CIE 1931 colour-matching functions -> XYZ -> linear sRGB, white balanced as
``ep.render_view`` does by default (the flat 400-700 nm white light maps to
D65).  A record's colour is its light per unit energy, with the negative
channels of out-of-gamut lines clipped per record (render_view's camera-like
R/G sensitivities); the points glow with strength proportional to their
energy and add up (results.py), so a pixel's colour is that of the energy
summed over the records it shows.  The legend's swatches show each
wavelength's hue at full brightness (largest channel 1).  ``endophoton.view.colour`` is imported when
first needed: the add-on registers before package_finder has found the package.
"""

from dataclasses import dataclass, field

import numpy as np


# --- wavelength -> colour (endophoton.view.colour owns the conversion) -------------
def _colour():
    """``endophoton.view.colour``, the wavelength conversion's owner (package_finder.require first:
    a missing engine raises EngineMissing naming the fix)."""
    from . import package_finder

    package_finder.require()
    from endophoton.view import colour

    return colour


def wavelength_rgb(nm):
    """Linear sRGB per unit energy of monochromatic light at ``nm`` (N, 3), negatives clipped:
    CMF -> XYZ -> white-balanced linear sRGB by ``endophoton.view.colour``."""
    colour = _colour()
    nm = np.asarray(nm, dtype=np.float64).reshape(-1)
    rgb = colour.xyz_to_linear_srgb(colour.cmf_xyz(nm), colour.white_balance_gains(None))
    return np.maximum(rgb, 0.0)


# The swatches' hue range: CIE 1931's chromaticity is constant from about 690 nm to 780 nm and
# nearly so below 400 nm, while the package's analytic colour-matching fit (endophoton.view.colour)
# turns green in its tails (above ~710 nm, below ~395 nm), where its values are ~1e-3 of the peak.
SWATCH_HUE_NM = (400.0, 680.0)


def wavelength_swatches(nm):
    """Legend colours (N, 3) in [0, 1]: each wavelength's hue at full brightness (largest
    channel 1) — :func:`wavelength_rgb` of the wavelength clamped to ``SWATCH_HUE_NM`` (a 719
    or 799 nm line shows the deep red of 680 nm, never black: the swatch names the hue,
    the points' glow carries the brightness)."""
    clamped = np.clip(np.asarray(nm, dtype=np.float64).reshape(-1), *SWATCH_HUE_NM)
    rgb = wavelength_rgb(clamped)
    return rgb / rgb.max(axis=1, keepdims=True)


def exposed_srgb(linear_rgb):
    """Display-encoded sRGB in [0, 1] of a linear render (..., 3) and the exposure used: the
    endoscope-view images' rule (``endophoton.view.colour.auto_exposure`` over the lit pixels: 99th
    percentile of the largest channel -> 0.5), each channel clipped, sRGB-encoded."""
    colour = _colour()
    linear = np.asarray(linear_rgb, dtype=np.float64)
    peak = linear.max(axis=-1)
    exposure = colour.auto_exposure(peak, peak > 0)
    return colour.srgb_encode(np.clip(linear * exposure, 0.0, 1.0)), exposure


# --- other colourings -------------------------------------------------------
# Viridis at 0, 1/4, 1/2, 3/4, 1 (linear-light values of the published map).
_RAMP = np.array(
    [
        [0.0630, 0.0000, 0.0766],
        [0.0497, 0.0997, 0.2345],
        [0.0168, 0.2961, 0.2302],
        [0.1480, 0.6510, 0.1043],
        [0.9734, 0.8227, 0.0164],
    ]
)
# Distinct categorical colours (linear sRGB).
PALETTE = np.array(
    [
        [0.80, 0.80, 0.80],
        [0.90, 0.05, 0.02],
        [0.02, 0.35, 0.95],
        [0.05, 0.75, 0.10],
        [0.95, 0.55, 0.00],
        [0.60, 0.10, 0.80],
        [0.00, 0.75, 0.75],
        [0.75, 0.65, 0.05],
    ]
)


def ramp_colours(t):
    t = np.clip(np.asarray(t, dtype=np.float64).reshape(-1), 0.0, 1.0)
    x = np.linspace(0.0, 1.0, len(_RAMP))
    return np.stack([np.interp(t, x, _RAMP[:, j]) for j in range(3)], axis=1)


@dataclass(frozen=True)
class ColourMap:
    key: str  # the "Colour By" enum value
    label: str
    column: str  # point attribute it reads
    kind: str  # "wavelength", "category" or "continuous"
    unit: str = ""
    scale: float = 1.0  # attribute value * scale = value in `unit`


COLOUR_MAPS = {
    m.key: m
    for m in (
        ColourMap("WAVELENGTH", "Wavelength", "wavelength", "wavelength", "nm"),
        ColourMap("FLUORESCENT", "Fluorescent", "fluorescent", "category"),
        ColourMap("FLUOROPHORE", "Fluorophore", "fluorophore", "category"),
        ColourMap("REGION", "Region", "region", "category"),
        ColourMap("DEPTH", "Depth", "depth", "continuous", "mm", 10.0),  # engine reports cm
        ColourMap("ENERGY", "Energy", "energy", "continuous", "500 nm photons"),
        ColourMap("SCATTERINGS", "Scatterings", "scatterings", "continuous", "events"),
        ColourMap("EXIT_ORDER", "Exit Order", "exit_order", "continuous", "rank"),
    )
}


@dataclass
class Legend:
    """What a colour bar shows: title with units, range, and (colour, label) entries."""

    title: str
    unit: str
    lo: float = 0.0
    hi: float = 0.0
    entries: list = field(default_factory=list)  # [(linear rgb tuple, label)]
    shown: int = 0
    total: int = 0

    def header(self):
        unit = f" [{self.unit}]" if self.unit else ""
        if not self.shown:  # no range or category to show: the filters hide every record
            return f"{self.title}{unit}: none shown"
        if self.entries and self.lo == self.hi == 0.0:
            return f"{self.title}{unit}"
        return f"{self.title}{unit}: {self.lo:.4g} – {self.hi:.4g}"

    def caption(self):
        """The header with how many records are shown (the panel's legend line)."""
        if not self.shown:
            return f"{self.header()} (0/{self.total:,})"
        return f"{self.header()} · {self.shown:,}/{self.total:,} shown"

    def to_dict(self):
        return dict(
            title=self.title,
            unit=self.unit,
            lo=float(self.lo),
            hi=float(self.hi),
            entries=[[list(map(float, c)), str(t)] for c, t in self.entries],
            shown=int(self.shown),
            total=int(self.total),
        )

    @classmethod
    def from_dict(cls, d):
        return cls(
            d["title"],
            d["unit"],
            d["lo"],
            d["hi"],
            [(tuple(c), t) for c, t in d["entries"]],
            d.get("shown", 0),
            d.get("total", 0),
        )


@dataclass(frozen=True)
class Filters:
    fluorescent_only: bool = False
    fluorophore: int = -2  # -2 = any; else the engine's fluorophore id
    region: int = -2  # -2 = any; else the region index
    # (camera position, cone half-angle in degrees), or None: only records whose exit direction
    # is within the cone around the direction to the camera (columns "position", "direction")
    toward: tuple = None


def toward_mask(position, direction, camera, cone_deg):
    """Records leaving toward ``camera``: exit direction within ``cone_deg`` of the direction from
    the exit point to the camera (the light the camera can record; ep.render_view's kernel cone)."""
    to_camera = np.asarray(camera, dtype=np.float64)[None, :] - np.asarray(position, dtype=np.float64)
    dist = np.linalg.norm(to_camera, axis=1)
    cos = np.einsum("ij,ij->i", np.asarray(direction, dtype=np.float64), to_camera)
    return (dist > 0) & (cos >= np.cos(np.radians(cone_deg)) * dist)


def shown_mask(columns, filters, count):
    show = np.ones(count, dtype=bool)
    if filters.toward is not None and "position" in columns and "direction" in columns:
        show &= toward_mask(columns["position"], columns["direction"], *filters.toward)
    if filters.fluorescent_only and "fluorescent" in columns:
        show &= np.asarray(columns["fluorescent"]).astype(bool)
    if filters.fluorophore != -2 and "fluorophore" in columns:
        show &= np.asarray(columns["fluorophore"]) == filters.fluorophore
    if filters.region != -2 and "region" in columns:
        show &= np.asarray(columns["region"]) == filters.region
    return show


def _category_names(cmap, names):
    if cmap.key == "FLUORESCENT":
        return {0: "excitation light", 1: "fluorescence"}
    listed = {i: n for i, n in enumerate(names.get(cmap.column, ()))}
    if cmap.key == "FLUOROPHORE":
        listed[-1] = "none"
    return listed


def colour_records(key, columns, filters=Filters(), names=None, count=None):
    """Colours, shown flags and legend for the records in ``columns``.

    ``columns``: {attribute name: array}; ``names``: {"fluorophore": [...],
    "region": [...]} for the legend labels.  Returns ``(rgb (N,3) float32,
    show (N,) bool, Legend)``.  Continuous ranges are those of the shown records.
    Raises KeyError naming the attribute when the result lacks the column.
    """
    cmap = COLOUR_MAPS[key]
    names = names or {}
    if cmap.column not in columns:
        raise KeyError(f"colour_by = '{key}': the result has no '{cmap.column}' attribute")
    values = np.asarray(columns[cmap.column]).reshape(-1)
    n = len(values) if count is None else count
    show = shown_mask(columns, filters, n)
    legend = Legend(cmap.label, cmap.unit, shown=int(show.sum()), total=n)
    if cmap.kind == "wavelength":
        rgb = wavelength_rgb(values)
        lo, hi = _range(values[show])
        legend.lo, legend.hi = lo, hi
        ticks = np.linspace(lo, hi, 6) if hi > lo else np.array([lo])
        legend.entries = [(tuple(c), f"{t:.0f} nm") for c, t in zip(wavelength_swatches(ticks), ticks)]
    elif cmap.kind == "category":
        codes = values.astype(np.int64)
        labels = _category_names(cmap, names)
        # Fluorescent: 0 grey, 1 red; ids (from -1 = none): -1 grey, 0 red, 1 blue, ...
        slot = (codes if cmap.key == "FLUORESCENT" else codes + 1) % len(PALETTE)
        rgb = PALETTE[slot]
        present = sorted(set(codes[show].tolist()))
        legend.entries = [
            (tuple(PALETTE[(c if cmap.key == "FLUORESCENT" else c + 1) % len(PALETTE)]), labels.get(c, f"#{c}"))
            for c in present
        ]
    else:
        scaled = values.astype(np.float64) * cmap.scale
        lo, hi = _range(scaled[show])
        rgb = ramp_colours((scaled - lo) / (hi - lo) if hi > lo else np.zeros_like(scaled))
        legend.lo, legend.hi = lo, hi
        ticks = np.linspace(lo, hi, 5) if hi > lo else np.array([lo])
        legend.entries = [(tuple(c), f"{t:.3g}") for c, t in zip(ramp_colours(np.linspace(0, 1, len(ticks))), ticks)]
    if not legend.shown:
        legend.entries = []  # a swatch for a range of no record would mean nothing
    return np.ascontiguousarray(rgb, dtype=np.float32), show, legend


def _range(values):
    values = values[np.isfinite(values)]
    if not len(values):
        return 0.0, 0.0
    return float(values.min()), float(values.max())


#: The first bytes of every PNG file.
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def legend_figure(legend, path, image=None, title=None):
    """Write a PNG with the colour bar (and ``image``, an (H, W, 3) display-encoded
    sRGB render in [0, 1], to its left when given) via matplotlib.  Returns ``path``.

    The PNG is rendered in memory, checked (non-empty, PNG signature) and written
    atomically by the package's ``endophoton.io.atomic_write_bytes`` (a temporary
    file in the same folder, then ``os.replace``; the temporary file is removed on
    failure): a failed write leaves the old file, or none, and raises a
    RuntimeError naming ``path``.  The folder must exist."""
    from . import package_finder

    package_finder.require()
    from endophoton.io import atomic_write_bytes

    data = _legend_png(legend, image, title, path)
    if not data.startswith(PNG_SIGNATURE):
        raise RuntimeError(f"legend: matplotlib made no PNG for '{path}' ({len(data)} bytes); nothing written")
    try:
        return atomic_write_bytes(path, data, make_dirs=False)
    except OSError as exc:
        raise RuntimeError(f"legend: could not write '{path}': {exc.strerror or exc}") from None


def _legend_png(legend, image, title, path):
    """The legend figure of :func:`legend_figure` as PNG bytes (``path`` only names it in errors)."""
    import io

    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot as plt
    from matplotlib.patches import Rectangle

    width = 3.0 + (5.0 if image is not None else 0.0)
    fig = plt.figure(figsize=(width, 4.0), dpi=100)
    if image is not None:
        ax_img = fig.add_axes([0.02, 0.05, 0.6, 0.85])
        ax_img.imshow(np.clip(image[..., :3], 0.0, 1.0), origin="upper")
        ax_img.set_axis_off()
        if title:
            ax_img.set_title(title, fontsize=9)
    ax = fig.add_axes([0.66 if image is not None else 0.05, 0.05, 0.3 if image is not None else 0.9, 0.85])
    ax.set_xlim(0, 1)
    ax.set_ylim(0, max(1, len(legend.entries)))
    ax.set_axis_off()
    ax.set_title(legend.header(), fontsize=8)
    for i, (colour, label) in enumerate(reversed(legend.entries)):
        ax.add_patch(Rectangle((0.0, i + 0.1), 0.25, 0.8, color=_colour().srgb_encode(colour)))
        ax.text(0.32, i + 0.5, label, va="center", fontsize=8)
    buf = io.BytesIO()
    try:
        fig.savefig(buf, format="png")
    except Exception as exc:  # matplotlib's own failure, for the operator to report
        raise RuntimeError(f"legend: matplotlib could not make the PNG for '{path}': {exc}") from exc
    finally:
        plt.close(fig)
    return buf.getvalue()
