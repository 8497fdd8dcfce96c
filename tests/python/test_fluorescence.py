"""Fluorescence, spectra and energy bookkeeping against analytic references (issue: seed model).

References used here are independent of the engine:
- the paper's decision rule: each eligible interaction fluoresces with probability d*c (binomial);
- the EEM row itself (piecewise linear in emission wavelength) for the emitted spectrum;
- the energy convention E = W * 500 nm / lambda for the Stokes loss.
"""
import math

import numpy as np
import pytest

import endophoton as ep
from physics_helpers import assert_energy_conserved, K_SIGMA, chi2_limit

LAMBDA0 = 405.0  # nm: photofrin's Soret band, a tabulated excitation row of the default EEM


def _mono(lam=LAMBDA0):
    """A nearly monochromatic source spectrum: a 2 pm wide triangle around lam (nm)."""
    return ep.Spectrum([lam - 1e-3, lam, lam + 1e-3], [0.0, 1.0, 0.0])


def _slab(fluorophores, mua=1.0, mus=10.0, g=0.0, n=1.0, thickness=0.05):
    scene = ep.Scene(unit="cm")
    scene.add_box(
        "tissue", (-50, -50, -thickness), (50, 50, 0), ep.Medium(mua=mua, mus=mus, g=g, n=n), fluorophores=fluorophores
    )
    return scene


def _row_pdf(eem, lam):
    """Emission pdf (per nm) of the EEM row at the tabulated excitation wavelength lam."""
    i = int(np.argmin(np.abs(eem.excitation_nm - lam)))
    assert abs(eem.excitation_nm[i] - lam) < 1e-9, "the test needs a tabulated row"
    em, row = eem.emission_nm, eem.values[i]
    return em, row / np.trapz(row, em)


def test_fraction_of_interactions_that_fluoresce_is_d_times_c():
    """Paper rule, one fluorophore: every interaction of a not-yet-fluorescent packet is a
    trial that succeeds with probability d*c. Trials are independent Bernoulli draws, so
    the ratio events/trials has binomial standard error sqrt(q (1-q) / trials)."""
    d, c = 0.2, 0.4
    scene = _slab([ep.Fluorophore("collagen", d, c)], mua=2.0, mus=50.0, g=0.8, thickness=1.0)
    src = ep.PencilSource((0, 0, 1), (0, 0, -1))
    res = ep.run(scene, src, photons=40000, seed=3, threads=0, record_escapes=False)
    assert_energy_conserved(res)
    n = res.photons
    trials = res.fluorescence_trials * n
    events = res.fluorescence_events * n
    assert trials > 1e5 and abs(trials - round(trials)) < 1e-6 * trials
    q = d * c
    sigma = math.sqrt(q * (1 - q) / trials)
    assert abs(events / trials - q) < K_SIGMA * sigma, (events / trials, q, sigma)


def test_escaping_emission_spectrum_matches_the_eem_row():
    """Optically thin, non-absorbing, index-matched slab whose coefficients do not depend on
    wavelength: whether a packet escapes does not depend on its emission wavelength, so the
    escaping fluorescent packets sample the EEM row at the excitation wavelength. Chi-square
    against the row integrated over 10 nm bins (exact for a piecewise-linear row on a 5 nm grid)."""
    f = ep.Fluorophore("photofrin", 1.0, 1.0)
    scene = _slab([f], mua=0.0, mus=5.0, thickness=0.05)
    src = ep.PencilSource((0, 0, 1), (0, 0, -1), spectrum=_mono())
    res = ep.run(scene, src, photons=200000, seed=11, threads=0, fluorescent_only=True, fluorescence_rule="paper")
    assert_energy_conserved(res)
    wl = res.escapes["wavelength"].astype(np.float64)
    assert len(wl) > 5000
    assert np.all(res.escapes["fluorescent"] == 1)
    em, pdf = _row_pdf(f.eem, LAMBDA0)
    edges = np.arange(em[0], em[-1] + 1e-9, 10.0)
    # Bin probabilities of the piecewise-linear pdf: trapezoids between grid nodes.
    cdf = np.concatenate([[0.0], np.cumsum(0.5 * (pdf[1:] + pdf[:-1]) * np.diff(em))])
    p_bins = np.diff(np.interp(edges, em, cdf))
    counts, _ = np.histogram(wl, bins=edges)
    expected = p_bins * len(wl)
    # Merge bins until each expects at least 5 (Cochran's rule).
    obs_m, exp_m, acc_o, acc_e = [], [], 0.0, 0.0
    for o, e in zip(counts, expected):
        acc_o, acc_e = acc_o + o, acc_e + e
        if acc_e >= 5:
            obs_m.append(acc_o)
            exp_m.append(acc_e)
            acc_o = acc_e = 0.0
    obs_m[-1] += acc_o
    exp_m[-1] += acc_e
    obs_m, exp_m = np.array(obs_m), np.array(exp_m)
    chi2 = float(np.sum((obs_m - exp_m) ** 2 / exp_m))
    dof = len(obs_m) - 1
    assert dof >= 10
    assert chi2 < chi2_limit(dof), (chi2, dof)


