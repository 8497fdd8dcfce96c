# SPDX-License-Identifier: MIT
"""Issue 36, "a live endoscope view": while a run is in flight its endoscope-view images refresh
from the records merged so far (ep.run_live), through the Run operator; when it ends the live images
give way to the run's own. Deterministic: snapshots are forced after the first merged chunks and the
worker waits until the main thread has shown each (live_view.FORCE_AFTER_CHUNKS, WAIT_FOR_DISPLAY_S);
"mid-run" is read from the packets each shown image holds, never from a clock."""

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


def _spy_refreshes(monkeypatch):
    """(packets of the live image, lit pixels) each time the main thread showed a snapshot."""
    monkeypatch.setattr(live_view, "FORCE_AFTER_CHUNKS", 2)
    monkeypatch.setattr(live_view, "WAIT_FOR_DISPLAY_S", 60.0)
    seen, original = [], live_view.LiveView.refresh

    def spy(self):
        shown = original(self)
        if shown:
            image = bpy.data.images[LIVE]
            px = np.empty(image.size[0] * image.size[1] * 4, np.float32)
            image.pixels.foreach_get(px)
            seen.append((image["endophoton_view_info"]["packets"], int((px.reshape(-1, 4)[:, :3].max(1) > 0).sum())))
        return shown

    monkeypatch.setattr(live_view.LiveView, "refresh", spy)
    return seen


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
