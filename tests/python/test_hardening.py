"""Regression corpus of issue 13 (hardening): every class of defect found by the hostile-user
trial has a case here. Contract: a sound result (finite, energy conserved) or a ValueError /
exit status 2 whose message names the field and the value; never a crash, hang or traceback.
No verdict depends on timing: runs that would take long are requests that can never finish,
stopped by a deterministic rule or a named error."""
import copy
import json
import math
import os
import signal
import subprocess
import sys
import textwrap
import warnings

import numpy as np
import pytest

import endophoton as ep
from endophoton import _core
from endophoton.cli import main as cli_main
from cli_helpers import start_cli
from physics_helpers import assert_energy_conserved, assert_no_nan, cube_mesh, run_physics

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))
TISSUE = ep.Medium(mua=1.0, mus=10.0, g=0.9, n=1.4)
DOWN = ep.PencilSource((0, 0, 1), (0, 0, -1))
NEVER_ENDS = 2**40


def slab(thickness=0.02, top=0.0, width=2.0, medium=TISSUE):
    s = ep.Scene("cm")
    s.add_box("slab", (-width / 2, -width / 2, top - thickness), (width / 2, width / 2, top), medium)
    return s


def _subprocess(code, timeout=300):
    env = dict(os.environ, PYTHONPATH=os.path.join(ROOT, "python") + os.pathsep + os.path.join(ROOT, "tests", "python"))
    return subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)],
        env=env,
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


# ---------------------------------------------------------------- crashes (float32 Embree)
@pytest.mark.parametrize(
    "source,field",
    [
        (ep.PencilSource((0, 0, 1e19), (0, 0, -1)), "position"),
        (ep.DiskSource((0, 0, 1), (0, 0, -1), radius=1e20), "radius"),
        (ep.ConeSource((0, 0, 1), (0, 0, -1), 7.5, radius=1e30), "radius"),
        (ep.EndoscopeRig.from_beta(0.0, 1e308), "position"),
    ],
)
def test_huge_source_coordinates_are_named_errors(source, field):
    with pytest.raises(ValueError, match=rf"source.lights\[\d\].*{field}.*beyond the limit 1e\+12"):
        ep.run(slab(1.0), source, photons=10)


def test_thread_creation_failure_is_a_named_error():
    """The engine's test hook makes the 3rd thread fail to start, as std::thread does when the
    system has no threads or memory left: the run stops the started workers and raises a
    named error (it used to end in std::terminate)."""
    opts = dict(photons=NEVER_ENDS, threads=8, unit_size=64, record_escapes=False, test_fail_thread=3)
    with pytest.raises(RuntimeError, match=r"threads = 8: could not start thread 3 \(.*\); ask for fewer threads"):
        _core.run(slab(1.0).to_native(), _core.Source(DOWN.native_lights(1.0)), _core.RunConfig(**opts))


# ---------------------------------------------------------------- corrupt output
@pytest.mark.slow
def test_grid_write_beyond_the_file_size_limit_fails_and_leaves_no_file(tmp_path):
    out = tmp_path / "g.vdb"
    p = _subprocess(
        f"""
        import resource, signal
        import endophoton as ep
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        s = ep.Scene("cm"); s.add_box("a", (-1, -1, -1), (1, 1, 0), ep.Medium(1, 10, 0.9, 1.4))
        resource.setrlimit(resource.RLIMIT_FSIZE, (4096, resource.RLIM_INFINITY))
        try:
            ep.run(s, ep.PencilSource((0, 0, 1), (0, 0, -1)), photons=20000, record_escapes=False,
                   grids=ep.GridRequest(0.01, {str(out)!r}))
            print("RETURNED")
        except RuntimeError as e:
            print("ERR", e)
    """
    )
    assert p.returncode == 0, p.stderr
    assert p.stdout.startswith("ERR vdb file '" + str(out) + "': write failed: File too large"), p.stdout
    assert list(tmp_path.iterdir()) == []


# ---------------------------------------------------------------- NaN
def test_refractive_index_beyond_100_is_refused():
    with pytest.raises(ValueError, match=r"scene.ambient_n = 1e\+155 must be a finite number in \[1, 100"):
        ep.Scene("cm", ambient_n=1e155)
    with pytest.raises(ValueError, match=r"medium.n = 1e\+155 must be in \[1, 100\]"):
        ep.Medium(1, 1, 0, 1e155)
    assert _core._testing.fresnel(1.0, 1.0, 100.0) == pytest.approx((99 / 101) ** 2, rel=1e-12)


@pytest.mark.parametrize("value", [-1, float("nan"), float("inf"), True, "512", 2.0**40])
def test_bad_cache_store_budget_is_refused(value):
    """The engine's cache budget is checked where it is given and where a run applies it."""
    with pytest.raises(
        ValueError, match=r"scene.cache_store_mb = .* must be None or a finite number of MiB in \[0, 2\*\*40\)"
    ):
        ep.Scene("cm", cache_store_mb=value)
    scene = slab(1.0)
    scene.cache_store_mb = value
    with pytest.raises(ValueError, match=r"scene.cache_store_mb = "):
        ep.run(scene, DOWN, photons=10)


@pytest.mark.parametrize("lanes", [False, True])
def test_a_zero_cache_store_budget_still_runs(lanes):
    """No stored caches at all: every step of the double walk takes the full query, and a walk in
    the float32 lanes gathers each cube into its slot's own caches; the same results either way."""
    runs = []
    for mb in (None, 0):
        ep.forget_native_scenes()
        scene = slab(1.0)
        scene.cache_store_mb = mb
        res = ep.run(scene, DOWN, photons=2000, seed=3, lanes=lanes)
        assert (res.lanes is not None) == lanes
        runs.append(run_physics(res))
        assert (scene.to_native().cache_store_bytes > 0) == (mb != 0)
    assert runs[0] == runs[1]
    ep.forget_native_scenes()


