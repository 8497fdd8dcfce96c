# SPDX-License-Identifier: MIT
"""Every β of a sweep becomes its own results collection (issue 15, "results kept and
compared"): the single Run's path (simulation.collection_from_run), tagged with the
sweep and its β, its point cloud holding exactly that β's stored records, its
endoscope-view Images when the rig has a camera, no grids (the sweep asks for none).
Deleting one β removes only its own datablocks."""

import importlib
import os

import bpy
import numpy as np

from endophoton_addon import endoscope_views, points, results, sweep_job
from conftest import data_snapshot, open_blend

BETAS, STORE, SEED = (0.0, 20.0, 40.0), 1_500, 7


def _sweep(tmp_path, seed_per_beta=False):
    scene = open_blend("flat_tissue.blend", tmp_path / "grids")
    s = scene.endophoton.sweep
    assert s.keep_runs == "AUTO"  # the default: kept for a small sweep like this one
    s.betas, s.store, s.seed, s.threads = ",".join(f"{b:g}" for b in BETAS), STORE, SEED, 1
    s.seed_per_beta = seed_per_beta
    s.visibility = False
    s.output_dir = str(tmp_path / "sweep")
    before = data_snapshot()
    job = sweep_job.prepare_job(bpy.context)
    assert job.inputs.keep_runs and job.inputs.endoscope_view
    job.start()
    assert job.wait(900.0)  # a hang guard, not a verdict on speed
    assert job.error is None and not job.cancelled, job.error_traceback
    sweep_job.finish_sweep(bpy.context, job)
    return scene, job, before


def _reference_records(ep, job):
    """The records of every β from endophoton.sweep itself on the same exported scene."""
    kept = {}
    ref = ep.sweep(
        job.engine_scene,
        progress=False,
        out_dir=None,
        plots=False,
        report=False,
        on_run=lambda i, beta, result: kept.setdefault(i, result.escapes),
        **job.inputs.sweep_kwargs(),
    )
    return ref, kept


def test_seed_per_beta_gives_every_beta_and_its_collection_its_own_seed(ep, tmp_path):
    """With "Seed per β" every β runs with endophoton.sweep.schema.beta_seed (seed + k x 0x9E3779B97F4A7C15
    mod 2^64): the CSV rows and each β's collection record that seed (as text where it exceeds an
    ID property's 32-bit int), and the records are ep.sweep(seed_per_beta=True)'s."""
    scene, job, _ = _sweep(tmp_path, seed_per_beta=True)
    seeds = [(SEED + k * 0x9E3779B97F4A7C15) % 2**64 for k in range(len(BETAS))]
    assert [
        importlib.import_module('endophoton.sweep.schema').beta_seed(SEED, k, True) for k in range(len(BETAS))
    ] == seeds
    assert len(set(seeds)) == len(BETAS) and seeds[0] == SEED
    assert [row["seed"] for row in job.result.rows] == seeds and job.result.meta["seed_per_beta"] is True
    ref, kept = _reference_records(ep, job)
    collections = sweep_job.sweep_collections(scene, sweep_job.sweep_id(job.inputs))
    for i, collection in enumerate(collections):
        params = collection[results.PARAMS_KEY].to_dict()
        assert params["seed"] == (seeds[i] if seeds[i] < 2**31 else str(seeds[i]))
        _, co = _points(collection)
        expected = np.asarray(kept[i]["position"], np.float64).reshape(-1, 3) / scene.unit_settings.scale_length
        np.testing.assert_allclose(co, expected.astype(np.float32), rtol=0, atol=1e-6 * np.abs(expected).max())
    assert [row["seed"] for row in ref.rows] == seeds
    assert dict(sweep_job.summary_rows(scene))["Store N"] == f"{STORE:,} · seed {SEED} (+ one per β)"


def _points(collection):
    (obj,) = points.points_objects(collection)
    co = np.empty(len(obj.data.vertices) * 3, np.float32)
    obj.data.vertices.foreach_get("co", co)
    return obj, co.reshape(-1, 3)


