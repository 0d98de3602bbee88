"""Offsets: averaging, window statistics, apply, product I/O, recovery on a simulated month."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from magcal.errors import InputError
from magcal.offsets import (OffsetEstimator, apply_offsets, average_to_cadence,
                            interpolate_offsets, quiet_mask, read_offsets_csv,
                            window_grid, window_statistics, write_offsets_csv)
from magcal.offsets.table import CONTRACT_COLUMNS
from magcal.offsets.windows import DAY_NS

MIN = np.timedelta64(60, "s")

# MAD -> standard deviation of a normal distribution, 1 / Phi^-1(3/4).
MAD_TO_STD = 1.0 / 0.6744897501960817


def test_average_never_bridges_gaps():
    t = np.datetime64("2019-11-01T00:00", "ns") + np.arange(600) * np.timedelta64(1, "s")
    v = np.stack([np.arange(600.0), -np.arange(600.0)], axis=1)
    v[150:320] = np.nan           # minute 2 empty, minutes 3 and 5 partly covered
    bt, m, c = average_to_cadence(t, v, 60.0, min_fraction=0.5)
    minutes = ((bt - t[0]) // MIN).astype(int).tolist()
    # minute 2 (120-179): 30 samples = 0.5 -> kept; 3, 4 empty; 5 (300-359): 40 -> kept
    assert minutes == [0, 1, 2, 5, 6, 7, 8, 9]
    assert_allclose(m[2], [134.5, -134.5])
    assert_allclose(m[3], [339.5, -339.5])
    assert_array_equal(c, [60, 60, 30, 40, 60, 60, 60, 60])
    assert str(bt[0])[11:19] == "00:00:30"   # bin centres


def test_quiet_mask_excludes_one_plus():
    assert_array_equal(quiet_mask([0, 1 / 3, 2 / 3, 1.0, 4 / 3, 1.3, np.nan], 1.0),
                       [True, True, True, True, False, False, False])


def test_window_grid_and_statistics_against_hand_values():
    s, e = window_grid(0, int(59.5 * DAY_NS), 28, 7)
    assert ((s // DAY_NS).tolist(), (e // DAY_NS).tolist()) == ([0, 7, 14, 21, 28, 35],
                                                              [28, 35, 42, 49, 56, 63])
    gen = np.random.default_rng(3)
    t = np.arange(0, 60 * 1440) * 60 * 10**9
    d = gen.normal(size=(t.size, 3)) * [1, 2, 3] + [5, -5, 0]
    sel = gen.random(t.size) < 0.6
    d[::97] = np.nan
    st = window_statistics(t, d, sel, s, e, min_used=10)
    for i in (0, 5):
        m = (t >= s[i]) & (t < e[i]) & sel & np.all(np.isfinite(d), axis=1)
        avail = (t >= s[i]) & (t < e[i]) & np.all(np.isfinite(d), axis=1)
        x = d[m]
        assert_allclose(st["median"][i], np.median(x, axis=0), rtol=0, atol=1e-12)
        assert_allclose(st["std"][i], np.std(x, axis=0, ddof=1), rtol=1e-12)
        assert_allclose(st["mad"][i], MAD_TO_STD * np.median(np.abs(x - np.median(x, 0)), 0))
        assert st["n_used"][i] == m.sum() and st["n_available"][i] == avail.sum()
        assert_allclose(st["fraction_used"][i], m.sum() / avail.sum())
    assert_allclose(st["mad"][0], [1, 2, 3], rtol=0.05)
    # no quiet data after day 50: the last window [35, 63) keeps ~15 quiet days (~13000
    # samples), the first ~24000; with min_used=20000 the last is NaN with a reason
    st2 = window_statistics(t, d, sel & (t < 50 * DAY_NS), s, e, min_used=20000)
    assert np.all(np.isnan(st2["median"][5])) and st2["reason"][5].startswith("too few")
    assert st2["reason"][0] == ""
    empty = window_statistics(t, d, sel, [100 * DAY_NS], [128 * DAY_NS])
    assert empty["reason"] == ["no data in window"] and np.isnan(empty["fraction_used"][0])


def test_interpolation_holds_ends_and_skips_nan_windows():
    c = np.array(["2019-11-15", "2019-11-22", "2019-11-29"], dtype="datetime64[ns]")
    off = np.array([[1.0, 2, 3], [np.nan, 0, 0], [3.0, 4, 5]])
    t = np.array(["2019-11-01", "2019-11-22", "2019-12-20"], dtype="datetime64[ns]")
    o, f = interpolate_offsets(t, c, off)
    assert_allclose(o, [[1, 2, 3], [2, 3, 4], [3, 4, 5]])
    # the middle sample lies between two valid centres with a skipped one between them
    assert_array_equal(f, [1, 4, 2])
    o, f = interpolate_offsets(t, c[:1], [[np.nan, 1, 1]])
    assert np.all(np.isnan(o)) and np.all(f == 3)


def _fit_sim(res, kp_max=1.0, method="lt_balanced"):
    est = OffsetEstimator(kp_max=kp_max, method=method).fit(
        res.times, res.measured_nT, res.model_nT, res.kp, lon_deg=res.config.lon_deg)
    tab = est.table_
    truth = np.array([res.offset_nT[(res.times >= a) & (res.times < b)].mean(axis=0)
                      for a, b in zip(tab.start, tab.end)])
    return tab, np.abs(tab.offset_nT - truth)


@pytest.fixture(scope="module")
def months():
    from magcal.simulate.month import MonthConfig, simulate_month

    quiet = simulate_month(MonthConfig(n_disturbed_days=0, n_jobs=1),
                           rng=np.random.default_rng(4))
    stormy = simulate_month(MonthConfig(n_disturbed_days=4, n_jobs=1),
                            rng=np.random.default_rng(4))
    return quiet, stormy


def test_offsets_recovered_on_simulated_month(months):
    quiet, stormy = months
    assert len(stormy.disturbed_day_index) == 4 and stormy.kp.max() >= 5
    assert np.ptp(stormy.local_time_nT[:, 0]) == pytest.approx(8.0, abs=0.01)
    tab_q, err_q = _fit_sim(quiet)
    tab_s, err_s = _fit_sim(stormy)
    assert len(tab_s) == 2 and np.all(tab_s.valid)
    assert np.all(err_q < 0.5) and np.all(err_s < 0.5), (err_q, err_s)
    # adding disturbed days does not degrade the estimate (Kp selection at work) ...
    assert err_s.max() <= err_q.max() + 0.15
    # ... while without the selection the storms bias Hp
    _, err_all = _fit_sim(stormy, kp_max=9.0)
    assert err_all[:, 0].max() > err_s[:, 0].max() + 0.1
    assert np.all(tab_s.fraction_used < tab_q.fraction_used)


def test_plain_median_is_the_contract_definition(months):
    _, stormy = months
    tab, _ = _fit_sim(stormy, method="median")
    q = quiet_mask(stormy.kp, 1.0)
    diff = stormy.measured_nT - stormy.model_nT
    m = q & (stormy.times >= tab.start[0]) & (stormy.times < tab.end[0])
    assert_allclose(tab.offset_nT[0], np.median(diff[m], axis=0), atol=1e-12)
    assert tab.n_used[0] == m.sum()


def test_product_csv_roundtrip_and_apply(tmp_path, months):
    _, stormy = months
    tab, _ = _fit_sim(stormy)
    path = write_offsets_csv(tmp_path / "OFFSETS.csv", tab)
    header = path.read_text().splitlines()[0].split(",")
    assert tuple(header[:11]) == CONTRACT_COLUMNS
    assert header[11:] == ["Hp_mad", "He_mad", "Hn_mad", "n_available", "reason",
                           "days_covered", "lt_hours_covered", "Hp_se", "He_se", "Hn_se",
                           "Hp_dof", "He_dof", "Hn_dof"]
    assert (tmp_path / "OFFSETS.csv.provenance.json").exists()
    back = read_offsets_csv(path)
    assert_array_equal(back.days_covered, tab.days_covered)
    assert_array_equal(back.lt_hours_covered, tab.lt_hours_covered)
    assert_allclose(back.offset_nT, tab.offset_nT, atol=6e-5)
    assert_allclose(back.se_nT, tab.se_nT, atol=6e-5)  # CONTRACTS 7.1 standard errors
    assert_array_equal(back.center, tab.center)
    corrected, off, flag = apply_offsets(stormy.times, stormy.measured_nT, back)
    assert set(np.unique(flag)) == {0, 1, 2}
    resid = corrected - (stormy.measured_nT - stormy.offset_nT)
    assert np.max(np.abs(resid[flag == 0])) < 0.5      # between centres: the window error
    assert_allclose(off[flag == 1], np.broadcast_to(back.offset_nT[0], off[flag == 1].shape))
    assert_allclose(off[flag == 2], np.broadcast_to(back.offset_nT[-1], off[flag == 2].shape))
    bad = tmp_path / "bad.csv"
    bad.write_text("center,start,end,Hp\n2019-11-15T00:00:00,2019-11-01,2019-11-29,1\n")
    with pytest.raises(InputError, match="missing column"):
        read_offsets_csv(bad)
    frame = tab.to_frame()
    frame["Hp"] = frame["Hp"].astype(object)
    frame.loc[1, "Hp"] = "x"
    frame.to_csv(bad, index=False)
    with pytest.raises(InputError, match="row 3: column Hp"):
        read_offsets_csv(bad)


def test_real_kp_november_2019_fraction(real_data):
    """Kp <= 1.0 over November 2019, from the CelesTrak file (read by hand: 156 of 240)."""
    from magcal.indices import kp_at, read_kp

    path = real_data("indices", "celestrak_SW_2017-2023_subset.txt")
    by_hand = []
    for line in path.read_text().splitlines():
        if line.startswith("2019 11 "):
            by_hand += [int(line[18 + 3 * i:21 + 3 * i]) for i in range(8)]
    assert len(by_hand) == 240
    n_quiet = sum(v <= 10 for v in by_hand)
    t = np.datetime64("2019-11-01", "ns") + np.arange(30 * 1440) * MIN
    kp = kp_at(read_kp(path), t)
    frac = quiet_mask(kp, 1.0).mean()
    assert frac == pytest.approx(n_quiet / 240, abs=1e-12)
    assert round(100 * frac) == 65     # the paper: "the index alone gives 65%"
    # through the estimator: one 30-day window, all data available
    est = OffsetEstimator(window_days=30, step_days=30).fit(
        t, np.zeros((t.size, 3)), np.zeros((t.size, 3)), kp)
    assert est.table_.fraction_used[0] == pytest.approx(n_quiet / 240, abs=1e-12)


def test_bad_usage():
    t = np.datetime64("2019-11-01", "ns") + np.arange(10) * MIN
    with pytest.raises(InputError, match="needs the longitude"):
        OffsetEstimator(method="lt_balanced").fit(t, np.zeros((10, 3)), np.zeros((10, 3)),
                                                  np.zeros(10))
    with pytest.raises(InputError, match="Kp values"):
        OffsetEstimator().fit(t, np.zeros((10, 3)), np.zeros((10, 3)), np.zeros(9))
    with pytest.raises(InputError, match="increasing"):
        OffsetEstimator().fit(t[::-1], np.zeros((10, 3)), np.zeros((10, 3)), np.zeros(10))
    assert isinstance(pd.Timestamp(t[0]), pd.Timestamp)


@pytest.mark.parametrize("window_days, step_days, name", [
    (np.nan, 7.0, "window_days"), (np.inf, 7.0, "window_days"), (28.0, np.nan, "step_days"),
    (-1.0, 7.0, "window_days")])
def test_window_grid_refuses_non_finite_or_non_positive(window_days, step_days, name):
    # sweep: NaN and inf reached int(round(...)) and crashed (ValueError, OverflowError)
    with pytest.raises(InputError, match=f"{name} must be a finite number > 0"):
        window_grid(0, 30 * 86_400_000_000_000, window_days, step_days)


def test_window_without_data_names_the_all_nan_column():
    # sweep: an all-NaN Hp column gave every window "no data in window", naming nothing
    t = np.datetime64("2019-11-01", "ns") + np.arange(3 * 1440) * MIN
    data = np.ones((t.size, 3))
    data[:, 0] = np.nan
    tab = OffsetEstimator(window_days=1, step_days=1, min_used=10).fit(
        t, data, np.zeros_like(data), np.zeros(t.size)).table_
    assert not tab.valid.any()
    assert set(tab.reason) == {"no data in window: column Hp has no finite value"}
    # a plain gap (every column empty) keeps the plain reason
    st = window_statistics(t.astype(np.int64), data, np.ones(t.size, bool),
                           [0], [1], min_used=1, columns=("Hp", "He", "Hn"))
    assert st["reason"] == ["no data in window"]