def test_a_kept_engine_scene_takes_each_scenes_budget():
    """Scenes of the same content share the kept engine scene; each run applies its own scene's
    budget, the engine's default for None."""

    def box(mb):
        scene = slab(1.0)
        scene.cache_store_mb = mb
        return scene

    ep.forget_native_scenes()
    first = box(1).to_native()
    assert first.cache_store_cap_bytes == 1 << 20
    again = box(None).to_native()
    assert again is first and again.cache_store_cap_bytes == _core.DEFAULT_CACHE_STORE_BYTES
    ep.forget_native_scenes()


@pytest.mark.parametrize("photons", [1, 2, 63, 64, 65])
def test_runs_of_one_work_unit_are_finite(photons):
    """1-64 packets are one unit: stderrs come from the per-packet variance. Independent
    check: for the specular tally every packet contributes the same Rsp, so its sample variance
    is 0; a single packet has no sample variance and reports the bound sqrt(w^2) = Rsp."""
    r = ep.run(slab(1.0), DOWN, photons=photons, seed=3, threads=2)
    assert_no_nan(r)
    assert_energy_conserved(r)
    assert r.specular_reflectance == pytest.approx(((1.4 - 1) / 2.4) ** 2, rel=1e-12)
    expected = r.specular_reflectance if photons == 1 else 0.0
    assert r.specular_reflectance_stderr == pytest.approx(expected, abs=1e-8)  # rounding of sum w^2 - (sum w)^2/N
    json.dumps(r.to_dict(), allow_nan=False)


@pytest.mark.parametrize("store", [1, 65])
def test_store_runs_of_one_unit_are_finite(store):
    r = ep.run(slab(1.0), DOWN, store=store, seed=2)
    assert r.stop_reason == "store" and len(r.escapes["weight"]) == store
    assert_no_nan(r)
    json.dumps(r.to_dict(), allow_nan=False)


def test_per_packet_stderr_matches_numpy_on_the_records():
    """One unit of 50 packets on a clear slab: every packet escapes once, so the transmitted
    weight per packet is in the records; the stderr must equal numpy's std(ddof=1)/sqrt(N)."""
    s = slab(0.5, medium=ep.Medium(mua=0.7, mus=20.0, g=0.8, n=1.3))
    r = ep.run(s, DOWN, photons=50, seed=9, threads=1, roulette_threshold=0.0)
    esc = r.escapes
    per_packet = np.zeros(50)
    mask = esc["kind"] == 1
    np.add.at(per_packet, esc["packet"][mask], esc["weight"][mask])
    assert r.transmittance == pytest.approx(per_packet.mean(), rel=1e-12)
    assert r.transmittance_stderr == pytest.approx(per_packet.std(ddof=1) / math.sqrt(50), rel=1e-9)


# ---------------------------------------------------------------- hangs
def test_fluorescent_only_store_without_fluorophores_is_refused():
    with pytest.raises(ValueError, match=r"store = 10 with fluorescent_only = True needs a fluorophore"):
        ep.run(slab(1.0), DOWN, store=10, fluorescent_only=True)


def test_store_that_never_gets_a_record_stops_and_says_so():
    """A pencil that misses every region: no record ever; the run stops after 1000 units."""
    r = ep.run(slab(1.0), ep.PencilSource((5, 5, 1), (0, 0, 1)), store=10, unit_size=64)
    assert r.stop_reason == "store_zero" and r.photons == 64_000 and r.missed == 1.0
    assert_no_nan(r)


def test_pathological_mus_is_capped_with_a_warning():
    """mus = 1e30 cm^-1 over 0.02 cm (2e28 mean free paths): packets are capped at 1e5
    events, the result warns, and the balance still closes (the cut weight is tallied)."""
    r = ep.run(slab(0.02, medium=ep.Medium(mua=1.0, mus=1e30, g=0.0, n=1.0)), DOWN, photons=200, seed=1)
    assert any("region 'slab': medium.mus = 1e+30" in w and "100000 events" in w for w in r.warnings), r.warnings
    assert_no_nan(r)
    assert_energy_conserved(r)
    if r.cut > 0:
        assert r.capped_packets > 0


def test_region_count_is_checked_before_anything_else():
    """100,000 regions whose entries are themselves invalid: the count error comes first
    (the cheapest check), so validation cannot spend time on the entries."""
    d = {"regions": [{"bogus": 1}] * 100_000}
    with pytest.raises(ValueError, match=r"scene.regions holds 100000 regions; a scene holds at most 64"):
        ep.Scene.from_dict(d)


# ---------------------------------------------------------------- silent wrong answers
def test_source_far_above_a_thin_slab_is_refused():
    s = ep.Scene("cm")
    s.add_box("slab", (-500, -500, -0.02), (500, 500, 0), TISSUE)
    with pytest.raises(ValueError, match=r"source.lights\[0\].*too far from the scene.*'slab'"):
        ep.run(s, ep.PencilSource((0, 0, 5000), (0, 0, -1)), photons=10)
    r = ep.run(s, ep.PencilSource((0, 0, 10), (0, 0, -1)), photons=200)  # near: fine
    assert r.missed == 0


