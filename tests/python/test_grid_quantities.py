"""A run tallies and writes only the grids it is asked for (GridRequest's absorbed, fluorescent_light and
emission switches): the file holds exactly those grids, each the same voxels as in a run that writes them
all (in the double walk: with the float32 lanes, the default, a run asking for the emission grids alone
takes the lanes, another sample; test_emission_grids.py), and the tallies do not change. Bad requests
are refused by name, before any tracing."""
import json
import math
import pathlib

import numpy as np
import pytest

import endophoton as ep
from endophoton import _core, scene_schema, vdb
from test_emission_grids import lesion_scene  # a collagen wall with a photofrin lesion, cm

pytest.importorskip("pyopenvdb")

EXAMPLES = pathlib.Path(__file__).resolve().parents[2] / "examples"
H = 0.05  # voxel size, cm
PER_FLUOROPHORE = ["fluorescent_light_collagen", "fluorescent_light_photofrin"]
EMISSION = ["emission_collagen", "emission_photofrin"]
ALL = ["absorbed", "fluorescent_light"] + PER_FLUOROPHORE + EMISSION


def _run(tmp_path, name, scene=None, threads=2, lanes=False, **asked):
    # The double walk by default: every grid request takes it, so their voxels compare bit for bit.
    path = tmp_path / f"{name}.vdb"
    grids = ep.GridRequest(voxel_size=H, path=str(path), **asked)
    src = ep.PencilSource((0.3, 0.0, 1.0), (0, 0, -1))
    return ep.run(scene or lesion_scene(), src, photons=800, seed=4, threads=threads, grids=grids,
                  record_escapes=False, lanes=lanes)  # fmt: skip


def _tallies(res):
    """The result without what depends on the grids asked for or on the clock."""
    skip = {"seconds", "threads", "grid_path", "grid_names", "grid_absorbed_sum"}
    return {k: v for k, v in res.to_dict().items() if k not in skip}


@pytest.mark.parametrize(
    "asked, names",
    [
        (dict(fluorescent_light=False, emission=False), ["absorbed"]),
        (dict(absorbed=False, emission=False, per_fluorophore=True), ["fluorescent_light"] + PER_FLUOROPHORE),
        (dict(absorbed=False, fluorescent_light=False), EMISSION),
        (dict(fluorescent_light=False), ["absorbed"] + EMISSION),
    ],
    ids=["absorbed", "fluorescent_light", "emission", "absorbed+emission"],
)
def test_a_run_writes_only_the_grids_asked_for_with_the_same_voxels(tmp_path, asked, names):
    full = _run(tmp_path, "all", per_fluorophore=True)
    assert full.grid_names == ALL
    part = _run(tmp_path, "part", threads=1, **asked)
    assert part.grid_names == names
    assert sorted(vdb.read_grid_summary(part.grid_path)["grids"]) == sorted(names)
    assert _tallies(part) == _tallies(full)
    for name in names:
        a, oa, ha = vdb.grid_to_numpy(part.grid_path, name)
        b, ob, hb = vdb.grid_to_numpy(full.grid_path, name)
        assert oa == ob and ha == hb and np.array_equal(a, b), name
    summary = vdb.read_grid_summary(part.grid_path)["grids"]
    if "absorbed" in names:
        # The absorbed grid's exact sum is the absorbed energy tally (another sum order: rel 1e-12).
        assert part.grid_absorbed_sum == full.grid_absorbed_sum
        assert part.grid_absorbed_sum == pytest.approx(part.absorbed_energy, rel=1e-12)
    else:
        assert part.grid_absorbed_sum == 0.0
    for fl in ("collagen", "photofrin"):
        if f"emission_{fl}" in names:
            meta = summary[f"emission_{fl}"]["metadata"]
            assert meta["accumulator_sum"] == pytest.approx(part.emitted_by_fluorophore[fl], rel=1e-12), fl
            assert part.emitted_by_fluorophore[fl] > 0


