"""Scenes: regions bounded by closed triangle meshes, each with a medium,
a priority and fluorophores, inside an ambient medium (index ``ambient_n``,
no scattering, no absorption).

Lengths are in the scene unit (``"m"``, ``"cm"`` or ``"mm"``); ``mua`` and
``mus`` are always in cm^-1. Where regions overlap, the one with the higher
priority is the medium; regions of equal priority may touch but not share volume (refused when
the engine scene is built: endophoton.overlaps).
"""
from __future__ import annotations

import hashlib
import itertools
import math
import os
from dataclasses import dataclass, field
from collections.abc import Iterable
from typing import Mapping, Sequence

import numpy as np

from . import media
from .medium import Medium
from .mesh_io import box_mesh, load_mesh
from .overlaps import check_overlaps
from .spectra import EEM, Fluorophore, Spectrum
from .io import check_keys as _check_keys, check_real, read_json_file, real_or_none, shown
from . import scene_schema
from .scene_schema import MAX_FLUOROPHORES, MAX_REGIONS, validate_document
from .units import unit_cm

#: Largest refractive index (ambient or medium): beyond, Fresnel terms overflow to NaN.
MAX_REFRACTIVE_INDEX = 100.0


@dataclass
class Region:
    name: str
    vertices: np.ndarray  # float32 (N, 3), scene units
    triangles: np.ndarray  # uint32 (M, 3), outward CCW
    medium: Medium
    priority: int = 0
    fluorophores: tuple = field(default_factory=tuple)


def _fluorophores_of(owner: str, fluorophores) -> tuple:
    """A region's ``fluorophores`` (an iterable of endophoton.Fluorophore; None for none) as a tuple.
    Reads at most MAX_FLUOROPHORES + 1 entries, checking each as it comes, so an endless iterator is
    refused by its first wrong entry or by its length, never read forever."""
    if fluorophores is None:  # documented: None means no fluorophores, like ()
        return ()
    if isinstance(fluorophores, (str, bytes, Fluorophore)) or not isinstance(fluorophores, Iterable):
        raise ValueError(
            f"{owner}: fluorophores = {shown(fluorophores)} must be a list of endophoton.Fluorophore "
            "(or None for none)"
        )
    fl = []
    for f in itertools.islice(fluorophores, MAX_FLUOROPHORES + 1):
        if not isinstance(f, Fluorophore):
            raise ValueError(f"{owner}: fluorophores entry {shown(f)} must be an endophoton.Fluorophore")
        fl.append(f)
    if len(fl) > MAX_FLUOROPHORES:
        raise ValueError(
            f"{owner}: fluorophores has more than {MAX_FLUOROPHORES} entries (a region holds at most that)"
        )
    return tuple(fl)


def _as_mesh_arrays(owner, vertices, triangles):
    v = np.asarray(vertices)
    t = np.asarray(triangles)
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"{owner}: mesh.vertices must have shape (N, 3), got {v.shape}")
    if t.ndim != 2 or t.shape[1] != 3:
        raise ValueError(f"{owner}: mesh.triangles must have shape (M, 3), got {t.shape}")
    if not np.issubdtype(t.dtype, np.integer):
        raise ValueError(f"{owner}: mesh.triangles must hold integers, got dtype {t.dtype}")
    if t.size and t.min() < 0:
        raise ValueError(f"{owner}: mesh.triangles contains the negative index {int(t.min())}")
    # Checked before narrowing to uint32, so an index >= 2^32 cannot wrap to a valid one.
    if t.size and int(t.max()) >= len(v):
        i, k = map(int, np.argwhere(t == t.max())[0])
        raise ValueError(
            f"{owner}: mesh.triangles[{i}][{k}] = {int(t[i, k])} is not a vertex index "
            f"(the mesh has {len(v)} vertices)"
        )
    if not np.issubdtype(v.dtype, np.number) or v.dtype == np.bool_ or np.issubdtype(v.dtype, np.complexfloating):
        raise ValueError(f"{owner}: mesh.vertices must hold real numbers, got dtype {v.dtype}")
    bad = ~np.isfinite(v)
    if bad.any():
        i, k = map(int, np.argwhere(bad)[0])
        raise ValueError(f"{owner}: mesh.vertices[{i}][{k}] = {v[i, k]} is not finite")
    with np.errstate(over="ignore"):
        v32 = np.ascontiguousarray(v, dtype=np.float32)
    bad = ~np.isfinite(v32)
    if bad.any():
        i, k = map(int, np.argwhere(bad)[0])
        raise ValueError(f"{owner}: mesh.vertices[{i}][{k}] = {v[i, k]} exceeds the float32 range")
    return v32, np.ascontiguousarray(t, dtype=np.uint32)