def test_thin_region_far_from_the_origin_is_refused():
    s = ep.Scene("cm")
    s.add_box("slab", (-1, -1, 1e6 - 0.5), (1, 1, 1e6), TISSUE)  # float32 spacing there: 0.0625
    with pytest.raises(
        ValueError, match=r"region 'slab': thinnest side 0.5 scene units at \|coordinate\| up to 1e\+06"
    ):
        ep.run(s, ep.PencilSource((0, 0, 1e6 + 1), (0, 0, -1)), photons=10)


def test_box_spanning_float_range_is_refused():
    s = ep.Scene("cm")
    s.add_box("huge", (-3e38, -3e38, -3e38), (3e38, 3e38, 0), TISSUE)
    with pytest.raises(ValueError, match=r"region 'huge': mesh.vertices reach \|coordinate\| = 3e\+38"):
        ep.run(s, DOWN, photons=10)


@pytest.mark.parametrize("n", [2**64 - 65_535, 2**64, 2**62 + 1])
def test_packet_requests_beyond_2_pow_62_are_refused(n):
    with pytest.raises(ValueError, match=rf"photons = {n} must be in \[1, {2 ** 62}\]"):
        ep.run(slab(1.0), DOWN, photons=n)
    with pytest.raises(ValueError, match=r"photons = \d+ exceeds the limit 2\^62"):
        _core.run(slab(1.0).to_native(), _core.Source(DOWN.native_lights(1.0)), _core.RunConfig(photons=2**62 + 1))


def test_triangle_index_beyond_2_pow_32_is_refused_before_narrowing():
    v, t = cube_mesh((-1, -1, -1), (1, 1, 0))
    t = t.astype(np.int64)
    t[3, 1] += 2**32  # would wrap to a valid index
    s = ep.Scene("cm")
    with pytest.raises(ValueError, match=rf"mesh.triangles\[3\]\[1\] = {int(t[3, 1])} is not a vertex index"):
        s.add_mesh("m", v, t, TISSUE)


def test_self_intersecting_mesh_is_refused():
    v1, t1 = cube_mesh((0, 0, 0), (1, 1, 1))
    v2, t2 = cube_mesh((0.3, 0.4, 0.45), (1.3, 1.4, 1.45))
    v = np.vstack([v1, v2])
    t = np.vstack([t1, t2 + len(v1)])
    s = ep.Scene("cm")
    s.add_mesh("two_cubes", v, t, TISSUE)
    with pytest.raises(ValueError, match=r"region 'two_cubes': mesh intersects itself: mesh.triangles\[\d+\] and"):
        ep.run(s, DOWN, photons=10)
    # Control: the same cubes apart are one valid (two-part) region.
    s2 = ep.Scene("cm")
    s2.add_mesh("apart", np.vstack([v1, v2 + 2.0]), t, TISSUE)
    r = ep.run(s2, ep.PencilSource((0.5, 0.5, 2), (0, 0, -1)), photons=100)
    assert_energy_conserved(r)


def _orient3d(a, b, c, d):
    """The sign-defining determinant of native/mesh_check.cpp's orient3d, in the same order."""
    ab, ac, ad = b - a, c - a, d - a
    return (
        ab[..., 0] * (ac[..., 1] * ad[..., 2] - ac[..., 2] * ad[..., 1])
        - ab[..., 1] * (ac[..., 0] * ad[..., 2] - ac[..., 2] * ad[..., 0])
        + ab[..., 2] * (ac[..., 0] * ad[..., 1] - ac[..., 1] * ad[..., 0])
    )


def _crossing_pairs(v, t):
    """Every pair (i < j) of triangles without a common vertex of which an edge of one strictly
    crosses the other's plane through the closed triangle: all pairs, by brute force."""
    P = v.astype(np.float64)[t]  # (n, 3 corners, 3)
    n = len(t)
    i, j = np.triu_indices(n, 1)
    shared = (t[i][:, :, None] == t[j][:, None, :]).any(axis=(1, 2))
    i, j = i[~shared], j[~shared]

    def pierces(e, f):
        a, b, c = P[f, 0], P[f, 1], P[f, 2]
        hit = np.zeros(len(e), bool)
        for k in range(3):
            p, q = P[e, k], P[e, (k + 1) % 3]
            sp, sq = _orient3d(a, b, c, p), _orient3d(a, b, c, q)
            s1, s2, s3 = _orient3d(p, q, a, b), _orient3d(p, q, b, c), _orient3d(p, q, c, a)
            opposite = ((sp > 0) & (sq < 0)) | ((sp < 0) & (sq > 0))
            inside = ((s1 >= 0) & (s2 >= 0) & (s3 >= 0)) | ((s1 <= 0) & (s2 <= 0) & (s3 <= 0))
            hit |= opposite & inside & ~((s1 == 0) & (s2 == 0) & (s3 == 0))
        return hit

    cross = pierces(i, j) | pierces(j, i)
    return list(zip(i[cross].tolist(), j[cross].tolist()))


