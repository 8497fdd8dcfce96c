"""endophoton.vdb helpers read back exactly what pyopenvdb itself wrote."""

import importlib.util
import math
import pathlib
import sys

import numpy as np
import pytest

pyopenvdb = pytest.importorskip("pyopenvdb")

ROOT = pathlib.Path(__file__).resolve().parents[2]


def _load_vdb_module():
    # Loaded by path so this test needs neither the compiled _core module nor
    # a conftest that puts python/ on sys.path.
    spec = importlib.util.spec_from_file_location(
        "endophoton_vdb_under_test", ROOT / "python" / "endophoton" / "vdb.py"
    )
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


vdb = _load_vdb_module()

H = 0.2  # voxel size, scene units
# Known voxels of the "absorbed" grid: index -> value (all exact in float32).
KNOWN = {
    (-3, 0, 2): 0.25,
    (4, -1, 2): 1.5,
    (0, 0, 0): 3.0,
    (2, 5, -4): 0.125,
}


def _write_file(path, rng):
    absorbed = pyopenvdb.FloatGrid()
    absorbed.name = "absorbed"
    absorbed.gridClass = pyopenvdb.GridClass.FOG_VOLUME
    absorbed.transform = pyopenvdb.createLinearTransform(voxelSize=H)
    absorbed["meaning"] = "absorbed weight per voxel"
    acc = absorbed.getAccessor()
    values = dict(KNOWN)
    # Random float32 values inside the known box, away from the known voxels.
    for _ in range(200):
        ijk = tuple(int(v) for v in rng.integers(-3, 5, size=3))
        if ijk not in KNOWN:
            values[ijk] = float(np.float32(rng.uniform(1e-4, 2.0)))
    for ijk, v in values.items():
        acc.setValueOn(ijk, v)

    empty = pyopenvdb.FloatGrid()
    empty.name = "fluorescence"
    empty.gridClass = pyopenvdb.GridClass.FOG_VOLUME
    empty.transform = pyopenvdb.createLinearTransform(voxelSize=H)

    pyopenvdb.write(str(path), grids=[absorbed, empty], metadata={"packets": "1000", "seed": "7", "unit": "cm"})
    return values


@pytest.fixture()
def written(tmp_path):
    path = tmp_path / "tally.vdb"
    values = _write_file(path, np.random.default_rng(11))
    return path, values


def test_summary_matches_written_grids(written):
    path, values = written
    s = vdb.read_grid_summary(path)
    assert s["path"] == str(path)
    assert s["metadata"] == {"packets": "1000", "seed": "7", "unit": "cm"}
    assert list(s["grids"]) == ["absorbed", "fluorescence"]

    g = s["grids"]["absorbed"]
    assert g["name"] == "absorbed"
    assert g["value_type"] == "float"
    assert g["grid_class"] == pyopenvdb.GridClass.FOG_VOLUME
    assert g["voxel_size"] == pytest.approx((H, H, H), rel=1e-15)
    assert g["active_voxel_count"] == len(values)
    # float32 values are exact doubles and fsum is exact: no tolerance needed.
    assert g["sum"] == math.fsum(values.values())
    keys = np.array(list(values))
    lo, hi = tuple(keys.min(axis=0)), tuple(keys.max(axis=0))
    assert g["index_bbox"] == (lo, hi)
    wlo, whi = g["world_bbox"]
    assert wlo == pytest.approx(tuple((v - 0.5) * H for v in lo), abs=1e-12)
    assert whi == pytest.approx(tuple((v + 0.5) * H for v in hi), abs=1e-12)
    assert g["metadata"]["meaning"] == "absorbed weight per voxel"

    e = s["grids"]["fluorescence"]
    assert e["active_voxel_count"] == 0
    assert e["sum"] == 0.0
    assert e["index_bbox"] is None and e["world_bbox"] is None


def test_grid_to_numpy_reproduces_values_and_positions(written):
    path, values = written
    array, origin, voxel_size = vdb.grid_to_numpy(path, "absorbed")
    keys = np.array(list(values))
    lo, hi = keys.min(axis=0), keys.max(axis=0)
    assert array.dtype == np.float32
    assert array.shape == tuple(int(v) for v in hi - lo + 1)
    assert voxel_size == pytest.approx(H, rel=1e-15)
    assert origin == pytest.approx(tuple(lo * H), abs=1e-12)

    expected = np.zeros_like(array)
    for ijk, v in values.items():
        expected[tuple(np.array(ijk) - lo)] = v
    np.testing.assert_array_equal(array, expected)

    # A known deposit sits at its world position in the dense frame.
    ijk = np.array((4, -1, 2))
    a = tuple(ijk - lo)
    assert array[a] == np.float32(KNOWN[(4, -1, 2)])
    world = np.array(origin) + np.array(a) * voxel_size
    assert world == pytest.approx(ijk * H, abs=1e-12)


def test_grid_to_numpy_empty_grid(written):
    path, _ = written
    array, origin, voxel_size = vdb.grid_to_numpy(path, "fluorescence")
    assert array.shape == (0, 0, 0)
    assert origin == (0.0, 0.0, 0.0)
    assert voxel_size == pytest.approx(H, rel=1e-15)


def test_errors_name_path_and_grid(written, tmp_path):
    path, _ = written
    with pytest.raises(KeyError, match="no grid named 'nope'"):
        vdb.grid_to_numpy(path, "nope")
    missing = tmp_path / "missing.vdb"
    with pytest.raises(FileNotFoundError, match="missing.vdb"):
        vdb.read_grid_summary(missing)
    with pytest.raises(ValueError, match=r"max_voxels = 10"):
        vdb.grid_to_numpy(path, "absorbed", max_voxels=10)


def test_rotated_transform_is_refused(tmp_path):
    grid = pyopenvdb.FloatGrid()
    grid.name = "tilted"
    t = pyopenvdb.createLinearTransform(voxelSize=0.5)
    t.rotate(0.3, pyopenvdb.Axis.Z)
    grid.transform = t
    grid.getAccessor().setValueOn((1, 1, 1), 2.0)
    path = tmp_path / "tilted.vdb"
    pyopenvdb.write(str(path), grids=[grid])
    with pytest.raises(ValueError, match="grid 'tilted'"):
        vdb.grid_to_numpy(path, "tilted")


def test_missing_pyopenvdb_gives_clear_import_error(monkeypatch, written):
    path, _ = written
    monkeypatch.setitem(sys.modules, "pyopenvdb", None)  # makes import fail
    with pytest.raises(ImportError, match="python3-openvdb"):
        vdb.read_grid_summary(path)
