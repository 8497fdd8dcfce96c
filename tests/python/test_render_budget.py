"""The render's cost (issue 38): work linear in the pixels, memory within a stated budget, sizes that cannot fit
refused by name before anything is allocated or run (endophoton.view.budget; docs/render.md "Memory").

No test times anything: work is counted (the elements every np.bincount of a render produces) and memory is
measured with tracemalloc, which counts every numpy allocation exactly.
"""
import sys
import tracemalloc

import numpy as np
import pytest

import endophoton as ep
from endophoton.view import budget, render
from endophoton.view.camera import Camera
from endophoton.view.render import render_view

from _synth import RecordsResult, lambertian_records


def _plane_result(n=20_000):
    s = ep.Scene(unit="cm")
    s.add_box("tissue", (-5, -5, -1), (5, 5, 0), ep.Medium(mua=1.0, mus=10.0))
    return RecordsResult(s, lambertian_records(n), n)


CAM = Camera.look_at((0, 0, 2), (0, 0, 0), up=(0, 1, 0), fov_deg=30)


def test_the_largest_image_is_refused_by_name_before_anything_is_allocated(monkeypatch):
    """8192 x 8192 (sources.MAX_IMAGE_SIDE) used to die in a MemoryError; now a ValueError naming width and
    height and the budget, before the primary rays (the render's first allocation) are cast."""

    def no_rays(*a, **k):
        raise AssertionError("the render started")

    monkeypatch.setattr(render._core, "first_surfaces", no_rays)
    with pytest.raises(
        ValueError, match=r"width = 8192, height = 8192: the render needs about .* memory budget of 4 GiB"
    ):
        render_view(_plane_result(100), CAM, 8192, 8192, kernel_radius=0.1)
    assert budget.render_memory_bytes(8192, 8192) > budget.RENDER_MEMORY_BUDGET_BYTES
    # a small budget refuses a small image by the same rule; the module constant is the default
    with pytest.raises(ValueError, match=r"width = 16, height = 8: .* raise memory_budget_bytes"):
        render_view(_plane_result(100), CAM, 16, 8, kernel_radius=0.1, memory_budget_bytes=1e5)
    monkeypatch.setattr(budget, "RENDER_MEMORY_BUDGET_BYTES", 1e5)
    with pytest.raises(ValueError, match=r"width = 16, height = 8: .*budget of 9.31e-05 GiB"):
        render_view(_plane_result(100), CAM, 16, 8, kernel_radius=0.1)


@pytest.mark.parametrize("bad", [0, -1.0, float("nan"), float("inf"), True, "1GB"])
def test_a_budget_that_is_not_a_positive_number_is_named(bad):
    with pytest.raises(ValueError, match=r"memory_budget_bytes = .* must be a positive number of bytes"):
        render_view(_plane_result(100), CAM, 4, 4, kernel_radius=0.1, memory_budget_bytes=bad)


def test_the_runs_camera_tally_is_refused_before_the_run(monkeypatch):
    """ep.run(..., view=...) allocates pixels x batches x 12 sums in the engine: checked before the run."""
    src = ep.DiskSource(position=(0, 0, 2), direction=(0, 0, -1), radius=1.0)
    view = dict(camera=CAM, width=8192, height=8192)
    with pytest.raises(ValueError, match=r"view width = 8192, view height = 8192: .*the camera tally"):
        ep.run(_plane_result().scene, src, photons=1000, view=view)
    with pytest.raises(ValueError, match=r"view width = 64, view height = 64: .*view memory_budget_bytes"):
        ep.run(_plane_result().scene, src, photons=1000, view=dict(view, width=64, height=64, memory_budget_bytes=1e6))


@pytest.mark.parametrize(
    "n_batches,aperture,estimator",
    [
        pytest.param(2, False, "kernel", marks=pytest.mark.slow),
        (20, True, "kernel"),
        pytest.param(50, False, "kernel", marks=pytest.mark.slow),
        pytest.param(20, False, "exitance", marks=pytest.mark.slow),
    ],
)
def test_the_estimate_bounds_the_measured_peak(n_batches, aperture, estimator):
    """The stated estimate is an upper bound of the render's peak memory (tracemalloc), and not a loose one.
    Many records per pixel here (10,000 on 4 cm^2, radius 0.1 cm): the pairs in flight are bounded too."""
    res = _plane_result(10_000)
    cam = Camera.look_at((0, 0, 2), (0, 0, 0), up=(0, 1, 0), fov_deg=30, aperture_radius=0.2 if aperture else 0.0)
    tracemalloc.start()
    try:
        render_view(res, cam, 96, 64, kernel_radius=0.1, n_batches=n_batches, estimator=estimator)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    records = len(res.escapes["weight"])
    need = budget.render_memory_bytes(96, 64, n_batches, records, aperture, exitance=estimator == "exitance")
    assert peak <= need, (peak, need)
    assert need < 3.0 * peak, (peak, need)  # the pairs' term is a bound (16 MiB) the records here do not reach