@pytest.mark.parametrize("offset", [(0.7, 0.1, 0.05), (1.2, 0.9, -0.4), (0.0, 0.3, 1.5)])
def test_self_intersection_names_the_first_crossing_pair(offset):
    """Two overlapping spheres in one mesh cross along a curve: the check names the pair with
    the lowest indices among all crossing pairs, found here by brute force over every pair."""
    from endophoton import meshes

    v1, t1 = meshes.uv_sphere((0, 0, 0), 1.0, n_lat=8, n_lon=14)
    v2, t2 = meshes.uv_sphere(offset, 0.8, n_lat=7, n_lon=12)
    v = np.vstack([v1, v2]).astype(np.float32)
    t = np.vstack([t2 + len(v1), t1])  # the second sphere first: its triangles have the low indices
    pairs = _crossing_pairs(v, t)
    assert len(pairs) > 10, len(pairs)  # the spheres cross along a curve
    first = min(pairs)
    with pytest.raises(
        ValueError,
        match=rf"mesh intersects itself: mesh.triangles\[{first[0]}\] and mesh.triangles\[{first[1]}\] cross",
    ):
        _core.check_mesh("two spheres", v, t)
    # Apart, no pair crosses, and the check passes.
    v_apart = np.vstack([v1, v2 + np.float32(5.0)])
    assert _crossing_pairs(v_apart, t) == []
    distinct = len(np.unique(np.ascontiguousarray(v_apart).view(np.uint32), axis=0))  # by bits, as welded
    assert _core.check_mesh("apart", v_apart, t)["welded_vertices"] == distinct


@pytest.mark.parametrize(
    "kw,match",
    [
        (dict(max_path_cm=True), r"max_path_cm = True must be a finite number"),
        (dict(roulette_threshold=True), r"roulette_threshold = True must be a finite number"),
        (dict(roulette_chance="0.5"), r"roulette_chance = '0.5' must be a finite number"),
        (dict(time_budget_s=-1.0), r"time_budget_s = -1.0 must be in \[0.0, inf\]"),
        (dict(time_budget_s=float("nan")), r"time_budget_s = nan must be a finite number"),
        (dict(seed=1.5), r"seed = 1.5 must be an integer"),
        (dict(threads=2**31), r"threads = 2147483648 must be in \[0, 4096\]"),
        (dict(record_escapes=1), r"record_escapes = 1 must be true or false"),
    ],
)
def test_strict_types_in_the_api(kw, match):
    with pytest.raises(ValueError, match=match):
        ep.run(slab(1.0), DOWN, photons=10, **kw)


@pytest.mark.parametrize(
    "kw,match",
    [
        (dict(grids="g.vdb"), r"grids = 'g.vdb' must be an endophoton.GridRequest or a dict of its fields"),
        (dict(grids={"voxel": 0.1, "path": "g.vdb"}), r"grids.voxel is not a field of GridRequest"),
        (dict(grids={"path": "g.vdb"}), r"grids.voxel_size is missing"),
        (dict(grids={"voxel_size": -1.0, "path": "g.vdb"}), r"grids.voxel_size = -1.0 must be in"),
        (dict(photons=None, target={"rel_err": 0.1}), r"target.rel_err is not a field of Target"),
        (dict(photons=None, target=0.01), r"target = 0.01 must be an endophoton.Target"),
    ],
)
def test_request_objects_given_as_anything_else_are_named_errors(kw, match):
    with pytest.raises(ValueError, match=match):
        ep.run(slab(1.0), DOWN, **{"photons": 10, **kw})


def test_request_objects_may_be_dicts_of_their_fields(tmp_path):
    path = str(tmp_path / "g.vdb")
    a = ep.run(slab(1.0), DOWN, photons=300, seed=4, grids={"voxel_size": 0.1, "path": path})
    assert os.path.exists(path) and a.grid_absorbed_sum == pytest.approx(a.absorbed, rel=1e-9)
    b = ep.run(slab(1.0), DOWN, seed=4, target={"tally": "absorbed", "rel_error": 0.05}, max_photons=50_000)
    assert b.target_reached and b.absorbed_stderr <= 0.05 * b.absorbed


def test_run_cancelled_before_it_starts_says_it_has_no_estimate():
    token = ep.CancelToken()
    token.cancel()
    r = ep.run(slab(1.0), DOWN, photons=NEVER_ENDS, cancel=token)
    assert r.cancelled and r.stop_reason == "cancelled" and r.photons == 0
    assert any("no work unit finished" in w for w in r.warnings)
    assert_no_nan(r)


# ---------------------------------------------------------------- signals
def test_keyboard_interrupt_in_the_api_cleans_up_and_writes_no_grid(tmp_path):
    path = tmp_path / "never.vdb"

    def progress(done, total):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        ep.run(slab(1.0), DOWN, photons=NEVER_ENDS, progress=progress, grids=ep.GridRequest(0.1, str(path)))
    assert list(tmp_path.iterdir()) == []


def test_ctrl_c_on_the_cli_prints_a_cancelled_result_and_exits_130(tmp_path):
    """The run cannot finish; SIGINT is sent once the CLI reports progress, so the verdict
    does not depend on timing."""
    scene = tmp_path / "s.json"
    scene.write_text(json.dumps(_scene_doc()))
    proc = start_cli("run", scene, "--photons", NEVER_ENDS, "--progress")
    line = proc.stderr.readline()
    assert line.startswith("progress "), line
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=300)
    assert proc.returncode == 130, err
    data = json.loads(out)
    assert data["cancelled"] is True and data["stop_reason"] == "cancelled"
    assert "Traceback" not in err


# ---------------------------------------------------------------- tracebacks -> exit 2
def _scene_doc():
    return {
        "unit": "cm",
        "ambient_n": 1.0,
        "regions": [
            {
                "name": "polyp_7",
                "medium": {"mua": 1.0, "mus": 10.0, "g": 0.9, "n": 1.4},
                "box": {"min": [-1, -1, -1], "max": [1, 1, 0]},
            }
        ],
        "source": {"type": "pencil", "position": [0, 0, 1], "direction": [0, 0, -1]},
        "run": {"photons": 100},
    }


