"""Unit tests of the discovery building blocks against closed forms."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose

from magcal.discover.effects import (Diurnal, EffectInputs, Rotation, Scale, Step,
                                     local_time_h)
from magcal.discover.inputs import build_inputs, covariates_on, to_unix_seconds
from magcal.discover.scan import scan_periods, scan_step
from magcal.discover.selection import BlockedGram, compare, time_blocks, wald_z


def _inputs(n=2000, m=3, rng=None):
    t = 1.5e9 + np.arange(n) * 600.0
    model = np.column_stack([100 + 10 * np.sin(t / 5e4), 20 * np.cos(t / 7e4), -30 + 0 * t])
    return EffectInputs(t, model[:, :m], ("Hp", "He", "Hn")[:m],
                        local_time_h=local_time_h(t, 128.2))


def test_local_time_closed_form():
    t = pd.Timestamp("2019-11-01T03:00:00Z").value / 1e9
    assert_allclose(local_time_h(np.array([t]), 128.2), [3 + 128.2 / 15])
    assert_allclose(local_time_h(np.array([t]), -90.0), [21.0])


def test_blocked_gram_matches_lstsq_and_exact_loo(rng):
    inp = _inputs()
    cols = np.concatenate([Diurnal(("Hp", "He"), harmonics=2).columns(inp),
                           Scale(("Hn",)).columns(inp), Rotation(("Hp", "He", "Hn")).columns(inp)])
    beta_true = rng.normal(size=cols.shape[0]) * 0.01
    y = np.tensordot(beta_true, cols, 1) + rng.normal(0, 0.1, (inp.n, 3))
    y[5, 1] = np.nan
    blocks = time_blocks(inp.times_s, block_s=86400.0)
    g = BlockedGram(y, blocks)
    idx = g.add(cols)
    s = g.score(idx)
    X = cols.reshape(cols.shape[0], -1).T
    yy = y.reshape(-1)
    ok = np.isfinite(yy)
    ref, *_ = np.linalg.lstsq(X[ok], yy[ok], rcond=None)
    assert_allclose(s.beta, ref, rtol=1e-7, atol=1e-10)
    # held-out error of block 3 from an explicit refit without it
    b = 3
    rows = np.repeat(blocks, 3)
    train = ok & (rows != b)
    test = ok & (rows == b)
    beta_b, *_ = np.linalg.lstsq(X[train], yy[train], rcond=None)
    assert_allclose(s.sse_blocks[b], np.sum((yy[test] - X[test] @ beta_b) ** 2), rtol=1e-7)
    assert_allclose(s.sse_in, np.sum((yy[ok] - X[ok] @ ref) ** 2), rtol=1e-7)


def test_wald_detects_signal_and_not_noise(rng):
    inp = _inputs(n=4000, m=1)
    step = Step(("Hp",), t_step_s=float(inp.times_s[2500])).columns(inp)
    ones = np.ones((1, inp.n, 1))
    noise = rng.normal(0, 1.0, (inp.n, 1))
    blocks = time_blocks(inp.times_s)
    for size, expect in ((0.0, False), (0.5, True)):
        g = BlockedGram(noise + size * step[0], blocks)
        base_cols = g.add(ones)
        cols = g.add(step)
        base = g.score(base_cols)
        cand = g.score(base_cols + cols)
        assert (compare(base, cand).z > 4) is expect
        assert (wald_z(cand, [1]) > 4) is expect


def test_scan_step_and_period(rng):
    t = np.arange(0, 20 * 86400, 60.0)
    r = np.column_stack([np.where(t >= 7.25 * 86400, 1.0, 0.0),
                         0.8 * np.cos(2 * np.pi * t / (5.5 * 3600))])
    r = r + rng.normal(0, 0.5, (t.size, 2))
    ts, size, _ = scan_step(t, r[:, :1])
    assert abs(ts - 7.25 * 86400) < 3600
    assert_allclose(size, [1.0], atol=0.05)
    peaks = scan_periods(t, r[:, 1:])
    assert_allclose(peaks[0][0] / 3600, 5.5, rtol=0.002)


def test_a_step_at_the_edge_of_a_week_long_gap_is_found_not_a_crash(rng):
    """Issue 20: an 8-day hole in a 35-day record made change_points ask scan_step for
    the step inside the hole (no sample there): IndexError. The step (2 nT, at the
    end of the hole) must come back as a change time at the gap's end or inside it."""
    from magcal.discover.scan import change_points

    t = np.arange(0, 35 * 86400, 60.0)
    t = t[(t < 12 * 86400) | (t >= 20 * 86400)]
    r = np.where(t >= 20 * 86400, 2.0, 0.0)[:, None] + rng.normal(0, 0.3, (t.size, 1))
    found = change_points(t, r)
    assert len(found) == 1
    assert 12 * 86400 - 3600 <= found[0][0] <= 20 * 86400 + 3600
    assert scan_step(t[:0], r[:0])[0] is None
    assert scan_step(t[:1], r[:1])[0] is None