def test_a_store_run_keeps_only_the_asked_for_grids_of_the_units_it_merges(tmp_path):
    """A "store N" run keeps grids per unit and discards those past its stop point (engine.cpp,
    grids_per_unit): asked for alone, its emission grids are those of a store run that writes all."""
    src = ep.PencilSource((0.3, 0.0, 1.0), (0, 0, -1))
    runs = []
    for label, asked in (("all", {}), ("emission", dict(absorbed=False, fluorescent_light=False))):
        grids = ep.GridRequest(voxel_size=H, path=str(tmp_path / f"{label}.vdb"), **asked)
        runs.append(
            ep.run(lesion_scene(), src, store=300, fluorescent_only=True, seed=2, threads=2, grids=grids, lanes=False)
        )
    full, part = runs
    assert part.stop_reason == full.stop_reason == "store" and part.packets_traced == full.packets_traced
    assert part.grid_names == EMISSION
    for name in EMISSION:
        a, oa, ha = vdb.grid_to_numpy(part.grid_path, name)
        b, ob, hb = vdb.grid_to_numpy(full.grid_path, name)
        assert oa == ob and ha == hb and np.array_equal(a, b) and a.size > 0, name


def test_emission_alone_needs_a_fluorophore_and_is_refused_before_the_run(tmp_path):
    s = ep.Scene(unit="cm")
    s.add_box("slab", (-1, -1, -1), (1, 1, 0), ep.Medium(20, 200, 0.9, 1.1))
    path = tmp_path / "none.vdb"
    with pytest.raises(ValueError, match=r"grids\.emission is the only grid asked for.*no fluorophore"):
        _run(tmp_path, "none", scene=s, absorbed=False, fluorescent_light=False)
    assert not path.exists()
    # Asked with another grid, a scene without fluorophores writes that one.
    res = _run(tmp_path, "plain", scene=s, fluorescent_light=False)
    assert res.grid_names == ["absorbed"]
    assert math.isfinite(res.grid_absorbed_sum) and res.grid_absorbed_sum > 0


@pytest.mark.parametrize(
    "asked, field",
    [
        (dict(absorbed=False, fluorescent_light=False, emission=False), r"grids\.absorbed, .* are all False"),
        (dict(per_fluorophore=True, fluorescent_light=False), r"grids\.per_fluorophore = True needs"),
        (dict(absorbed="yes"), r"grids\.absorbed"),
        (dict(emission=1), r"grids\.emission"),
        (dict(fluorescent_light=None), r"grids\.fluorescent_light"),
    ],
)
def test_bad_grid_requests_are_refused_by_name(tmp_path, asked, field):
    with pytest.raises(ValueError, match=field):
        ep.GridRequest(voxel_size=H, path=str(tmp_path / "g.vdb"), **asked)


def test_the_native_config_refuses_what_the_request_refuses(tmp_path):
    """A RunConfig made without GridRequest (a Dask worker's, a script's) is checked again by the engine."""
    s = lesion_scene()
    src = ep.PencilSource((0.3, 0.0, 1.0), (0, 0, -1))
    for fields, message in (
        (dict(grid_absorbed=False, grid_fluorescent_light=False, grid_emission=False), "are all False"),
        (dict(grid_per_fluorophore=True, grid_fluorescent_light=False), "grids.per_fluorophore = True needs"),
    ):
        cfg = _core.RunConfig(photons=10, grid_voxel_size=H, grid_path=str(tmp_path / "n.vdb"), **fields)
        with pytest.raises(ValueError, match=message):
            _core.run(s.to_native(), _core.Source(src.native_lights(s.unit_cm)), cfg)
    assert not (tmp_path / "n.vdb").exists()


def test_a_scene_file_asks_for_grids_by_quantity():
    doc = json.loads((EXAMPLES / "seed_tissue.json").read_text())
    doc["run"]["grids"] = {"voxel_size": 0.01, "path": "g.vdb", "absorbed": True, "emission": False}
    scene_schema.validate_document(doc)
    request = ep.GridRequest(**doc["run"]["grids"])
    assert (request.absorbed, request.fluorescent_light, request.emission) == (True, True, False)
    doc["run"]["grids"]["fluorescent_light"] = "no"
    with pytest.raises(ValueError, match="fluorescent_light"):
        scene_schema.validate_document(doc)