CLI_CASES = [  # (mutation of the document, expected text of the message)
    ("mus null", lambda d: d["regions"][0]["medium"].update(mus=None), "medium.mus = None"),
    ("mus list", lambda d: d["regions"][0]["medium"].update(mus=[1]), "medium.mus = [1]"),
    ("g inf", lambda d: d["regions"][0]["medium"].update(g=float("inf")), "medium.g = inf"),
    ("priority 2^31", lambda d: d["regions"][0].update(priority=2**31), "priority = 2147483648"),
    ("seed 2^64", lambda d: d["run"].update(seed=2**64), "run.seed = 18446744073709551616"),
    ("photons abc", lambda d: d["run"].update(photons="abc"), "run.photons = 'abc'"),
    ("max_path_cm true", lambda d: d["run"].update(max_path_cm=True), "run.max_path_cm = True"),
    ("roulette bool", lambda d: d["run"].update(roulette_chance=False), "run.roulette_chance = False"),
    ("roulette string", lambda d: d["run"].update(roulette_threshold="1e-4"), "run.roulette_threshold = '1e-4'"),
    ("deep nesting", "deep", "nested too deeply"),
    ("lone surrogate", lambda d: d["regions"][0].update(name="\ud800"), "lone surrogate"),
    ("fluorophores 5", lambda d: d["regions"][0].update(fluorophores=5), "fluorophores = 5"),
    ("short box.min", lambda d: d["regions"][0]["box"].update(min=[1, 2]), "box.min = [1, 2]"),
    (
        "eem is a directory",
        lambda d: d["regions"][0].update(fluorophores=[{"name": "f", "d": 0.1, "c": 0.1, "eem": "."}]),
        "fluorophores[0].eem = '.' is not a file",
    ),
]


@pytest.mark.parametrize("name,mutate,text", CLI_CASES, ids=[c[0] for c in CLI_CASES])
def test_bad_scene_files_exit_2_naming_the_field(tmp_path, capsys, name, mutate, text):
    path = tmp_path / "s.json"
    if mutate == "deep":  # 1000 levels: too deep for json.dumps itself, so written by hand
        path.write_text('{"regions": ' + '{"x": ' * 1000 + "{}" + "}" * 1000 + "}")
    else:
        d = _scene_doc()
        mutate(d)
        path.write_text(json.dumps(d))
    code = cli_main(["run", str(path)])
    err = capsys.readouterr().err
    assert code == 2, err
    assert text in err, err


@pytest.mark.parametrize(
    "args,text",
    [
        (["--photons", str(2**64 - 65_535)], "argument --photons"),
        (["--photons", "abc"], "argument --photons: 'abc' is not an integer"),
        (["--time-budget", "-1"], "argument --time-budget"),
        (["--time-budget", "nan"], "argument --time-budget"),
        (["--threads", "1e9"], "argument --threads"),
        (["--seed", "-1"], "argument --seed"),
    ],
)
def test_bad_cli_options_exit_2_naming_the_option(tmp_path, capsys, args, text):
    path = tmp_path / "s.json"
    path.write_text(json.dumps(_scene_doc()))
    with pytest.raises(SystemExit) as ei:
        cli_main(["run", str(path), *args])
    assert ei.value.code == 2
    assert text in capsys.readouterr().err


@pytest.mark.parametrize(
    "name,content,text",
    [
        (
            "trunc.ply",
            b"ply\nformat binary_little_endian 1.0\nelement vertex 8\nproperty float x\nproperty float y\n"
            b"property float z\nend_header\n\x00\x00",
            "malformed or truncated PLY",
        ),
        ("type.ply", b"ply\nformat ascii 1.0\nelement vertex 1\nproperty quux x\nend_header\n1\n", "unknown type"),
        ("fmt.ply", b"ply\nformat\nend_header\n", "'format' line has no format"),
        ("big.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 1e23\n", "face index '1e23' is not an integer"),
        ("wrap.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4294967297\n", "face index '4294967297' names no vertex"),
    ],
)
def test_bad_mesh_files_are_named_errors(tmp_path, capsys, name, content, text):
    (tmp_path / name).write_bytes(content)
    d = _scene_doc()
    del d["regions"][0]["box"]
    d["regions"][0]["mesh"] = name
    path = tmp_path / "s.json"
    path.write_text(json.dumps(d))
    assert cli_main(["run", str(path)]) == 2
    err = capsys.readouterr().err
    assert "region 'polyp_7'" in err and name in err and text in err, err


_PLY_CUBE = (
    b"ply\nformat ascii 1.0\nelement vertex 8\nproperty float x\nproperty float y\nproperty float z\n",
    b"0 0 0\n1 0 0\n0 1 0\n1 1 0\n0 0 1\n1 0 1\n0 1 1\n1 1 1\n",
)
_PLY_BIN3 = (
    b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
    b"property float z\n"
)