def _check_cache_store_mb(value) -> float | None:
    if value is None:
        return None
    x = real_or_none(value)
    if x is None or not 0 <= x < 2**40:
        raise ValueError(f"scene.cache_store_mb = {shown(value)} must be None or a finite number of MiB in [0, 2**40)")
    return x


# The engine scene built last, by content (Scene.native_key): a new Scene with the same content --
# the add-on exports one per run -- takes it instead of building it again. One is kept, and the
# next build replaces it; forget_native_scenes() frees it.
_last_built: tuple | None = None


def forget_native_scenes(*scenes: "Scene") -> None:
    """Free the engine scene kept for the next Scene with the same content, and those kept on
    ``scenes`` (see Scene.to_native); the next run builds its engine scene anew."""
    global _last_built
    for i, sc in enumerate(scenes):
        if not isinstance(sc, Scene):
            raise TypeError(f"forget_native_scenes: scenes[{i}] = {sc!r} must be an endophoton.Scene")
    _last_built = None
    for sc in scenes:
        sc.__dict__.pop("_native", None)


class Scene:
    """A set of regions in an ambient medium.

    Parameters
    ----------
    unit : length unit of every coordinate: "m", "cm" or "mm"
    ambient_n : refractive index of the ambient medium (>= 1)
    cache_store_mb : memory budget in MiB of the engine's per-cube triangle caches (a speed-up
        filled as light reaches new places; past the budget the rest of the scene takes the
        full ray query, with the same results); None: the engine's default,
        ``_core.DEFAULT_CACHE_STORE_BYTES`` (512 MiB). Not part of the scene's content or file;
        a run applies the value the scene holds then, in Dask workers too.
    """

    def __init__(self, unit: str = "cm", ambient_n: float = 1.0, cache_store_mb: float | None = None):
        self.cache_store_mb = _check_cache_store_mb(cache_store_mb)
        self.unit = unit
        self.unit_cm = unit_cm(unit)
        n = real_or_none(ambient_n)
        if n is None or not 1 <= n <= MAX_REFRACTIVE_INDEX:  # nan and +-inf fail the range
            raise ValueError(
                f"scene.ambient_n = {shown(ambient_n)} must be a finite number in [1, {MAX_REFRACTIVE_INDEX}]"
            )
        self.ambient_n = n
        self.regions: list[Region] = []
        self._names: set[str] = set()

    # ---- building ---------------------------------------------------------
    def add_mesh(
        self,
        name: str,
        vertices,
        triangles,
        medium: Medium,
        priority: int = 0,
        fluorophores: Sequence[Fluorophore] = (),
    ) -> Region:
        """Add a region bounded by a closed triangle mesh (vertices in scene units).

        ``fluorophores``: a list of endophoton.Fluorophore, at most MAX_FLUOROPHORES (64); None or () for
        none (a string is an error)."""
        if len(self.regions) >= MAX_REGIONS:  # cheapest check first
            raise ValueError(f"region {name!r}: a scene holds at most {MAX_REGIONS} regions")
        if not isinstance(name, str) or not name:
            raise ValueError(f"region.name = {name!r} must be a non-empty string")
        try:
            name.encode("utf-8")
        except UnicodeEncodeError:
            raise ValueError(f"region.name = {name!r} holds a lone surrogate: not valid text") from None
        owner = f"region '{name}'"
        if name in self._names:
            raise ValueError(f"{owner}: name is used by another region")
        if not isinstance(medium, Medium):
            raise ValueError(f"{owner}: medium = {medium!r} must be an endophoton.Medium")
        medium.validate(owner + ": ")
        if isinstance(priority, bool) or not isinstance(priority, (int, np.integer)):
            raise ValueError(f"{owner}: priority = {priority!r} must be an integer")
        fl = _fluorophores_of(owner, fluorophores)
        v, t = _as_mesh_arrays(owner, vertices, triangles)
        if not -(2**31) <= int(priority) < 2**31:
            raise ValueError(f"{owner}: priority = {priority!r} must be a 32-bit integer")
        region = Region(name, v, t, medium, int(priority), fl)
        self.regions.append(region)
        self._names.add(name)
        return region

    def add_box(
        self, name: str, min, max, medium: Medium, priority: int = 0, fluorophores: Sequence[Fluorophore] = ()
    ) -> Region:
        """Add an axis-aligned box region from corner ``min`` to ``max`` (scene units)."""
        try:
            v, t = box_mesh(min, max)
        except ValueError as e:
            raise ValueError(f"region '{name}': {e}") from None
        return self.add_mesh(name, v, t, medium, priority, fluorophores)

    @property
    def has_fluorophores(self) -> bool:
        return any(r.fluorophores for r in self.regions)

    def region(self, name: str) -> Region:
        for r in self.regions:
            if r.name == name:
                return r
        raise KeyError(name)

    # ---- native -----------------------------------------------------------
    def native_key(self) -> bytes:
        """A digest of everything :meth:`to_native` reads: units, ambient index, and per region
        its name, priority, medium, mesh arrays and fluorophores (with their EEMs). Equal keys
        give the same engine scene; any change of content, in place or by replacement, a new key."""
        h = hashlib.blake2b(digest_size=20)

        def put_array(a):
            a = np.ascontiguousarray(a)
            h.update(repr((a.dtype.str, a.shape)).encode())
            h.update(a.data)

        h.update(repr((self.unit_cm, self.ambient_n, len(self.regions))).encode())
        for r in self.regions:
            h.update(repr((r.name, int(r.priority), r.medium.native_args(), len(r.fluorophores))).encode())
            put_array(r.vertices)
            put_array(r.triangles)
            for f in r.fluorophores:
                h.update(repr((f.name, float(f.d), float(f.c))).encode())
                for a in (f.eem.excitation_nm, f.eem.emission_nm, f.eem.values):
                    put_array(np.asarray(a, dtype=np.float64))
        return h.digest()

    def to_native(self):
        """The engine's scene (validates meshes: ValueError naming the region).

        Built once and kept while the scene's content (:meth:`native_key`) stays the same, so a
        sweep of runs over one scene pays the mesh checks, the BVH build and the lazily built
        per-cube triangle caches once, not per run. The last one built is also kept for the next
        Scene with the same content (:func:`forget_native_scenes` frees it). Results do not
        depend on it: a run gives the same bits on a fresh engine scene and on a kept one (the
        caches are exact)."""
        global _last_built
        try:
            key = self.native_key()
        except (TypeError, ValueError):  # content the build rejects by name (e.g. an object array)
            key = None
        cap_mb = _check_cache_store_mb(getattr(self, "cache_store_mb", None))
        kept = getattr(self, "_native", None)
        if kept is not None and kept[0] == key:
            native = kept[1]
        else:
            self._native = None  # release the old engine scene before building its successor
            last = _last_built
            if key is not None and last is not None and last[0] == key:
                native = last[1]
            else:
                _last_built = None
                native = self._build_native()
            if key is not None:
                self._native = _last_built = (key, native)
        from . import _core

        native.cache_store_cap_bytes = _core.DEFAULT_CACHE_STORE_BYTES if cap_mb is None else int(cap_mb * 2**20)
        return native

    def __getstate__(self):
        # The kept engine scene is not picklable (and a worker builds its own).
        state = dict(self.__dict__)
        state.pop("_native", None)
        return state

    def _build_native(self):
        from . import _core

        if not self.regions:
            raise ValueError("scene.regions is empty: add at least one region")
        check_overlaps(self.regions)  # equal priorities that share volume: refused (endophoton.overlaps)
        s = _core.Scene(self.unit_cm, self.ambient_n)
        ids: dict[str, int] = {}
        eems: dict[str, EEM] = {}
        for r in self.regions:
            idx = s.add_region(r.name, r.vertices, r.triangles, priority=r.priority, **r.medium.native_args())
            refs = []
            for f in r.fluorophores:
                if f.name in eems and eems[f.name] is not f.eem and not _same_eem(eems[f.name], f.eem):
                    raise ValueError(
                        f"region '{r.name}': fluorophore '{f.name}' has a different EEM than in "
                        "another region; give distinct names"
                    )
                if f.name not in ids:
                    e = f.eem
                    ids[f.name] = s.add_fluorophore(
                        f.name,
                        list(map(float, e.excitation_nm)),
                        list(map(float, e.emission_nm)),
                        list(map(float, np.asarray(e.values).ravel())),
                    )
                    eems[f.name] = f.eem
                refs.append((ids[f.name], float(f.d), float(f.c)))
            if refs:
                s.set_region_fluorophores(idx, refs)
        s.commit()
        return s

    def fluorophore_names(self) -> list[str]:
        """Names of the scene's fluorophores in engine-id order (record column ``fluorophore``)."""
        names: list[str] = []
        for r in self.regions:
            for f in r.fluorophores:
                if f.name not in names:
                    names.append(f.name)
        return names

    # ---- dict / JSON ------------------------------------------------------
    def to_dict(self) -> dict:
        return {
            "unit": self.unit,
            "ambient_n": self.ambient_n,
            "regions": [
                {
                    "name": r.name,
                    "priority": r.priority,
                    "medium": r.medium.to_dict(),
                    "mesh": {"vertices": r.vertices.tolist(), "triangles": r.triangles.tolist()},
                    "fluorophores": [{"name": f.name, "d": f.d, "c": f.c} for f in r.fluorophores],
                }
                for r in self.regions
            ],
        }

    @classmethod
    def from_dict(cls, data: dict, base_dir: str = ".") -> "Scene":
        """Build a scene from the SCENE.json structure (docs/scene.schema.json, enforced here:
        ValueError naming the region, field and value). Unknown keys are errors."""
        validate_document(data)
        _check_keys(
            "scene",
            data,
            scene_schema.required(),
            extra={"unit", "ambient_n", "source", "run", "name", "description", "camera"},
        )
        # an omitted unit or ambient_n takes the schema's default (one rule: scene_schema.default)
        scene = cls(
            unit=data.get("unit", scene_schema.default("scene", "unit")),
            ambient_n=data.get("ambient_n", scene_schema.default("scene", "ambient_n")),
        )
        regions = data.get("regions")
        if not isinstance(regions, list) or not regions:
            raise ValueError(f"scene.regions = {regions!r} must be a non-empty list")
        for i, rd in enumerate(regions):
            if not isinstance(rd, dict):
                raise ValueError(f"scene.regions[{i}] = {rd!r} must be an object")
            name = rd.get("name", f"region{i}")
            owner = f"region '{name}'"
            _check_keys(owner, rd, {"name", "medium"}, extra={"priority", "box", "mesh", "fluorophores"})
            medium = _medium_from_dict(owner, rd["medium"])
            fl = []
            for j, fd in enumerate(rd.get("fluorophores", [])):
                _check_keys(f"{owner}: fluorophores[{j}]", fd, {"name", "d", "c"}, extra={"eem"})
                eem = None
                if "eem" in fd:
                    path = fd["eem"] if os.path.isabs(fd["eem"]) else os.path.join(base_dir, fd["eem"])
                    if not os.path.isfile(path):
                        raise ValueError(f"{owner}: fluorophores[{j}].eem = {fd['eem']!r} is not a file")
                    try:
                        eem = EEM.from_csv(path, name=fd["name"])
                    except (OSError, UnicodeError) as e:
                        raise ValueError(f"{owner}: fluorophores[{j}].eem = {fd['eem']!r}: {e}") from None
                try:
                    fl.append(Fluorophore(fd["name"], fd["d"], fd["c"], eem=eem))
                except ValueError as e:
                    raise ValueError(f"{owner}: {e}") from None
            priority = rd.get("priority", scene_schema.default("region", "priority"))
            has_box, has_mesh = "box" in rd, "mesh" in rd
            if has_box == has_mesh:
                raise ValueError(f"{owner}: give exactly one of 'box' or 'mesh'")
            if has_box:
                _check_keys(f"{owner}: box", rd["box"], {"min", "max"})
                scene.add_box(name, rd["box"]["min"], rd["box"]["max"], medium, priority, fl)
            else:
                m = rd["mesh"]
                if isinstance(m, str):
                    path = m if os.path.isabs(m) else os.path.join(base_dir, m)
                    try:
                        v, t = load_mesh(path)
                    except ValueError as e:
                        raise ValueError(f"{owner}: {e}") from None
                else:
                    _check_keys(f"{owner}: mesh", m, {"vertices", "triangles"})
                    v, t = m["vertices"], m["triangles"]
                scene.add_mesh(name, v, t, medium, priority, fl)
        return scene

    @classmethod
    def from_json(cls, path: str) -> "Scene":
        data = read_json_file(path, "scene file")  # a regular file within its limit, unique keys
        return cls.from_dict(data, base_dir=os.path.dirname(os.path.abspath(path)))


