"""The next-event estimate in a β sweep (issue 34): each β's view comes from runs of its own with the camera
tally (``ep.run(..., view=...)``), added batch by batch (``view_runs._Tally``). Checked against an
independent recomputation: the render of one run made by hand with the same seed, and the numpy mean of
two runs' images weighted by their packets."""
import argparse

import numpy as np
import pytest

import endophoton as ep
from endophoton.sweep import cli as sweep_cli
from endophoton.sweep import driver as sw
from endophoton.sweep import view_runs
from endophoton.sweep.view_sweep import visibility_columns
from endophoton.view.render import render_view
from endophoton.view.visibility import contrast

needs_engine = pytest.mark.skipif(not hasattr(ep, "run"), reason="engine not built")

SIZE = dict(width=24, height=24)


def _store_run(seed=5, store=600):
    scene = ep.default_flat_scene()
    rig = ep.EndoscopeRig.from_beta(20.0, 1.0)
    return ep.run(scene, rig, store=store, seed=seed, fluorescent_only=True, threads=1)


@needs_engine
def test_nee_view_of_a_beta_is_the_render_of_its_own_run():
    """Without a target, a β's next-event view is one run of as many packets as the store run traced, with
    the seed of the β's first extra piece: the columns equal those of that run made and rendered by hand,
    to the bit, and the store run's records are not used."""
    res = _store_run()
    cols = visibility_columns(res, "polyp", "tissue", estimator="nee", **SIZE)
    assert cols["view_packets"] == cols["white_packets"] == res.packets_traced
    own = ep.run(
        res.scene,
        res.source,
        photons=res.packets_traced,
        seed=view_runs.piece_seed(5, "fluorescence", 0),
        view=dict(**SIZE),
        record_escapes=False,
        threads=2,
    )
    c = contrast(render_view(own, estimator="nee", **SIZE), "polyp", "tissue")
    for key in ("white", "fluorescence", "red_green"):
        assert cols[f"{key}_contrast"] == c[key] and cols[f"{key}_contrast_stderr"] == c[f"{key}_stderr"]
    assert cols["white_contrast"] != cols["fluorescence_contrast"]


@needs_engine
def test_tallies_of_two_runs_add_to_the_packet_weighted_mean():
    """_Tally adds two runs' tallies batch by batch: the rendered radiance is the packet-weighted mean of the
    two runs' own images (numpy), its batches hold the two runs' packets, and the batch-means error of the
    sum is about that of the two images combined."""
    scene, rig = ep.default_flat_scene(), ep.EndoscopeRig.from_beta(20.0, 1.0)
    runs = [
        ep.run(scene, rig, photons=n, seed=s, view=dict(**SIZE), record_escapes=False, threads=1)
        for n, s in ((3000, 11), (4937, 12))
    ]
    tally = view_runs._Tally(runs[0])
    tally.add(runs[1])
    assert tally.packets_traced == 7937 and int(tally.camera_packets_per_batch.sum()) == 7937
    assert tally.camera_packets_per_batch.min() >= 7937 // 20 and tally.camera_packets_per_batch.max() <= 7937 // 20 + 2
    both = render_view(tally, estimator="nee", **SIZE)
    single = [render_view(r, estimator="nee", **SIZE) for r in runs]
    for name in ("white", "fluorescence"):
        a, b = (v.images[name]["radiance"] for v in single)
        want = (3000 * a + 4937 * b) / 7937
        np.testing.assert_allclose(both.images[name]["radiance"], want, rtol=1e-12, atol=1e-300)
        # errors: the sum's batch means against the two images' errors combined (same order, not the same bits)
        sa, sb = (v.images[name]["radiance_stderr"] for v in single)
        comb = np.sqrt((3000 * sa) ** 2 + (4937 * sb) ** 2) / 7937
        lit = (comb > 0) & (both.images[name]["radiance_stderr"] > 0)
        ratio = np.median(both.images[name]["radiance_stderr"][lit] / comb[lit])
        assert 0.6 < ratio < 1.4, ratio
    with pytest.raises(ValueError, match="camera_packets_per_batch"):
        tally.camera_packets_per_batch = tally.camera_packets_per_batch[:-1]
        render_view(tally, estimator="nee", **SIZE)