def test_each_beta_is_a_tagged_collection_and_deletes_alone(ep, tmp_path):
    scene, job, before = _sweep(tmp_path)
    sid = sweep_job.sweep_id(job.inputs)
    collections = sweep_job.sweep_collections(scene, sid)
    assert len(collections) == len(BETAS)
    assert set(collections) <= set(results.result_collections(scene))  # the Results panel lists them
    assert scene[sweep_job.SUMMARY_KEY]["collections"] == [c.name for c in collections]
    assert dict(sweep_job.summary_rows(scene))["Per β"] == f"{len(BETAS)} result collections (Results)"
    ref, kept = _reference_records(ep, job)
    scale = scene.unit_settings.scale_length
    for i, (collection, beta) in enumerate(zip(collections, BETAS)):
        params = collection[results.PARAMS_KEY].to_dict()
        assert params[sweep_job.SWEEP_ID_KEY] == sid and params["sweep_index"] == i
        assert params["beta_deg"] == beta and list(params["sweep_betas"]) == list(BETAS)
        assert (params["kind"], params["count"], params["seed"]) == ("store", STORE, SEED)
        assert params["voxel_size_m"] == 0.0  # no grids: the sweep asked for none
        assert f"β={beta:+.1f}°" in collection.name
        # Point count = the package's per-β record count (store-N: N records).
        obj, co = _points(collection)
        assert len(co) == job.result.rows[i]["records"] == ref.rows[i]["records"] == STORE
        assert collection[results.SUMMARY_KEY]["records"] == STORE
        # The points are that β's records (same seed: bit-identical runs), metres -> Blender units.
        expected = np.asarray(kept[i]["position"], np.float64).reshape(-1, 3) / scale
        np.testing.assert_allclose(co, expected.astype(np.float32), rtol=0, atol=1e-6 * np.abs(expected).max())
        # The rig camera's images beside the run, tagged with the sweep too.
        views = endoscope_views.view_images(collection)
        assert sorted(views) == ["fluorescence", "white"]
        assert all(img[results.PARAMS_KEY][sweep_job.SWEEP_ID_KEY] == sid for img in views.values())
        assert all(img[results.PARAMS_KEY]["beta_deg"] == beta for img in views.values())
    # One parent collection per sweep holds its β collections (the outliner groups a sweep).
    parent = next(c for c in bpy.data.collections if c.get(results.SWEEP_KEY) == sid)
    assert parent.name in scene.collection.children and list(parent.children) == collections
    assert not parent.objects and not any(c.name in scene.collection.children for c in collections)
    added = data_snapshot()
    assert added["volumes"] == before["volumes"]
    assert not any(results.run_files(c) for c in collections)  # no .vdb written

    # Side by side: hiding one β leaves the others shown.
    collections[0].hide_viewport = True
    assert not any(c.hide_viewport for c in collections[1:])
    collections[0].hide_viewport = False

    # Delete the middle β: only its collection, objects, meshes, materials, images go.
    middle = collections[1]
    own = {
        kind: {b.name for b in getattr(bpy.data, kind) if b.get(results.RUN_KEY) == middle[results.RUN_KEY]}
        for kind in ("objects", "meshes", "materials", "images")
    }
    assert all(own.values()) and len(own["images"]) == 2
    sweep_files = sorted(os.listdir(job.inputs.out_dir))
    middle_name = middle.name
    assert bpy.ops.endophoton.result_delete(name=middle_name) == {"FINISHED"}
    after = data_snapshot()
    for kind, names in own.items():
        assert set(added[kind]) - set(after[kind]) == names, kind
    assert set(added["collections"]) - set(after["collections"]) == {middle_name}
    assert set(after["collections"]) < set(added["collections"])
    assert sweep_job.sweep_collections(scene, sid) == [collections[0], collections[2]]
    for collection, i in ((collections[0], 0), (collections[2], 2)):
        assert len(_points(collection)[1]) == ref.rows[i]["records"]
        assert sorted(endoscope_views.view_images(collection)) == ["fluorescence", "white"]
    assert sorted(os.listdir(job.inputs.out_dir)) == sweep_files  # the sweep's own files stay
    # The parent goes with its last β, and nothing of the sweep is left in the scene.
    parent_name = parent.name
    for collection in (collections[0], collections[2]):
        assert bpy.ops.endophoton.result_delete(name=collection.name) == {"FINISHED"}
        assert (parent_name in bpy.data.collections) == (collection is collections[0])
    assert sweep_job.sweep_collections(scene, sid) == []


def test_keep_runs_off_makes_no_collections(ep, tmp_path):
    scene = open_blend("flat_tissue.blend", tmp_path / "grids")
    s = scene.endophoton.sweep
    s.betas, s.store, s.seed, s.threads, s.keep_runs = "0,20", 500, SEED, 1, "OFF"
    s.output_dir = str(tmp_path / "sweep")
    assert bpy.ops.endophoton.sweep_beta() == {"FINISHED"}
    assert sweep_job.sweep_collections(scene) == [] and not results.result_collections(scene)
    assert not any(c.get(results.SWEEP_KEY) for c in bpy.data.collections)  # no empty parent either
    # AUTO keeps records only up to KEEP_AUTO_RECORDS (β values × Store N).
    assert sweep_job.keeps_runs("AUTO", 2, sweep_job.KEEP_AUTO_RECORDS // 2)
    assert not sweep_job.keeps_runs("AUTO", 2, sweep_job.KEEP_AUTO_RECORDS // 2 + 1)
    assert sweep_job.keeps_runs("ON", 12, 10**7) and not sweep_job.keeps_runs("OFF", 1, 1)
