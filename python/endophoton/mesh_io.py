"""Triangle meshes: the box builder and PLY / OBJ readers.

Meshes are float32 (N, 3) vertices in scene units and uint32 (M, 3)
counter-clockwise (outward) triangles.
"""
from __future__ import annotations

import io
import math
import os
import struct

import numpy as np

from .io import check_path, float_array, open_input, shown


def box_mesh(lo, hi):
    """Closed, outward-oriented box from corner ``lo`` to corner ``hi`` (scene units).

    Returns (vertices float32 (8, 3), triangles uint32 (12, 3)).
    """
    corners = []
    for field, c in (("box.min", lo), ("box.max", hi)):
        a = float_array(c)
        if (
            a is None
            or a.shape != (3,)
            or any(isinstance(x, (bool, np.bool_)) for x in np.ravel(np.asarray(c, dtype=object)))
        ):
            raise ValueError(f"{field} = {shown(c)} must be 3 numbers")
        corners.append(a)
    lo, hi = corners
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
        raise ValueError(f"box.min = {lo.tolist()} / box.max = {hi.tolist()} must be finite")
    if np.any(hi <= lo):
        raise ValueError(f"box.max = {hi.tolist()} must exceed box.min = {lo.tolist()} on every axis")
    # Vertex k has bit 0 -> x, bit 1 -> y, bit 2 -> z taken from hi.
    v = np.array(
        [[hi[0] if k & 1 else lo[0], hi[1] if k & 2 else lo[1], hi[2] if k & 4 else lo[2]] for k in range(8)],
        dtype=np.float32,
    )
    quads = [  # outward-facing quads, counter-clockwise seen from outside
        (0, 2, 3, 1),  # z = lo
        (4, 5, 7, 6),  # z = hi
        (0, 1, 5, 4),  # y = lo
        (2, 6, 7, 3),  # y = hi
        (0, 4, 6, 2),  # x = lo
        (1, 3, 7, 5),  # x = hi
    ]
    tris = []
    for a, b, c, d in quads:
        tris += [(a, b, c), (a, c, d)]
    return v, np.array(tris, dtype=np.uint32)


def load_mesh(path: str):
    """Read a triangle mesh from a PLY (ASCII or binary little-endian) or OBJ file.

    Polygons are fan-triangulated. Returns (vertices float32 (N,3), triangles uint32 (M,3)).
    """
    path = check_path("mesh", path)
    ext = os.path.splitext(path)[1].lower()
    if not os.path.exists(path):
        raise ValueError(f"mesh = {path!r}: file not found")
    if not os.path.isfile(path):
        raise ValueError(f"mesh = {path!r}: not a regular file")
    if ext not in (".obj", ".ply"):
        raise ValueError(f"mesh = {path!r}: unsupported format {ext!r} (use .ply or .obj)")
    try:
        # a regular file within MAX_INPUT_BYTES["mesh"] (a FIFO is refused without blocking)
        with open_input(path, "mesh", binary=True, name="mesh =") as fh:
            v, t = _load_obj(path, fh) if ext == ".obj" else _load_ply(path, fh)
    except MemoryError:
        raise ValueError(f"mesh = {path!r}: not enough memory to read it: simplify the mesh") from None
    except ValueError as e:
        msg = str(e)
        raise ValueError(msg if msg.startswith("mesh = ") else f"mesh = {path!r}: {msg}") from None
    except OSError as e:
        raise ValueError(f"mesh = {path!r}: cannot read the file: {e.strerror or e}") from None
    except (IndexError, KeyError, struct.error, OverflowError, UnicodeError) as e:
        raise ValueError(
            f"mesh = {path!r}: malformed or truncated {ext[1:].upper()} file " f"({type(e).__name__}: {e})"
        ) from None
    if t.size and int(t.max()) >= len(v):
        raise ValueError(
            f"mesh = {path!r}: triangle index {int(t.max())} is not a vertex index " f"(the file has {len(v)} vertices)"
        )
    return v, t


def _fan(poly):
    return [(poly[0], poly[i], poly[i + 1]) for i in range(1, len(poly) - 1)]


def _load_obj(path, raw):
    verts, tris = [], []
    with io.TextIOWrapper(raw, encoding="utf-8", errors="replace") as fh:
        for lineno, line in enumerate(fh, 1):
            parts = line.split()
            if not parts:
                continue
            if parts[0] == "v":
                if len(parts) < 4:
                    raise ValueError(f"line {lineno}: vertex has fewer than 3 coordinates")
                try:
                    verts.append([float(x) for x in parts[1:4]])
                except ValueError:
                    raise ValueError(f"line {lineno}: vertex {parts[1:4]} is not 3 numbers") from None
            elif parts[0] == "f":
                idx = []
                for tok in parts[1:]:
                    try:
                        i = int(tok.split("/")[0])
                    except ValueError:
                        raise ValueError(f"line {lineno}: face index {tok!r} is not an integer") from None
                    j = i - 1 if i > 0 else len(verts) + i
                    # Checked before narrowing to uint32: an index beyond the vertices read so far
                    # (or 0, which OBJ does not allow) is an error, never wrapped.
                    if i == 0 or not 0 <= j < len(verts):
                        raise ValueError(
                            f"line {lineno}: face index {tok!r} names no vertex " f"({len(verts)} vertices so far)"
                        )
                    idx.append(j)
                if len(idx) < 3:
                    raise ValueError(f"mesh = {path!r}: face on line {lineno} has fewer than 3 vertices")
                tris += _fan(idx)
    return np.asarray(verts, dtype=np.float32).reshape(-1, 3), np.asarray(tris, dtype=np.uint32).reshape(-1, 3)


