# SPDX-License-Identifier: MIT
"""Export Result: a run's photon map (the positions and every record column) and its summary
as CSV, NPZ or JSON, written atomically through the package (endophoton.io)."""

import numpy as np

from . import points
from .keys import PARAMS_KEY, SUMMARY_KEY

EXPORT_FORMATS = ("CSV", "NPZ", "JSON")


def _plain(value):
    return value.to_dict() if hasattr(value, "to_dict") else value


def export_result(collection, path, fmt):
    """Write the run's photon map and summary: CSV (one row per record, the header names the
    columns, vectors as ``_x/_y/_z``; the summary in ``<path>.json`` beside it), NPZ (one array
    per column + ``summary_json``) or JSON (summary, parameters and names only).  The columns are
    ``position`` (metres) and then every record column of the engine (points.record_columns; units
    in docs/addon.md).  Atomic writes through the package (endophoton.io).  Returns the paths."""
    import io
    import json

    from endophoton.io import atomic_write_bytes, atomic_write_text

    if fmt not in EXPORT_FORMATS:
        raise ValueError(f"export format = '{fmt}' must be one of {', '.join(EXPORT_FORMATS)}")
    clouds = points.points_objects(collection)
    parameters = _plain(collection.get(PARAMS_KEY, {}))
    scale_length = float(parameters.get("scale_length_m", 1.0)) if hasattr(parameters, "get") else 1.0
    columns = points.record_columns(clouds[0], scale_length) if clouds else {}
    info = {
        "name": collection.name,
        "summary": _plain(collection.get(SUMMARY_KEY, {})),
        "parameters": parameters,
        "names": points.point_names(clouds[0]) if clouds else {},
    }
    summary_text = json.dumps(info, indent=1, sort_keys=True)
    if fmt == "JSON":
        return [atomic_write_text(path, summary_text)]
    if fmt == "NPZ":
        buffer = io.BytesIO()
        np.savez(buffer, summary_json=np.array(summary_text), **columns)
        return [atomic_write_bytes(path, buffer.getvalue())]
    return [atomic_write_text(path, csv_text(columns)), atomic_write_text(path + ".json", summary_text)]


def csv_text(columns):
    """The columns as CSV text: a header naming them (vectors as ``name_x,name_y,name_z``), one row
    per record; integers written exactly, floats with 9 significant digits."""
    import io

    names, cells = [], []
    for name, values in columns.items():
        values = np.asarray(values)
        if values.ndim == 2:
            names += [f"{name}_{axis}" for axis in "xyz"]
            cells += [values[:, j] for j in range(values.shape[1])]
        else:
            names.append(name)
            cells.append(values)
    count = len(cells[0]) if cells else 0
    table = np.empty((count, len(cells)), dtype=object)
    formats = []
    for j, values in enumerate(cells):
        table[:, j] = (
            values.astype(np.uint64 if values.dtype.kind == "u" else np.int64) if values.dtype.kind in "uib" else values
        )
        formats.append("%d" if values.dtype.kind in "uib" else "%.9g")
    buffer = io.StringIO()
    buffer.write(",".join(names) + "\n")
    if count:
        np.savetxt(buffer, table, delimiter=",", fmt=formats)
    return buffer.getvalue()
