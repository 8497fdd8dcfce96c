"""The scene inputs the package computes have the same bits on every x86-64 machine (endophoton.det;
docs/numerics.md, "Elementary functions"; docs/distributed.md, "Any instruction set").

det_inputs_digest.py builds the native inputs of a set of scenes (the seed tissue; the colon bench
scene, bench/scenes/colon.json read as data; the spectral colon with its media presets; the
endoscope's pose from beta at the paper's tilts and at tilts where glibc's sin or cos round
differently by processor; cone, disk and pencil sources; media at 305 wavelengths; generated
spheres, ellipsoids and the sweep's default flat scenes; the camera tally's request of runs on the
colon with view=, from the rig's camera and from SCENE.json cameras) in two processes:

- this machine as it is, and
- an old machine (OLD_MACHINE below): glibc's libm without FMA and AVX (GLIBC_TUNABLES), numpy's
  float64 loops without any of the features it dispatches on above its SSE3 baseline
  (NPY_DISABLE_CPU_FEATURES, numpy 1.24's spelling: names separated by spaces), and OpenBLAS's
  oldest x86-64 kernel (OPENBLAS_CORETYPE=Prescott),

and asks for the same sha-256 of every case. Guards show that the environment takes effect:
numpy's np.sin and math.exp over fixed arguments give other bits in the second process (where this
processor has the features they dispatch on), so the test cannot pass by comparing one machine with
itself. The BLAS guard needs OpenBLAS: where numpy runs Debian's reference BLAS (libblas3, one
compiled code path for every processor, as on this machine as set up by scripts/setup.sh), the
test runs both processes with OpenBLAS's libblas.so.3 when Debian's libopenblas0-pthread is on the
machine (LD_LIBRARY_PATH, the system left as it is), and otherwise has no BLAS whose kernel
OPENBLAS_CORETYPE could change: it then checks the other two guards only. (With Debian's OpenBLAS
0.3.21 unpacked beside the system and put first by LD_LIBRARY_PATH, the BLAS guard differed here,
Cooperlake's kernel against Prescott's, and the inputs did not.) Before endophoton.det, the old
machine's spectral colon, media and rig poses differed here; before the view's camera used it, the
colon view's pixel solid angles (np.arctan) and channel tables (np.exp in the colour-matching
functions) did.
"""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest

from endophoton import _core, det

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))
DIGEST = os.path.join(os.path.dirname(os.path.abspath(__file__)), "det_inputs_digest.py")

#: numpy 1.24's dispatch targets above its x86-64 baseline (SSE SSE2 SSE3), all of which
#: NPY_DISABLE_CPU_FEATURES may name; numpy refuses to disable a baseline feature.
NUMPY_DISPATCHED = (
    "SSSE3 SSE41 POPCNT SSE42 AVX F16C FMA3 AVX2 AVX512F AVX512CD AVX512_SKX AVX512_CLX AVX512_CNL AVX512_ICL"
)
#: An x86-64 machine without AVX and FMA, as far as libm, numpy and OpenBLAS can tell.
OLD_MACHINE = {
    "GLIBC_TUNABLES": "glibc.cpu.hwcaps=-AVX2,-FMA,-AVX512F,-AVX,-FMA4",
    "NPY_DISABLE_CPU_FEATURES": NUMPY_DISPATCHED,
    "OPENBLAS_CORETYPE": "Prescott",
}
#: Where Debian's libopenblas0-pthread puts its libblas.so.3 (used only if numpy does not run OpenBLAS).
OPENBLAS_DIR = "/usr/lib/x86_64-linux-gnu/openblas-pthread"


def _cpu_flags() -> set:
    with open("/proc/cpuinfo", encoding="utf-8") as f:
        for line in f:
            if line.startswith("flags"):
                return set(line.split(":", 1)[1].split())
    return set()


def _numpy_dispatches() -> bool:
    """Whether numpy runs any of its dispatched kernels above the baseline on this processor."""
    from numpy.core._multiarray_umath import __cpu_features__

    return any(__cpu_features__.get(f, False) for f in NUMPY_DISPATCHED.split())


