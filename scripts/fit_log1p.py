"""Coefficients of a polynomial q(r) = (ln(1 + r) - r) / r^2, so that ln(1 + r) = r + r^2 q(r): a Chebyshev fit
(mpmath.chebyfit, 60 digits), printed in ascending powers with the largest error of r + r^2 q(r) relative to
ln(1 + r) once the coefficients are rounded.

    /usr/bin/python3 scripts/fit_log1p.py        # native/fast_log.h: degree 4 on [-2^-8, 2^-8], doubles
    /usr/bin/python3 scripts/fit_log1p.py f32    # scripts/lane_step_f32_bench.cpp: degree 7 on
                                                 # [sqrt(1/2) - 1, sqrt(2) - 1], floats, evaluated in float
"""
import sys

import mpmath as mp
import numpy as np

mp.mp.dps = 60
F32 = len(sys.argv) > 1 and sys.argv[1] == "f32"
LO, HI = (mp.sqrt(0.5) - 1, mp.sqrt(2) - 1) if F32 else (-(mp.mpf(2) ** -8), mp.mpf(2) ** -8)
DEGREE = 7 if F32 else 4


def q(r):
    return mp.mpf(-1) / 2 if r == 0 else (mp.log1p(r) - r) / r**2


def approx(coef, r):
    """r + r^2 q(r) by Horner's rule, in float32 for the f32 fit (as the lanes evaluate it), else exactly."""
    if not F32:
        return r + r**2 * sum(mp.mpf(c) * r**k for k, c in enumerate(coef))
    x, acc = np.float32(r), np.float32(coef[-1])
    for c in coef[-2::-1]:
        acc = np.float32(acc * x + np.float32(c))
    return mp.mpf(float(np.float32(x + np.float32(np.float32(x * x) * acc))))


poly, _ = mp.chebyfit(q, [LO, HI], DEGREE + 1, error=True)
coef = [float(np.float32(float(c))) if F32 else float(c) for c in poly[::-1]]
points = (LO + (HI - LO) * mp.mpf(i) / 4000 for i in range(4001))
if F32:  # the float32 argument the lanes see
    points = (mp.mpf(float(np.float32(float(r)))) for r in points)
worst = max(abs(approx(coef, r) / mp.log1p(r) - 1) for r in points if r != 0)
print([repr(c) for c in coef])
print("max relative error:", mp.nstr(worst, 3))
