"""Determinability of the rotation (issue 13 case 1): checks against closed-form truth."""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pytest
from numpy.testing import assert_allclose

from magcal.alignment.determinability import (check_after, check_before, identity_fit,
                                              rotation_bound)
from magcal.alignment.estimator import Aligner
from magcal.alignment.gls import (fit_alignment, information_inverse, predict_and_jacobian,
                                  prepare, starting_point, variance_dof, whitened_rss)
from magcal.alignment.noise import OUNoise
from magcal.alignment.synthetic import synthetic_pair


def _white(std_nT, n):
    """A white-noise model (correlation time far below the spacing)."""
    return OUNoise(std_nT=np.full(3, float(std_nT)), tau_s=np.full(3, 1e-6),
                   effective_n=np.full(3, float(n)), tau_at_bound=(False,) * 3)


def _skew_gram(c):
    """sum_i skew(c_i)^T skew(c_i) = sum_i (|c_i|^2 I - c_i c_i^T)."""
    return np.sum(np.sum(c ** 2, axis=1)) * np.eye(3) - c.T @ c


def test_bound_equals_closed_form_for_white_noise(rng):
    # For white isotropic noise the information of w with a fitted offset is
    # sum_i skew(r_i - mean r)^T skew(r_i - mean r) / sigma^2 (the offset absorbs the mean).
    n, sigma = 500, 0.7
    times = np.datetime64("2019-03-01", "ns") + np.arange(n) * np.timedelta64(60, "s")
    ref = rng.normal(0.0, 20.0, size=(n, 3)) + [100.0, 10.0, 0.0]
    data = ref + rng.normal(0.0, sigma, size=(n, 3))
    ident = dataclasses.replace(identity_fit(times, data, ref), noise=_white(sigma, n))
    crb, alone, _ = rotation_bound(times, data, ref, ident)
    centred = ref - ref.mean(axis=0)
    expect = np.sqrt(np.diag(np.linalg.inv(_skew_gram(centred) / sigma ** 2)))
    expect_alone = np.sqrt(np.diag(np.linalg.inv(_skew_gram(ref) / sigma ** 2)))
    assert_allclose(crb, np.rad2deg(expect), rtol=1e-6)
    assert_allclose(alone, np.rad2deg(expect_alone), rtol=1e-6)


def test_constant_reference_rotation_not_determinable():
    # R(w) @ r + o == r + o' for a constant r: no rotation is identifiable at all.
    n = 300
    times = np.datetime64("2019-03-01", "ns") + np.arange(n) * np.timedelta64(60, "s")
    ref = np.tile([100.0, 20.0, -5.0], (n, 1))
    data = ref + np.random.default_rng(5).normal(0.0, 0.5, size=(n, 3))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        al = Aligner().fit(times, data, ref)
    res = al.result_
    assert not res.determinable
    assert np.all(np.isnan(res.angles_deg)) and np.all(np.isnan(res.std_deg))
    assert not any(res.significant())
    assert np.all(res.determinability.crb_std_deg > 45.0)
    assert "Cramer-Rao" in res.determinability.reason
    doc = res.to_json()
    assert doc["determinable"] is False and doc["angles_deg"]["Hp"] is None
    assert doc["reason"] == res.determinability.reason
    with pytest.raises(Exception, match="no rotation to undo"):
        al.transform(data)


def test_minutes_of_slowly_turning_field_not_determinable():
    # Ten minutes of a geostationary-like field at 1 s: the reference turns by well
    # under a nT while the noise is 0.3 nT, as in the GOES-16 minutes.
    case = synthetic_pair(np.random.default_rng(11), n=600, cadence_s=1.0,
                          rotvec_deg=(1.0, -0.5, 0.5), noise_std_nT=(0.3,) * 3,
                          noise_tau_s=(3.0,) * 3)
    res = Aligner().fit(case.times, case.data, case.ref).result_
    det = res.determinability
    assert not res.determinable and det.reason.startswith("with the offset fitted")
    assert np.all(det.crb_std_deg > 45.0 / 1.96) or np.any(det.crb_std_deg > 45.0)
    assert_allclose(det.reference_variation_nT, case.ref.std(axis=0), rtol=1e-12)
    # the identity leaves the injected noise (plus the rotation of the mean field, which
    # the offset absorbs)
    assert np.all(det.identity_rms_nT < 2 * 0.3)


def test_harmonics_over_less_than_a_day_not_determinable():
    case = synthetic_pair(np.random.default_rng(2), n=144, cadence_s=300.0)  # 12 h
    res = Aligner(lt_harmonics=3, window_days=None).fit(case.times, case.data,
                                                        case.ref).result_
    assert not res.determinable
    assert "less than the 24 h period of the local-time harmonics" in res.determinability.reason
    assert res.determinability.nuisance_periods_s == (86400.0, 43200.0, 28800.0)


