"""Reference physics and assertion helpers for the physics acceptance tests.

Everything here is independent of the engine: the formulas are written from
the oracles (docs: /work/shared/reference/oracles.md) and textbook results,
not copied from native/.

Tolerance convention used by every statistical check in the suite:

    |x - ref| < K * sigma + ref_unc,   K = K_SIGMA = Z_FAMILY = 4.5

where sigma is the engine's batch-means standard error of x and ref_unc the
reference's own uncertainty (0.5 in the last quoted digit for tabulated exact
values, or the Monte Carlo error of a Monte Carlo reference, see
``mc_reference_sigma``). Chi-square tests reject above the quantile of the
same per-comparison false-alarm probability (``chi2_limit``). Why 4.5 and not
3: see ``Z_FAMILY`` and docs/numerics.md, "How many sigma".
"""
from __future__ import annotations

import dataclasses
import math
import os

import numpy as np

#: Every fraction the engine reports; they must sum to 1 (launched weight).
BALANCE_KEYS = (
    "specular_reflectance",
    "diffuse_reflectance",
    "transmittance",
    "absorbed",
    "missed",
    "cut",
    "roulette",
    "occluded",
    "camera_collected",
)
# One family-wise threshold for every statistical comparison of the suite
# (Bonferroni). A full run makes about N_COMPARISONS of them (counted for
# issue 11: ~130 assert_within / assert_same_within_stats calls, ~75 roulette
# checks in assert_energy_conserved, ~60 inline sigma and chi-square checks).
# The suite should pass a correct engine with any random stream with
# probability 1 - FAMILY_ALPHA, so each comparison may fail by chance with
# probability FAMILY_ALPHA / N_COMPARISONS = 3.3e-5 at most. Our sigmas are
# batch means over 50 batches, so z = diff / sigma is Student t with 49 degrees
# of freedom rather than normal: 2 P(t49 > 4.5) = 4.2e-5 (normal: 6.8e-6), so
# 300 comparisons fail together with probability about 1 %. At 3 sigma the
# same suite fails somewhere with probability 1 - (1 - 0.0042)^300 = 72 % each
# time the stream changes: a changed seed or generator "breaks" some test.
N_COMPARISONS = 300
FAMILY_ALPHA = 0.01
Z_FAMILY = 4.5
K_SIGMA = Z_FAMILY
#: Two-sided normal tail of Z_FAMILY: the per-comparison false-alarm
#: probability that chi-square and other exact tests use.
P_COMPARISON = math.erfc(Z_FAMILY / math.sqrt(2.0))


def k_sigma_for_batches(batches: int) -> float:
    """The threshold in sigmas for a batch-means sigma of ``batches`` batches: K_SIGMA at the
    engine's default of 50 or more, else Student t with batches - 1 degrees of freedom at the
    same two-sided tail as t49 at K_SIGMA (4.2e-5). A run of few work units has few batches and a
    very uncertain sigma: at 2 batches (t1) the threshold is about 15,000 sigma, as it must be. Below
    2 batches (one unit) the engine's sigma is the per-packet one, and K_SIGMA holds."""
    if batches >= 50 or batches < 2:
        return K_SIGMA
    from scipy import stats

    return float(stats.t.isf(stats.t.sf(K_SIGMA, 49), batches - 1))


def chi2_limit(dof):
    """Rejection threshold of a chi-square statistic with ``dof`` degrees of
    freedom at the suite's per-comparison false-alarm probability P_COMPARISON."""
    from scipy import stats

    return float(stats.chi2.isf(P_COMPARISON, dof))


# ----------------------------------------------------------------------------
# Assertions
# ----------------------------------------------------------------------------
def _has(res, key):
    return key in res if isinstance(res, dict) else hasattr(res, key)


def _get(res, key):
    if isinstance(res, dict):
        return res[key]
    return getattr(res, key)


