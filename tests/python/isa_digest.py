"""Digests of a set of runs, for comparing engine builds bit for bit (test_isa_bits.py).

    PYTHONPATH=<package parent> /usr/bin/python3 tests/python/isa_digest.py OUT_DIR

imports whichever ``endophoton`` PYTHONPATH names, traces the cases below and prints one JSON
object: case name -> the sha-256 of everything the run returned that does not depend on the
clock or on where its files went (every tally and its standard error, the exit records, the
camera tally, and every voxel of every grid as written to the .vdb file). ``OUT_DIR`` holds the
runs' grid files. Two builds that compute the same IEEE results print the same digests.
"""
from __future__ import annotations

import hashlib
import json
import os
import sys

import numpy as np

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))

import endophoton as ep  # noqa: E402
from bit_digest import feed  # noqa: E402  (beside this file)
from endophoton import vdb  # noqa: E402

# Fields that depend on the clock, the output path, the thread count or the lane kernel chosen for this
# processor (its name), not on the arithmetic.
NOT_ARITHMETIC = {"seconds", "grid_path", "threads", "lanes"}


def _grid_voxels(path: str, name: str, metadata: dict) -> dict:
    """Every active voxel of grid ``name``, its index coordinates and float32 value in index order,
    and the grid's metadata (the engine's exact sum, the dropped deposits, OpenVDB's statistics)."""
    grid = vdb._read_grid(vdb._openvdb(), path, name)
    coords, values = [], []
    for it in grid.citerOnValues():
        if it.count != 1:  # a tile: engine grids hold none
            raise ValueError(f"{path}: grid {name} holds a tile at {it.min}")
        coords.append(it.min)
        values.append(it.value)
    c = np.array(coords, dtype=np.int32).reshape(-1, 3)
    v = np.array(values, dtype=np.float32)
    order = np.lexsort((c[:, 2], c[:, 1], c[:, 0]))
    return {"ijk": c[order], "value": v[order], "metadata": metadata}


def digest(result, grid_path: str | None = None) -> str:
    h = hashlib.sha256()
    raw = {k: v for k, v in result._raw.items() if k not in NOT_ARITHMETIC}
    feed(h, raw)
    if result.camera_image is not None:
        feed(h, {"camera_view": result.camera_image})
    if grid_path is not None:
        summary = vdb.read_grid_summary(grid_path)
        feed(h, {"file": summary["metadata"]})
        for name in result.grid_names:
            feed(h, {name: _grid_voxels(grid_path, name, summary["grids"][name]["metadata"])})
    return h.hexdigest()


def scene_file(*path: str):
    """The scene and source of a SCENE.json file under the repository, as the CLI reads them."""
    from endophoton.sources import source_from_dict

    path = os.path.join(ROOT, *path)
    with open(path) as f:
        data = json.load(f)
    return ep.Scene.from_dict(data, base_dir=os.path.dirname(path)), source_from_dict(data["source"])


def cone_over_clear_layer():
    """A wide disk-and-cone source (two sin/cos pairs a packet) onto a clear layer (mus = 0: its
    absorption is -expm1(-mua t)) over the seed tissue: (scene, source)."""
    clear = ep.layered_slab(
        [(ep.Medium(mua=2.0, mus=0.0, g=0.0, n=1.4), 0.05), (ep.Medium(mua=20, mus=200, g=0.9, n=1.1), 1.0)]
    )
    cone = ep.ConeSource(position=(0, 0, 0.5), direction=(0, 0, -1), half_angle_deg=30.0, radius=0.2)
    return clear, cone


def cases(out_dir: str):
    """(name, run) pairs; each run returns (result, grid path or None)."""
    seed, slab = scene_file("examples", "seed_tissue.json"), scene_file("examples", "mcml_slab.json")
    colon, rig = scene_file("bench", "scenes", "colon.json")  # the paper's scene: rig at 20 degrees, fluorescence

    def plain(scene_source, n, threads, **kw):
        scene, source = scene_source
        return lambda: (ep.run(scene, source, photons=n, seed=7, threads=threads, **kw), None)

    def colon_grids(threads):
        path = os.path.join(out_dir, f"colon_{threads}.vdb")
        grids = ep.GridRequest(voxel_size=5e-4, path=path)
        return lambda: (ep.run(colon, rig, photons=3000, seed=7, threads=threads, grids=grids), path)

    def colon_emission(threads):  # the emission grids alone: the spectral lanes serve the run
        path = os.path.join(out_dir, f"colon_emission_{threads}.vdb")
        grids = ep.GridRequest(voxel_size=5e-4, path=path, absorbed=False, fluorescent_light=False)
        return lambda: (ep.run(colon, rig, photons=3000, seed=7, threads=threads, grids=grids), path)

    return [
        ("cone_over_clear_layer/2", plain(cone_over_clear_layer(), 20000, 2)),
        ("seed_tissue/1", plain(seed, 20000, 1)),
        ("seed_tissue/2", plain(seed, 20000, 2)),
        ("mcml_slab/2", plain(slab, 50000, 2)),
        ("seed_tissue_lanes_records/2", plain(seed, 20000, 2, lanes=True, record_escapes=True)),
        ("colon_lanes_records/2", plain((colon, rig), 3000, 2, lanes=True, record_escapes=True)),  # spectral lanes
        ("colon_lanes_emission/2", colon_emission(2)),
        ("colon_grids_records/1", colon_grids(1)),
        ("colon_grids_records/2", colon_grids(2)),
        ("colon_camera/2", lambda: (ep.run(colon, rig, photons=2000, seed=7, threads=2, view=True), None)),
    ]


def main(out_dir: str) -> None:
    out = {"_package": os.path.dirname(os.path.abspath(ep.__file__))}
    for name, run in cases(out_dir):
        result, path = run()
        out[name] = digest(result, path)
    print(json.dumps(out, sort_keys=True))


if __name__ == "__main__":
    main(sys.argv[1])