def test_well_sampled_rotation_is_determinable_and_bound_matches_std():
    case = synthetic_pair(np.random.default_rng(4), n=2000, cadence_s=300.0,
                          rotvec_deg=(3.0, -1.0, 0.5), noise_tau_s=(1800.0,) * 3)
    res = Aligner().fit(case.times, case.data, case.ref).result_
    det = res.determinability
    assert res.determinable and det.reason is None and res.to_json()["reason"] is None
    assert np.all(np.abs(res.angles_deg - case.rotvec_deg) < 4 * res.std_deg)
    # the rotation removes the injected rotation's signature: better than the identity
    assert np.sqrt(np.mean(det.rotation_rms_nT ** 2)) < np.sqrt(np.mean(det.identity_rms_nT ** 2))
    # the bound at the identity (noise fitted there, larger) is no smaller than the std,
    # and within 1.5x of it: the same information, evaluated at w = 0
    assert np.all(det.crb_std_deg > 0.9 * res.std_deg)
    assert np.all(det.crb_std_deg < 1.5 * res.std_deg)


def test_rotation_beyond_the_sensible_range_is_flagged_and_allowed_when_widened():
    case = synthetic_pair(np.random.default_rng(8), n=1500, cadence_s=300.0,
                          rotvec_deg=(0.0, 0.0, 60.0), noise_tau_s=(1800.0,) * 3)
    res = Aligner().fit(case.times, case.data, case.ref).result_
    assert not res.determinable and "+-45 deg" in res.determinability.reason
    det = res.determinability
    assert abs(det.fitted_angles_deg[2] - 60.0) < 4 * det.fitted_std_deg[2]
    wide = Aligner(max_angle_deg=90.0).fit(case.times, case.data, case.ref).result_
    assert wide.determinable
    assert abs(wide.angles_deg[2] - 60.0) < 4 * wide.std_deg[2]


def test_check_after_rejects_a_fit_worse_than_the_identity():
    case = synthetic_pair(np.random.default_rng(6), n=2000, cadence_s=300.0,
                          rotvec_deg=(0.0, 0.0, 0.0), noise_tau_s=(1800.0,) * 3)
    ident = identity_fit(case.times, case.data, case.ref)
    before = check_before(case.times, case.data, case.ref, ident)
    fit = fit_alignment(case.times, case.data, case.ref)
    assert check_after(fit, before).determinable
    worse = dataclasses.replace(fit, residual_rms_nT=ident.residual_rms_nT * 1.05)
    verdict = check_after(worse, before)
    assert not verdict.determinable and "more than" in verdict.reason
    assert_allclose(verdict.fitted_angles_deg, fit.angles_deg)


def test_gauss_newton_never_ends_worse_than_its_start():
    # near-degenerate case: the refinement may not run away from its start (it reached
    # 1e6 deg and 34-88 nT residuals on the GOES minutes before step halving)
    case = synthetic_pair(np.random.default_rng(11), n=600, cadence_s=1.0,
                          noise_std_nT=(0.3,) * 3, noise_tau_s=(3.0,) * 3)
    ident = identity_fit(case.times, case.data, case.ref)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no invalid log/sqrt from a singular information
        fit = fit_alignment(case.times, case.data, case.ref, noise=ident.noise)
    t, d, r, _ = prepare(case.times, case.data, case.ref)
    names = fit.param_names
    start = starting_point(d, r, names)
    theta = np.concatenate([np.deg2rad(np.nan_to_num(fit.angles_deg)), fit.offset_nT])
    end = whitened_rss(t, d, predict_and_jacobian(theta, names, r)[0], ident.noise)
    begin = whitened_rss(t, d, predict_and_jacobian(start, names, r)[0], ident.noise)
    assert end <= begin * (1 + 1e-9)


def test_singular_information_gives_nan_not_negative_variance():
    a = np.array([[1.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.0, 2.0]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert np.all(np.isnan(information_inverse(a)))
        assert np.all(np.isnan(information_inverse(-np.eye(2))))
    assert_allclose(information_inverse(np.diag([4.0, 0.25])), np.diag([0.25, 4.0]))


def test_variance_dof_conservative_when_parameters_not_identified():
    from magcal.alignment.gls import component_stats, noise_stats, param_names

    n = 200
    times = np.arange(n) * 60.0
    ref = np.tile([100.0, 20.0, -5.0], (n, 1))
    data = ref + np.random.default_rng(1).normal(0.0, 0.5, size=(n, 3))
    names = param_names(True, True)
    theta = np.zeros(6)
    mu, jac = predict_and_jacobian(theta, names, ref)
    noise = _white(0.5, n)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        dof = variance_dof(component_stats(times, data, mu, jac),
                           noise_stats(times, data, mu, jac), noise)
    assert_allclose(dof, 1.0)
