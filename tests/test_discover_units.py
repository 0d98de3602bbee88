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
                         0.8 * np.cos(2 * np.pi * t / (5.5 * 3600))]) + rng.normal(0, 0.5, (t.size, 2))
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