@pytest.mark.parametrize(
    "content,text",
    [
        (  # a count no file can hold: refused before any item is read (it used to loop ~forever)
            _PLY_CUBE[0]
            + b"element face 1000000000000000000\nproperty list uchar int vertex_indices\nend_header\n"
            + _PLY_CUBE[1],
            "element 'face' count 1000000000000000000 does not fit the 0 values left",
        ),
        (
            _PLY_BIN3.replace(b"vertex 3", b"vertex 1000000000000000000") + b"end_header\n" + bytes(36),
            "element 'vertex' count 1000000000000000000 does not fit the 36 bytes left",
        ),
        (
            _PLY_BIN3 + b"element face 1\nproperty list uint uint vertex_indices\nend_header\n" + bytes(36)
            # one face whose list claims 4e9 indices
            + (4_000_000_000).to_bytes(4, "little") + bytes(12),
            "list 'vertex_indices' length 4000000000 does not fit the 12 bytes left",
        ),
        (
            _PLY_CUBE[0]
            + b"element face 1\nproperty list int int vertex_indices\nend_header\n"
            + _PLY_CUBE[1]
            + b"-3 0 1 2\n",
            "list 'vertex_indices' length -3 does not fit",
        ),
        (
            _PLY_CUBE[0]
            + b"element face 1\nproperty list uchar int vertex_indices\nend_header\n"
            + _PLY_CUBE[1]
            + b"3 -1 1 2\n",
            "face 0: vertex index -1 is negative",
        ),
        (
            _PLY_CUBE[0] + b"element face 1\nproperty list float int vertex_indices\nend_header\n" + _PLY_CUBE[1],
            "'list float int vertex_indices' must be 'property list COUNT_TYPE ITEM_TYPE NAME'",
        ),
        (
            b"ply\nformat ascii 1.0\nelement vertex 1\nproperty list uchar float x\nproperty float y\n"
            b"property float z\nend_header\n1 0 0 0\n",
            "vertex property 'x' is a list",
        ),
        (_PLY_CUBE[0] + b"element junk " + b"9" * 5000 + b"\nend_header\n", "element 'junk' count 9999"),
    ],
    ids=[
        "ascii-face-1e18",
        "binary-vertex-1e18",
        "binary-list-4e9",
        "negative-list",
        "negative-index",
        "float-list-count",
        "vertex-x-list",
        "5000-digit-count",
    ],
)
def test_ply_counts_beyond_the_file_are_named_errors(tmp_path, content, text):
    path = tmp_path / "bad_count.ply"
    path.write_bytes(content)
    with pytest.raises(ValueError) as ei:
        ep.load_mesh(str(path))
    msg = str(ei.value)
    assert repr(str(path)) in msg and text in msg, msg


def test_ply_elements_without_properties_are_skipped_and_vertex_lists_are_read(tmp_path):
    """An element with no properties holds no bytes whatever its count (it used to be looped over
    10^18 times); a list property on the vertices is read past, not misread as the next number."""
    path = tmp_path / "junk.ply"
    path.write_bytes(
        _PLY_CUBE[0]
        + b"element junk 1000000000000000000\nelement face 1000000000000000000\n"
        + b"element face 1\nproperty list uchar int vertex_indices\nend_header\n"
        + _PLY_CUBE[1]
        + b"3 0 1 2\n"
    )
    v, t = ep.load_mesh(str(path))
    assert v.shape == (8, 3) and v[7].tolist() == [1, 1, 1] and t.tolist() == [[0, 1, 2]]
    path = tmp_path / "vlist.ply"
    path.write_bytes(
        b"ply\nformat ascii 1.0\nelement vertex 3\nproperty list uchar float extra\nproperty float x\n"
        b"property float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\n"
        b"end_header\n2 9 9 0 0 0\n0 1 0 0\n1 9 0 1 0\n3 0 1 2\n"
    )
    v, t = ep.load_mesh(str(path))
    assert v.tolist() == [[0, 0, 0], [1, 0, 0], [0, 1, 0]] and t.tolist() == [[0, 1, 2]]
    path = tmp_path / "vlist.bin.ply"
    path.write_bytes(
        _PLY_BIN3.replace(b"property float x", b"property list uchar int extra\nproperty float x")
        + b"end_header\n"
        + b"".join(bytes([k]) + bytes(4 * k) + np.array([k, 2 * k, 3 * k], dtype="<f4").tobytes() for k in range(3))
    )
    v, _ = ep.load_mesh(str(path))
    assert v.tolist() == [[0, 0, 0], [1, 2, 3], [2, 4, 6]]


@pytest.mark.parametrize("path", ["/tmp", "/dev/zero"])
def test_mesh_path_that_is_not_a_regular_file_says_so(path):
    with pytest.raises(ValueError) as ei:
        ep.load_mesh(path)
    assert f"mesh = {path!r}: not a regular file" in str(ei.value)


def test_zero_weight_escapes_are_not_records():
    """A clear region with mua = 1e10 cm^-1: the transmitted weight exp(-1e10) is exactly 0 in
    double, so no packet carries weight out and no record may be stored (a zero-weight record
    used to count towards store N)."""
    s = slab(1.0, medium=ep.Medium(mua=1e10, mus=0.0, g=0.0, n=1.0))
    r = ep.run(s, DOWN, photons=100, seed=1)
    assert r.transmittance == 0.0 and r.absorbed == 1.0
    assert len(r.escapes["weight"]) == 0


@pytest.mark.parametrize("corner", [(1, 2), (True, 0, 0), "abc", [[0, 0, 0]]])
def test_short_or_bad_box_corner_names_the_field_in_the_api(corner):
    s = ep.Scene("cm")
    with pytest.raises(ValueError, match=r"region 'b': box.min = .* must be 3 numbers"):
        s.add_box("b", corner, (1, 1, 1), TISSUE)


# ---------------------------------------------------------------- input validation audit
def _raises_naming(make, text):
    """``make()`` raises ValueError whose message contains ``text``; returns the message."""
    with pytest.raises(ValueError) as ei:
        make()
    assert text in str(ei.value), str(ei.value)
    return str(ei.value)


HUGE = 10**400  # a Python int no float holds
HUGE_SHOWN = "1.00000e+400"