@needs_engine
@pytest.mark.slow
def test_nee_target_sweep_tops_up_to_the_error_or_the_cap(tmp_path):
    """ep.sweep(visibility={..., "estimator": "nee"}, target=...): each β's tally grows until the criterion's
    error is reached or the cap; no white pass (the tally holds all the light); the report says so."""
    vis = {"target": "polyp", "background": "tissue", "estimator": "nee", **SIZE}
    res = sw.sweep(
        None,
        betas=[0, 30],
        store=400,
        progress=False,
        visibility=vis,
        target=("white", 0.15, 40_000),
        threads=1,
        out_dir=tmp_path,
    )
    for r in res.rows:
        assert r["white_packets"] == r["view_packets"] >= r["packets_traced"]
        assert (r["target_reached"] == 1 and r["white_contrast_stderr"] <= 0.15) or (
            r["target_reached"] == 0 and r["view_packets"] == 40_000
        )
    assert any(r["view_packets"] > r["packets_traced"] for r in res.rows)
    text = (tmp_path / "report.md").read_text(encoding="utf-8")
    assert "`nee` estimator's own tallies" in text


def test_cli_takes_the_nee_estimator_and_refuses_others():
    p = argparse.ArgumentParser()
    sweep_cli.add_sweep_arguments(p)
    args = p.parse_args(["--target", "Polyp", "--background", "Colon", "--estimator", "nee"])
    kw = sweep_cli.sweep_kwargs(args)
    assert kw["visibility"]["estimator"] == "nee"
    assert sweep_cli.sweep_kwargs(p.parse_args(sweep_cli.forward_argv(args)))["visibility"]["estimator"] == "nee"
    with pytest.raises(SystemExit):  # argparse: exit 2 naming --estimator's choices
        p.parse_args(["--target", "p", "--estimator", "knn"])
    with pytest.raises(ValueError, match=r"visibility\['estimator'\] = 'knn'"):
        sw.sweep(
            ep.default_flat_scene(),
            betas=[0],
            store=100,
            progress=False,
            visibility={"target": "x", "estimator": "knn"},
        )


def _sweep_of(level, estimator, light="white"):
    from endophoton.sweep.schema import SweepResult

    betas = np.arange(0, 60, 10.0)
    rows = [
        {"beta_deg": b, "red_green_camera_contrast": level, "red_green_camera_contrast_stderr": 0.04} for b in betas
    ]
    meta = {
        "visibility": {"target": "Polyp", "background": "Colon", "estimator": estimator},
        "contrast_target": {"criterion": "red_green_camera", "stderr": 0.05, "max_packets": 10**6},
        "light": light,
    }
    return SweepResult(rows=rows, meta=meta)


def test_lights_report_names_each_estimator_and_compares_only_like_with_like():
    from endophoton.sweep.view_sweep import _records_words, lights_report

    same = lights_report([("white", _sweep_of(0.4, "nee")), ("blue", _sweep_of(1.5, "nee", "blue405"))])
    assert "| white | nee | red/green contrast, camera channels |" in same
    assert "σ apart): blue light shows the polyp more clearly." in same
    mixed = lights_report([("white", _sweep_of(0.4, "nee")), ("blue", _sweep_of(1.5, "auto", "blue405"))])
    assert "| blue | exitance |" in mixed  # a sweep's "auto" is the exitance estimate
    assert (
        "not compared, since the white light's views come from the nee estimate and the blue light's from the "
        "exitance" in mixed
    )
    assert "shows the polyp more clearly" not in mixed
    kernel = lights_report([("white", _sweep_of(0.4, "nee")), ("blue", _sweep_of(1.5, "kernel", "blue405"))])
    assert "| blue | kernel |" in kernel and "the blue light's from the kernel" in kernel
    assert "white pass" in _records_words({"visibility": {"estimator": "auto"}})
    assert "`nee` estimator's own tallies" in _records_words({"visibility": {"estimator": "nee"}})


@pytest.mark.parametrize("estimator", ["kernel", "nee"])
@pytest.mark.parametrize("bad", [float("nan"), -5, 3, "x", True])
def test_white_packets_is_checked_by_name_before_any_run(estimator, bad, monkeypatch):
    """visibility['white_packets'] (the white pass's or the first next-event run's packets) must be an integer
    of at least the view's batches (20 by default); else a ValueError naming it, before the store run."""
    vis = {"target": "polyp", "background": "tissue", "estimator": estimator, "white_packets": bad}
    monkeypatch.setattr(sw, "run", lambda *a, **k: pytest.fail("the store run started"))
    with pytest.raises(ValueError, match=r"visibility\['white_packets'\] = .* must be"):
        sw.sweep(
            ep.default_flat_scene(),
            betas=[0],
            store=100,
            progress=False,
            visibility=vis,
        )
