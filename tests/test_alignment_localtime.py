"""Alignment against a model that lacks a local-time field (issue 5, second pass).

The simulated month (``simulate_month(MonthConfig(), rng=default_rng(20191101))``) has no
rotation; its data carry a local-time field T89 lacks (8 / 5 / 1.5 nT peak-to-peak),
storms, substorms and ULF waves. Offsets are removed with the simulated truth so that
only the alignment is under test.
"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose
from scipy.spatial.transform import Rotation

from magcal.alignment.checks import inflate, window_consistency
from magcal.alignment.estimator import Aligner
from magcal.alignment.gls import fit_alignment, param_names, prepare
from magcal.alignment.localtime import harmonic_basis, local_time_hours, peak_to_peak
from magcal.alignment.posterior import AlignmentPosterior, log_likelihood_direct
from magcal.alignment.synthetic import synthetic_pair

LON = 128.2
INJECTED = (1.7, -0.5, -0.5)


@pytest.fixture(scope="module")
def month():
    from magcal.simulate.month import MonthConfig, simulate_month

    return simulate_month(MonthConfig(), rng=np.random.default_rng(20191101))


def _quiet(month, rotvec_deg=None, kp_max=1.0):
    data = month.measured_nT - month.offset_nT
    if rotvec_deg is not None:
        data = Rotation.from_rotvec(np.deg2rad(rotvec_deg)).apply(month.model_nT) + (
            data - month.model_nT)
    data = data.copy()
    data[month.kp > kp_max] = np.nan
    return data


def test_local_time_field_is_not_taken_for_a_rotation(month):
    # model + the local-time field + white noise only: the pure confounding case
    data = month.model_nT + month.local_time_nT + month.noise_nT
    plain = fit_alignment(month.times, data, month.model_nT)
    # absorbed: -5.6 deg in Hn, over 20 std of the OU model, which misses the field
    assert np.max(np.abs(plain.angles_deg) / plain.model_std_deg) > 20
    # the stated (sandwich) std sees the daily field in the residual's spectrum and
    # widens (Hn 5.8x), but no width removes the bias: the fit is still wrong by > 10 std
    assert plain.std_deg[2] > 3 * plain.model_std_deg[2]
    assert np.max(np.abs(plain.angles_deg) / plain.std_deg) > 10
    res = fit_alignment(month.times, data, month.model_nT, lt_harmonics=3, lon_deg=LON)
    assert np.all(np.abs(res.angles_deg) < 3 * res.std_deg)
    assert np.all(np.abs(res.angles_deg) < 0.05)
    pp = [res.local_time["peak_to_peak_nT"][c] for c in ("Hp", "He", "Hn")]
    assert_allclose(pp, month.config.local_time_pp_nT, atol=0.1)
    # in local time the fitted Hp field is the simulated one: minimum near midnight
    coef = np.array(res.local_time["coefficients_nT"]["Hp"])
    assert coef[0] < -3.5  # -cos(LT) dominates


@pytest.mark.slow
def test_quiet_month_truth_zero_inside_interval(month):
    al = Aligner().fit(month.times, _quiet(month), month.model_nT, lon_deg=LON)
    res = al.result_
    assert al.lt_harmonics_ == 3
    assert np.all((res.ci95_deg[:, 0] < 0.0) & (0.0 < res.ci95_deg[:, 1])), res.ci95_deg
    # honest, not vacuous: the intervals are a fraction of a degree (paper: requirement 10)
    assert np.all(res.std_deg < 0.4)
    assert any("local-time signature" in w for w in res.warnings)
    check = res.checks["local_time_check"]
    assert check["strong"] and max(abs(v) for v in check["shift_sigma"].values()) > 10


@pytest.mark.slow
def test_injected_rotation_recovered_within_stated_uncertainty(month):
    res = Aligner().fit(month.times, _quiet(month, INJECTED), month.model_nT,
                        lon_deg=LON).result_
    err = res.angles_deg - np.array(INJECTED)
    assert np.all(np.abs(err) < 2 * res.std_deg), (res.angles_deg, res.std_deg)
    assert np.all(res.std_deg < 0.4)  # no systematic added: whole record agrees with windows
    assert np.all((res.ci95_deg[:, 0] < INJECTED) & (np.array(INJECTED) < res.ci95_deg[:, 1]))


@pytest.mark.slow
def test_disturbed_month_windows_disagree_and_intervals_widen(month):
    data = month.measured_nT - month.offset_nT  # every sample, storms included
    # the window checks' mechanism under the OU model (the default two-scale model's
    # windows carry more of the storm-time residual in their errors: Hn p 1e-3)
    al = Aligner(noise_model="ou").fit(month.times, data, month.model_nT, lon_deg=LON)
    res = al.result_
    cons = res.checks["window_consistency"]
    assert cons["n_windows"] == 5
    # the windows' stated (sandwich) errors already carry the storm-time residual, so
    # their disagreement is smaller in units of them than under the OU model (chi2/dof
    # over 50 there, 10.5 here), and still far beyond chance
    assert not cons["consistent"]["Hn"] and cons["p_value"]["Hn"] < 1e-6
    assert any("disagree beyond their errors" in w and "--kp" in w for w in res.warnings)
    before = np.array([res.checks["uninflated"]["std_deg"][c] for c in ("Hp", "He", "Hn")])
    factor = np.array([cons["inflation"][c] for c in ("Hp", "He", "Hn")])
    syst = np.array([res.checks["whole_vs_windows"]["systematic_deg"][c]
                     for c in ("Hp", "He", "Hn")])
    fitted_std = res.determinability.fitted_std_deg
    assert_allclose(fitted_std, np.hypot(before * factor, syst), rtol=1e-12)
    # widened twice: the sandwich over the OU model's std, then the inflation
    assert before[2] > 3 * al.closed_form_.model_std_deg[2]
    assert fitted_std[2] > 10 * al.closed_form_.model_std_deg[2]
    assert fitted_std[2] > 3 * before[2]
    # the storm bias is shared by the windows (Hp 1.03 deg for a truth of 0), which
    # inflation alone could not cover (under the OU model's std Hp stayed off 0); the
    # sandwich's intervals, inflated, hold the truth ...
    lo = res.determinability.fitted_angles_deg - 1.96 * fitted_std
    hi = res.determinability.fitted_angles_deg + 1.96 * fitted_std
    assert np.all((lo < 0.0) & (0.0 < hi)), (lo, hi)
    assert res.determinability.fitted_angles_deg[0] > 1.5 * fitted_std[0]
    # ... and the product does not deliver it: the rotation fits worse than the identity
    # (plain residual RMS). (Before the fit left residuals beyond 8 robust std out, the
    # storm peaks stayed in and Hn's inflated interval also left the +-45 deg range; the
    # refusal does not depend on that.) The warning's remedy (--kp) is what the
    # quiet-month tests exercise.
    assert not res.determinable and np.all(np.isnan(res.angles_deg))
    det = res.determinability
    assert np.sqrt(np.mean(det.rotation_rms_nT ** 2)) > np.sqrt(np.mean(det.identity_rms_nT ** 2))
    assert "more than" in det.reason and "of the identity" in det.reason


def test_marginal_likelihood_equals_direct_projection():
    case = synthetic_pair(np.random.default_rng(1), n=1500, cadence_s=300.0,
                          noise_tau_s=(1800.0,) * 3)
    t = np.arange(1500) * 300.0
    t[700:] += 3600.0
    _, d, r, _ = prepare(t, case.data, case.ref)
    basis = harmonic_basis(local_time_hours(t, LON), 3)
    names = param_names(True, True, False)
    post = AlignmentPosterior(t, d, r, names, basis=basis)
    rng = np.random.default_rng(2)
    thetas = np.array([list(np.deg2rad(case.rotvec_deg) + rng.normal(0, 0.01, 3))
                       + list(rng.normal(0, 3, 3)) + list(np.log([6.0, 2.0, 2.5]))
                       + list(np.log(rng.uniform(500, 5000, 3))) for _ in range(4)])
    fast = post.log_likelihood(thetas)
    slow = [log_likelihood_direct(th, t, d, r, names, basis=basis) for th in thetas]
    assert_allclose(fast, slow, rtol=1e-10)


def test_birge_inflation_and_student_interval():
    from magcal.alignment.windows import WindowAngles

    z, one = np.zeros((4, 3)), np.ones((4, 3))
    angles = np.array([[0.0, 0, 0], [3.0, 0, 0], [0.0, 0, 0], [3.0, 0, 0]])
    win = WindowAngles(z, z, angles, one, np.ones(4), np.array([1.5, 0, 0]), np.ones(3),
                       np.ones(3), np.array([3.0, 0.0, 0.0]), z[0], z[0])
    cons, warn = window_consistency(win)
    assert cons["inflation"] == {"Hp": pytest.approx(np.sqrt(3.0)), "He": 1.0, "Hn": 1.0}
    assert len(warn) == 1
    case = synthetic_pair(np.random.default_rng(3), n=500, cadence_s=300.0)
    res = fit_alignment(case.times, case.data, case.ref)
    wide = inflate(res, [np.sqrt(3.0), 1.0, 1.0], cons["dof"])
    assert_allclose(wide.std_deg[0], np.sqrt(3.0) * res.std_deg[0], rtol=1e-12)
    half = 3.182446305284263 * wide.std_deg[0]  # Student t, 3 dof, 97.5 %
    assert_allclose(wide.ci95_deg[0], res.angles_deg[0] + np.array([-half, half]), rtol=1e-9)
    assert_allclose(wide.ci95_deg[1:], res.ci95_deg[1:])


def test_short_record_fits_no_harmonics_and_says_why():
    case = synthetic_pair(np.random.default_rng(4), n=2000, cadence_s=60.0)  # 1.4 days
    al = Aligner().fit(case.times, case.data, case.ref)
    assert al.lt_harmonics_ == 0
    assert "cannot be separated" in al.result_.checks["local_time_check"]["note"]
    assert peak_to_peak(np.zeros((3, 2))).tolist() == [0.0, 0.0, 0.0]


def _write_month_files(month, tmp_path, data):
    from magcal.indices import write_kp_csv
    from magcal.io.csv import write_csv_frame

    idx = pd.DatetimeIndex(month.times, name="time").tz_localize("UTC")
    write_csv_frame(tmp_path / "corrected.csv",
                    pd.DataFrame(data, index=idx, columns=["Hp", "He", "Hn"]))
    write_csv_frame(tmp_path / "model.csv",
                    pd.DataFrame(month.model_nT, index=idx, columns=["Hp", "He", "Hn"]))
    write_kp_csv(tmp_path / "kp.csv", month.kp_3h)
    return tmp_path / "corrected.csv", tmp_path / "model.csv", tmp_path / "kp.csv"


@pytest.mark.slow
def test_pipeline_month_estimated_offsets_truth_inside(month):
    """The realistic chain: offsets estimated (lt_balanced, 0.7 nT drift error left), not
    the truth. Under the OU model a single whole-record fit is pulled 7 sigma off (Hp
    -2.85 +- 0.20); the windows are not, and the whole-vs-windows systematic makes the
    interval honest. The default two-scale model reads the drift error as slow noise:
    its whole-record fit is not pulled off (within 3 sigma of the windows) and its
    intervals hold the truth without a systematic."""
    from magcal.offsets import apply_offsets, fit_offsets

    cfg = month.config
    table, _ = fit_offsets(month.times, month.measured_nT, cfg.lon_deg, 0.0, cfg.r_re,
                           month.kp_3h, model="T89", kp_max=1.0, window_days=28,
                           step_days=7, method="lt_balanced")
    corrected, _, _ = apply_offsets(month.times, month.measured_nT, table)
    corrected[month.kp > 1.0] = np.nan
    two = Aligner().fit(month.times, corrected, month.model_nT, lon_deg=LON).result_
    assert np.all((two.ci95_deg[:, 0] < 0.0) & (0.0 < two.ci95_deg[:, 1])), two.ci95_deg
    assert all(abs(v) < 3 for v in two.checks["whole_vs_windows"]["difference_sigma"].values())
    res = Aligner(noise_model="ou").fit(month.times, corrected, month.model_nT,
                                        lon_deg=LON).result_
    assert np.all((res.ci95_deg[:, 0] < 0.0) & (0.0 < res.ci95_deg[:, 1])), res.ci95_deg
    whole = res.checks["whole_vs_windows"]
    assert abs(whole["difference_sigma"]["Hp"]) > 3 and whole["systematic_applied"]
    assert all(abs(whole["window_mean_deg"][c]) < 0.5 for c in ("Hp", "He", "Hn"))
    assert any("whole-record angles differ" in w for w in res.warnings)


@pytest.mark.slow
def test_cli_month_with_kp_selection_and_mcmc(month, tmp_path):
    from magcal.cli import main

    data, model, kp = _write_month_files(month, tmp_path, month.measured_nT - month.offset_nT)
    out = tmp_path / "ALIGN.json"
    assert main(["align", str(data), "--reference", str(model), "--kp", str(kp),
                 "--longitude", str(LON), "--mcmc", "--seed", "2019", "-o", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["converged"] is True and doc["lt_harmonics"] == 3
    assert doc["selection"]["kp_max"] == 1.0
    assert_allclose(doc["selection"]["quiet_fraction"], np.mean(month.kp <= 1.0 + 1e-6),
                    atol=1e-9)
    for c in ("Hp", "He", "Hn"):
        lo, hi = doc["ci95_deg"][c]
        assert lo < 0.0 < hi
        assert doc["std_deg"][c] < 0.4
    assert set(doc["windows"]["paper_style"]) == {"Hp", "He", "Hn"}
    assert doc["local_time_field"]["time_base"].startswith("local time")
    assert doc["local_time_check"]["strong"] is True
    assert doc["window_consistency"]["n_windows"] == 5
    assert doc["longitude"] == {"source": "--longitude", "lon_deg": LON}
