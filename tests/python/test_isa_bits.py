"""The same seed gives the same bits on every x86-64 machine (issue 39; docs/distributed.md,
"Any instruction set").

A machine differs from this one in two ways that can reach a result's bits: the instruction set
the engine was built for (the set-up builds with AVX2 where the machine has it, so the 4-lane
vectors of vecmath.h run in 256-bit registers; a build for baseline x86-64 runs them as SSE2
pairs), the libm variant glibc picks at load time (with or without FMA), and the kernels Embree
picks (SSE2 to AVX-512). This test builds the engine twice more, for baseline x86-64 and with
AVX-512 (where this processor has it), and runs one set of cases (isa_digest.py: seed tissue, the
MCML slab, a disk-and-cone source over a clear layer, the seed tissue in float32 lanes with records,
the colon with grids and records on 1 and 2 threads, the colon's emission grids alone (in the
spectral lanes), the colon's camera tally) with

- this build, this machine's libm and Embree's best kernels (the reference),
- this build with glibc's pre-AVX libm (GLIBC_TUNABLES below: the libm of an old machine),
- this build with Embree's SSE2 kernels (ENDOPHOTON_EMBREE_ISA),
- the baseline x86-64 build with both (an old machine),
- the AVX-512 build (a newer machine's build),

and asks for the same digests from all five: every tally and standard error, the exit records,
the camera tally, and every voxel of every grid. Last, a Dask cluster whose one worker is the old
machine traces runs that this process merges, and gets the bits of the same runs traced here.
"""
from __future__ import annotations

import functools
import json
import os
import shutil
import subprocess
import sys

import pytest

import endophoton as ep
from bit_digest import cpu_flags

pytestmark = pytest.mark.slow

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))
DIGEST = os.path.join(os.path.dirname(os.path.abspath(__file__)), "isa_digest.py")
BUILDS = os.path.join(ROOT, "build", "isa")

# glibc's tunable that hides these processor features from its own dispatch: libm then runs its
# SSE2 code, as on an x86-64 machine without AVX and FMA.
OLD_LIBM = {"GLIBC_TUNABLES": "glibc.cpu.hwcaps=-AVX2,-FMA,-AVX512F,-AVX,-FMA4"}
# An old machine: that libm, Embree's SSE2 kernels (native/embree_device.h) and the 4-lane SSE2 kernel of
# the float32 lanes (native/lane_block.h).
OLD_MACHINE = dict(OLD_LIBM, ENDOPHOTON_EMBREE_ISA="sse2", ENDOPHOTON_LANE_ISA="sse2")

# Arguments whose glibc exp differs by one unit between the FMA and the SSE2 variant (glibc 2.36,
# found by scanning 300,000 arguments): where this machine has FMA, they show that OLD_LIBM is in
# force, so that the comparison below is not between two runs of the same libm.
EXP_PROBES = ["-0x1.1d10b1feeb2d0p-3", "-0x1.281f969e3c968p-2", "-0x1.4b0f49491f2dcp-1"]

VARIANTS = {
    "x86-64": {"cmake": ["-DENDOPHOTON_HOST_ISA=OFF"], "cpu": [], "env": OLD_MACHINE},
    "avx512": {
        "cmake": ["-DCMAKE_CXX_FLAGS=-mavx512f -mavx512vl -mavx512dq -mavx512bw"],
        "cpu": ["avx512f", "avx512vl", "avx512dq", "avx512bw"],
        "env": {},
    },
}


@functools.lru_cache(maxsize=None)
def _build(name: str) -> str:
    """The package of variant ``name``: a copy of python/endophoton whose native module and writer
    library are built with the variant's flags (kept in build/isa/<name> between test runs; built
    once per test session, for the variant's digests and the cluster's worker alike)."""
    v = VARIANTS[name]
    here = os.path.join(BUILDS, name)
    pkg = os.path.join(here, "python", "endophoton")
    shutil.rmtree(os.path.join(here, "python"), ignore_errors=True)
    shutil.copytree(
        os.path.join(ROOT, "python", "endophoton"),
        pkg,
        ignore=shutil.ignore_patterns("*.so", "*.so.*", "__pycache__"),
    )
    for d in ("docs", "data"):  # the schema and tables, where an uninstalled package looks for them
        link = os.path.join(here, d)
        if not os.path.lexists(link):
            os.symlink(os.path.join(ROOT, d), link)
    configure = [
        "cmake",
        "-S",
        ROOT,
        "-B",
        os.path.join(here, "cmake"),
        "-DCMAKE_BUILD_TYPE=Release",
        "-DENDOPHOTON_BUILD_TESTS=OFF",
        f"-DPython3_EXECUTABLE={sys.executable}",
        f"-DENDOPHOTON_MODULE_OUTPUT_DIR={pkg}",
    ] + v["cmake"]
    for cmd in (
        configure,
        ["cmake", "--build", os.path.join(here, "cmake"), "--target", "_core", "endophoton_vdb", "-j", "2"],
    ):
        out = subprocess.run(cmd, capture_output=True, text=True)
        assert out.returncode == 0, f"{' '.join(cmd)}\n{out.stdout[-3000:]}\n{out.stderr[-3000:]}"
    return os.path.dirname(pkg)


