# SPDX-License-Identifier: MIT
"""Issue 15, "results kept": the endoscope-view images (ep.render_view) appear
as Image datablocks beside their run and go with it."""

import os
import re

import bpy
import numpy as np

from endophoton_addon import endoscope_views, results, rig, simulation
from conftest import open_blend


def _run(blend, tmp_path, prepare=None, **settings):
    scene = open_blend(blend, tmp_path)
    if prepare is not None:
        prepare(scene)
    s = scene.endophoton
    s.quality, s.photons, s.output_grids = "CUSTOM", 20_000, False
    for name, value in settings.items():
        setattr(s, name, value)
    job = simulation.prepare_job(bpy.context)
    job.start()
    job.wait()
    return scene, job, simulation.finish_job(bpy.context, job)


def _pixels(image):
    w, h = image.size
    values = np.empty(w * h * 4, np.float32)
    image.pixels.foreach_get(values)
    return values.reshape(h, w, 4)


def _srgb8(linear):
    """IEC 61966-2-1 encoding, written out here independently of endophoton.view.colour."""
    c = np.clip(linear, 0.0, 1.0)
    return np.round(255 * np.where(c <= 0.0031308, 12.92 * c, 1.055 * c ** (1 / 2.4) - 0.055)).astype(int)


def test_view_images_made_kept_and_removed(ep, tmp_path):
    scene, job, collection = _run("colon_polyp.blend", tmp_path)
    images = endoscope_views.view_images(collection)
    assert set(images) == {"white", "fluorescence"}
    assert sorted(collection[endoscope_views.VIEWS_KEY]) == sorted(im.name for im in images.values())
    # the package's own image of the same records, computed here again
    view = ep.render_view(job.result, threads=job.inputs.threads)
    size = tuple(job.engine_rig.camera_resolution)
    assert size == (256, 256)  # EndoscopeRig's camera: the add-on asks for no other size
    for name, image in images.items():
        assert tuple(image.size) == size and image.is_float
        assert image["endophoton_collection"] == collection.name
        assert image[results.RUN_KEY] == collection[results.RUN_KEY]
        assert image[results.PARAMS_KEY]["beta_deg"] == collection[results.PARAMS_KEY]["beta_deg"]
        info = image["endophoton_view_info"]
        expected = view.images[name]
        assert info["exposure"] == expected["exposure"] and info["packets"] == job.result.packets_traced
        pixels = _pixels(image)[::-1]  # Blender's rows run bottom-up; the package's row 0 is the top
        np.testing.assert_allclose(pixels[..., :3], expected["rgb"] * expected["exposure"], rtol=1e-6, atol=1e-9)
        np.testing.assert_array_equal(pixels[..., 3], 1.0)
        lit = (pixels[..., :3].max(axis=2) > 0.01).sum()
        assert lit > 0.01 * size[0] * size[1], (name, lit)  # non-empty (20k packets light ~2 % of it)
        assert np.abs(_srgb8(pixels[..., :3]) - expected["srgb8"].astype(int)).max() <= 1
    # kept in the .blend (packed, fake user) with their pixels
    path, collection_name = str(tmp_path / "kept.blend"), collection.name
    names = {name: im.name for name, im in images.items()}
    before = {name: _pixels(im) for name, im in images.items()}
    bpy.ops.wm.save_as_mainfile(filepath=path)
    bpy.ops.wm.open_mainfile(filepath=path)
    collection = bpy.data.collections[collection_name]
    for name, image_name in names.items():
        image = bpy.data.images[image_name]
        np.testing.assert_allclose(_pixels(image), before[name], rtol=2e-3, atol=1e-6)  # EXR half floats
    results.remove_run(collection)
    assert not any(bpy.data.images.get(n) for n in names.values())


def _remove_camera(scene):
    root = rig.find_rigs(scene)[0]
    bpy.data.objects.remove(next(c for c in root.children if c.type == "CAMERA"))
    assert not rig.has_camera(root)


def test_no_view_without_camera_or_when_off(ep, tmp_path):
    for prepare, settings in ((_remove_camera, {}), (None, {"output_views": False})):
        _scene, job, collection = _run("flat_tissue.blend", tmp_path, prepare, **settings)
        assert not job.inputs.endoscope_view and job.view is None and job.view_error is None
        assert not endoscope_views.view_images(collection) and endoscope_views.VIEWS_KEY not in collection
        assert not any(endoscope_views.VIEW_KEY in im for im in bpy.data.images)


def test_a_grids_only_run_asks_for_no_records(ep, tmp_path):
    """Compute only what the scene needs: no point cloud and no view images, so no escape records."""
    settings = {"output_points": False, "output_views": False, "output_grids": True, "voxel_size": 0.002}
    _scene, job, collection = _run("flat_tissue.blend", tmp_path, **settings)
    assert job.run_kwargs["record_escapes"] is False
    assert job.result.escapes is None and job.result.to_dict()["escape_records"] == 0
    assert job.result.grid_absorbed_sum > 0 and collection[results.SUMMARY_KEY]["records"] == 0
    for views in (False, True):  # either output that reads records turns them back on
        settings = {"output_points": not views, "output_views": views, "output_grids": False}
        _scene, job, _collection = _run("flat_tissue.blend", tmp_path, **settings)
        assert job.run_kwargs["record_escapes"] is True and job.result.to_dict()["escape_records"] > 0


