# SPDX-License-Identifier: MIT
"""Issue 36, "a live endoscope view": while a run or a sweep's β is in flight its endoscope-view images
refresh from the records merged so far (ep.run_live), through the Run and Sweep β operators; when it
ends the live images give way to the run's own (a sweep's: its last kept β's). Deterministic: snapshots are forced after the first merged chunks and the
worker waits until the main thread has shown each (live_view.FORCE_AFTER_CHUNKS, WAIT_FOR_DISPLAY_S);
"mid-run" is read from the packets each shown image holds, never from a clock."""

import importlib
import types

import bpy
import numpy as np

from endophoton_addon import endoscope_views, live_view, results
from conftest import open_blend

LIVE = "EP View white (live)"


def _setup(tmp_path, **settings):
    scene = open_blend("colon_polyp.blend", tmp_path)
    s = scene.endophoton
    s.quality, s.photons, s.output_grids, s.output_points, s.threads = "CUSTOM", 20_000, False, False, 2
    for name, value in settings.items():
        setattr(s, name, value)
    return scene


def _spy(monkeypatch, force, look):
    """``look(image)`` of the live white Image each time the main thread showed a snapshot (forced after
    each of the first ``force`` merged chunks, the worker waiting until each is shown)."""
    monkeypatch.setattr(live_view, "FORCE_AFTER_CHUNKS", force)
    monkeypatch.setattr(live_view, "WAIT_FOR_DISPLAY_S", 60.0)
    seen, original = [], live_view.LiveView.refresh

    def spy(self):
        shown = original(self)
        if shown:
            (image,) = [im for im in bpy.data.images if im.get(live_view.LIVE_KEY) == "white"]
            seen.append(look(image))
        return shown

    monkeypatch.setattr(live_view.LiveView, "refresh", spy)
    return seen


def _spy_refreshes(monkeypatch):
    """(packets of the live image, lit pixels) each time the main thread showed a snapshot."""

    def look(image):
        assert image.name == LIVE
        px = np.empty(image.size[0] * image.size[1] * 4, np.float32)
        image.pixels.foreach_get(px)
        return image["endophoton_view_info"]["packets"], int((px.reshape(-1, 4)[:, :3].max(1) > 0).sum())

    return _spy(monkeypatch, 2, look)


def test_the_view_image_refreshes_mid_run_and_gives_way_to_the_runs_own(ep, tmp_path, monkeypatch):
    scene = _setup(tmp_path)
    assert scene.endophoton.live_view  # on by default (the view images are on)
    seen = _spy_refreshes(monkeypatch)
    assert bpy.ops.endophoton.run_simulation() == {"FINISHED"}
    collection = scene.endophoton.result_collection
    final = collection[results.SUMMARY_KEY]["packets_traced"]
    assert len(seen) >= 2, seen  # the two forced snapshots, shown while the run went on
    packets = [p for p, _ in seen]
    assert packets == sorted(packets) and 0 < packets[0] < packets[1] < final == 20_000
    assert all(lit > 0 for _, lit in seen), seen  # each shown image holds light
    assert not [im.name for im in bpy.data.images if live_view.LIVE_KEY in im]  # live images removed
    assert set(endoscope_views.view_images(collection)) == {"white", "fluorescence"}


def test_live_view_off_or_views_off_runs_plain(ep, tmp_path, monkeypatch):
    calls = []
    monkeypatch.setattr(ep, "run_live", lambda *a, **k: calls.append(1))
    for settings in (dict(live_view=False), dict(output_views=False, output_points=True)):
        scene = _setup(tmp_path, photons=3_000, **settings)
        assert bpy.ops.endophoton.run_simulation() == {"FINISHED"}
        assert scene.endophoton.result_collection is not None
    assert calls == []  # ep.run: nothing live computed
    assert LIVE not in bpy.data.images


def _spy_sweep_refreshes(monkeypatch):
    """(live image name, packets it holds) each time the main thread showed a sweep's snapshot. Chunks of
    one work unit (endophoton.live.CHUNK_SECONDS tiny), so each β's forced snapshots come after 1, 2, 3
    units whatever the machine's speed."""
    import endophoton.live

    monkeypatch.setattr(endophoton.live, "CHUNK_SECONDS", 1e-9)
    return _spy(monkeypatch, 3, lambda image: (image.name, image["endophoton_view_info"]["packets"]))