def _digests(package_parent: str, env: dict, tmp_path, tag: str) -> dict:
    out_dir = tmp_path / tag
    out_dir.mkdir()
    out = subprocess.run(
        [sys.executable, DIGEST, str(out_dir)],
        env=dict(os.environ, PYTHONPATH=package_parent, **env),
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert out.returncode == 0, out.stderr[-3000:]
    d = json.loads(out.stdout)
    assert d.pop("_package") == os.path.join(package_parent, "endophoton"), f"{tag} imported another package"
    return d


def _exp_bits(env: dict) -> list:
    code = "import math; print(*[math.exp(float.fromhex(x)).hex() for x in %r])" % (EXP_PROBES,)
    out = subprocess.run([sys.executable, "-c", code], env=dict(os.environ, **env), capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    return out.stdout.split()


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    return _digests(os.path.join(ROOT, "python"), {}, tmp_path_factory.mktemp("ref"), "reference")


def test_old_libm_is_in_force():
    """Where this processor has FMA, OLD_LIBM makes glibc's exp give other bits at the probes:
    the runs below under OLD_LIBM use the other libm."""
    if "fma" not in cpu_flags():
        pytest.skip("this processor has no FMA: its own libm is already the old machine's")
    assert _exp_bits({}) != _exp_bits(OLD_LIBM)


def test_thread_counts_give_the_same_bits(reference):
    assert reference["seed_tissue/1"] == reference["seed_tissue/2"]
    assert reference["colon_grids_records/1"] == reference["colon_grids_records/2"]


def test_the_old_machines_libm_gives_the_same_bits(reference, tmp_path):
    assert _digests(os.path.join(ROOT, "python"), OLD_LIBM, tmp_path, "old_libm") == reference


def test_the_old_machines_embree_kernels_give_the_same_bits(reference, tmp_path):
    env = {"ENDOPHOTON_EMBREE_ISA": "sse2"}
    assert _digests(os.path.join(ROOT, "python"), env, tmp_path, "embree_sse2") == reference


@pytest.mark.parametrize("name", sorted(VARIANTS))
def test_other_builds_give_the_same_bits(name, reference, tmp_path):
    v = VARIANTS[name]
    missing = [f for f in v["cpu"] if f not in cpu_flags()]
    if missing:
        pytest.skip(f"this processor lacks {', '.join(missing)}: the {name} build cannot run here")
    assert _digests(_build(name), v["env"], tmp_path, name) == reference


@pytest.fixture
def old_machine_worker(tmp_path):
    """A Dask scheduler in this process and one worker process that is an old machine: the baseline
    x86-64 build, glibc's pre-AVX libm and Embree's SSE2 kernels. Yields a client of that cluster."""
    distributed = pytest.importorskip("distributed")
    package_parent = _build("x86-64")
    cluster = distributed.LocalCluster(n_workers=0, processes=True, dashboard_address=":0")
    log = open(tmp_path / "worker.log", "w")
    worker = subprocess.Popen(
        [sys.executable, "-m", "distributed.cli.dask_worker", cluster.scheduler_address]
        + ["--nthreads", "1", "--no-nanny", "--no-dashboard"],
        env=dict(os.environ, PYTHONPATH=package_parent, **OLD_MACHINE),
        stdout=log,
        stderr=subprocess.STDOUT,
    )
    try:
        with distributed.Client(cluster) as client:
            try:
                client.wait_for_workers(1, timeout=120)
            except TimeoutError:
                raise AssertionError("the old machine's worker did not join:\n" + (tmp_path / "worker.log").read_text())
            yield client, package_parent
    finally:
        worker.terminate()
        worker.wait(timeout=60)
        log.close()
        cluster.close()


def test_a_cluster_worker_on_an_old_machine_gives_the_same_bits(old_machine_worker, tmp_path):
    """The promise itself (docs/distributed.md): this machine's client merges the chunks that an old
    machine traced into the bits of a run on this machine alone. Two cases: the disk-and-cone source
    over a clear layer (whose bits depended on glibc's variant before det_math.h), and the colon with
    its four grids and records (the voxels arrive as exact fixed-point sums)."""
    from isa_digest import cone_over_clear_layer, digest, scene_file

    client, package_parent = old_machine_worker

    def who():
        import os
        import endophoton

        return os.path.dirname(endophoton._core.__file__), os.environ.get("GLIBC_TUNABLES")

    ((_, (worker_package, tunables)),) = client.run(who).items()
    assert (worker_package, tunables) == (os.path.join(package_parent, "endophoton"), OLD_LIBM["GLIBC_TUNABLES"])
    cases = {"cone": cone_over_clear_layer(), "colon": scene_file("bench", "scenes", "colon.json")}
    for name, (scene, source) in cases.items():
        results = {}
        for where, kw in (("here", {"threads": 2}), ("old", {"client": client, "chunk_units": 4})):
            path = str(tmp_path / f"{name}_{where}.vdb")
            grids = ep.GridRequest(voxel_size=5e-4, path=path) if name == "colon" else None
            run = ep.run(scene, source, photons=3000 if name == "colon" else 20000, seed=7, grids=grids, **kw)
            results[where] = digest(run, path if grids else None)
        assert results["old"] == results["here"], name