def _digests(env: dict) -> dict:
    package_parent = os.path.join(ROOT, "python")
    out = subprocess.run(
        [sys.executable, DIGEST],
        env=dict(os.environ, PYTHONPATH=package_parent, OPENBLAS_NUM_THREADS="1", **env),
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 0, out.stderr[-3000:]
    d = json.loads(out.stdout)
    assert d["package"] == os.path.join(package_parent, "endophoton"), "the digest imported another package"
    return d


def _with_openblas(env: dict) -> dict:
    """``env`` plus LD_LIBRARY_PATH to Debian's OpenBLAS where it is installed but not numpy's BLAS."""
    if os.path.isfile(os.path.join(OPENBLAS_DIR, "libblas.so.3")):
        return dict(
            env, LD_LIBRARY_PATH=os.pathsep.join(filter(None, [OPENBLAS_DIR, os.environ.get("LD_LIBRARY_PATH")]))
        )
    return env


@pytest.mark.slow  # two subprocesses build every case's inputs: about 1.7 s
def test_inputs_have_the_same_bits_on_an_old_machine():
    here, old = _digests(_with_openblas({})), _digests(_with_openblas(OLD_MACHINE))
    # The guards: the old machine's environment is in force (where this processor is newer).
    if "fma" in _cpu_flags():
        assert here["guards"]["math_exp"] != old["guards"]["math_exp"], "GLIBC_TUNABLES did not take effect"
    if _numpy_dispatches():
        assert here["guards"]["numpy_sin"] != old["guards"]["numpy_sin"], "NPY_DISABLE_CPU_FEATURES did not take effect"
    assert here["blas"] == old["blas"]
    if here["blas"] == "openblas" and "avx2" in _cpu_flags():
        assert here["guards"]["blas_dot"] != old["guards"]["blas_dot"], "OPENBLAS_CORETYPE did not take effect"
    assert len(here["inputs"]) == 8
    differ = sorted(k for k in here["inputs"] if here["inputs"][k] != old["inputs"][k])
    assert differ == [], f"inputs with other bits on the old machine: {differ}"


def _within_one_ulp(got, want) -> bool:
    want = np.asarray(want)
    return bool(np.all(np.abs(got - want) <= np.spacing(np.abs(want))))


def test_det_functions_are_within_one_ulp_of_libm():
    """det's functions against glibc's (math: both within about half an ulp to 1 ulp of the true value;
    numpy's AVX-512 sin and cos are up to 3 ulp from SLEEF's, so glibc is the reference)."""
    x = np.random.default_rng(5).uniform(-10.0, 10.0, 2000)
    pairs = ((det.sin, math.sin), (det.cos, math.cos), (det.tan, math.tan), (det.atan, math.atan), (det.exp, math.exp))
    for f, ref in pairs:
        assert _within_one_ulp(f(x), [ref(v) for v in x.tolist()]), f.__name__
    w = np.linspace(250.0, 1000.0, 376) / 500.0  # lambda / 500 nm over Prahl's table
    assert _within_one_ulp(det.log(w), [math.log(v) for v in w.tolist()])
    assert _within_one_ulp(det.pow(w, -1.286), [v**-1.286 for v in w.tolist()])
    # Numbers in, floats out; arrays keep their shape; pow broadcasts.
    assert isinstance(det.sin(0.5), float) and det.sin(0.0) == 0.0 and det.cos(0.0) == 1.0
    assert det.tan(0.0) == 0.0 and det.atan(1.0) == math.pi / 4 and det.atan(np.inf) == math.pi / 2
    assert det.log(10.0) == math.log(10.0)  # ln 10 correctly rounded by both
    assert det.pow(np.ones((2, 3)), np.array([0.5, 1.0, 2.0])).shape == (2, 3)
    assert _core.det_sin(np.zeros((4, 0))).shape == (4, 0)
    with pytest.raises(ValueError, match="same shape"):
        _core.det_pow(np.ones(2), np.ones(3))


def test_det_products_add_in_a_fixed_order():
    rng = np.random.default_rng(6)
    A, B, v = rng.uniform(-1, 1, (3, 3)), rng.uniform(-1, 1, (3, 3)), rng.uniform(-1, 1, 3)
    left_to_right = [[(A[i, 0] * B[0, j] + A[i, 1] * B[1, j]) + A[i, 2] * B[2, j] for j in range(3)] for i in range(3)]
    assert det.matmul(A, B).tolist() == left_to_right
    assert det.matvec(A, v).tolist() == [(A[i, 0] * v[0] + A[i, 1] * v[1]) + A[i, 2] * v[2] for i in range(3)]
    assert det.dot(v, v) == (v[0] * v[0] + v[1] * v[1]) + v[2] * v[2]
    assert det.norm(np.array([[3.0, 4.0, 0.0], [0.0, 0.0, -2.0]])).tolist() == [5.0, 2.0]
    M = rng.uniform(-1, 1, (4, 4))
    assert np.array_equal(det.matmul(M, np.eye(4)), M)  # a transform times the identity, exactly
    with pytest.raises(ValueError, match="matrix product"):
        det.matmul(np.ones((3, 3)), np.ones((4, 4)))