@pytest.mark.parametrize(
    "make,field",
    [
        (lambda: ep.Medium(mua=HUGE), "medium.mua"),
        (lambda: ep.Medium(g=-HUGE), "medium.g"),
        (lambda: ep.Scene(ambient_n=HUGE), "scene.ambient_n"),
        (lambda: ep.Scene(cache_store_mb=HUGE), "scene.cache_store_mb"),
        (lambda: ep.PencilSource(position=[HUGE, 0, 0]), "source.position"),
        (lambda: ep.DiskSource(radius=HUGE), "source.radius"),
        (lambda: ep.EndoscopeRig.from_beta(HUGE, 2.0), "rig.beta_deg"),
        (lambda: ep.EndoscopeRig.from_beta(10.0, HUGE), "rig.distance"),
        (lambda: ep.EndoscopeRig(head_diameter_mm=HUGE), "rig.head_diameter_mm"),
        (lambda: ep.Camera((0, 0, 1), (0, 0, -1), (0, 1, 0), fov_deg=HUGE), "camera.fov_deg"),
        (lambda: ep.Camera((0, 0, 1), (0, 0, -1), (0, 1, 0), aperture_radius=HUGE), "camera.aperture_radius"),
        (lambda: ep.layered_slab([(TISSUE, HUGE)]), "thickness"),
        (lambda: ep.layered_slab([(TISSUE, 1.0)], top=HUGE), "top"),
        (lambda: ep.run(slab(1.0), DOWN, photons=10, max_path_cm=HUGE), "max_path_cm"),
        (lambda: ep.run(slab(1.0), DOWN, photons=HUGE), "photons"),
    ],
)
def test_ints_beyond_the_float_range_are_named_short_errors(make, field):
    with pytest.raises(ValueError) as ei:
        make()
    msg = str(ei.value)
    assert field + " = " in msg and HUGE_SHOWN in msg, msg
    assert len(msg) < 300, msg  # not 400 digits


@pytest.mark.parametrize("scalar", [np.float32, np.float64, np.int64, np.int32, np.uint8])
def test_numpy_scalars_are_numbers_and_become_python_floats(scalar):
    m = ep.Medium(mua=scalar(1), mus=scalar(10), g=np.float32(0.9), n=np.float32(1.3))
    assert all(type(getattr(m, f)) is float for f in ("mua", "mus", "g", "n"))
    assert (m.mua, m.mus, m.n) == (1.0, 10.0, pytest.approx(1.3))
    s = ep.Scene(ambient_n=np.float32(1.3))  # 1.2999999523..., still in [1, 100]
    assert type(s.ambient_n) is float and s.ambient_n == pytest.approx(1.3)
    rig = ep.EndoscopeRig.from_beta(scalar(10), scalar(2), camera_fov_deg=scalar(100))
    assert type(rig.beta_deg) is float and rig.beta_deg == 10.0 and type(rig.camera_fov_deg) is float
    cam = ep.Camera((0, 0, 1), (0, 0, -1), (0, 1, 0), fov_deg=scalar(40))
    assert type(cam.fov_deg) is float and cam.fov_deg == 40.0
    layered = ep.layered_slab([(m, scalar(2))], width=scalar(4))
    assert layered.regions[0].vertices[:, 2].min() == -2.0 and layered.regions[0].vertices[:, 0].max() == 2.0
    assert ep.run(layered, DOWN, photons=10, max_path_cm=scalar(100)).photons == 10


@pytest.mark.parametrize(
    "make,text",
    [
        (lambda: ep.Medium(mua=np.bool_(True)), "medium.mua = True must be a number"),
        (lambda: ep.Medium(n=np.float32(0.5)), "medium.n = 0.5 must be in [1, 100]"),
        (lambda: ep.Scene(ambient_n=np.float32(0.5)), "scene.ambient_n = 0.5 must be a finite number in [1, 100"),
        (lambda: ep.EndoscopeRig.from_beta(np.float32(90), 2), "rig.beta_deg = 90.0 must be a finite angle"),
        (lambda: ep.DiskSource(radius=np.float32(-1)), "source.radius = -1.0 must be a finite number >= 0"),
    ],
)
def test_bad_numpy_scalars_are_named_by_their_value(make, text):
    _raises_naming(make, text)


@pytest.mark.parametrize(
    "kw,text",
    [
        (dict(source=None), "source = None must be an endophoton source"),
        (dict(source={}), "source = {} must be an endophoton source"),
        (dict(source=5), "source = 5 must be an endophoton source"),
        (dict(cancel=5), "cancel = 5 must be None or an endophoton.CancelToken"),
        (dict(cancel=True), "cancel = True must be None or an endophoton.CancelToken"),
        (dict(progress=5), "progress = 5 must be None or a callable"),
        (dict(progress="bar"), "progress = 'bar' must be None or a callable"),
    ],
)
def test_run_names_a_bad_source_progress_or_cancel(kw, text):
    kw = {"source": DOWN, **kw}
    _raises_naming(lambda: ep.run(slab(1.0), photons=10, **kw), text)


@pytest.mark.parametrize(
    "make,text",
    [
        (lambda: ep.PencilSource(position={}), "source.position = {} must be 3 finite numbers"),
        (lambda: ep.PencilSource(position="abc"), "source.position = 'abc' must be 3 finite numbers"),
        (lambda: ep.PencilSource(position=[1j, 0, 0]), "source.position = [1j, 0, 0] must be 3 finite numbers"),
        (lambda: ep.ConeSource(direction=[[0, 0], -1]), "source.direction = [[0, 0], -1] must be 3 finite numbers"),
        (lambda: ep.EndoscopeRig(transform={}), "rig.transform = {} must be a finite 4x4 matrix"),
        (
            lambda: ep.EndoscopeRig(transform=[[1, 0, 0, 0], [0, 1, 0], [0, 0, 1, 0], [0, 0, 0, 1]]),
            "rig.transform = [[1, 0, 0, 0], [0, 1, 0], [0, 0, 1, 0], [0, 0, 0, 1]] must be a finite 4x4 matrix",
        ),
    ],
)
def test_vectors_and_transforms_that_are_not_numbers_are_named(make, text):
    _raises_naming(make, text)


