"""The sweep's answer (issues 34, 35): the target-accuracy stopping rule on a synthetic contrast of known
standard deviation, the white-light image of all the light (never the fluorescence image's records), the
contrast against the surround ring, the independent streams per beta by default and the command line."""
import argparse
import math

import numpy as np
import pytest

import endophoton as ep
from endophoton.sweep import cli as sweep_cli
from endophoton.sweep import driver as sw
from endophoton.sweep import view_runs
from endophoton.sweep.view_sweep import criterion_answer, flat_band, visibility_report
from endophoton.view.camera import Camera
from endophoton.view.visibility import contrast, fit_peak, surround_mask

from _synth import RecordsResult, lambertian_records

needs_engine = pytest.mark.skipif(not hasattr(ep, "run"), reason="engine not built")


# --------------------------------------------------------------------------- the stopping rule


def _synthetic_run(sigma, target, seed, B=20):
    """A contrast whose per-packet values are N(0.3, sigma): its estimate after P packets is their mean,
    with the batch-means standard error over B blocks (the sweep's errors are of this kind). Driven by the
    sweep's own loop (view_runs.grow_to_target); returns (packets at the stop, stderr at the stop, reached)."""
    rng = np.random.default_rng(seed)
    values = []

    def stderr():
        x = np.concatenate(values)
        blocks = np.array_split(x, B)
        means = np.array([b.mean() for b in blocks])
        return float(np.std(means, ddof=1) / math.sqrt(B))

    def grow(n):
        values.append(rng.normal(0.3, sigma, n))
        return True

    grow(400)  # the store run
    reached = view_runs.grow_to_target(lambda: sum(v.size for v in values), stderr, grow, target)
    return sum(v.size for v in values), stderr(), reached


def test_stopping_rule_stops_at_the_requested_error_on_a_contrast_of_known_sd():
    """sigma = 2, error 0.05: the packets needed are (2 / 0.05)^2 = 1600. Over 200 independent runs every
    one stops with its estimated error <= 0.05 (the rule's promise), the true error sigma / sqrt(P) at the
    stop is within 25 % of the request in at least 95 % of them, and the packets average 1.0-1.6 x the
    need (the 10 % margin and the estimated error's own noise, about 16 % at B = 20)."""
    sigma, err = 2.0, 0.05
    need = (sigma / err) ** 2
    target = view_runs.ContrastTarget("red_green", err, 10**9)
    runs = [_synthetic_run(sigma, target, seed) for seed in range(200)]
    packets = np.array([p for p, _, _ in runs], dtype=float)
    assert all(reached and se <= err for _, se, reached in runs)
    true_err = sigma / np.sqrt(packets)
    assert np.mean(true_err <= 1.25 * err) >= 0.95
    assert 1.0 <= packets.mean() / need <= 1.6


def test_stopping_rule_stops_at_the_cap_and_its_steps():
    """A cap below the need stops there, the target unmet; the step is (se/err)^2 x 1.1 - 1 of the packets,
    at most 7 x them, never past the cap; an undefined error doubles; a met error adds none."""
    target = view_runs.ContrastTarget("red_green", 0.05, 1000)
    packets, se, reached = _synthetic_run(2.0, target, 1)
    assert packets == 1000 and not reached and se > 0.05
    assert view_runs.next_packets(1000, 0.1, 0.05, 10**9) == math.ceil(1000 * 4 * 1.1) - 1000
    assert view_runs.next_packets(1000, 1.0, 0.05, 10**9) == 7000  # at most x8 a step
    assert view_runs.next_packets(1000, 0.0501, 0.05, 10**9) == math.ceil(1000 * (0.0501 / 0.05) ** 2 * 1.1) - 1000
    assert view_runs.next_packets(1000, 1.0, 0.05, 1500) == 500  # never past the cap
    assert view_runs.next_packets(1000, None, 0.05, 10**9) == 1000
    assert view_runs.next_packets(1000, 0.05, 0.05, 10**9) == 0
    assert view_runs.next_packets(1500, 1.0, 0.05, 1500) == 0