def assert_energy_conserved(res, tol=1e-9):
    """Rsp + Rd + Tt + A + missed + cut + roulette == 1 within ``tol``.

    Also: every fraction and its stderr is finite, stderr >= 0, and the net
    Russian-roulette weight (expectation 0 for an unbiased roulette) is within
    K_SIGMA of its own standard errors of 0, plus an allowance of 5 boosted packet
    weights, 5 * threshold / (chance * photons), plus 1e-12 for rounding.

    Why the allowance: each roulette event adds +W (killed, chance 1 - m) or
    -W (1/m - 1) (survivor boosted to W/m, chance m), a strongly skewed term.
    When a run has few roulette events the batch-means sigma is itself very
    uncertain and z = roulette/sigma has heavy tails: for 40 seeds of the
    vertex-launch scene of test_extremes (about 50 events per run), z had mean
    -0.01 (no bias) but standard deviation 1.42, with |z| > 3 in 3 runs. The
    allowance is the tally's granularity (one boosted weight is threshold/m
    per launched packet at most); it is negligible next to 3 sigma as soon as
    the run has many roulette events. A run of fewer work units than batches
    (a cancelled one, say) has fewer batches, and K_SIGMA becomes the Student t
    threshold of that many (k_sigma_for_batches).
    """
    total = 0.0
    for k in BALANCE_KEYS:
        v = _get(res, k)
        s = _get(res, k + "_stderr")
        assert math.isfinite(v), f"{k} = {v} is not finite"
        assert math.isfinite(s) and s >= 0, f"{k}_stderr = {s} is not a finite non-negative number"
        total += v
    assert abs(total - 1.0) < tol, f"energy balance: sum of {BALANCE_KEYS} = {total!r}, |sum - 1| = {abs(total - 1)}"
    r, rs = _get(res, "roulette"), _get(res, "roulette_stderr")
    opts = getattr(res, "options", None) or {}
    threshold = float(opts.get("roulette_threshold", 1e-4))
    chance = float(opts.get("roulette_chance", 0.1))
    photons = max(1, int(_get(res, "photons")))
    allowance = 5.0 * threshold / (chance * photons)
    k = K_SIGMA
    unit = int(_get(res, "unit_size")) if _has(res, "unit_size") else 0
    if unit > 0:  # the batches of the sigma: the units merged, at most the run's batches
        k = k_sigma_for_batches(min(-(-photons // unit), int(opts.get("batches", 50))))
    assert (
        abs(r) < k * rs + allowance + 1e-12
    ), f"roulette = {r} is not within {k:g} sigma ({rs}) + {allowance:.3g} of 0: biased roulette"
    for k in ("absorbed", "specular_reflectance", "diffuse_reflectance", "transmittance", "missed", "cut"):
        assert _get(res, k) >= -1e-12, f"{k} = {_get(res, k)} is negative"
    a_reg = _get(res, "absorbed_by_region")
    if a_reg:
        assert (
            abs(sum(a_reg.values()) - _get(res, "absorbed")) < tol
        ), f"absorbed_by_region sums to {sum(a_reg.values())}, absorbed = {_get(res, 'absorbed')}"
    return total


def _log(line):
    """Append a line to $EP_PHYSICS_LOG if set (a table of measured vs reference values)."""
    path = os.environ.get("EP_PHYSICS_LOG")
    if path:
        test = os.environ.get("PYTEST_CURRENT_TEST", "").split(" ")[0]
        with open(path, "a", encoding="utf-8") as fh:
            fh.write(f"{test}\t{line}\n")


def assert_within(label, value, sigma, ref, ref_unc=0.0, k=K_SIGMA):
    """|value - ref| < k*sigma + ref_unc, with a message that shows every number."""
    tol = k * sigma + ref_unc
    z = abs(value - ref) / sigma if sigma else 0.0
    _log(
        f"{label}\t{value:.6g}\t{sigma:.2g}\t{ref:.6g}\t{ref_unc:.2g}\t{abs(value - ref) / tol if tol else 0:.2f}\tz={z:.2f}"
    )
    assert math.isfinite(value), f"{label}: value {value} is not finite"
    assert abs(value - ref) < tol, (
        f"{label}: measured {value:.6g} +- {sigma:.3g} (1 sigma), reference {ref:.6g} "
        f"(+- {ref_unc:.3g}); |diff| = {abs(value - ref):.3g} >= {k:g} sigma + ref_unc "
        f"= {tol:.3g}"
    )


def assert_same_within_stats(label, a, sa, b, sb, k=K_SIGMA, extra=0.0):
    """Two independent estimates agree: |a - b| < k * sqrt(sa^2 + sb^2) (+ extra)."""
    tol = k * math.hypot(sa, sb) + extra
    z = abs(a - b) / math.hypot(sa, sb) if (sa or sb) else 0.0
    _log(f"{label}\t{a:.6g}\t{sa:.2g}\t{b:.6g}\t{sb:.2g}\t{abs(a - b) / tol if tol else 0:.2f}\tz={z:.2f}")
    assert (
        abs(a - b) < tol
    ), f"{label}: {a:.6g} +- {sa:.3g} vs {b:.6g} +- {sb:.3g}; |diff| = {abs(a - b):.3g} >= {tol:.3g}"


def mc_reference_sigma(p, photons):
    """Upper bound on the standard error of a Monte Carlo reference fraction.

    A photon's contribution X to a tally (Rd, Tt, A, ...) lies in [0, 1]
    (its weight never exceeds 1 except for Russian-roulette survivors, whose
    weight is below 10 * threshold = 1e-3), and E[X] = p. For X in [0, 1],
    X^2 <= X, so Var X = E[X^2] - p^2 <= p - p^2 = p(1 - p); hence the
    reference's standard error is at most sqrt(p(1 - p) / N).
    """
    return math.sqrt(p * (1.0 - p) / photons)


def finite_array(a):
    a = np.asarray(a)
    return bool(np.all(np.isfinite(a)))


def assert_no_nan(res):
    """No NaN / inf in any numeric output, including the escape records."""
    for k in BALANCE_KEYS:
        assert math.isfinite(_get(res, k)) and math.isfinite(_get(res, k + "_stderr")), k
    for field in ("absorbed_by_region", "absorbed_by_region_stderr"):
        for name, v in _get(res, field).items():
            assert math.isfinite(v), f"{field}[{name}] = {v}"
    summary = res if isinstance(res, dict) else res.to_dict()
    for k, v in summary.items():
        if isinstance(v, float):
            assert math.isfinite(v), f"{k} = {v}"
    esc = _get(res, "escapes")
    if esc:
        for key, arr in esc.items():
            arr = np.asarray(arr)
            if arr.dtype.kind == "f":
                assert np.all(np.isfinite(arr)), f"escapes[{key}] holds non-finite values"


def assert_nan_free(obj, where="result"):
    """No NaN or inf anywhere in ``obj``, nested fields included (the product's rule: an undefined
    value is None): dicts, lists, tuples, dataclasses (each field), numpy arrays and scalars are
    walked; ``where`` names the path of the first offending value in the message."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        for f in dataclasses.fields(obj):
            assert_nan_free(getattr(obj, f.name), f"{where}.{f.name}")
    elif isinstance(obj, dict):
        for k, v in obj.items():
            assert_nan_free(v, f"{where}[{k!r}]")
    elif isinstance(obj, (list, tuple)):
        for i, v in enumerate(obj):
            assert_nan_free(v, f"{where}[{i}]")
    elif isinstance(obj, np.ndarray) and obj.dtype.kind in "fc":
        bad = np.argwhere(~np.isfinite(obj))
        assert bad.size == 0, f"{where}{bad[0].tolist()} is not finite"
    elif isinstance(obj, (float, np.floating)):
        assert math.isfinite(obj), f"{where} = {obj!r} (an undefined value must be None)"


# ----------------------------------------------------------------------------
# Reference physics
# ----------------------------------------------------------------------------
def fresnel_unpolarized(n1, n2, theta_i):
    """Unpolarised Fresnel reflectance going from index n1 into n2 at incidence angle theta_i (rad).

    Oracles §4: R = 1/2 [sin^2(i - t)/sin^2(i + t) + tan^2(i - t)/tan^2(i + t)],
    R = ((n1 - n2)/(n1 + n2))^2 at normal incidence, R = 1 beyond the critical angle.
    """
    if theta_i == 0.0:
        return ((n1 - n2) / (n1 + n2)) ** 2
    s = n1 / n2 * math.sin(theta_i)
    if s >= 1.0:
        return 1.0
    theta_t = math.asin(s)
    if n1 == n2:
        return 0.0
    a, b = theta_i - theta_t, theta_i + theta_t
    return 0.5 * (math.sin(a) ** 2 / math.sin(b) ** 2 + math.tan(a) ** 2 / math.tan(b) ** 2)


def slab_clear_totals(R, mua, path):
    """Absorbing, non-scattering slab with equal Fresnel reflectance R at both faces,
    one-way path length ``path`` (cm), all internal reflections summed.

    Returns (Rsp, Rd, Tt): Rsp = R; with q = exp(-mua*path),
    Tt = (1-R)^2 q / (1 - R^2 q^2), Rd = (1-R)^2 R q^2 / (1 - R^2 q^2).
    """
    q = math.exp(-mua * path)
    denom = 1.0 - R * R * q * q
    return R, (1 - R) ** 2 * R * q * q / denom, (1 - R) ** 2 * q / denom


def hg_pdf(g, mu):
    """Henyey-Greenstein density over mu = cos(theta) in [-1, 1] (oracles §4)."""
    mu = np.asarray(mu, dtype=np.float64)
    return (1 - g * g) / (2.0 * (1 + g * g - 2 * g * mu) ** 1.5)


def hg_cdf(g, mu):
    """CDF of ``hg_pdf``: the closed-form integral from -1 to mu.

    F(mu) = (1 - g^2)/(2g) * [ (1 + g^2 - 2 g mu)^(-1/2) - 1/(1 + g) ],  g != 0;
    F(mu) = (mu + 1)/2 for g = 0.
    """
    mu = np.asarray(mu, dtype=np.float64)
    if g == 0:
        return 0.5 * (mu + 1.0)
    return (1 - g * g) / (2 * g) * (1.0 / np.sqrt(1 + g * g - 2 * g * mu) - 1.0 / (1 + g))


def chandrasekhar_H(omega, mu, nodes=200):
    """Chandrasekhar's H-function for isotropic scattering with single-scattering albedo omega.

    Solves H(x) = 1 + (omega/2) x H(x) int_0^1 H(y)/(x + y) dy on Gauss-Legendre
    nodes with Newton's method, then evaluates at ``mu`` with the Nystrom
    formula. Checked in test_mcml against Chandrasekhar's table (omega = 1:
    H(1) = 2.90781, H(0.5) = 2.01278).
    """
    from scipy.optimize import fsolve

    x, w = np.polynomial.legendre.leggauss(nodes)
    x = 0.5 * (x + 1.0)
    w = 0.5 * w
    K = 0.5 * omega * x[:, None] * w[None, :] / (x[:, None] + x[None, :])

    def F(H):
        return H - 1.0 - H * (K @ H)

    def J(H):
        return np.eye(nodes) - np.diag(K @ H) - H[:, None] * K

    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        H = fsolve(F, np.ones(nodes), fprime=J, xtol=1e-14)
    mu = np.atleast_1d(np.asarray(mu, dtype=np.float64))
    Km = 0.5 * omega * mu[:, None] * w[None, :] / (mu[:, None] + x[None, :])
    return 1.0 / (1.0 - Km @ H)


def semi_infinite_isotropic_reflectance(mua, mus, mu0=1.0):
    """Exact total (diffuse) reflectance of a semi-infinite, index-matched medium with
    isotropic scattering, for a collimated beam at incidence cosine mu0:
    R = 1 - H(mu0) sqrt(1 - omega), omega = mus/(mua + mus)  (Chandrasekhar 1950, §§ 26-27;
    the plane albedo of a semi-infinite atmosphere). A pencil beam on an
    infinitely wide medium gives the same total as a broad beam (superposition).
    """
    omega = mus / (mua + mus)
    return 1.0 - float(chandrasekhar_H(omega, mu0)[0]) * math.sqrt(1.0 - omega)


# ----------------------------------------------------------------------------
# Geometry
# ----------------------------------------------------------------------------
def cube_mesh(lo, hi):
    """Closed, outward-oriented (CCW seen from outside) box mesh written for the tests.

    The top face (z = hi) is split along the diagonal from (lo_x, lo_y) to
    (hi_x, hi_y), so its centre lies exactly on a mesh edge.
    Returns float32 (8, 3) vertices and uint32 (12, 3) triangles.
    """
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    v = np.array(
        [
            [x0, y0, z0],
            [x1, y0, z0],
            [x1, y1, z0],
            [x0, y1, z0],  # 0..3 bottom
            [x0, y0, z1],
            [x1, y0, z1],
            [x1, y1, z1],
            [x0, y1, z1],  # 4..7 top
        ],
        dtype=np.float32,
    )
    t = np.array(
        [
            [4, 5, 6],
            [4, 6, 7],  # top    (+z) diagonal 4-6
            [0, 2, 1],
            [0, 3, 2],  # bottom (-z)
            [0, 1, 5],
            [0, 5, 4],  # y = y0 (-y)
            [2, 3, 7],
            [2, 7, 6],  # y = y1 (+y)
            [0, 4, 7],
            [0, 7, 3],  # x = x0 (-x)
            [1, 2, 6],
            [1, 6, 5],  # x = x1 (+x)
        ],
        dtype=np.uint32,
    )
    return v, t


def mesh_signed_volume(v, t):
    v = np.asarray(v, dtype=np.float64)
    a, b, c = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    return float(np.sum(np.einsum("ij,ij->i", a, np.cross(b, c))) / 6.0)


def distance_to_box_surface(p, lo, hi):
    """Distance of points p (K,3) from the surface of the box [lo, hi] (0 on the surface)."""
    p = np.asarray(p, dtype=np.float64)
    lo = np.asarray(lo, dtype=np.float64)
    hi = np.asarray(hi, dtype=np.float64)
    outside = np.maximum(np.maximum(lo - p, p - hi), 0.0)
    d_out = np.linalg.norm(outside, axis=1)
    inside = np.all((p >= lo) & (p <= hi), axis=1)
    d_in = np.min(np.concatenate([p - lo, hi - p], axis=1), axis=1)
    return np.where(inside, d_in, d_out)


# Fields of Result.to_dict() that describe the run's environment, not its physics.
RUN_ENV_KEYS = {"seconds", "threads", "peak_record_bytes", "grid_path"}


def run_physics(result):
    """Every tally, standard error and escape record of a run, without its timing and
    environment fields: equal for runs that must agree bit for bit."""
    d = {k: v for k, v in result.to_dict().items() if k not in RUN_ENV_KEYS and "time" not in k and "second" not in k}
    esc = result.escapes or {}
    d["escapes"] = {k: np.asarray(v).tobytes() for k, v in esc.items()}
    return d