def _same_eem(a: EEM, b: EEM) -> bool:
    return (
        np.array_equal(a.excitation_nm, b.excitation_nm)
        and np.array_equal(a.emission_nm, b.emission_nm)
        and np.array_equal(a.values, b.values)
    )


def _coefficient_from_json(owner, field, v):
    if isinstance(v, dict):
        _check_keys(f"{owner}: medium.{field}", v, {"wavelength_nm", "values"})
        return Spectrum(v["wavelength_nm"], v["values"], name=f"{owner}: medium.{field}")
    return v


def _medium_from_dict(owner: str, md) -> Medium:
    """A region's medium: ``{"preset": NAME}`` (endophoton.media) or mua, mus[, g, n]."""
    if isinstance(md, dict) and "preset" in md:
        _check_keys(f"{owner}: medium", md, {"preset"})
        try:
            return media.preset(md["preset"])
        except ValueError as e:
            raise ValueError(f"{owner}: {e}") from None
    _check_keys(f"{owner}: medium", md, {"mua", "mus"}, extra={"g", "n"})
    try:
        return Medium(
            mua=_coefficient_from_json(owner, "mua", md["mua"]),
            mus=_coefficient_from_json(owner, "mus", md["mus"]),
            g=md.get("g", scene_schema.default("medium_values", "g")),
            n=md.get("n", scene_schema.default("medium_values", "n")),
        )
    except ValueError as e:
        msg = str(e)
        raise ValueError(msg if msg.startswith(owner) else f"{owner}: {msg}") from None


