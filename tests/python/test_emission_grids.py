"""Emission grids (issue 35): where each fluorophore converts light into fluorescence, how much,
and what every grid of a run's file holds (endophoton.vdb.GRID_QUANTITIES)."""
import math

import numpy as np
import pytest

import endophoton as ep
from endophoton import vdb
from physics_helpers import K_SIGMA

pytest.importorskip("pyopenvdb")

H = 0.05  # voxel size, cm
LESION_MIN, LESION_MAX = (-0.3, -0.3, -0.4), (0.3, 0.3, 0.0)  # cm: the only region holding photofrin


def lesion_scene():
    """A collagen tissue box (cm) with a lesion box (higher priority) that also holds photofrin."""
    s = ep.Scene(unit="cm")
    tissue = ep.Medium(20, 200, 0.9, 1.1)
    s.add_box("wall", (-3, -3, -3), (3, 3, 0), tissue, fluorophores=[ep.Fluorophore("collagen", 0.2, 0.4)])
    s.add_box(
        "lesion",
        LESION_MIN,
        LESION_MAX,
        tissue,
        priority=1,
        fluorophores=[ep.Fluorophore("collagen", 0.2, 0.4), ep.Fluorophore("photofrin", 0.1, 0.33)],
    )
    return s


def _run(tmp_path, name, threads=1, photons=3000, seed=3, lanes=True, **asked):
    """The lesion scene with grids: every grid, per fluorophore too, unless ``asked`` says otherwise."""
    # An oblique pencil entering at the lesion's edge: light reaches both the lesion and the wall.
    src = ep.PencilSource((0.3, 0.0, 1.0), (0, 0, -1))
    path = tmp_path / f"{name}.vdb"
    grids = ep.GridRequest(voxel_size=H, path=str(path), **{"per_fluorophore": True, **asked})
    return ep.run(lesion_scene(), src, photons=photons, seed=seed, threads=threads, grids=grids,
                  record_escapes=False, lanes=lanes)  # fmt: skip


def _voxel_centres(path, name):
    """(centres of the nonzero voxels (n, 3), their float32 values) of grid ``name``."""
    arr, origin, h = vdb.grid_to_numpy(path, name)
    idx = np.argwhere(arr > 0)
    return np.asarray(origin) + idx * h, arr[arr > 0]


def _overlaps_lesion(centres):
    """Whether each voxel cell (centre +- H/2) overlaps the lesion box (touching faces count)."""
    lo, hi = np.asarray(LESION_MIN), np.asarray(LESION_MAX)
    eps = 1e-9
    return np.all((centres + H / 2 >= lo - eps) & (centres - H / 2 <= hi + eps), axis=1)


def test_photofrin_emission_lies_in_the_lesion_and_sums_to_its_tally(tmp_path):
    res = _run(tmp_path, "one")
    assert res.grid_names == [
        "absorbed",
        "fluorescent_light",
        "fluorescent_light_collagen",
        "fluorescent_light_photofrin",
        "emission_collagen",
        "emission_photofrin",
    ]
    tally, se = res.emitted_by_fluorophore["photofrin"], res.emitted_by_fluorophore_stderr["photofrin"]
    assert tally > 10 * se > 0  # photofrin converts a clearly nonzero weight
    centres, values = _voxel_centres(res.grid_path, "emission_photofrin")
    assert len(values) > 0 and np.all(_overlaps_lesion(centres))
    # Its light spreads beyond the lesion: that grid is not where photofrin is.
    light, _ = _voxel_centres(res.grid_path, "fluorescent_light_photofrin")
    assert np.count_nonzero(~_overlaps_lesion(light)) > 0
    # Collagen is in both regions: its emission reaches outside the lesion too.
    collagen, _ = _voxel_centres(res.grid_path, "emission_collagen")
    assert np.count_nonzero(~_overlaps_lesion(collagen)) > 0
    summary = vdb.read_grid_summary(res.grid_path)["grids"]
    for name in ("collagen", "photofrin"):
        meta = summary[f"emission_{name}"]["metadata"]
        # The exact voxel sum (fixed point, rounded once) against the tally's double sum in unit order.
        assert meta["accumulator_sum"] == pytest.approx(res.emitted_by_fluorophore[name], rel=1e-12), name
        # The float32 voxels: each rounded to 24 bits.
        assert math.fsum(vdb.grid_to_numpy(res.grid_path, f"emission_{name}")[0].ravel().tolist()) == pytest.approx(
            res.emitted_by_fluorophore[name], rel=1e-6
        )