@pytest.mark.parametrize(
    "args,kw,text",
    [
        (([(TISSUE, 1), (TISSUE, 1)],), dict(names=["a"]), "names = ['a'] must be a list of 2 names"),
        (([(TISSUE, 1)],), dict(names="a"), "names = 'a' must be a list of 1 names"),
        (([TISSUE],), {}, "layers[0] = Medium("),
        (([(TISSUE, 1, 2)],), {}, "layers[0] = ("),
        ((5,), {}, "layers = 5 must be a list of (Medium, thickness) pairs"),
        (([(TISSUE, 1)],), dict(width="x"), "width = 'x' must be a finite number"),
        (([(TISSUE, 1)],), dict(width=-1.0), "width = -1.0 must be in (0.0, inf]"),
        (([(TISSUE, "1")],), {}, "region 'layer1': thickness = '1' must be a positive number"),
    ],
)
def test_layered_slab_names_bad_layers_names_and_width(args, kw, text):
    msg = _raises_naming(lambda: ep.layered_slab(*args, **kw), text)
    if "layers[0]" in text:
        assert "must be a (Medium, thickness) pair" in msg


@pytest.mark.parametrize("scale,shown", [(1e39, "1e+39"), (-3.5e38, "-3.5e+38")])
def test_vertices_beyond_the_float32_range_are_refused_at_add_mesh(scale, shown):
    v, t = cube_mesh((0, 0, 0), (1, 1, 1))
    v = np.asarray(v, dtype=np.float64) * scale
    i, k = map(int, np.argwhere(v != 0)[0])
    s = ep.Scene("cm")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no RuntimeWarning on the way
        with pytest.raises(ValueError) as ei:
            s.add_mesh("far", v, t, TISSUE)
    assert f"region 'far': mesh.vertices[{i}][{k}] = {shown} exceeds the float32 range" in str(ei.value)
    assert s.regions == []


def test_complex_vertices_are_refused_by_dtype():
    v, t = cube_mesh((0, 0, 0), (1, 1, 1))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no ComplexWarning on the way
        with pytest.raises(ValueError) as ei:
            ep.Scene("cm").add_mesh("c", np.asarray(v, dtype=np.float64) * (1 + 0j), t, TISSUE)
    assert "region 'c': mesh.vertices must hold real numbers, got dtype complex128" in str(ei.value)


def test_a_nul_byte_in_the_grid_path_is_refused_and_nothing_is_written(tmp_path):
    path = str(tmp_path / "x\x00.vdb")
    with pytest.raises(ValueError) as ei:
        ep.run(slab(1.0), DOWN, photons=10, grids=dict(voxel_size=0.5, path=path))
    assert str(ei.value) == f"grids.path = {path!r} contains a NUL byte"
    with pytest.raises(ValueError, match=r"grids.path = .* contains a NUL byte"):
        ep.GridRequest(0.5, tmp_path / "y\x00.vdb")
    assert list(tmp_path.iterdir()) == []


def test_a_nul_byte_in_an_output_path_is_refused_by_the_atomic_writer(tmp_path):
    from endophoton.io import write_json

    path = str(tmp_path / "r\x00.json")
    with pytest.raises(ValueError) as ei:
        write_json(path, {"a": 1})
    assert str(ei.value) == f"path = {path!r} contains a NUL byte"
    assert list(tmp_path.iterdir()) == []


def test_require_finite_descends_into_lists_and_tuples():
    from endophoton.run import _require_finite

    _require_finite({"a": [1.0, (2.0, {"b": [3.0]})], "escapes": [float("nan")]})  # finite; escapes skipped
    with pytest.raises(RuntimeError) as ei:
        _require_finite({"a": [1.0, {"b": (2.0, float("nan"))}]})
    assert "result.a[1].b[1] = nan is not finite" in str(ei.value)
    with pytest.raises(RuntimeError, match=r"result.c\[0\] = inf is not finite"):
        _require_finite({"c": [float("inf")]})


@pytest.mark.parametrize("bad", ["ab", (0, 0), (256,), (256, 256, 3), (256.0, 256), (True, 2), (9000, 10), None, {}])
def test_rig_camera_resolution_is_checked_by_name(bad):
    with pytest.raises(ValueError, match=r"rig\.camera_resolution = .* must be \(width, height\) in pixels"):
        ep.EndoscopeRig(camera_resolution=bad)


def test_rig_takes_numpy_resolution_and_body():
    rig = ep.EndoscopeRig(camera_resolution=np.array([64, 48]), body=np.bool_(False))
    assert rig.camera_resolution == (64, 48) and type(rig.camera_resolution[0]) is int
    assert rig.body is False


def test_box_corner_beyond_float_range_and_mesh_path_none_are_named():
    with pytest.raises(ValueError, match=r"box\.max = \(1, 1, 1\.0+e\+400\) must be 3 numbers"):
        ep.box_mesh((0, 0, 0), (1, 1, 10**400))
    with pytest.raises(ValueError, match=r"box\.max = .*e\+400"):
        ep.Scene("cm").add_box("b", (0, 0, 0), (1, 1, 10**400), ep.Medium(mua=1, mus=1, g=0, n=1))
    with pytest.raises(ValueError, match=r"mesh = None must be a file path"):
        ep.load_mesh(None)