def layered_slab(
    layers,
    unit: str = "cm",
    width: float = 1000.0,
    ambient_n: float = 1.0,
    top: float = 0.0,
    names: Sequence[str] | None = None,
) -> Scene:
    """MCML-style stack of layers: ``layers`` = [(Medium, thickness), ...], the first on top.

    The top surface is at z = ``top`` and layers go down (-z); each is a box of
    side ``width`` (scene units) in x and y, touching its neighbours. Thicknesses
    are in scene units. A source above the stack points along -z.
    """
    scene = Scene(unit=unit, ambient_n=ambient_n)
    z = check_real("top", top, -math.inf, math.inf)
    half = 0.5 * check_real("width", width, 0.0, math.inf, lo_open=True)
    layers = _slab_layers(layers)
    names = _slab_names(names, len(layers))
    for i, item in enumerate(layers):
        try:
            medium, thickness = item
        except (TypeError, ValueError):
            raise ValueError(f"layers[{i}] = {item!r} must be a (Medium, thickness) pair") from None
        name = names[i] if names else f"layer{i + 1}"
        t = real_or_none(thickness)
        if t is None or not math.isfinite(t) or t <= 0:
            raise ValueError(f"region '{name}': thickness = {shown(thickness)} must be a positive number")
        scene.add_box(name, (-half, -half, z - t), (half, half, z), medium, priority=0)
        z -= t
    return scene


def _slab_layers(layers) -> list:
    """``layers`` as a list (its items are checked one by one)."""
    if not isinstance(layers, (str, bytes, Mapping)):
        try:
            return list(layers)
        except TypeError:
            pass
    raise ValueError(f"layers = {layers!r} must be a list of (Medium, thickness) pairs")


def _slab_names(names, n: int):
    """``names`` (None or empty: layer1, layer2, ...) as a list of ``n`` names."""
    if names is None or (isinstance(names, (list, tuple)) and not names):
        return None
    if isinstance(names, str) or not isinstance(names, Sequence) or len(names) != n:
        raise ValueError(f"names = {names!r} must be a list of {n} names, one per layer")
    return list(names)