def test_inputs_interpolate_covariates_and_hold_kp():
    t = pd.date_range("2019-11-01", periods=360, freq="1min", tz="UTC")
    cov = pd.DataFrame({"kp": [1.0, 2.0, 3.0], "temperature": [0.0, 30.0, 60.0]},
                       index=pd.DatetimeIndex(["2019-11-01T00:00Z", "2019-11-01T03:00Z",
                                               "2019-11-01T06:00Z"]))
    out = covariates_on(to_unix_seconds(t), cov)
    assert_allclose(out["kp"][[0, 179, 180, 359]], [1, 1, 2, 2])
    assert_allclose(out["temperature"][90], 15.0)
    model = pd.DataFrame({"Hp": np.ones(360)}, index=t)
    inputs, index = build_inputs(None, model, ("Hp",), {"lon_deg": np.full(360, -90.0)})
    assert_allclose(inputs.local_time_h[0], 18.0)
    assert index.equals(t)


def test_cumsum_costs_equal_ruptures_own_costs():
    """The O(1) costs give ruptures' l2 and clinear segment costs (its reference
    implementations) to 1e-8 relative, on 1- and 2-column random walks, and the same
    binary segmentation."""
    import ruptures as rpt
    from ruptures.costs import CostCLinear, CostL2

    from magcal.discover.costs import CumsumCLinear, CumsumL2

    rng = np.random.default_rng(3)
    for dim in (1, 2):
        x = np.cumsum(rng.normal(0, 1, (500, dim)), axis=0) + 40.0
        for ref, fast in ((CostL2(), CumsumL2()), (CostCLinear(), CumsumCLinear())):
            ref.fit(x)
            fast.fit(x)
            for _ in range(300):
                s = int(rng.integers(0, 490))
                e = int(rng.integers(s + 3, 501))
                assert fast.error(s, e) == pytest.approx(ref.error(s, e), rel=1e-8, abs=1e-8)
    y = np.concatenate([np.zeros(200), np.full(150, 3.0), np.ones(150)])[:, None]
    y = y + rng.normal(0, 0.5, y.shape)
    for model, cost in (("l2", CumsumL2()), ("clinear", CumsumCLinear())):
        a = rpt.Binseg(model=model, min_size=10, jump=1).fit(y).predict(pen=20.0)
        b = rpt.Binseg(custom_cost=cost, min_size=10, jump=1).fit(y).predict(pen=20.0)
        assert a == b


def _direct_acf(x):
    """Autocovariance sums at every lag by np.correlate (NaN as zero after centring)."""
    ok = np.isfinite(x)
    v = np.where(ok, x - x[ok].mean(), 0.0)
    return np.correlate(v, v, "full")[v.size - 1:]


def test_autocorrelation_equals_the_direct_sums_at_every_lag_asked(rng):
    from magcal.discover.selection import autocorrelation

    n = 3000
    x = np.convolve(rng.normal(size=n + 40), np.ones(40), "valid")[:n]
    x[rng.random(n) < 0.1] = np.nan
    direct = _direct_acf(x)
    direct = direct / direct[0]
    assert_allclose(autocorrelation(x), direct, atol=1e-12)
    for lag in (0, 1, 37, 999, n - 2, n - 1, 5 * n):
        assert_allclose(autocorrelation(x, lag), direct[:lag + 1], atol=1e-12)
    cols = np.column_stack([x, rng.normal(size=n), np.zeros(n)])
    got = autocorrelation(cols, 200)
    assert_allclose(got[:, 0], direct[:201], atol=1e-12)
    assert_allclose(got[:, 1], _direct_acf(cols[:, 1])[:201] / _direct_acf(cols[:, 1])[0],
                    atol=1e-12)
    assert not got[:, 2].any()  # a constant has no autocorrelation: zero, not NaN


