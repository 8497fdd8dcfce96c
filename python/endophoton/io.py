"""File output and input of the package: atomic writes, checked reads and strict JSON.

Every file the package writes (sweep CSV/JSON, plots, reports, EEM CSVs) goes
through :func:`atomic_write_bytes`: the data are written to a temporary file in
the destination folder, flushed to disk and renamed over the target with
``os.replace``, so a reader sees either the old file or the complete new one,
never a torn one.  JSON is strict (RFC 8259): non-finite floats become ``null``
on the way out (:func:`jsonable`).

An undefined result value is ``None``, never NaN (the product's rule: no NaN ever
reaches a result).  :func:`finite_or_none` owns that rule for one number and
:func:`no_nan` for a nested result; the files follow from it (``null`` in JSON,
an empty cell in CSV).  numpy float arrays (histograms, per-batch values and
plotting columns) keep NaN as their mark of an undefined entry (:func:`unjson`
turns a JSON ``null`` back into it).

Every file the package reads (SCENE.json, meshes, EEM tables, sweep.json) is opened by
:func:`open_input`: a regular file (a FIFO, device or folder is refused without blocking) no larger
than the limit of its kind (:data:`MAX_INPUT_BYTES`, docs/numerics.md), read to that limit at most.
JSON is read by :func:`read_json_file`/:func:`parse_json`: a key twice in one object and an
integer literal of more digits than Python converts are errors naming the file and the field.

This module imports nothing from the package (it is a leaf of the import graph).
"""
from __future__ import annotations

import decimal
import json
import math
import numbers
import os
import stat
import sys
import tempfile
from typing import Any, Mapping

import numpy as np

__all__ = [
    "atomic_write_bytes",
    "atomic_write_text",
    "write_json",
    "jsonable",
    "unjson",
    "finite_or_none",
    "no_nan",
    "check_keys",
    "check_int",
    "check_real",
    "check_bool",
    "real_or_none",
    "float_array",
    "shown",
    "check_path",
    "check_output_files",
    "MAX_INPUT_BYTES",
    "open_input",
    "read_input_text",
    "read_json_file",
    "parse_json",
]

#: The largest input file of each kind, in bytes (docs/numerics.md, "Input files"). A file above
#: its limit is refused by name before it is read: the readers build Python objects several times
#: the file's size (a 2 GB file would end in a MemoryError). Owner: :func:`open_input`.
MAX_INPUT_BYTES = {
    "scene file": 64 * 2**20,  # SCENE.json, inline meshes included
    "mesh": 128 * 2**20,  # .obj / .ply (a 1M-triangle binary PLY is ~20 MB, its OBJ ~60 MB)
    "eem file": 8 * 2**20,  # EEM / spectrum tables (data/eem: a few kB)
    "sweep file": 256 * 2**20,  # sweep.json written by SweepResult.to_json
}


def atomic_write_bytes(path: str | os.PathLike, data: bytes, make_dirs: bool = True) -> str:
    """Write ``data`` to ``path`` atomically (temp file in the same folder, fsync, os.replace).

    ``make_dirs`` creates the folder if it is missing.  The file gets mode 0644
    (mkstemp's 0600 would hide ordinary data from other users).  Returns the path.
    """
    path = check_path("path", path)
    folder = os.path.dirname(os.path.abspath(path))
    if make_dirs:
        os.makedirs(folder, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix="." + os.path.basename(path) + ".", suffix=".tmp", dir=folder)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise
    return path


def atomic_write_text(path: str | os.PathLike, text: str, make_dirs: bool = True) -> str:
    """Write UTF-8 ``text`` to ``path`` atomically (see :func:`atomic_write_bytes`)."""
    return atomic_write_bytes(path, text.encode("utf-8"), make_dirs=make_dirs)