_PLY_TYPES = {
    "char": "b",
    "int8": "b",
    "uchar": "B",
    "uint8": "B",
    "short": "h",
    "int16": "h",
    "ushort": "H",
    "uint16": "H",
    "int": "i",
    "int32": "i",
    "uint": "I",
    "uint32": "I",
    "float": "f",
    "float32": "f",
    "double": "d",
    "float64": "d",
}


def _load_ply(path, fh):
    """The vertices and triangles of the PLY file ``fh`` (open, binary) at ``path``."""
    if fh.readline().strip() != b"ply":
        raise ValueError(f"mesh = {path!r}: not a PLY file")
    fmt, elements = None, []
    while True:
        line = fh.readline()
        if not line:
            raise ValueError(f"mesh = {path!r}: PLY header has no end_header")
        words = line.decode("ascii", "replace").split()
        if not words:
            continue
        if words[0] == "format":
            if len(words) < 2:
                raise ValueError("PLY 'format' line has no format")
            fmt = words[1]
        elif words[0] == "element":
            if len(words) < 3 or not words[2].isdigit():
                raise ValueError(f"PLY element line {line!r} must be 'element NAME COUNT'")
            try:
                count = int(words[2])
            except ValueError:  # more digits than Python converts
                raise ValueError(f"PLY element {words[1]!r} count {words[2][:20]}... is too large") from None
            elements.append([words[1], count, []])
        elif words[0] == "property":
            if not elements:
                raise ValueError("PLY property before any element")
            types = [w for w in words[1:-1] if w != "list"]
            if not types or any(w not in _PLY_TYPES for w in types):
                raise ValueError(f"PLY property {' '.join(words[1:])!r} has an unknown type")
            if words[1] == "list" and (len(words) != 5 or _PLY_TYPES[words[2]] in "fd"):
                raise ValueError(
                    f"PLY property {' '.join(words[1:])!r} must be 'property list COUNT_TYPE ITEM_TYPE NAME' "
                    "with an integer COUNT_TYPE"
                )
            elements[-1][2].append(words[1:])
        elif words[0] == "end_header":
            break
    if fmt not in ("ascii", "binary_little_endian"):
        raise ValueError(f"mesh = {path!r}: PLY format {fmt!r} is not supported")
    verts, tris = None, []
    text = fh.read()
    pos = 0
    tokens = text.split() if fmt == "ascii" else None
    # Every read takes at least one value (ASCII) or its size in bytes (binary) of what is left, so
    # no count in the file can make the reader loop beyond what the file holds.
    total, unit = (len(tokens), "values") if tokens is not None else (len(text), "bytes")

    def size(kind):
        return 1 if tokens is not None else struct.calcsize("<" + _PLY_TYPES[kind])

    def read(kind):
        nonlocal pos
        if tokens is not None:
            v = tokens[pos]
            pos += 1
            return float(v) if _PLY_TYPES[kind] in "fd" else int(v)
        code = "<" + _PLY_TYPES[kind]
        (v,) = struct.unpack_from(code, text, pos)
        pos += struct.calcsize(code)
        return v

    def read_list(name, item, p):
        n = read(p[1])
        if n < 0 or n * size(p[2]) > total - pos:
            raise ValueError(
                f"mesh = {path!r}: malformed or truncated PLY file: element {name!r} item {item}: list {p[-1]!r} "
                f"length {n} does not fit the {total - pos} {unit} left in the file"
            )
        return [read(p[2]) for _ in range(n)]

    for name, count, props in elements:
        if name == "vertex":
            names = [p[-1] for p in props]
            if not all(k in names for k in ("x", "y", "z")):
                raise ValueError(f"mesh = {path!r}: PLY vertices lack x, y, z")
            ix = [names.index(k) for k in ("x", "y", "z")]
            for i in ix:
                if props[i][0] == "list":
                    raise ValueError(f"mesh = {path!r}: PLY vertex property {names[i]!r} is a list, not a number")
        # The least one item takes: a value per scalar property and the length of each list.
        least = sum(size(p[1] if p[0] == "list" else p[0]) for p in props)
        if least == 0:  # an element without properties holds no data: nothing to read
            continue
        if count > (total - pos) // least:
            raise ValueError(
                f"mesh = {path!r}: malformed or truncated PLY file: element {name!r} count {count} "
                f"does not fit the {total - pos} {unit} left in the file (an item takes at least {least})"
            )
        if name == "vertex":
            rows = []
            for item in range(count):
                row = [read_list(name, item, p) if p[0] == "list" else read(p[0]) for p in props]
                rows.append([row[i] for i in ix])
            verts = np.asarray(rows, dtype=np.float32).reshape(-1, 3)
        else:
            for item in range(count):
                for p in props:
                    if p[0] == "list":
                        idx = read_list(name, item, p)
                        if name == "face" and p[-1] in ("vertex_indices", "vertex_index"):
                            for x in idx:  # a float item type would otherwise be truncated
                                if not (math.isfinite(x) and x == int(x)):
                                    raise ValueError(
                                        f"mesh = {path!r}: PLY face {item}: vertex index {x!r} is not an integer"
                                    )
                            idx = [int(x) for x in idx]
                            if idx and min(idx) < 0:
                                raise ValueError(
                                    f"mesh = {path!r}: PLY face {item}: vertex index {min(idx)} is negative"
                                )
                            tris += _fan(idx)
                    else:
                        read(p[0])
    if verts is None:
        raise ValueError(f"mesh = {path!r}: PLY file has no vertex element")
    return verts, np.asarray(tris, dtype=np.uint32).reshape(-1, 3)