def test_integrated_autocorr_time_is_sokals_definition_within_and_beyond_the_first_lags(rng):
    """Sokal's tau summed to the first lag M >= 5 tau, from all lags by np.correlate:
    the same whether M lies within the lags computed first (white, a short correlation)
    or beyond them (a 0.9995 AR(1), tau ~ 4000; a random walk)."""
    from magcal.discover.selection import _FIRST_LAGS, integrated_autocorr_time

    def sokal(x):
        v = x[np.isfinite(x)]
        acf = _direct_acf(v)
        taus = 2.0 * np.cumsum(acf / acf[0]) - 1.0
        window = np.arange(v.size) >= 5.0 * taus
        m = int(np.argmax(window)) if window.any() else v.size - 1
        return max(float(taus[m]), 1.0), m

    n = 30000
    e = rng.normal(size=n)
    ar = np.zeros(n)
    for i in range(1, n):
        ar[i] = 0.9995 * ar[i - 1] + e[i]
    short = np.convolve(e, np.ones(20) / 20, "same")
    short[rng.random(n) < 0.05] = np.nan
    windows = []
    for x in (e, short, ar, np.cumsum(e)):
        tau, m = sokal(x)
        windows.append(m)
        assert integrated_autocorr_time(x) == pytest.approx(tau, rel=1e-10)
    # the cases reach both branches: a window within the first lags and beyond them
    assert windows[0] < _FIRST_LAGS and windows[1] < _FIRST_LAGS
    assert windows[2] > _FIRST_LAGS and windows[3] > _FIRST_LAGS
    # white noise: one sample per sample, to the estimate's own scatter
    assert integrated_autocorr_time(e) == pytest.approx(1.0, abs=0.1)


def test_model_covariance_of_a_trend_in_white_noise_is_the_ols_variance(rng):
    """A slope fitted with a level in white noise of std 2: variance
    sigma^2 / sum((t - mean t)^2), the closed form. Tolerance 15 %: the Bartlett factor
    sums the noise's sample autocorrelation over the first 10 lags, which scatters by
    2 sqrt(10 / n) = 4.5 % around 1 for white noise."""
    from magcal.discover.selection import model_covariance

    n = 20000
    t = np.arange(n) * 60.0
    x = (t - t.mean()) / t.std()
    y = 0.3 * x + rng.normal(0, 2.0, n)
    g = BlockedGram(y[:, None], time_blocks(t))
    cols = g.add(np.stack([np.ones(n), x])[:, :, None])
    cov = model_covariance(g, g.score(cols), [0, 1], time_blocks(t))
    closed = 4.0 / np.sum((x - x.mean()) ** 2)
    assert cov[1, 1] == pytest.approx(closed, rel=0.15)
    assert cov[0, 0] == pytest.approx(4.0 / n, rel=0.15)  # the level: sigma^2 / n
    assert abs(cov[0, 1]) < 0.05 * np.sqrt(cov[0, 0] * cov[1, 1])  # centred: uncorrelated