def jsonable(x: Any) -> Any:
    """numpy -> Python, tuples -> lists, non-finite floats -> None (strict JSON)."""
    if isinstance(x, Mapping):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return jsonable(x.tolist())
    if isinstance(x, (np.bool_, bool)):
        return bool(x)
    if isinstance(x, (np.integer, int)):
        return int(x)
    if isinstance(x, (np.floating, float)):
        return finite_or_none(x)
    return x


def unjson(x: Any) -> Any:
    """A JSON value as an entry of a numpy float array: ``None`` -> nan (the arrays' mark of an
    undefined entry; result values keep ``None``)."""
    return float("nan") if x is None else x


def finite_or_none(x: Any) -> Any:
    """One result value under the rule "an undefined value is None, never NaN": a float (Python
    or numpy) as a Python float if finite, else ``None`` (NaN and +-inf alike); anything else
    (ints, bools, strings, None) unchanged."""
    if isinstance(x, (np.floating, float)):
        x = float(x)
        return x if math.isfinite(x) else None
    return x


def no_nan(x: Any) -> Any:
    """:func:`finite_or_none` of every number of a nested result: mappings, lists and tuples are
    copied with their values mapped; numpy float arrays are kept as they are (NaN marks an
    undefined entry there); numpy scalars become Python numbers."""
    if isinstance(x, Mapping):
        return {k: no_nan(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return type(x)(no_nan(v) for v in x) if type(x) in (list, tuple) else [no_nan(v) for v in x]
    if isinstance(x, (np.bool_, np.integer)):
        return x.item()
    return finite_or_none(x)


def write_json(path: str | os.PathLike, obj: Any, indent: int | None = 1) -> str:
    """Write ``jsonable(obj)`` as strict JSON (non-finite -> null), atomically."""
    return atomic_write_text(path, json.dumps(jsonable(obj), indent=indent, allow_nan=False) + "\n")


def check_keys(owner: str, d: Any, required: set, extra: set = frozenset()) -> None:
    """Check a JSON object: ``d`` is a dict holding every key of ``required`` and no key
    outside ``required | extra``.  Raises ValueError naming ``owner`` and the key."""
    if not isinstance(d, dict):
        raise ValueError(f"{owner} = {d!r} must be an object")
    allowed = set(required) | set(extra)
    for k in d:
        if k not in allowed:
            raise ValueError(f"{owner}: unknown key {k!r} (allowed: {', '.join(sorted(allowed))})")
    for k in required:
        if k not in d:
            raise ValueError(f"{owner}: missing key {k!r}")


def real_or_none(v) -> float | None:
    """``v`` as a Python float if it is a real number (int, float, a numpy integer or floating
    scalar; not a bool, numpy's included, nor a string), else None. An int beyond the float
    range gives +-inf: a non-finite number, which the caller refuses by name."""
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, numbers.Real):
        return None
    try:
        return float(v)
    except OverflowError:
        return math.inf if v > 0 else -math.inf


def float_array(v):
    """``v`` as a float64 array, or None if it is not numbers (strings, mappings, ragged or
    complex values, ints beyond the float range)."""
    if isinstance(v, (str, bytes, Mapping)):
        return None
    try:
        return None if np.iscomplexobj(v) else np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        return None


def shown(v) -> str:
    """``repr(v)`` for a message, kept short: an int of more than ~30 digits as ``1.00000e+400``
    (lists and tuples of them too)."""
    if isinstance(v, (list, tuple)):
        inner = ", ".join(shown(x) for x in v)
        return f"[{inner}]" if isinstance(v, list) else f"({inner}{',' if len(v) == 1 else ''})"
    if isinstance(v, int) and not isinstance(v, bool) and v.bit_length() > 100:
        return format(decimal.Decimal(v), ".6g")
    return repr(v)


def check_path(name: str, v) -> str:
    """``v`` is a file path (str or os.PathLike, not empty, no NUL byte): the path as a str."""
    p = os.fspath(v) if isinstance(v, (str, os.PathLike)) else None
    if not isinstance(p, str) or not p:
        raise ValueError(f"{name} = {v!r} must be a file path")
    if "\0" in p:
        raise ValueError(f"{name} = {v!r} contains a NUL byte")
    return p


def check_output_files(folder: str | os.PathLike, names) -> list[str]:
    """The paths ``folder/name`` of the files a writer is about to write, checked before it writes
    any: a path that exists must be a regular file, the rule of the grid writer
    (``vdb_writer.cpp`` ``check_vdb_path``). A directory (``os.replace`` cannot put a file there, so
    the writer would stop half way, leaving its new files beside old ones), a FIFO, socket or device
    (the rename would silently replace it) and any symbolic link (replacing it breaks the link;
    writing through it puts the file where the path does not say) are refused: ValueError naming
    the path, before anything is written."""
    paths = [os.path.join(os.fspath(folder), n) for n in names]
    for p in paths:
        try:
            mode = os.lstat(p).st_mode
        except FileNotFoundError:
            continue
        except OSError as e:
            raise ValueError(f"output file {p!r}: cannot check it: {e.strerror or e} (nothing was written)") from None
        if stat.S_ISDIR(mode):
            raise ValueError(f"output file {p!r} is a directory: remove or rename it (nothing was written)")
        if stat.S_ISLNK(mode):
            raise ValueError(f"output file {p!r} is a symbolic link: remove it (nothing was written)")
        if not stat.S_ISREG(mode):
            raise ValueError(
                f"output file {p!r} is not a regular file (a FIFO, socket or device): remove it (nothing was written)"
            )
    return paths


#: The most worker threads a run may ask for (ep.run, render_view; 0 = all cores).
MAX_THREADS = 4096


def check_int(name: str, v, lo: int, hi: int) -> int:
    """``v`` is an integer (not a bool, not a float, not a string) in [lo, hi]."""
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, numbers.Integral):
        raise ValueError(f"{name} = {shown(v)} must be an integer")
    if not lo <= int(v) <= hi:
        raise ValueError(f"{name} = {shown(v)} must be in [{lo}, {hi}]")
    return int(v)


