"""Coefficients of native/fast_log.h's polynomial: q(r) = (ln(1 + r) - r) / r^2 on [-2^-8, 2^-8],
a Chebyshev fit of degree 4 (mpmath.chebyfit, 60 digits), printed as doubles (ascending powers) with the
largest error of r + r^2 q(r) relative to ln(1 + r) once the coefficients are rounded.

    /usr/bin/python3 scripts/fit_log1p.py
"""
import mpmath as mp

mp.mp.dps = 60
R = mp.mpf(2) ** -8


def q(r):
    return mp.mpf(-1) / 2 if r == 0 else (mp.log1p(r) - r) / r**2


poly, _ = mp.chebyfit(q, [-R, R], 5, error=True)
coef = [float(c) for c in poly[::-1]]
worst = max(
    abs((r + r**2 * sum(mp.mpf(c) * r**k for k, c in enumerate(coef))) / mp.log1p(r) - 1)
    for r in (R * (2 * mp.mpf(i) / 4000 - 1) for i in range(4001))
    if r != 0
)
print([repr(c) for c in coef])
print("max relative error:", mp.nstr(worst, 3))