def test_contrast_target_forms_and_errors():
    t = view_runs.contrast_target("red_green:0.05")
    assert (t.criterion, t.stderr, t.max_packets) == ("red_green", 0.05, view_runs.DEFAULT_MAX_PACKETS)
    assert view_runs.contrast_target(("white", 0.1, 500)).image == "white"
    assert view_runs.contrast_target({"criterion": "fluorescence", "stderr": 1}).column == "fluorescence_contrast"
    for bad, msg in (
        ("red:0.05", "criterion = 'red' must be one of"),
        ("red_green", "use CRITERION:ERR"),
        ("red_green:x", "ERR = 'x' must be a number"),
        (("red_green", 0), "stderr"),
        (("red_green", 0.1, 0), "max_packets"),
    ):
        with pytest.raises(ValueError, match=msg):
            view_runs.contrast_target(bad, "target")
    with pytest.raises(ValueError, match="needs a view"):
        sw.sweep(None, betas=[0], store=100, target=("red_green", 0.05), progress=False)


# --------------------------------------------------------------------------- the surround


def _flat_wall():
    """A flat wall (top face z = 0) with a 'spot' region of the same optics whose top lies 1e-3 cm above
    it, both lit uniformly: synthetic Lambertian records at 550-650 nm, all fluorescent, uniform over the view."""
    m = ep.Medium(mua=1.0, mus=10.0, g=0.0, n=1.0)
    s = ep.Scene(unit="cm")
    s.add_box("wall", (-3, -3, -2), (3, 3, 0), m)
    s.add_box("spot", (-0.3, -0.3, -0.3), (0.3, 0.3, 1e-3), m, priority=1)
    rec = lambertian_records(400_000, half=1.5, wavelength=600.0, seed=4)
    rec["wavelength"] = np.random.default_rng(5).uniform(550.0, 650.0, 400_000).astype(np.float32)
    rec["energy"] = 500.0 / rec["wavelength"].astype(np.float64)  # a colour that varies: R/G has noise
    rec["fluorescent"][:] = 1
    cam = dict(camera=Camera.look_at((0.0, 0.0, 3.0), (0.0, 0.0, 0.0), up=(0, 1, 0), fov_deg=40), width=32, height=32)
    return RecordsResult(s, rec, 400_000), cam


@pytest.mark.slow
def test_surround_equals_the_whole_region_on_a_uniformly_lit_flat_wall():
    """Uniform radiance: the ring's contrasts and the whole region's agree within their errors (and with 0);
    a ring wider than the image holds the whole region, and gives its contrasts to rounding."""
    res, cam = _flat_wall()
    view = ep.render_view(res, **cam, estimator="kernel")  # the records carry no region: gathered across them
    whole = contrast(view, "spot", "wall")
    ring = contrast(view, "spot", "wall", surround_px=4)
    assert 0 < ring["background_pixels"] < whole["background_pixels"]
    for key in ("fluorescence", "white", "red_green", "fluorescence_michelson"):
        se = math.hypot(ring[key + "_stderr"], whole[key + "_stderr"])
        assert abs(ring[key] - whole[key]) <= 3 * se, key
        assert abs(ring[key]) <= 3 * ring[key + "_stderr"], key
    wide = contrast(view, "spot", None, surround_px=1e6)
    assert wide["background_pixels"] == whole["background_pixels"]
    for key in ("fluorescence", "white", "red_green", "white_michelson"):
        assert wide[key] == pytest.approx(whole[key], rel=1e-9, abs=1e-12), key
        assert wide[key + "_stderr"] == pytest.approx(whole[key + "_stderr"], rel=1e-6), key


