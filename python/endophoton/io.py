"""File output of the package: atomic writes and strict JSON.

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

This module imports nothing from the package (it is a leaf of the import graph).
"""
from __future__ import annotations

import decimal
import json
import math
import numbers
import os
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
]


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
    any: a path that exists must not be a directory (``os.replace`` cannot put a file there, so the
    writer would stop half way, leaving its new files beside old ones). ValueError naming the path."""
    paths = [os.path.join(os.fspath(folder), n) for n in names]
    for p in paths:
        if os.path.isdir(p) and not os.path.islink(p):
            raise ValueError(f"output file {p!r} is a directory: remove or rename it (nothing was written)")
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
