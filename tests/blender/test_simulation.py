# SPDX-License-Identifier: MIT
"""Plain-Python parts of a run: budgets from quality presets, progress text, threads."""

import os

import bpy
import pytest

from endophoton_addon import presets, simulation


@pytest.mark.parametrize(
    "quality,mode,expected",
    [
        ("PREVIEW", "PHOTONS", ("target", 1_000_000, 0.05)),
        ("STANDARD", "PHOTONS", ("target", 20_000_000, 0.01)),
        ("REFERENCE", "STORE", ("store", 2_000_000, None)),
        ("CUSTOM", "PHOTONS", ("photons", 123, None)),
        ("CUSTOM", "STORE", ("store", 456, None)),
    ],
)
def test_resolve_budget(quality, mode, expected):
    assert presets.resolve_budget(quality, mode, 123, 456) == expected


def test_quality_enum_matches_presets():
    items = bpy.types.Scene.bl_rna.properties["endophoton"].fixed_type.properties["quality"].enum_items
    assert [i.identifier for i in items] == [*presets.QUALITY_PRESETS, "CUSTOM"]
    # The add-on's presets are the package's (endophoton.QUALITY_PRESETS): same errors and caps.
    import endophoton as ep

    for key, p in presets.QUALITY_PRESETS.items():
        q = ep.QUALITY_PRESETS[key.lower()]
        assert q.target.rel_error == p.target_error and q.target.tally == "diffuse_reflectance"
        assert q.max_photons == presets.TARGET_CAPS[key]


def test_progress_text():
    p = simulation.Progress(done=50_000, total=200_000, elapsed=2.0, rate=25_000.0, eta=6.0)
    assert p.fraction == 0.25
    assert p.text() == "EndoPhoton: 50,000/200,000 packets · 25,000 packets/s · ETA 6s · Esc to cancel"
    long = simulation.Progress(done=1, total=10**9, elapsed=1.0, rate=1.0, eta=3725.0)
    assert "ETA 1h02m" in long.text()
    store = simulation.Progress(done=7_000, total=0, elapsed=1.0, rate=7_000.0, eta=None)
    assert store.fraction == 0.0
    assert store.text() == (
        "EndoPhoton: 7,000 packets · 7,000 packets/s · ETA -- (until N records are stored) · Esc to cancel"
    )
    # Issue 36, defect 8: a quality preset's run says what ends it and bounds the ETA by its cap.
    preset = simulation.Progress(
        done=10_000, total=0, elapsed=1.0, rate=10_000.0, eta=None, target_error=0.05, cap=1_000_000
    )
    assert preset.text() == (
        "EndoPhoton: 10,000 packets · 10,000 packets/s · until Rd ±5 % (≤ 1,000,000 packets, ETA ≤ 1m39s)"
        " · Esc to cancel"
    )
    assert "store N" not in preset.text()
    # After the tracing the worker renders the endoscope view (seconds with the exitance estimate): the status
    # says so instead of a finished count with ETA 0s.
    view = simulation.Progress(
        done=200_000, total=200_000, elapsed=3.0, rate=66_000.0, eta=0.0, stage="rendering the endoscope view"
    )
    assert view.text() == "EndoPhoton: 200,000 packets traced · rendering the endoscope view · Esc to cancel"


def test_interactive_threads_leave_a_core():
    cores = os.cpu_count() or 1
    assert simulation.interactive_threads(0) == max(1, cores - 1)
    assert simulation.interactive_threads(3) == 3