def test_surround_mask_is_the_ring_of_surface_pixels_around_the_target():
    rmap = np.full((9, 9), 0)
    rmap[4, 4] = 1  # the target
    rmap[0, :] = -1  # no surface
    rmap[4, 6] = 2  # another region
    ring = surround_mask(rmap, 1, 2)
    expect = np.zeros((9, 9), bool)
    yy, xx = np.mgrid[:9, :9]
    expect[(yy - 4) ** 2 + (xx - 4) ** 2 <= 4] = True
    expect[4, 4] = False
    assert (ring == expect).all()
    assert not surround_mask(rmap, 1, 2, background_index=0)[4, 6] and surround_mask(rmap, 1, 2)[4, 6]
    assert not surround_mask(rmap, 5, 2).any()
    res, cam = _flat_wall()
    view = ep.render_view(RecordsResult(res.scene, {k: v[:2000] for k, v in res.escapes.items()}, 2000), **cam)
    with pytest.raises(ValueError, match="surround_px = 0 must be a number of pixels >= 1"):
        contrast(view, "spot", "wall", surround_px=0)
    with pytest.raises(ValueError, match="background = 'spot' is the target region"):
        contrast(view, "spot", "spot", surround_px=3)


# --------------------------------------------------------------------------- white light


@needs_engine
@pytest.mark.slow
def test_white_image_never_uses_the_fluorescence_records(monkeypatch):
    """A fluorescent-only sweep: the white image is rendered from a white pass (every exit, non-fluorescent
    ones among them, another seed), the fluorescence image from the fluorescent records, and the two
    contrasts differ. Fails if both images come from the same records."""
    seen = []
    real = view_runs.render_view

    def spy(records, **kw):
        seen.append(records.escapes)
        return real(records, **kw)

    monkeypatch.setattr(view_runs, "render_view", spy)
    vis = {"target": "polyp", "background": "tissue", "width": 24, "height": 24}
    row = sw.sweep(None, betas=[20], store=2000, progress=False, visibility=vis, threads=1).rows[0]
    assert len(seen) == 2
    fl, wh = seen
    assert (fl["fluorescent"] == 1).all() and (wh["fluorescent"] == 0).any()
    assert not np.array_equal(fl["position"][:100], wh["position"][:100])
    assert row["white_packets"] == row["packets_traced"] and row["view_packets"] == row["packets_traced"]
    assert row["white_contrast"] != row["fluorescence_contrast"]
    assert row["white_contrast_stderr"] != row["fluorescence_contrast_stderr"]


@needs_engine
@pytest.mark.slow
def test_target_sweep_tops_up_each_beta_until_the_error(tmp_path):
    """ep.sweep(target=...): each beta's view is topped up to the error (or the cap), the columns say how
    many packets, and the report states the target and an answer per criterion."""
    vis = {"target": "polyp", "background": "tissue", "surround_px": 6, "width": 24, "height": 24}
    res = sw.sweep(
        None,
        betas=[0, 20, 40],
        store=1000,
        progress=False,
        visibility=vis,
        target=("fluorescence", 0.3, 60_000),
        threads=1,
        out_dir=tmp_path,
    )
    assert any(r["view_packets"] > r["packets_traced"] for r in res.rows)
    for r in res.rows:
        assert r["view_packets"] >= r["packets_traced"]
        assert (r["target_reached"] == 1 and r["fluorescence_contrast_stderr"] <= 0.3) or (
            r["target_reached"] == 0 and r["view_packets"] == 60_000
        )
        assert r["region_fluorescence_contrast"] is not None and r["background_pixels"] > 0
    assert res.meta["contrast_target"] == {"criterion": "fluorescence", "stderr": 0.3, "max_packets": 60_000}
    text = (tmp_path / "report.md").read_text(encoding="utf-8")
    assert "Target: each β ran until the fluorescence contrast's standard error was ≤ 0.3" in text
    assert "ring of 6 pixels" in text and (tmp_path / "surround_vs_region.png").exists()
    assert "white pass" in text


# --------------------------------------------------------------------------- the answer, the defaults


def test_answer_per_criterion_flat_band_and_peak():
    betas = np.arange(0, 60, 5.0)
    flat = [{"c": 0.5, "c_stderr": 0.05} for _ in betas]
    f = fit_peak(betas, [r["c"] for r in flat], [r["c_stderr"] for r in flat])
    assert flat_band(flat, "c") == pytest.approx(0.1)
    assert criterion_answer(f, flat, "c", betas) == "flat within ±0.1 over the swept range (0–55°)"
    peaked = [{"c": 1 - ((b - 30) / 30) ** 2, "c_stderr": 0.01} for b in betas]
    f = fit_peak(betas, [r["c"] for r in peaked], [r["c_stderr"] for r in peaked])
    text = criterion_answer(f, peaked, "c", betas)
    assert text.startswith("most visible at β = 30.0° ± ") and "(68 %: " in text


