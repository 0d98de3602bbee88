"""Alignment under outliers that passed quality control, and the OU + white noise model
(issues 20 part 3 and 21)."""

import numpy as np
import pytest

from magcal.alignment.gls import fit_alignment, outlier_rows
from magcal.alignment.ouwhite import fit_component, simulate
from magcal.alignment.synthetic import synthetic_pair

TRUTH = np.array([1.7, -0.5, -0.5])


@pytest.fixture(scope="module")
def clean():
    case = synthetic_pair(np.random.default_rng(20), n=8 * 1440, cadence_s=60.0,
                          rotvec_deg=TRUTH, noise_std_nT=(2.0, 2.0, 2.0),
                          noise_tau_s=(3600.0,) * 3)
    return case, fit_alignment(case.times, case.data, case.ref, noise_model="ou")


def _check(res, clean_res):
    assert np.all(np.abs(res.angles_deg - TRUTH) < 3 * res.std_deg)
    assert np.all(np.abs(res.std_deg / clean_res.std_deg - 1) < 0.10)


def test_spikes_do_not_ruin_the_alignment(clean):
    case, ref_res = clean
    data = case.data.copy()
    day = slice(3 * 1440, 4 * 1440)
    idx = np.arange(data.shape[0])[day][::97]
    data[idx, 1] = 1e6  # one component at 1e6 nT every 97th sample of one day
    res = fit_alignment(case.times, data, case.ref, noise_model="ou")
    _check(res, ref_res)
    assert res.n_used == data.shape[0] - idx.size
    assert any("outliers" in w for w in res.warnings)


def test_saturation_does_not_ruin_the_alignment(clean):
    case, ref_res = clean
    data = case.data.copy()
    data[5000:5400] = 65535.0  # all three components stuck for 400 samples
    res = fit_alignment(case.times, data, case.ref, noise_model="ou")
    _check(res, ref_res)


def test_clean_data_lose_no_sample(clean):
    _, res = clean
    assert res.n_used == 8 * 1440 and not res.warnings


def test_outlier_rows_flags_only_gross_values():
    x = np.random.default_rng(0).normal(size=(20000, 3))
    assert not outlier_rows(x, 8.0).any()
    x[[5, 50]] = 40.0
    assert np.flatnonzero(outlier_rows(x, 8.0)).tolist() == [5, 50]


def test_ou_plus_white_recovers_time_constant_a_pure_ou_fit_misses():
    """The issue's case: OU 2 nT tau 1 h plus 0.3 nT white at 1 min. A pure OU fit read
    tau ~1450 s; the OU + white fit must find 3600 s within 25 %, and the white part."""
    rng = np.random.default_rng(7)
    t = np.arange(10 * 1440) * 60.0
    x = simulate(rng, t, 2.0, 3600.0, 0.3)
    std, tau, white, at_bound = fit_component(x, t, design=np.ones((t.size, 1)))
    assert abs(tau / 3600.0 - 1) < 0.25 and abs(white / 0.3 - 1) < 0.15
    assert abs(std / 2.0 - 1) < 0.2 and not at_bound


def test_ou_plus_white_alignment_coverage_short():
    """Short version of the benchmark's OU + white family: 8 draws x 3 angles of 10 days
    at 10 min; std within 1.2x the exact Cramer-Rao bound and |z| < 3.5 everywhere, and
    at least 20 of the 24 95 % intervals hold the truth (the full 50-draw table is
    benchmarks/bench_alignment.py --families)."""
    from magcal.alignment.families import draw

    inside, ratio, z = [], [], []
    for s in range(8):
        dr = draw("ou+white", np.random.default_rng(900 + s), n=720)
        res = fit_alignment(dr["times_s"], dr["data"], dr["ref"], noise_model="ou+white")
        ci = np.asarray(res.ci95_deg)
        inside.append((ci[:, 0] <= dr["truth_deg"]) & (dr["truth_deg"] <= ci[:, 1]))
        ratio.append(res.std_deg / dr["crb_std_deg"])
        z.append((res.angles_deg - dr["truth_deg"]) / res.std_deg)
    assert np.sum(inside) >= 20
    assert np.all(np.abs(z) < 3.5)
    assert np.all(np.median(ratio, axis=0) < 1.2) and np.all(np.median(ratio, axis=0) > 0.8)


def test_a_200_minute_gap_leaves_the_std_stable():
    """Issue 20: 400 saturated 30 s samples masked (a 200-min gap) in 35 days moved the
    alignment's Hn std by -24 %. Under the fitted noise model a gap of 0.4 % of the
    record removes ~0.4 % of the information: std within 10 % of the no-gap fit, and
    the estimates stay within 3 std of the truth."""
    case = synthetic_pair(np.random.default_rng(21), n=35 * 1440, cadence_s=60.0,
                          rotvec_deg=TRUTH, noise_std_nT=(2.0, 2.0, 2.0),
                          noise_tau_s=(3600.0,) * 3)
    full = fit_alignment(case.times, case.data, case.ref, noise_model="ou+white")
    data = case.data.copy()
    data[20000:20200] = np.nan  # 200 min cut
    gap = fit_alignment(case.times, data, case.ref, noise_model="ou+white")
    assert gap.n_used == full.n_used - 200
    assert np.all(np.abs(gap.std_deg / full.std_deg - 1) < 0.10)
    for res in (full, gap):
        assert np.all(np.abs(res.angles_deg - TRUTH) < 3 * res.std_deg)