def test_model_covariance_equals_its_block_sums_written_out(rng):
    """The covariance as its docstring writes it, by explicit loops over components,
    coefficient pairs and blocks, on three components with gaps, correlated noise and
    block-to-block changes of the noise level."""
    from magcal.discover.selection import (TAU_FLOOR, autocorrelation,
                                           integrated_autocorr_time, model_covariance)

    inp = _inputs(n=3000)
    blocks = time_blocks(inp.times_s)
    cols = np.concatenate([np.ones((1, inp.n, 3)), Diurnal(("Hp", "He"), harmonics=1).columns(inp),
                           Scale(("Hn",)).columns(inp)])
    level = 1.0 + blocks[:, None] / 5.0
    noise = np.stack([np.convolve(rng.normal(size=inp.n + 9), np.ones(10) / 3, "valid")
                      for _ in range(3)], axis=1)
    y = np.tensordot(rng.normal(size=cols.shape[0]), cols, 1) + level * noise
    y[rng.random(y.shape) < 0.05] = np.nan
    g = BlockedGram(y, blocks)
    idx = g.add(cols)
    score = g.score(idx)
    params = [1, 2, 4, 5]
    got = model_covariance(g, score, params, blocks)

    G = sum(g.G[b] for b in range(g.n_blocks))
    Minv = np.linalg.inv(G)
    resid = g.residual(idx, score.beta)
    X = g.column_matrix(idx).reshape(len(idx), inp.n, 3)
    want = np.zeros((len(params), len(params)))
    for c in range(3):
        ok = np.isfinite(resid[:, c])
        s2 = [np.mean(resid[(blocks == b) & ok, c] ** 2) for b in range(g.n_blocks)]
        tau_e = integrated_autocorr_time(resid[:, c])
        rho_e = autocorrelation(resid[:, c], int(min(max(5 * tau_e, 10), 1440)))
        k = rho_e.size
        a = [np.tensordot(Minv[:, j], X[:, :, c], 1) for j in params]
        tau = [max(TAU_FLOOR, 1 + 2 * rho_e[1:k] @ (np.correlate(ai, ai, "full")[ai.size - 1:]
                                                    / np.sum(ai ** 2))[1:k])
               if ai.any() else 0.0 for ai in a]
        for i in range(len(params)):
            for j in range(len(params)):
                if a[i].any() and a[j].any():
                    want[i, j] += np.sqrt(tau[i] * tau[j]) * sum(
                        s2[b] * np.sum(a[i][blocks == b] * a[j][blocks == b])
                        for b in range(g.n_blocks))
    assert_allclose(got, want, rtol=1e-8, atol=1e-12 * np.abs(want).max())


@pytest.mark.parametrize("n, gaps", [(32768, 0.0), (43200, 0.05)])
def test_model_covariance_of_a_level_in_red_noise_is_the_variance_of_its_mean(n, gaps):
    """A level in AR(1) noise of 30 samples' correlation (tau_int = 60): the variance of
    the mean of the valid samples, sum_(i,j valid) phi^|i - j| / n_valid^2 (closed form),
    in 100 seeded draws, without gaps at a length whose mean is exact in floating point
    and with 5 % of the samples missing at random. Centring the level's weights before
    their lagged sums (a constant: nothing left) had stated 1 / sqrt(60) of it and held
    the truth in 15 % of the draws."""
    from scipy.signal import lfilter

    from magcal.discover.selection import _lag_sums, model_covariance

    phi = np.exp(-1.0 / 30.0)
    t = np.arange(n) * 60.0
    blocks = time_blocks(t)
    ratio, inside = [], []
    for seed in range(100):
        rng = np.random.default_rng(seed)
        w = rng.normal(0, np.sqrt(1 - phi ** 2), n)
        w[0] = rng.normal()  # a stationary start: unit variance from the first sample
        y = (3.0 + lfilter([1.0], [1.0, -phi], w))[:, None]
        valid = rng.random(n) >= gaps
        y[~valid] = np.nan
        g = BlockedGram(y, blocks)
        cols = g.add(np.ones((1, n, 1)))
        score = g.score(cols)
        se = float(np.sqrt(model_covariance(g, score, [0], blocks)[0, 0]))
        pairs = _lag_sums(valid.astype(float)[:, None], n)[:, 0]  # valid pairs per lag
        var = (pairs[0] + 2 * np.sum(pairs[1:] * phi ** np.arange(1, n))) / valid.sum() ** 2
        ratio.append(se / np.sqrt(var))
        inside.append(abs(score.beta[0] - 3.0) < 1.96 * se)
    assert 0.85 < np.median(ratio) < 1.15, np.median(ratio)
    assert np.mean(inside) >= 0.89, np.mean(inside)