def test_independent_streams_per_beta_by_default_and_the_cli():
    import inspect

    assert inspect.signature(sw.sweep).parameters["seed_per_beta"].default is True
    p = argparse.ArgumentParser()
    sweep_cli.add_sweep_arguments(p)
    args = p.parse_args(["--betas", "0,10", "--target", "polyp"])
    kw = sweep_cli.sweep_kwargs(args)
    assert kw["seed_per_beta"] is True and "--common-seed" not in sweep_cli.forward_argv(args)
    assert kw["visibility"]["surround_px"] == 8 and kw["visibility"]["background"] is None
    args = p.parse_args(
        [
            "--target",
            "Polyp",
            "--background",
            "Colon",
            "--surround",
            "6",
            "--target-contrast",
            "red_green:0.05",
            "--max-packets",
            "900000",
            "--light",
            "blue",
            "--common-seed",
            "--estimator",
            "kernel",
        ]
    )
    kw = sweep_cli.sweep_kwargs(args)
    assert kw["seed_per_beta"] is False
    assert kw["target"] == view_runs.ContrastTarget("red_green", 0.05, 900000)
    assert kw["visibility"]["surround_px"] == 6 and kw["visibility"]["estimator"] == "kernel"
    assert kw["rig_kwargs"]["spectrum"].name == "blue405"
    back = sweep_cli.sweep_kwargs(p.parse_args(sweep_cli.forward_argv(args)))
    assert back["target"] == kw["target"] and back["seed_per_beta"] is False and back["visibility"]["surround_px"] == 6
    with pytest.raises(SystemExit):  # argparse: exit 2 naming --estimator's choices
        p.parse_args(["--target", "p", "--estimator", "knn"])
    for argv, msg in (
        (["--background", "Colon"], "--background needs --target"),
        (["--target", "p", "--surround", "0"], "--surround = 0.0 must be"),
        (["--target-contrast", "red_green:0.05"], "needs --target"),
        (["--target", "p", "--max-packets", "5"], "--max-packets is the cap"),
    ):
        with pytest.raises(ValueError, match=msg):
            sweep_cli.sweep_kwargs(p.parse_args(argv))


def test_report_words_the_seeds_and_the_records():
    betas = [0.0, 10.0, 20.0]
    rows = [{"red_green_contrast": 0.1, "red_green_contrast_stderr": 0.05} for _ in betas]
    text = visibility_report(betas, rows, "Polyp", "Colon", seed_per_beta=True, surround_px=8, meta={})
    assert "every β ran with a seed of its own" in text and "ring of 8 pixels" in text and "white pass" in text
    assert "flat within ±" in text


def test_answer_reads_the_criterion_the_sweep_ran_to():
    """The report's answer uses the target's colour criterion (camera channels here), also under blue light,
    where the sRGB red/green contrast is undefined; without a target under white light it stays sRGB."""
    betas = [0.0, 10.0, 20.0, 30.0, 40.0, 50.0]
    peaked = [1 - ((b - 30) / 30) ** 2 for b in betas]
    rows = [
        {"red_green_camera_contrast": y, "red_green_camera_contrast_stderr": 0.01, "red_green_contrast": None}
        for y in peaked
    ]
    meta = {"contrast_target": {"criterion": "red_green_camera", "stderr": 0.05, "max_packets": 10**6}}
    text = visibility_report(betas, rows, "Polyp", "Colon", meta=meta)
    assert (
        "**Answer.** By the red/green contrast in the camera's channels" in text and "most visible at β = 30." in text
    )
    blue = visibility_report(betas, rows, "Polyp", "Colon", meta={"light": "blue405"})
    assert "By the red/green contrast in the camera's channels" in blue
    white = visibility_report(betas, rows, "Polyp", "Colon", meta={})
    assert "Too few β values with a defined red/green contrast to locate a maximum." in white
    assert "packets per β n/a" in text
