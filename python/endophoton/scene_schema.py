"""The SCENE.json schema (docs/scene.schema.json) and the loader's checks of a document.

The loader checks the cheapest limits first and in time linear in the document:
the region count, then the document's structure and types against the schema,
then inline mesh arrays (which can hold millions of numbers) with the schema's
own rules in plain Python. Errors are ValueErrors that name the region, the field
and the value, e.g. ``region 'tissue': medium.mus = True is not of type 'number'``.
"""
from __future__ import annotations

import functools
import json
import math
from pathlib import Path

#: Most regions a scene holds (the engine keeps region sets as 64-bit masks).
MAX_REGIONS = 64
#: Most fluorophores a region holds (the schema's regions[].fluorophores maxItems; far above any real
#: tissue, which has a handful). Scene.add_mesh reads at most one more, so an endless iterator is refused.
MAX_FLUOROPHORES = 64
#: Largest |coordinate| in scene units (float32 ray tracing; docs/numerics.md).
MAX_COORDINATE = 1e12
#: Largest vertex index (uint32).
MAX_INDEX = 2**32 - 1
#: Deepest JSON nesting the loader reads (SCENE.json needs 6).
MAX_DEPTH = 32


@functools.lru_cache(maxsize=1)
def schema() -> dict:
    """The schema: inside the installed package, else the repository's docs/."""
    here = Path(__file__).resolve().parent
    for p in (here / "data" / "scene.schema.json", here.parents[1] / "docs" / "scene.schema.json"):
        if p.is_file():
            return json.loads(p.read_text(encoding="utf-8"))
    raise RuntimeError("scene.schema.json not found (reinstall endophoton)")


def default(definition: str, field: str):
    """The schema's ``default`` of ``field`` of the object ``definition`` ("scene" for the top level,
    else a name under ``definitions``, e.g. "medium_values", "region"): the loader's value for an omitted
    field, so that the schema and the loader are one rule (test_hardening_38 holds them together)."""
    node = schema() if definition == "scene" else schema()["definitions"][definition]
    return node["properties"][field]["default"]


def required(definition: str = "scene") -> set:
    """The keys the schema requires of the object ``definition`` (see :func:`default`)."""
    node = schema() if definition == "scene" else schema()["definitions"][definition]
    return set(node.get("required", ()))


def check_depth(data, limit: int = MAX_DEPTH) -> None:
    """Refuses documents nested deeper than ``limit`` (iteratively: no recursion error)."""
    stack = [(data, 1)]
    while stack:
        node, depth = stack.pop()
        if isinstance(node, (dict, list)):
            if depth > limit:
                raise ValueError(f"scene: nesting deeper than {limit} levels is not a SCENE.json")
            children = node.values() if isinstance(node, dict) else node
            stack.extend((c, depth + 1) for c in children if isinstance(c, (dict, list)))


def validate_document(data) -> None:
    """Raise ValueError naming the field if ``data`` is not a valid SCENE.json document."""
    if not isinstance(data, dict):
        raise ValueError(f"scene = {_short(data)} must be an object")
    regions = data.get("regions")
    if isinstance(regions, list) and len(regions) > MAX_REGIONS:  # cheapest first
        raise ValueError(f"scene.regions holds {len(regions)} regions; a scene holds at most {MAX_REGIONS}")
    check_depth(data)
    skeleton, meshes = _split_meshes(data)
    import jsonschema

    validator = jsonschema.Draft7Validator(schema())
    error = jsonschema.exceptions.best_match(validator.iter_errors(skeleton))
    if error is not None:
        raise ValueError(_message(error, data))
    for owner, mesh in meshes:
        check_mesh_lists(owner, mesh["vertices"], mesh["triangles"])
    _check_names(regions)