def test_effective_sample_size_of_a_level_in_red_noise_is_n_over_tau():
    """The level's effective sample size in AR(1) noise of 30 samples' correlation is
    n / tau_int = n (1 - phi) / (1 + phi), 720 of 43200 (closed form; median of 20
    seeded draws within 15 %). A centred level (nothing left) had counted all 43200."""
    from scipy.signal import lfilter

    from magcal.discover.selection import regression_n_eff

    n, phi = 43200, np.exp(-1.0 / 30.0)
    got = []
    for seed in range(20):
        rng = np.random.default_rng(seed)
        w = rng.normal(0, np.sqrt(1 - phi ** 2), n)
        w[0] = rng.normal()
        e = lfilter([1.0], [1.0, -phi], w)[:, None]
        got.append(regression_n_eff(e, np.full((n, 1), 4.0), centre_signal=False))
    assert np.median(got) == pytest.approx(n * (1 - phi) / (1 + phi), rel=0.15)


@pytest.mark.parametrize("sizes, lo, hi", [([300] * 8, 0.935, 0.965),
                                           ([600, 600, 60, 60, 60, 60, 60], 0.935, 0.99)])
def test_student_interval_on_the_jackknife_dof_covers_where_1_96_does_not(sizes, lo, hi):
    """A level in white noise over few blocks, 3000 seeded draws (binomial sd 0.004).
    The jackknife standard error of a level in B equal blocks has B - 1 degrees of
    freedom (exactly, Bell-McCaffrey): value +- 1.96 std holds the truth in 91 %
    (t_0.975(7) = 2.36), the Student interval on ``jackknife_dof`` in 95 %. With unequal
    blocks (two large, five small: dof ~1.3) 1.96 covers 86 % and the Student interval
    at least 93.5 % (the jackknife overstates a leveraged coefficient's variance, so
    it covers more: 98 %)."""
    from magcal.stats import student_interval

    rng = np.random.default_rng(11)
    blocks = np.repeat(np.arange(len(sizes)), sizes)
    n = blocks.size
    X = np.ones((1, n, 1))
    normal = inside = 0
    draws = 3000
    for k in range(draws):
        g = BlockedGram(1.0 + rng.standard_normal((n, 1)), blocks)
        cols = g.add(X)
        sc = g.score(cols)
        if k == 0:  # the dof depend on the design only
            dof = g.jackknife_dof(cols)
        normal += abs(sc.beta[0] - 1.0) <= 1.96 * sc.beta_std[0]
        a, b = student_interval(sc.beta, sc.beta_std, dof)
        inside += a[0] <= 1.0 <= b[0]
    assert lo <= inside / draws <= hi, inside / draws
    assert normal / draws < 0.925, normal / draws
    if len(set(sizes)) == 1:
        assert dof[0] == pytest.approx(len(sizes) - 1, rel=1e-9)


def test_jackknife_dof_of_a_coefficient_one_block_carries_is_finite_and_covers():
    """A storm-time regressor (a 5-unit bump in one of 30 blocks over 0.3-unit quiet
    scatter) beside a level, 1000 seeded draws in white noise: the regressor's dof is
    1-3 (Satterthwaite's effective blocks - 1 had given 0.7 and, with 0.02 quiet
    scatter, 0.05: an unbounded quantile) and its Student interval covers at least
    95 % (99.8 %: conservative); the level keeps about B - 1 (28.6) and 95 %."""
    from magcal.stats import student_interval

    rng = np.random.default_rng(5)
    m, B = 200, 30
    blocks = np.repeat(np.arange(B), m)
    n = blocks.size
    inside = np.zeros(2)
    dofs = []
    draws = 1000
    for _ in range(draws):
        x = 0.3 * rng.standard_normal(n)
        x[5 * m:6 * m] += 5.0 * np.hanning(m)
        X = np.zeros((2, n, 1))
        X[0, :, 0] = 1.0
        X[1, :, 0] = x
        g = BlockedGram((1.0 + 0.8 * x + rng.standard_normal(n))[:, None], blocks)
        cols = g.add(X)
        sc = g.score(cols)
        dof = g.jackknife_dof(cols)
        a, b = student_interval(sc.beta, sc.beta_std, dof)
        inside += (a <= [1.0, 0.8]) & ([1.0, 0.8] <= b)
        dofs.append(dof)
    med = np.median(dofs, axis=0)
    assert 1.0 <= med[1] <= 3.0, med
    assert med[0] == pytest.approx(B - 1, rel=0.05), med
    # the level at 95 % (binomial sd 0.007 over 1000 draws), the regressor above it
    assert inside[0] / draws >= 0.93 and inside[1] / draws >= 0.95, inside / draws
