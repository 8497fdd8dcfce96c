"""Arithmetic with the same bits on every x86-64 machine, for the scene inputs the package computes.

The engine's promise, the same seed gives the same bits on any machine (docs/distributed.md, "Any
instruction set"), needs its inputs to be the same bits too. Three things the package would otherwise
compute them with pick their code by the processor they run on, and the variants round differently
now and then (docs/numerics.md, "Elementary functions"):

* ``math.sin``, ``math.cos``, ``math.tan``, ``math.atan``, ``math.exp``, ``math.log`` and ``**`` on floats
  call glibc's libm, which runs its FMA variants on a machine with FMA and others without;
* numpy's float64 ``np.sin``, ``np.cos``, ``np.tan``, ``np.arctan``, ``np.exp``, ``np.log`` and ``np.power``
  run AVX-512, AVX2 or baseline kernels by the processor;
* ``@``, ``np.dot``, ``np.linalg.norm`` on float64 call the BLAS, and OpenBLAS picks its kernel (and
  with it the order of the sums and whether they are fused) by the processor.

This module is the one owner of the rule "a scene input is computed with these": its sin, cos, tan,
atan, exp, log and pow are SLEEF's deterministic functions (``native/det_math.h``, 1 ulp, through
``endophoton._core.det_*``, vectorised in C++), and its products of 3-vectors and small matrices are
written as numpy elementwise products and sums in a fixed order. IEEE 754 rounds every elementwise
``+ - * /`` and ``np.sqrt`` correctly, so those are the same everywhere, whatever SIMD width numpy
uses. tests/python/test_det_inputs.py builds scenes' native inputs on this machine and as an old one
(glibc's pre-AVX libm, numpy's baseline kernels, OpenBLAS's oldest core) and compares their bits.

Angles are in radians. Each function takes a Python number (returns a float) or an array (returns a
float64 array of the broadcast shape).
"""
from __future__ import annotations

import numpy as np

from . import _core

__all__ = ["sin", "cos", "tan", "atan", "exp", "log", "pow", "dot", "norm", "matmul", "matvec"]


def _elementwise(native, x):
    """``native`` (an ``_core.det_*`` function) over ``x``: a float for a number, else a float64 array."""
    a = np.asarray(x, dtype=np.float64)
    out = native(a)
    return float(out) if a.ndim == 0 else out


def sin(x):
    """sin x, x in radians (SLEEF, within 1 ulp)."""
    return _elementwise(_core.det_sin, x)


def cos(x):
    """cos x, x in radians (SLEEF, within 1 ulp)."""
    return _elementwise(_core.det_cos, x)


def tan(x):
    """tan x, x in radians (SLEEF, within 1 ulp)."""
    return _elementwise(_core.det_tan, x)


def atan(x):
    """atan x in radians, in (-pi/2, pi/2) (SLEEF, within 1 ulp)."""
    return _elementwise(_core.det_atan, x)


def exp(x):
    """e^x (SLEEF, within 1 ulp)."""
    return _elementwise(_core.det_exp, x)


def log(x):
    """The natural logarithm ln x (SLEEF, within 1 ulp; -inf at 0, NaN below)."""
    return _elementwise(_core.det_log, x)


def pow(x, y):  # noqa: A001 - the name of the function it replaces (x ** y)
    """x ** y, broadcast like numpy (SLEEF, within 1 ulp; C99's special cases)."""
    a, b = np.broadcast_arrays(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64))
    out = _core.det_pow(a, b)
    return float(out) if out.ndim == 0 else out


def dot(a, b):
    """Sum over the last axis of a * b, added left to right: a[..., 0] b[..., 0] + a[..., 1] b[..., 1] + ...

    For 3-vectors or rows of them (shapes broadcast, e.g. (N, 3) with (3,)); a float for two vectors."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    n = a.shape[-1]
    if b.shape[-1] != n or n == 0:
        raise ValueError(f"det.dot: last axes of length {a.shape[-1]} and {b.shape[-1]} must be equal and > 0")
    s = a[..., 0] * b[..., 0]
    for k in range(1, n):
        s = s + a[..., k] * b[..., k]
    return float(s) if np.ndim(s) == 0 else s


def norm(a):
    """Euclidean length over the last axis, sqrt(dot(a, a)) (a float for one vector)."""
    s = np.sqrt(dot(a, a))
    return float(s) if np.ndim(s) == 0 else s


def matmul(A, B):
    """The matrix product A B of (..., n, k) and (..., k, m) arrays (3x3, 4x4), each entry's sum over k
    added left to right."""
    A, B = np.asarray(A, dtype=np.float64), np.asarray(B, dtype=np.float64)
    if A.ndim < 2 or B.ndim < 2 or A.shape[-1] != B.shape[-2]:
        raise ValueError(f"det.matmul: shapes {A.shape} and {B.shape} do not make a matrix product")
    return dot(A[..., :, None, :], np.swapaxes(B, -1, -2)[..., None, :, :])


def matvec(A, v):
    """The product A v of an (..., n, k) matrix and a (..., k) vector, each entry added left to right."""
    A, v = np.asarray(A, dtype=np.float64), np.asarray(v, dtype=np.float64)
    if A.ndim < 2 or v.ndim < 1 or A.shape[-1] != v.shape[-1]:
        raise ValueError(f"det.matvec: shapes {A.shape} and {v.shape} do not make a matrix-vector product")
    return dot(A, v[..., None, :])