def check_mesh_lists(owner: str, vertices, triangles) -> None:
    """The schema's rules for inline meshes, in linear time: vertices are [x, y, z] numbers
    with |x| <= MAX_COORDINATE, triangles [i, j, k] integers in [0, MAX_INDEX] (checked
    before any narrowing to uint32)."""
    for field, rows in (("mesh.vertices", vertices), ("mesh.triangles", triangles)):
        if not isinstance(rows, list):
            raise ValueError(f"{owner}: {field} = {_short(rows)} must be a list of [a, b, c] rows")
        is_vertex = field == "mesh.vertices"
        for i, row in enumerate(rows):
            if not isinstance(row, list) or len(row) != 3:
                raise ValueError(
                    f"{owner}: {field}[{i}] = {_short(row)} must be a list of 3 "
                    f"{'numbers' if is_vertex else 'integers'}"
                )
            for k, x in enumerate(row):
                if is_vertex:
                    if type(x) not in (int, float) or not -MAX_COORDINATE <= x <= MAX_COORDINATE:
                        raise ValueError(
                            f"{owner}: {field}[{i}][{k}] = {_short(x)} must be a number with "
                            f"|x| <= {MAX_COORDINATE:g} (scene units)"
                        )
                elif type(x) is not int or not 0 <= x <= MAX_INDEX:
                    raise ValueError(
                        f"{owner}: {field}[{i}][{k}] = {_short(x)} must be an integer in " f"[0, {MAX_INDEX}]"
                    )


def _split_meshes(data):
    """A shallow copy of ``data`` whose inline mesh arrays are left out (checked separately)."""
    regions = data.get("regions")
    if not isinstance(regions, list):
        return data, []
    out, meshes = [], []
    for i, r in enumerate(regions):
        m = r.get("mesh") if isinstance(r, dict) else None
        if isinstance(m, dict) and set(m) == {"vertices", "triangles"}:
            meshes.append((_owner(data, ["regions", i]), m))
            r = dict(r, mesh={"vertices": [[0, 0, 0]] * 3, "triangles": [[0, 1, 2]] * 4})
        out.append(r)
    return dict(data, regions=out), meshes


def _check_names(regions) -> None:
    seen = set()
    for r in regions:
        name = r["name"]
        try:
            name.encode("utf-8")
        except UnicodeEncodeError as e:
            raise ValueError(
                f"region {name!r}: name holds a lone surrogate at index {e.start}: not valid text"
            ) from None
        if name in seen:
            raise ValueError(f"region '{name}': name is used by another region")
        seen.add(name)
        for f in r.get("fluorophores", []):
            try:
                f["name"].encode("utf-8")
            except UnicodeEncodeError:
                raise ValueError(f"region '{name}': fluorophores name {f['name']!r} holds a lone surrogate") from None


def _owner(data, path) -> str:
    """ "region 'NAME'" for paths under regions[i] (when the name is usable), else "scene"."""
    if len(path) >= 2 and path[0] == "regions" and isinstance(path[1], int):
        try:
            name = data["regions"][path[1]].get("name")
        except (AttributeError, IndexError, KeyError, TypeError):
            name = None
        if isinstance(name, str) and name:
            return f"region {name!r}" if "'" in name else f"region '{name}'"
        return f"scene.regions[{path[1]}]"
    return "scene"


def _message(error, data) -> str:
    path = list(error.absolute_path)
    owner = _owner(data, path)
    rest = path[2:] if owner != "scene" else path
    field = ".".join(str(p) if not isinstance(p, int) else f"[{p}]" for p in rest).replace(".[", "[")
    if error.validator == "additionalProperties":
        allowed = sorted(error.schema.get("properties", {}))
        extra = sorted(set(error.instance) - set(allowed))
        where = f"{owner}{': ' + field if field else ''}"
        return f"{where}: unknown key {extra[0]!r} (allowed: {', '.join(allowed)})"
    if error.validator == "required" and error.validator_value in (["box"], ["mesh"]):
        return f"{owner}: give exactly one of 'box' or 'mesh'"
    if error.validator == "required":
        where = f"{owner}{': ' + field if field else ''}"
        return f"{where}: missing key: {error.message}"
    if "propertyNames" in error.absolute_schema_path:
        allowed = ", ".join(error.validator_value) if error.validator == "enum" else ""
        return f"{owner}: {field or 'source'}: unknown key {_short(error.instance)} (allowed: {allowed})"
    value = _short(error.instance)
    if error.validator in ("oneOf", "anyOf"):
        rule = error.schema.get("description", "matches none of the allowed forms")
        return f"{owner}: {rule}" if not field else f"{owner}: {field} = {value} is not valid: {rule}"
    detail = error.message if len(error.message) < 200 else error.message[:200] + "..."
    if value in detail:
        detail = detail.replace(value, "", 1).strip()
    return f"{owner}: {field or 'document'} = {value} {detail}"


def _short(v) -> str:
    text = repr(v)
    if isinstance(v, float) and not math.isfinite(v):
        text = str(v)
    return text if len(text) <= 80 else text[:77] + "..."