def test_a_sweep_shows_each_betas_snapshots_named_with_it_and_gives_way_to_its_own(ep, tmp_path, monkeypatch):
    from endophoton_addon import operators, sweep_job

    scene = open_blend("flat_tissue.blend", tmp_path / "grids")
    s = scene.endophoton.sweep
    s.betas, s.store, s.seed, s.threads, s.keep_runs, s.visibility = "0,20", 1_500, 7, 2, "ON", False
    s.output_dir = str(tmp_path / "sweep")
    assert scene.endophoton.live_view and scene.endophoton.output_views
    seen = _spy_sweep_refreshes(monkeypatch)
    assert bpy.ops.endophoton.sweep_beta() == {"FINISHED"}
    job = operators._running["job"]
    assert job.live is not None and job.inputs.endoscope_view
    finals = [row["packets_traced"] for row in job.result.rows]
    for k, beta in enumerate((0, 20)):
        packets = [p for name, p in seen if name == f"EP View white (live, β {beta}°)"]
        assert len(packets) >= 2 and packets == sorted(set(packets)), seen  # the noise falls within the β
        assert 0 < packets[0] and packets[-1] < finals[k], (packets, finals)  # shown while the β ran
    assert [name for name, _ in seen] == sorted(name for name, _ in seen)  # β 0° first, then β 20°
    assert not [im.name for im in bpy.data.images if live_view.LIVE_KEY in im]  # live images removed
    assert job.collections and set(endoscope_views.view_images(job.collections[-1])) == {"white", "fluorescence"}
    # the live path gives the bits of endophoton.sweep without it (the run's seconds aside)
    ref = ep.sweep(
        job.engine_scene, progress=False, out_dir=None, plots=False, report=False, **job.inputs.sweep_kwargs()
    )
    strip = lambda rows: [{k: v for k, v in row.items() if k != "seconds"} for row in rows]  # noqa: E731
    assert strip(job.result.rows) == strip(ref.rows)
    assert sweep_job.sweep_collections(scene, sweep_job.sweep_id(job.inputs)) == job.collections


def test_a_sweep_with_live_view_off_runs_plain(ep, tmp_path, monkeypatch):
    calls = []
    monkeypatch.setattr(ep, "run_live", lambda *a, **k: calls.append(1))
    driver = importlib.import_module("endophoton.sweep.driver")  # ep.sweep is the function
    monkeypatch.setattr(driver, "run_live", lambda *a, **k: calls.append(1))
    scene = open_blend("flat_tissue.blend", tmp_path / "grids")
    s = scene.endophoton.sweep
    s.betas, s.store, s.threads, s.keep_runs, s.visibility = "0", 500, 2, "OFF", False
    s.output_dir = str(tmp_path / "sweep")
    scene.endophoton.live_view = False
    assert bpy.ops.endophoton.sweep_beta() == {"FINISHED"}
    assert calls == [] and not [im for im in bpy.data.images if live_view.LIVE_KEY in im]


def test_a_late_snapshot_of_an_earlier_beta_is_not_shown_and_each_beta_finds_its_own_kernel():
    """ep.run_live lets a snapshot under way when a β's run ends finish in the background: it must not
    overwrite the next β's image, nor hand it its kernel radius (the camera has moved)."""
    radii = []

    def render_view(result, **knobs):
        radii.append(knobs.get("kernel_radius"))
        return types.SimpleNamespace(packets=result.packets, kernel={"radius": result.radius})

    live = live_view.LiveView(types.SimpleNamespace(render_view=render_view), threads=1)
    result = lambda packets, radius: types.SimpleNamespace(  # noqa: E731
        escapes={"weight": [1.0]},
        packets=packets,
        radius=radius,
        source=types.SimpleNamespace(camera_resolution=(8, 8)),
    )
    live.on_beta_snapshot(0, 0.0, result(100, 4.0))
    assert live._pending[1] == "β 0°" and live.kernel_radius == 2.0
    live.on_beta_snapshot(1, 20.0, result(200, 8.0))  # β 20°: found afresh
    live.on_beta_snapshot(0, 0.0, result(300, 4.0))  # late, of β 0°: dropped
    live.on_beta_snapshot(1, 20.0, result(400, 8.0))
    live.on_snapshot(result(500, 1.0), part=0, label="β 0°")  # a render of β 0° under way at its end: dropped
    view, label = live._pending
    assert (view.packets, label, live.kernel_radius) == (400, "β 20°", 4.0)
    assert radii == [None, None, 4.0, 4.0]  # β 20°'s first render finds its own radius; the next use it
