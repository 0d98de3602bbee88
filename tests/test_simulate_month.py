"""simulate_month: parts add up, knobs act, truths are as configured, speed."""

from __future__ import annotations

import time

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from magcal.simulate.month import (MonthConfig, boom_temperature, local_time_field,
                                   simulate_dst, simulate_month)


@pytest.fixture(scope="module")
def month():
    tic = time.perf_counter()
    res = simulate_month(MonthConfig(n_jobs=1), rng=np.random.default_rng(11))
    return res, time.perf_counter() - tic


def test_parts_sum_to_measured_and_model_is_t89(month):
    res, elapsed = month
    assert elapsed < 5.0
    n = 30 * 1440
    assert res.measured_nT.shape == (n, 3) and res.times.size == n
    total = (res.model_nT + res.offset_nT + res.local_time_nT + res.disturbed_nT + res.ulf_nT
             + res.temperature_nT + res.noise_nT)
    assert_allclose(res.measured_nT, total, atol=1e-9)
    from magcal.models.field import model_field_hpen
    direct = model_field_hpen(res.times[:50], 128.2, 0.0, 6.6, "T89", kp=res.kp[:50],
                              cadence_s=None, n_jobs=1).b_hpen_nT
    assert_allclose(res.model_nT[:50], direct, atol=1e-9)
    assert_allclose(res.offset_nT[0], [14.8, 38.4, -89.8], atol=1e-12)
    drift = res.offset_nT[-1] - res.offset_nT[0]
    assert np.all(np.abs(drift) < 2.0)          # slowly drifting
    assert_allclose(np.ptp(res.local_time_nT, axis=0), [8.0, 5.0, 1.5], atol=0.01)
    assert_allclose(res.noise_nT.std(axis=0), 0.15, rtol=0.03)


def test_kp_series_is_thirds_quiet_mostly_with_storms(month):
    res, _ = month
    kp3 = res.kp_3h.to_numpy()
    assert kp3.size == 240
    assert_allclose(kp3 * 3, np.round(kp3 * 3), atol=1e-9)
    assert 0.5 < np.mean(kp3 <= 1.0 + 1e-9) < 0.8
    assert len(res.disturbed_day_index) == 3
    for d in res.disturbed_day_index:
        assert kp3[d * 8:d * 8 + 12].max() >= 5.0
    # persistence: lag-one autocorrelation of the 3-hour series
    assert np.corrcoef(kp3[:-1], kp3[1:])[0, 1] > 0.6
    # the disturbed field lives at high Kp
    big = np.abs(res.disturbed_nT[:, 0]) > 5
    assert big.any() and np.median(res.kp[big]) >= 3
    assert res.dst.min() < -30 and res.dst.max() <= 0


def test_disturbed_days_leave_other_streams_unchanged():
    a = simulate_month(MonthConfig(n_days=5, n_disturbed_days=0, n_jobs=1),
                       rng=np.random.default_rng(2))
    b = simulate_month(MonthConfig(n_days=5, disturbed_days=(2,), n_jobs=1),
                       rng=np.random.default_rng(2))
    assert_array_equal(a.noise_nT, b.noise_nT)
    assert_array_equal(a.kp[:2 * 1440], b.kp[:2 * 1440])
    assert b.kp.max() >= 5 and a.kp.max() < 5
    assert b.disturbed_day_index == (2,)


def test_covariates_and_gaps():
    cfg = MonthConfig(n_days=3, n_jobs=1, gaps=(("2019-11-02T06:00", 2.0),),
                      temperature_coeff_nT_per_C=(0.01, 0.0, 0.0))
    res = simulate_month(cfg, rng=np.random.default_rng(3))
    cov = res.covariates_frame()
    assert cov.columns.tolist() == ["temperature", "kp", "dst", "lon_deg"]
    assert np.isnan(res.measured_nT).any(axis=1).sum() == 120
    temp = res.temperature_C
    assert temp.max() == pytest.approx(30.0, abs=0.5) and temp.min() < -80
    # the shadow lasts 8.5 h each day: the time spent below -30 C is most of it
    assert 6.0 < np.mean(temp < -30) * 24 < 8.5
    assert_allclose(res.temperature_nT[:, 0], 0.01 * (temp - 30.0))
    assert res.to_frame().index.tz is not None


def test_helpers_against_closed_forms():
    f = local_time_field(np.linspace(0, 24, 24001)[:-1], (8.0, 5.0, 1.5))
    assert_allclose(f.mean(axis=0), 0.0, atol=1e-9)
    assert_allclose(np.median(f, axis=0), 0.0, atol=1e-3)      # odd harmonics: symmetric
    hp = local_time_field(np.array([0.0, 12.0]), (8.0, 5.0, 1.5))[:, 0]
    assert hp[0] < -3.5 and hp[1] > 3.0                          # min midnight, max noon
    dst = simulate_dst(np.r_[np.full(600, 6.0), np.zeros(600)], 60.0, MonthConfig())
    tau = MonthConfig().dst_tau_h * 3600
    assert_allclose(dst[-1] / dst[599], np.exp(-600 * 60 / tau), rtol=1e-9)
    temp = boom_temperature(np.zeros(5), 60.0, MonthConfig(shadow_start_lt_h=23.0,
                                                           shadow_hours=2.0))
    assert_allclose(temp[0], -90 + 120 * np.exp(-60 / 5400), rtol=1e-12)


def test_needs_generator():
    with pytest.raises(Exception, match="Generator"):
        simulate_month(MonthConfig(n_days=1), rng=42)
