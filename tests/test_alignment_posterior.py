"""Alignment posterior (emcee): likelihood, convergence reporting, calibration."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose

from magcal.alignment.gls import fit_alignment, param_names, prepare
from magcal.alignment.posterior import (AlignmentPosterior, log_likelihood_direct,
                                        sample_posterior)
from magcal.alignment.synthetic import synthetic_pair


def _case(seed, **kw):
    kw.setdefault("n", 1500)
    kw.setdefault("cadence_s", 300.0)
    kw.setdefault("noise_tau_s", (1800.0,) * 3)
    return synthetic_pair(np.random.default_rng(seed), **kw)


@pytest.mark.parametrize("flags", [(True, False), (True, True), (False, False)])
def test_vectorised_likelihood_equals_direct(flags):
    fit_offset, fit_scale = flags
    case = _case(1, offset_nT=(5.0, -3.0, 2.0))
    t = np.arange(case.data.shape[0]) * 300.0
    t[700:] += 3600.0  # a gap: two spacing groups
    _, d, r, _ = prepare(t, case.data, case.ref)
    names = param_names(True, fit_offset, fit_scale)
    post = AlignmentPosterior(t, d, r, names)
    rng = np.random.default_rng(2)
    thetas = []
    for _ in range(5):
        th = list(np.deg2rad(case.rotvec_deg) + rng.normal(0, 0.01, 3))
        if fit_offset:
            th += list(rng.normal(0, 3, 3))
        if fit_scale:
            th += [1.0 + rng.normal(0, 0.01)]
        th += list(np.log([6.0, 2.0, 2.5])) + list(np.log(rng.uniform(500, 5000, 3)))
        thetas.append(th)
    thetas = np.array(thetas)
    fast = post.log_likelihood(thetas)
    slow = [log_likelihood_direct(th, t, d, r, names) for th in thetas]
    assert_allclose(fast, slow, rtol=1e-9)


def test_posterior_converges_and_agrees_with_closed_form():
    case = _case(3, rotvec_deg=(2.0, -1.0, 0.5), offset_nT=(4.0, 1.0, -2.0))
    closed = fit_alignment(case.times, case.data, case.ref)
    res = sample_posterior(case.times, case.data, case.ref, np.random.default_rng(4),
                           start=closed)
    assert res.method == "emcee"
    assert res.converged is True
    assert res.mcmc["n_steps"] > 50 * res.autocorr_steps
    assert_allclose(res.angles_deg, closed.angles_deg, atol=0.25 * closed.std_deg.max())
    assert_allclose(res.std_deg, closed.std_deg, rtol=0.15)
    assert np.all(np.abs(res.angles_deg - case.rotvec_deg) < 4 * res.std_deg)
    doc = res.to_json()
    assert doc["converged"] is True and doc["autocorr_steps"] == pytest.approx(res.autocorr_steps)
    assert set(doc["ci95_deg"]) == {"Hp", "He", "Hn"}


def test_short_chain_is_reported_unconverged():
    case = _case(5)
    res = sample_posterior(case.times, case.data, case.ref, np.random.default_rng(6),
                           first_steps=200, max_steps=200)
    assert res.mcmc["n_steps"] == 200
    assert res.converged is False
    assert "NOT CONVERGED" in res.mcmc["message"]
    assert res.to_json()["converged"] is False


def test_same_seed_same_chain():
    case = _case(7)
    a = sample_posterior(case.times, case.data, case.ref, np.random.default_rng(8),
                         first_steps=300, max_steps=300)
    b = sample_posterior(case.times, case.data, case.ref, np.random.default_rng(8),
                         first_steps=300, max_steps=300)
    assert_allclose(a.samples, b.samples, rtol=0, atol=0)


@pytest.mark.slow
def test_posterior_intervals_cover_truth():
    """MCMC coverage on 8 seeded simulations (24 angles); binomial check for 95 %.

    The tight 93-97 % calibration is tested on the closed form with 600 angles; here
    each posterior must also match that calibrated closed form in width.
    """
    inside, ratio = [], []
    for k in range(8):
        rng = np.random.default_rng(900 + k)
        truth = rng.normal(0.0, 2.0, 3)
        case = synthetic_pair(rng, n=1440, cadence_s=300.0, rotvec_deg=truth,
                              offset_nT=rng.normal(0.0, 5.0, 3), noise_tau_s=(3600.0,) * 3)
        closed = fit_alignment(case.times, case.data, case.ref)
        res = sample_posterior(case.times, case.data, case.ref, rng, start=closed,
                               min_autocorr_times=30)
        assert res.converged
        inside.append((res.ci95_deg[:, 0] < truth) & (truth < res.ci95_deg[:, 1]))
        ratio.append(res.std_deg / closed.std_deg)
    # 24 cases at 95 %: P(fewer than 20 inside) < 1 %
    assert np.sum(inside) >= 20
    assert_allclose(np.mean(ratio), 1.0, atol=0.1)


def test_posterior_takes_the_sandwich_when_the_noise_model_is_wrong():
    """1/f noise (Whittle bound known, :mod:`magcal.alignment.families`): the OU model's
    own std is 0.6x the Cramer-Rao bound, the stated sandwich within 15 % of it; the
    posterior, mapped onto the sandwich (Mueller 2013), states the same width within
    15 %, not the model's."""
    from magcal.alignment.families import draw

    dr = draw("power-law@1", np.random.default_rng(1))
    t, d, r = dr["times_s"], dr["data"], dr["ref"]
    closed = fit_alignment(t, d, r, noise_model="ou")
    assert np.all(closed.model_std_deg < 0.75 * dr["crb_std_deg"])
    assert_allclose(closed.std_deg, dr["crb_std_deg"], rtol=0.15)
    res = sample_posterior(t, d, r, np.random.default_rng(2), start=closed)
    assert res.converged
    assert_allclose(res.std_deg, closed.std_deg, rtol=0.15)
    assert "rescaled_to_sandwich" in res.mcmc
    assert np.all(np.abs(res.angles_deg - dr["truth_deg"]) < 4 * res.std_deg)
