"""Engine counters (``run --stats``, ``ep.run(..., stats=True)``; native/stats.h): what they count is
checked against the run's own tallies and against counts fixed by the geometry, per unit and in total,
and they are the same on any number of threads."""
import pytest

import endophoton as ep
from cli_helpers import EXAMPLES, bench_scene, run_cli, run_json, scene_file

COUNTERS = ("interactions", "crossings", "cache_hits", "cache_misses", "full_queries")


def _run(scene, source, **kw):
    return ep.run(scene, source, record_escapes=False, **kw)


def test_interactions_counter_is_the_interactions_tally():
    """The counter sums each packet's interactions; the tally is their mean per packet."""
    scene, source = scene_file(f"{EXAMPLES}/seed_tissue.json")
    r = _run(scene, source, photons=3000, seed=4, threads=2, stats=True)
    assert r.stats["interactions"] == round(r.interactions * r.photons)
    assert r.stats["interactions"] > 50 * r.photons  # albedo 0.91 in a deep box: ~72 a packet


def test_clear_slab_crossings_are_two_per_packet():
    """A clear (mus = 0), matched (n = 1) slab: every packet crosses its top and its bottom face, nothing else,
    and scatters nowhere; mua = 0 so no roulette ends one inside."""
    scene = ep.Scene("cm")
    scene.add_box("slab", (-1, -1, -0.1), (1, 1, 0), ep.Medium(mua=0.0, mus=0.0, g=0.0, n=1.0))
    r = _run(scene, ep.PencilSource((0, 0, 1), (0, 0, -1)), photons=500, threads=1, stats=True)
    assert r.stats["crossings"] == 2 * 500 and r.stats["interactions"] == 0
    assert r.transmittance == pytest.approx(1.0)


def test_counters_are_per_unit_and_the_same_on_any_thread_count():
    scene, rig = bench_scene("colon")
    one = _run(scene, rig, photons=1500, seed=3, threads=1, stats=True, unit_size=100)
    two = _run(scene, rig, photons=1500, seed=3, threads=2, stats=True, unit_size=100)
    assert one.stats == two.stats
    assert one.stats["units"] == 15
    for name in COUNTERS:
        assert len(one.stats["per_unit"][name]) == 15
        assert sum(one.stats["per_unit"][name]) == one.stats[name]
    # curved walls: the triangle caches answer steps, and some steps need Embree
    assert one.stats["cache_hits"] > 0 and one.stats["full_queries"] > 0


def test_safe_distance_off_sends_every_step_to_embree():
    scene, source = scene_file(f"{EXAMPLES}/mcml_slab.json")
    # The double walk both times: the float32 lanes need the caches, so they would serve only one.
    off = _run(scene, source, photons=2000, threads=1, stats=True, safe_distance=False, lanes=False)
    on = _run(scene, source, photons=2000, threads=1, stats=True, lanes=False)
    assert off.stats["cache_hits"] == off.stats["cache_misses"] == 0
    assert on.stats["cache_hits"] > 0 and on.stats["full_queries"] < off.stats["full_queries"]
    assert on.diffuse_reflectance == off.diffuse_reflectance  # the same answer (docs/performance.md)


def test_no_stats_unless_asked_and_not_on_a_client():
    scene, source = scene_file(f"{EXAMPLES}/mcml_slab.json")
    assert not hasattr(_run(scene, source, photons=200, threads=1), "stats")

    class FakeClient:
        def submit(self, *a, **k):
            raise AssertionError("no task may be submitted")

    with pytest.raises(ValueError, match="stats"):
        _run(scene, source, photons=200, stats=True, client=FakeClient())
    with pytest.raises(ValueError, match="stats"):
        _run(scene, source, photons=200, stats="yes")


@pytest.mark.slow
def test_cli_stats_block():
    out = run_json("run", f"{EXAMPLES}/seed_tissue.json", "--photons", 2000, "--threads", 2, "--stats")
    stats = out["stats"]
    assert set(stats) == {"units", "total", "per_packet", "per_unit", "process"}
    assert stats["total"]["interactions"] == round(out["interactions"] * out["photons"])
    for name in COUNTERS:
        assert stats["per_packet"][name] == pytest.approx(stats["total"][name] / 2000)
        u = stats["per_unit"][name]
        assert u["min"] <= u["mean"] <= u["max"] and u["mean"] == pytest.approx(stats["total"][name] / stats["units"])
    assert stats["process"]["peak_rss_mb"] > 10 and stats["process"]["run_cpu_seconds"] >= 0
    assert "stats" not in run_json("run", f"{EXAMPLES}/seed_tissue.json", "--photons", 200)
    bad = run_cli("run", f"{EXAMPLES}/seed_tissue.json", "--stats=1")
    assert bad.returncode == 2 and "--stats" in bad.stderr