def test_emission_grids_and_tallies_are_the_same_bits_on_any_thread_count(tmp_path):
    one, two = _run(tmp_path, "t1", threads=1), _run(tmp_path, "t2", threads=2)
    assert one.emitted_by_fluorophore == two.emitted_by_fluorophore
    assert one.emitted_by_fluorophore_stderr == two.emitted_by_fluorophore_stderr
    for name in one.grid_names:
        a, oa, ha = vdb.grid_to_numpy(one.grid_path, name)
        b, ob, hb = vdb.grid_to_numpy(two.grid_path, name)
        assert oa == ob and ha == hb and np.array_equal(a, b), name


def _emission_alone(tmp_path, name, threads=1, seed=3, lanes=True):
    alone = dict(per_fluorophore=False, absorbed=False, fluorescent_light=False)
    return _run(tmp_path, name, threads=threads, photons=20_000, seed=seed, lanes=lanes, **alone)


def test_the_emission_grids_alone_take_the_lanes(tmp_path):
    """A run asking for the emission grids alone takes the float32 lanes (issue 39): its deposits
    come at fluorescence events, which the walk finishes, straight into the unit's grids. Each grid
    sums exactly to its fluorophore's tally, photofrin's lies in the lesion, the bits do not depend
    on the thread count, and the tallies agree with the double walk's."""
    one = _emission_alone(tmp_path, "l1")
    assert one.lanes is not None
    assert one.grid_names == ["emission_collagen", "emission_photofrin"]
    summary = vdb.read_grid_summary(one.grid_path)["grids"]
    for name in ("collagen", "photofrin"):
        tally = one.emitted_by_fluorophore[name]
        assert tally > 10 * one.emitted_by_fluorophore_stderr[name] > 0, name
        assert summary[f"emission_{name}"]["metadata"]["accumulator_sum"] == pytest.approx(tally, rel=1e-12), name
    centres, values = _voxel_centres(one.grid_path, "emission_photofrin")
    assert len(values) > 0 and np.all(_overlaps_lesion(centres))
    two = _emission_alone(tmp_path, "l2", threads=2)
    assert one.emitted_by_fluorophore == two.emitted_by_fluorophore
    for name in one.grid_names:
        a, oa, ha = vdb.grid_to_numpy(one.grid_path, name)
        b, ob, hb = vdb.grid_to_numpy(two.grid_path, name)
        assert oa == ob and ha == hb and np.array_equal(a, b), name
    double = _emission_alone(tmp_path, "d", seed=4, lanes=False)
    assert double.lanes is None
    for name in ("collagen", "photofrin"):
        a, b = one.emitted_by_fluorophore[name], double.emitted_by_fluorophore[name]
        sigma = math.hypot(one.emitted_by_fluorophore_stderr[name], double.emitted_by_fluorophore_stderr[name])
        assert abs(a - b) < K_SIGMA * sigma, (name, a, b, sigma)


def test_a_scene_without_fluorophores_makes_no_emission_grid(tmp_path):
    s = ep.Scene(unit="cm")
    s.add_box("slab", (-1, -1, -1), (1, 1, 0), ep.Medium(20, 200, 0.9, 1.1))
    path = tmp_path / "plain.vdb"
    res = ep.run(s, ep.PencilSource((0, 0, 1), (0, 0, -1)), photons=500, grids=ep.GridRequest(H, str(path)))
    assert res.grid_names == ["absorbed", "fluorescent_light"]
    assert res.emitted_by_fluorophore == {} and res.emitted_by_fluorophore_stderr == {}


def test_every_grid_says_what_it_holds_and_old_names_still_read(tmp_path):
    res = _run(tmp_path, "names", photons=300)
    summary = vdb.read_grid_summary(res.grid_path)["grids"]
    for name in res.grid_names:
        text = vdb.grid_quantity(name)
        assert "per launched packet" in text and "Dimensionless" in text, name
        assert "per launched packet" in summary[name]["metadata"]["meaning"], name
    assert "photofrin" in vdb.grid_quantity("emission_photofrin")
    # The names of files written before the rename read the renamed grids, and back.
    assert vdb.current_grid_name("fluorescence") == "fluorescent_light"
    assert vdb.current_grid_name("fluorescence_photofrin") == "fluorescent_light_photofrin"
    assert vdb.grid_quantity("fluorescence_photofrin") == vdb.grid_quantity("fluorescent_light_photofrin")
    old, _, _ = vdb.grid_to_numpy(res.grid_path, "fluorescence_photofrin")
    new, _, _ = vdb.grid_to_numpy(res.grid_path, "fluorescent_light_photofrin")
    assert np.array_equal(old, new) and old.size > 0
    with pytest.raises(KeyError, match="not one the engine writes"):
        vdb.grid_quantity("photofrin")
    with pytest.raises(KeyError, match="has no grid named 'emission_hpph'"):
        vdb.grid_to_numpy(res.grid_path, "emission_hpph")
