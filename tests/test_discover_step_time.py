"""The 95 % interval of a named step's time (magcal.discover.step_time): the published
critical values, coverage over seeded draws of red plus white noise, a step inside a
gap, and bad input."""

from __future__ import annotations

import numpy as np
import pytest

from magcal.alignment.noise import simulate_ou
from magcal.discover.scan import joint_step_time
from magcal.discover.step_time import lr_critical_value, step_time_interval

DAY = 86400.0


@pytest.mark.parametrize("level, published", [(0.80, 4.50), (0.90, 5.94), (0.95, 7.35),
                                              (0.99, 10.59)])
def test_critical_values_are_hansens(level, published):
    """Hansen (2000, Econometrica 68, 575), Table 1: the likelihood ratio's critical
    values of a threshold's (here: a step time's) confidence set."""
    assert lr_critical_value(level) == pytest.approx(published, abs=0.006)
    # the quantile of (1 - exp(-x / 2))^2, the distribution it inverts
    assert (1 - np.exp(-lr_critical_value(level) / 2)) ** 2 == pytest.approx(level, abs=1e-12)


def test_critical_value_is_the_quantile_of_the_brownian_functional():
    """``max_s (2 W(s) - |s|)`` for a two-sided Brownian motion, simulated on a fine grid
    (5000 seeded draws): at most 5 % exceed 7.35 (binomial sd 0.3 %; the grid misses a
    little of each maximum, so the fraction may fall short of 5 %, not exceed it)."""
    rng = np.random.default_rng(11)
    ds, n = 0.01, 4000  # |s| up to 40: beyond it 2 W(s) - |s| is almost never positive
    s = np.arange(1, n + 1) * ds
    xi = np.concatenate([  # in chunks of 250 draws (16 MB each)
        (2 * np.cumsum(rng.normal(0.0, np.sqrt(ds), (250, 2, n)), axis=2) - s).max(axis=(1, 2))
        for _ in range(20)])
    frac = float(np.mean(xi > lr_critical_value(0.95)))
    assert 0.040 <= frac <= 0.051, frac


def _draw(seed: int, size, *, tau_s: float, days: float = 20.0, dt: float = 600.0):
    """A step at a random time in OU (1 nT, ``tau_s``) plus white (1 nT) noise per
    component; the step placed by the joint scan and sized by least squares, as the
    discovery names it. Returns (truth in the interval, width h, |error| h)."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, days * DAY, dt)
    truth = t[np.searchsorted(t, rng.uniform(0.3, 0.7) * days * DAY)]
    noise = np.column_stack([simulate_ou(rng, t, 1.0, tau_s) + rng.normal(0.0, 1.0, t.size)
                             for _ in size])
    y = noise + np.outer(t >= truth, size)
    named = joint_step_time(t, y)
    x = np.column_stack([np.ones_like(t), t >= named])
    beta = np.linalg.lstsq(x, y, rcond=None)[0]
    lo, hi = step_time_interval(t, y - x @ beta, named, beta[1])
    assert lo < named <= hi
    return lo < truth <= hi, (hi - lo) / 3600.0, abs(named - truth) / 3600.0


@pytest.mark.parametrize("size, tau_s", [([2.0, 2.0], 6 * 3600.0), ([3.0, -2.0], DAY)])
def test_interval_holds_the_true_time_as_often_as_stated_and_is_not_wasteful(size, tau_s):
    """200 seeded 20-day records of 10-min data: the 95 % interval holds the true step
    time in at least 93 % (binomial sd 1.5 %); and its median width is at most 2.5 times
    the 95th percentile of the named time's error (an interval of fixed half-width
    reaching that percentile, centred on the named time, holds the truth 95 % of the
    time with twice its width)."""
    out = np.array([_draw(seed, size, tau_s=tau_s) for seed in range(200)])
    covered, width, error = out[:, 0], out[:, 1], out[:, 2]
    assert covered.mean() >= 0.93, covered.mean()
    assert np.median(width) <= 2.5 * np.quantile(error, 0.95), (np.median(width),
                                                                np.quantile(error, 0.95))


def test_a_step_inside_a_gap_spans_the_gap():
    """A 3 nT step in the middle of a two-day gap: the data place it at the gap's end
    and cannot say where inside the gap it happened, so the interval covers all of it."""
    rng = np.random.default_rng(5)
    t = np.arange(0.0, 20 * DAY, 600.0)
    y = np.where(t >= 9 * DAY, 3.0, 0.0) + rng.normal(0.0, 1.0, t.size)
    keep = (t < 8 * DAY) | (t >= 10 * DAY)
    t, y = t[keep], y[keep]
    named = joint_step_time(t, y)
    assert named == 10 * DAY
    x = np.column_stack([np.ones_like(t), t >= named])
    beta = np.linalg.lstsq(x, y, rcond=None)[0]
    lo, hi = step_time_interval(t, (y - x @ beta)[:, None], named, beta[1:])
    assert lo < 8 * DAY and 10 * DAY <= hi <= 10 * DAY + 3 * 3600.0, (lo / DAY, hi / DAY)


def test_bad_input():
    t = np.arange(0.0, 10 * DAY, 600.0)
    with pytest.raises(ValueError, match="2 values for 1 components"):
        step_time_interval(t, np.zeros(t.size), 5 * DAY, [1.0, 2.0])
    with pytest.raises(ValueError, match="level"):
        lr_critical_value(1.0)
    # too short to place a step away from the ends
    assert step_time_interval(t[:60], np.zeros(60), t[30], [1.0]) is None


def test_report_account_and_figure_carry_the_interval(tmp_path):
    """Discovery on 20 days of 10-min data with a 6 nT step in Hp: REPORT.json's step
    holds the true time in ``time_ci95``, the account line states the interval, and the
    figure shades it on the Hp time panel (not on He, which has no step)."""
    import json

    import pandas as pd

    from magcal.discover import discover_gap
    from magcal.discover.plots import plot_gap

    rng = np.random.default_rng(8)
    t = pd.date_range("2019-11-01", periods=20 * 144, freq="10min", tz="UTC")
    truth = pd.Timestamp("2019-11-09T13:20:00Z")
    model = pd.DataFrame({"Hp": 100.0 + 0 * t.hour, "He": 0.0 * t.hour}, index=t)
    meas = model + np.column_stack([6.0 * (t >= truth), 0 * t.hour]) \
        + rng.normal(0.0, 1.0, (t.size, 2))
    res = discover_gap(meas, model)
    step = res.effect("step")
    assert step.components == ("Hp",)
    doc = json.loads(json.dumps(res.to_json()))
    p = next(e for e in doc["effects"] if e["name"] == "step")["parameters"]
    after, by = (pd.Timestamp(v) for v in p["time_ci95"])
    assert after < truth <= by and (by - after) <= pd.Timedelta(hours=4), p["time_ci95"]
    line = next(x for x in res.account() if "added step" in x)
    assert f"after {after:%Y-%m-%d %H:%M}, by {by:%Y-%m-%d %H:%M} UTC" in line, line
    fig = plot_gap(res, tmp_path / "gap.png")
    assert (tmp_path / "gap.png").stat().st_size > 0
    t0 = res.times_s[0]
    spans = [patch.get_patch_transform().transform(patch.get_path().vertices)[:, 0]
             for patch in fig.axes[0].patches]  # x in days, as the panel's axis
    want = [(v - t0) / DAY for v in step.time_ci95_s]
    assert any(np.isclose(min(x), want[0]) and np.isclose(max(x), want[1]) for x in spans), spans
    assert len(fig.axes) == 2 and not fig.axes[1].patches  # He (no local-time panels)