def test_stokes_loss_follows_the_energy_convention():
    """No absorption and matched indices: the weight stays 1, and every packet that interacts
    fluoresces once (d = c = 1, paper rule) from 405 nm into the EEM row. The engine's
    Stokes loss per event must equal 500 (1/405 - E[1/lambda_em]) with E over the row's pdf,
    and the energy balance launched = sum of energy tallies + Stokes loss must be exact."""
    f = ep.Fluorophore("photofrin", 1.0, 1.0)
    scene = _slab([f], mua=0.0, mus=5.0, thickness=0.05)
    src = ep.PencilSource((0, 0, 1), (0, 0, -1), spectrum=_mono())
    res = ep.run(scene, src, photons=100000, seed=5, threads=0)
    assert_energy_conserved(res)
    energy_sum = sum(getattr(res, k + "_energy") for k in ep.FRACTIONS) + res.stokes_loss
    assert abs(energy_sum - res.launched_energy) < 1e-9 * res.launched_energy
    assert res.launched_energy == pytest.approx(500.0 / LAMBDA0, rel=1e-5)
    em, pdf = _row_pdf(f.eem, LAMBDA0)
    inv_mean = np.trapz(pdf / em, em)
    per_event_ref = 500.0 * (1.0 / LAMBDA0 - inv_mean)
    assert per_event_ref > 0  # emission is red-shifted
    per_event = res.stokes_loss / res.fluorescence_events
    # sigma from the spread of 500/lambda over the escaping fluorescent packets (all weight 1).
    wl = res.escapes["wavelength"][res.escapes["fluorescent"] == 1].astype(np.float64)
    sigma = 500.0 * np.std(1.0 / wl) / math.sqrt(len(wl))
    assert abs(per_event - per_event_ref) < K_SIGMA * sigma + 1e-4 * per_event_ref, (per_event, per_event_ref, sigma)
    # The energy of each escape record is weight x 500 / wavelength, and the escaped-energy
    # tally is their sum per launched packet (every escape is recorded here): the reflected
    # plus transmitted energy of the balance.
    e = res.escapes
    assert np.allclose(e["energy"], e["weight"] * 500.0 / e["wavelength"].astype(np.float64), rtol=1e-6)
    assert res.escaped_energy == pytest.approx(e["energy"].sum() / res.photons, rel=1e-9)
    assert res.escaped_energy == pytest.approx(res.diffuse_reflectance_energy + res.transmittance_energy, rel=1e-12)


def test_eem_rule_scales_the_decision_by_the_excitation_efficiency():
    """Rule 'eem': a trial succeeds with probability d * eta(lambda) * c, eta being the EEM's
    relative excitation efficiency. Source at 420 nm (eta = 0.62 for the default photofrin
    EEM), d = c = 1. Coefficients do not depend on wavelength, so escaping does not depend on
    the outcome; among escaped packets that interacted exactly once (one scattering, one trial
    at 420 nm) the fluorescent fraction is therefore exactly eta(420): a binomial proportion."""
    lam = 420.0
    f = ep.Fluorophore("photofrin", 1.0, 1.0)
    eta = float(f.eem.efficiency(lam))
    assert 0.2 < eta < 0.9
    scene = _slab([f], mua=0.0, mus=2.0, thickness=0.05)
    src = ep.PencilSource((0, 0, 1), (0, 0, -1), spectrum=_mono(lam))
    res = ep.run(scene, src, photons=100000, seed=21, threads=0, fluorescence_rule="eem")
    assert_energy_conserved(res)
    e = res.escapes
    once = e["scatterings"] == 1
    n1 = int(once.sum())
    assert n1 > 2000
    frac = float(e["fluorescent"][once].mean())
    sigma = math.sqrt(eta * (1 - eta) / n1)
    assert abs(frac - eta) < K_SIGMA * sigma, (frac, eta, sigma)
    # The paper rule ignores eta: the same packets fluoresce with probability d*c = 1.
    res_p = ep.run(scene, src, photons=20000, seed=21, threads=0, fluorescence_rule="paper")
    once_p = res_p.escapes["scatterings"] == 1
    assert np.all(res_p.escapes["fluorescent"][once_p] == 1)


def test_no_spectral_work_without_fluorophores_or_spectra():
    """Compute only what the scene needs: a plain scene traces no wavelengths, reports no
    energy tallies and writes no grid."""
    scene = _slab([])
    res = ep.run(scene, ep.PencilSource((0, 0, 1), (0, 0, -1)), photons=2000, seed=1)
    assert res.spectral is False
    assert not hasattr(res, "stokes_loss")
    assert res.grid_path is None
    assert np.all(res.escapes["wavelength"] == 0)
    assert np.array_equal(res.escapes["energy"], res.escapes["weight"])
    assert res.fluorescence_trials == 0 and res.fluorescence_events == 0