def check_real(name: str, v, lo: float, hi: float, lo_open: bool = False) -> float:
    """``v`` is a finite real number (not a bool, not a string) in [lo, hi] (or (lo, hi])."""
    x = real_or_none(v)
    if x is None or not math.isfinite(x):
        raise ValueError(f"{name} = {shown(v)} must be a finite number")
    if not (lo < x if lo_open else lo <= x) or not x <= hi:
        raise ValueError(f"{name} = {shown(v)} must be in {'(' if lo_open else '['}{lo}, {hi}]")
    return x


def check_bool(name: str, v) -> bool:
    """``v`` is True or False (not 0/1, not a string)."""
    if not isinstance(v, (bool, np.bool_)):
        raise ValueError(f"{name} = {v!r} must be true or false")
    return bool(v)


def open_input(path, kind: str, binary: bool = False, name: str | None = None):
    """``path`` opened for reading as a file of ``kind`` (a key of :data:`MAX_INPUT_BYTES`): a file
    object, text (UTF-8) or ``binary``. Refused by a ValueError naming ``name`` (default: the kind)
    and the path: a path that cannot be opened, anything but a regular file (opened without
    blocking, so a FIFO with no writer is refused at once rather than waited on) and a file larger
    than the kind's limit. The caller reads it with :func:`read_input_text` (or keeps within the
    limit itself)."""
    name = name or kind
    p = check_path(name, path)
    limit = MAX_INPUT_BYTES[kind]
    try:
        fd = os.open(p, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))
    except OSError as e:
        raise ValueError(f"{name} {p!r}: cannot read: {e.strerror or e}") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise ValueError(f"{name} {p!r} is not a regular file (a FIFO, device or folder is not read)")
        if st.st_size > limit:
            raise ValueError(
                f"{name} {p!r} is {st.st_size:,} bytes, more than the {limit:,} bytes a {kind} may have "
                "(endophoton.io.MAX_INPUT_BYTES, docs/numerics.md)"
            )
        if hasattr(os, "set_blocking"):
            os.set_blocking(fd, True)
        return os.fdopen(fd, "rb" if binary else "r", **({} if binary else {"encoding": "utf-8"}))
    except BaseException:
        os.close(fd)
        raise