def test_all_outputs_off_is_a_named_error(ep, tmp_path):
    scene = open_blend("flat_tissue.blend", tmp_path)
    s = scene.endophoton
    s.output_points, s.output_grids, s.output_views = False, False, False
    try:
        simulation.collect_inputs(bpy.context)
    except simulation.InputError as exc:
        assert "simulation outputs are all off" in str(exc) and "endoscope-view images" in str(exc)
    else:
        raise AssertionError("a run with every output off was accepted")


def _lit_share(image, view):
    """Share of the pixels that see tissue (the package's region map) with a nonzero channel in ``image``."""
    tissue = view.region_map[::-1] >= 0  # Blender's rows run bottom-up
    assert tissue.mean() > 0.5  # the flat tissue fills most of the rig camera's view
    return float((_pixels(image)[..., :3].max(axis=2) > 0)[tissue].mean())


def test_each_view_estimator_makes_the_packages_image(ep, tmp_path):
    """simulation.view_estimator picks ep.render_view's estimator: the Image holds the package's image
    of the same run, says which estimator made it, and a next-event run tallies the camera itself
    (view=True) and asks for no records when nothing else reads them."""
    shares = {}
    rna = bpy.context.scene.endophoton.bl_rna.properties["view_estimator"]
    assert rna.default == "EXITANCE"  # the default, as render_view's "auto" without a camera tally
    for choice in ("KERNEL", "KNN", "EXITANCE", "NEE"):
        _scene, job, collection = _run("flat_tissue.blend", tmp_path, output_points=False, view_estimator=choice)
        estimator = choice.lower()
        assert job.inputs.view_estimator == estimator
        assert job.run_kwargs.get("view") is (True if estimator == "nee" else None)
        assert job.run_kwargs["record_escapes"] is (estimator != "nee")
        assert (job.result.camera_image is not None) is (estimator == "nee")
        view = ep.render_view(job.result, threads=job.inputs.threads, estimator=estimator)
        image = endoscope_views.view_images(collection)["white"]
        info = image["endophoton_view_info"]
        assert info["estimator"] == estimator and info["exposure"] == view.images["white"]["exposure"]
        expected = view.images["white"]["rgb"] * view.images["white"]["exposure"]
        np.testing.assert_allclose(_pixels(image)[::-1][..., :3], expected, rtol=1e-6, atol=1e-9)
        shares[estimator] = _lit_share(image, view)
    # the k-nearest and exitance estimates leave no pixel that sees tissue black; the kernel's records leave
    # most of them black at 20,000 packets
    assert shares["knn"] == 1.0 and shares["exitance"] == 1.0 and shares["kernel"] < 0.5, shares


def test_next_event_needs_a_photon_count(ep, tmp_path):
    scene = open_blend("flat_tissue.blend", tmp_path)
    s = scene.endophoton
    s.quality, s.mode, s.store, s.view_estimator = "CUSTOM", "STORE", 1000, "NEE"
    collections_before = set(bpy.data.collections.keys())
    try:
        simulation.collect_inputs(bpy.context)
    except simulation.InputError as exc:
        assert "simulation.view_estimator = 'NEE'" in str(exc) and "store run" in str(exc), str(exc)
    else:
        raise AssertionError("a next-event view of a store run was accepted")
    assert set(bpy.data.collections.keys()) == collections_before  # the scene is left as it was
    s.output_views = False  # no view asked for: the estimator does not matter
    assert simulation.collect_inputs(bpy.context).view_estimator == "nee"


def test_the_status_says_the_view_is_rendering(ep, tmp_path, monkeypatch):
    """Once the packets are traced the worker renders the view (seconds with the exitance estimate): the status
    line and the sidebar say so, naming the estimator, instead of a finished count with ETA 0s."""
    seen = {}
    render = simulation.endoscope_view

    def watched(ep_, inputs, result, cancel=None):
        seen["text"], seen["lines"] = job.progress().text(), job.panel_lines()
        return render(ep_, inputs, result, cancel)

    monkeypatch.setattr(simulation, "endoscope_view", watched)
    scene = open_blend("flat_tissue.blend", tmp_path)
    s = scene.endophoton
    s.quality, s.photons, s.output_grids = "CUSTOM", 20_000, False
    job = simulation.prepare_job(bpy.context)
    job.start()
    job.wait()
    assert simulation.finish_job(bpy.context, job) is not None
    # the count is the last progress report's (the engine reports about every 0.1 s)
    assert re.fullmatch(
        r"EndoPhoton: [\d,]+ packets traced · rendering the endoscope view \(exitance estimate\) · Esc to cancel",
        seen["text"],
    ), seen["text"]
    assert seen["lines"][0].startswith("Traced: ")
    assert seen["lines"][1:] == ["Rendering the endoscope view (exitance estimate)"]
