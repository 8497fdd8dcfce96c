"""Henyey-Greenstein sampling (oracles §4) through endophoton._core._testing.sample_hg_cos.

- chi-square goodness of fit of the sampled cos(theta) against the analytic HG pdf,
  with equal-probability bins from the analytic CDF (expected count per bin
  n/K >= 5), rejected above chi2_limit(K - 1) (physics_helpers);
- Legendre moments E[P_l(cos)] = g^l, l = 1..3, within K_SIGMA sigma (sigma from the
  sample variance of P_l);
- g = +-1: deltas (cos = 1 / cos = -1 exactly); g near 0 and near +-1: finite, in range.
"""
import math

import numpy as np
import pytest
from scipy import integrate, optimize, special

from endophoton import _core
from physics_helpers import hg_cdf, hg_pdf, K_SIGMA, chi2_limit

N = 1_000_000
BINS = 200  # expected 5000 per bin


def _equal_probability_edges(g, k):
    """Bin edges e_0 = -1 < ... < e_k = 1 with F(e_i) = i/k, by root finding on the analytic CDF."""
    edges = [-1.0]
    for i in range(1, k):
        q = i / k
        edges.append(optimize.brentq(lambda m: float(hg_cdf(g, m)) - q, -1.0, 1.0, xtol=1e-15, rtol=1e-15))
    edges.append(1.0)
    return np.array(edges)


@pytest.mark.parametrize("g", [-0.9, -0.3, 0.0, 0.3, 0.75, 0.9, 0.99])
def test_hg_cdf_reference_is_the_integral_of_the_pdf(g):
    """Check of the reference: the closed-form CDF equals the quadrature of the oracle's pdf."""
    for m in (-1.0, -0.5, 0.0, 0.5, 0.9, 0.999, 1.0):
        val, err = integrate.quad(lambda x: float(hg_pdf(g, x)), -1.0, m, limit=500, epsabs=1e-13)
        assert float(hg_cdf(g, m)) == pytest.approx(val, abs=1e-9), (g, m)


@pytest.mark.parametrize("g", [-0.9, 0.0, 0.3, 0.9, 0.99])
def test_hg_chi_square(g):
    x = np.asarray(_core._testing.sample_hg_cos(g, N, 101 + int(1000 * abs(g))))
    assert x.dtype == np.float64 and x.shape == (N,)
    assert np.all(np.isfinite(x)) and np.all(np.abs(x) <= 1.0)
    edges = _equal_probability_edges(g, BINS)
    assert np.all(np.diff(edges) > 0)
    counts, _ = np.histogram(x, bins=edges)
    assert counts.sum() == N
    expected = np.full(BINS, N / BINS)
    assert expected.min() >= 5
    chi2 = float(np.sum((counts - expected) ** 2 / expected))
    limit = chi2_limit(BINS - 1)
    assert chi2 < limit, f"g = {g}: chi2 = {chi2:.1f} >= chi2_limit({BINS - 1}) = {limit:.1f}"


@pytest.mark.parametrize("g", [-0.9, 0.0, 0.3, 0.9, 0.99])
def test_hg_legendre_moments(g):
    x = np.asarray(_core._testing.sample_hg_cos(g, N, 202 + int(1000 * abs(g))))
    for l in (1, 2, 3):
        p = special.eval_legendre(l, x)
        mean = p.mean()
        sigma = p.std(ddof=1) / math.sqrt(N)
        ref = g**l
        assert (
            abs(mean - ref) < K_SIGMA * sigma + 1e-12
        ), f"g = {g}: E[P_{l}] = {mean:.6f} +- {sigma:.2g}, expected g^{l} = {ref:.6f}"


@pytest.mark.parametrize("g,value", [(1.0, 1.0), (-1.0, -1.0)])
def test_hg_delta_limits(g, value):
    x = np.asarray(_core._testing.sample_hg_cos(g, 10_000, 3))
    assert np.all(x == value)


@pytest.mark.parametrize("g", [1e-7, -1e-7, 1e-5, -1e-5, 1 - 1e-9, -(1 - 1e-9), 0.9999])
def test_hg_near_singular_g(g):
    """The inverse CDF divides by 2g and by (1 - g + 2g u): near g = 0 and g = +-1 the
    samples must stay finite, in [-1, 1], with the right mean (E[cos] = g within K_SIGMA sigma).
    Near |g| = 1 the law is heavy-tailed (the deviation of the mean comes from rare wide
    angles), so sigma uses the exact variance Var[cos] = E[P_2]*2/3 + 1/3 - g^2 = (1 - g^2)/3."""
    n = 200_000
    x = np.asarray(_core._testing.sample_hg_cos(g, n, 17))
    assert np.all(np.isfinite(x)) and np.all(np.abs(x) <= 1.0)
    sigma = math.sqrt((1 - g * g) / 3 / n)
    assert abs(x.mean() - g) < K_SIGMA * sigma + 1e-12, (g, x.mean(), sigma)
    if abs(g) < 1e-4:
        # indistinguishable from isotropic: chi-square against the uniform law on 100 bins
        counts, _ = np.histogram(x, bins=np.linspace(-1, 1, 101))
        e = n / 100
        assert np.sum((counts - e) ** 2 / e) < chi2_limit(99)


def test_hg_seed_reproducible_and_seeds_differ():
    a = np.asarray(_core._testing.sample_hg_cos(0.5, 1000, 42))
    b = np.asarray(_core._testing.sample_hg_cos(0.5, 1000, 42))
    c = np.asarray(_core._testing.sample_hg_cos(0.5, 1000, 43))
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)


@pytest.mark.parametrize("g", [1.0000001, -1.5, float("nan"), float("inf")])
def test_hg_rejects_invalid_g(g):
    with pytest.raises(ValueError) as ei:
        _core._testing.sample_hg_cos(g, 10, 1)
    assert "g" in str(ei.value)