def read_input_text(path, kind: str, name: str | None = None) -> str:
    """The whole text of ``path`` (:func:`open_input`'s checks), read to the kind's limit at most (a
    file that grows while read is refused, not followed). ValueError naming the file: not UTF-8,
    too large, or a read error."""
    name = name or kind
    limit = MAX_INPUT_BYTES[kind]
    with open_input(path, kind, binary=True, name=name) as fh:
        try:
            data = fh.read(limit + 1)
        except OSError as e:
            raise ValueError(f"{name} {os.fspath(path)!r}: cannot read: {e.strerror or e}") from None
    if len(data) > limit:
        raise ValueError(f"{name} {os.fspath(path)!r} grew beyond {limit:,} bytes while it was read")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise ValueError(
            f"{name} {os.fspath(path)!r}: not UTF-8 text (byte 0x{e.object[e.start]:02x}: {e.reason})"
        ) from None


class _LongInteger:
    """An integer literal of more digits than Python converts (sys.get_int_max_str_digits): kept as
    a mark while the document is parsed, then refused naming its field (:func:`parse_json`)."""

    __slots__ = ("digits",)

    def __init__(self, digits: int):
        self.digits = digits


def _int_limit() -> int:
    get = getattr(sys, "get_int_max_str_digits", None)
    limit = get() if get else 0
    return limit if limit > 0 else 4300


def _unique_keys(pairs):
    d = {}
    for k, v in pairs:
        if k in d:
            raise _DuplicateKey(k)
        d[k] = v
    return d


class _DuplicateKey(ValueError):
    pass


def _field_of(data, match) -> str:
    """The path (``regions[2].medium.mua``) of the first value ``match(value)`` holds for, or ``""``."""
    stack = [(data, "")]
    while stack:
        node, where = stack.pop()
        if match(node):
            return where or "(the document)"
        if isinstance(node, dict):
            stack.extend((v, f"{where}.{k}" if where else str(k)) for k, v in reversed(list(node.items())))
        elif isinstance(node, list):
            stack.extend((v, f"{where}[{i}]") for i, v in reversed(list(enumerate(node))))
    return ""


def parse_json(text: str, where: str):
    """``text`` as strict JSON (RFC 8259 objects with unique keys). ValueError naming ``where`` (the file)
    and the cause: not JSON (line and column), a key twice in one object (the key: the last one would
    silently win), an integer of more digits than Python converts (its field), nesting too deep."""
    limit = _int_limit()
    long_ints = []

    def parse_int(s: str):
        if len(s.lstrip("-")) > limit:
            long_ints.append(_LongInteger(len(s.lstrip("-"))))
            return long_ints[-1]
        return int(s)

    try:
        data = json.loads(text, object_pairs_hook=_unique_keys, parse_int=parse_int)
    except _DuplicateKey as e:
        raise ValueError(
            f"{where}: key {e.args[0]!r} appears twice in one object (keys must be unique: the last would win)"
        ) from None
    except json.JSONDecodeError as e:
        raise ValueError(f"{where}: not JSON: {e}") from None
    except RecursionError:
        raise ValueError(f"{where}: nested too deeply") from None
    if long_ints:
        field = _field_of(data, lambda v: isinstance(v, _LongInteger))
        raise ValueError(
            f"{where}: {field} is an integer of {long_ints[0].digits:,} digits (at most {limit:,} are read)"
        )
    return data


def read_json_file(path, kind: str, name: str | None = None):
    """The JSON document in the file ``path`` of ``kind`` (:func:`read_input_text`, :func:`parse_json`);
    every failure is a ValueError naming the file (``name`` or the kind, and the path)."""
    name = name or kind
    return parse_json(read_input_text(path, kind, name=name), f"{name} {os.fspath(path)!r}")