def test_render_work_is_linear_in_the_pixels(monkeypatch):
    """The kernel gather used to bincount into arrays of the whole image for every 4,096-pixel chunk (pixels^2
    work: 512^2 took 102 s). Counted as the elements every np.bincount of a render produces: 4 x the pixels
    must cost about 4 x the work (the old code: 16 x)."""
    res = _plane_result(5_000)
    produced = []
    real = np.bincount

    def counting(*a, **k):
        out = real(*a, **k)
        produced.append(out.size)
        return out

    monkeypatch.setattr(np, "bincount", counting)
    work = {}
    for n in (64, 128):  # one chunk of pixels, then four
        produced.clear()
        view = render_view(res, CAM, n, n, kernel_radius=0.05)
        assert view.images["white"]["radiance"].any()
        work[n] = sum(produced)
    assert work[128] <= 4.5 * work[64], work


def test_the_same_records_give_the_same_region_means_at_two_sizes():
    """Bit-identical sums are the existing tests' business; here the region mean of a flat radiance at 32^2 and
    64^2 agree within their errors (a pixel-count-dependent bug would show)."""
    res = _plane_result(40_000)
    a, b = (render_view(res, CAM, n, n, kernel_radius=0.1).regions()["tissue"] for n in (32, 64))
    diff = abs(a["white_radiance"] - b["white_radiance"])
    assert diff < 4 * max(a["white_radiance_stderr"], b["white_radiance_stderr"]), (a, b)


def test_render_cli_refuses_an_image_beyond_the_budget_before_the_run(tmp_path, monkeypatch, capsys):
    """`render --width 8192 --height 8192` exits 2 naming the options and the budget before the engine runs;
    so do a bad emission filter and a camera inside tissue with the kernel estimator."""
    import json

    from endophoton.cli import main
    from test_render_cli import SCENE

    def no_run(*a, **k):
        raise AssertionError("the engine ran")

    real_run = sys.modules["endophoton.run"].run
    monkeypatch.setattr(sys.modules["endophoton.run"], "run", no_run)  # the package's `run` is the function
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(SCENE))  # the render CLI tests' scene
    base = ["render", str(path), "--out", str(tmp_path / "o"), "--photons", "100"]
    for extra, needle in [
        (["--width", "8192", "--height", "8192"], "--width = 8192, --height = 8192: the render needs about"),
        (["--width", "8192"], "--width = 8192, --height = 128: "),
        (["--estimator", "kernel", "--width", "8192", "--height", "8192"], "more than the memory budget of 4 GiB"),
        (["--width", "64", "--height", "64", "--memory-budget-gib", "0.001"], "raise --memory-budget-gib"),
        (["--memory-budget-gib", "-1"], "--memory-budget-gib = -1.0 must be a positive number of GiB"),
        (["--memory-budget-gib", "nan"], "--memory-budget-gib = nan must be a positive number of GiB"),
        (["--estimator", "kernel", "--emission-filter", "5000"], "emission_filter = 5000.0 must be a cut-on"),
    ]:
        assert main(base + extra) == 2, extra
        err = capsys.readouterr().err
        assert needle in err and "Traceback" not in err, (extra, err)
    inside = dict(SCENE, camera=dict(SCENE["camera"], position=[2, 2, -1], look_at=[2, 2, 0]))  # in the wall
    path.write_text(json.dumps(inside))
    for estimator in ("kernel", "nee"):  # nee: ep.run's view request refuses it before tracing
        monkeypatch.setattr(sys.modules["endophoton.run"], "run", no_run if estimator == "kernel" else real_run)
        assert main(base + ["--estimator", estimator]) == 2
        err = capsys.readouterr().err
        assert "camera.position = [2.0, 2.0, -1.0] lies inside a region" in err and "Traceback" not in err, err
    assert not (tmp_path / "o").exists()
