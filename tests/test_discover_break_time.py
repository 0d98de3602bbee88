"""The 95 % interval of a drift break's time (magcal.discover.break_time): coverage over
seeded draws of red plus white noise, widths against the named time's error, the
simulated critical value against the theory's limits, a break inside a gap, bad input,
and the interval through the discovery loop (REPORT.json, the account, the figure)."""

from __future__ import annotations

import numpy as np
import pytest

from magcal.alignment.noise import simulate_ou
from magcal.discover.break_time import break_likelihood, break_time_interval, noise_dof
from magcal.discover.scan import change_points

DAY = 86400.0


def _named(t, y, named=None):
    """The break named as the loop names it (the strongest change of slope), the level,
    rate and rate change refitted by least squares: (named, residual, rate change)."""
    if named is None:
        named = max(change_points(t, y, kind="slope"), key=lambda p: p[2])[0]
    x = np.column_stack([np.ones_like(t), (t - t.mean()) / DAY, np.maximum(t - named, 0) / DAY])
    beta = np.linalg.lstsq(x, y, rcond=None)[0]
    return named, y - x @ beta, beta[2]


def _draw(seed, rates, *, ou_nT: float, tau_s: float, days: float = 20.0, dt: float = 600.0):
    """A hinge at a random time in OU (``ou_nT``, ``tau_s``) plus white (1 nT) noise per
    component. Returns (truth in the interval, width h, |error of the named time| h)."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, days * DAY, dt)
    truth = rng.uniform(0.3, 0.7) * days * DAY
    y = np.column_stack([simulate_ou(rng, t, ou_nT, tau_s) + rng.normal(0.0, 1.0, t.size)
                         for _ in rates]) + np.outer(np.maximum(t - truth, 0) / DAY, rates)
    named, resid, change = _named(t, y)
    lo, hi = break_time_interval(t, resid, named, change)
    assert lo < named <= hi
    return lo < truth <= hi, (hi - lo) / 3600.0, abs(named - truth) / 3600.0


@pytest.mark.parametrize("rates, ou_nT, tau_s, days", [
    ([0.8], 0.3, 600.0, 14.0),             # nearly white
    ([1.0, 1.0], 1.0, 6 * 3600.0, 20.0),   # red, two components
    ([1.5], 1.0, DAY, 30.0),               # a day's memory: where 3.84 held 87 %
])
def test_interval_holds_the_true_time_as_often_as_stated_and_is_not_wasteful(rates, ou_nT,
                                                                             tau_s, days):
    """200 seeded records of 10-min data: the 95 % interval holds the true break time in
    92-99 % of them (binomial sd 1.5 %), and its median width is at most 3 times the
    95th percentile of the named time's error (an interval of fixed half-width reaching
    that percentile, centred on the named time, would hold the truth 95 % of the time
    with twice its width; the hourly bins add 2 h)."""
    out = np.array([_draw(seed, rates, ou_nT=ou_nT, tau_s=tau_s, days=days)
                    for seed in range(200)])
    covered, width, error = out[:, 0], out[:, 1], out[:, 2]
    assert 0.92 <= covered.mean() <= 0.99, covered.mean()
    assert np.median(width) <= 3.0 * np.quantile(error, 0.95), (np.median(width),
                                                                np.quantile(error, 0.95))


def test_simulated_critical_value_follows_the_noise_colour():
    """The theory's limits: in white noise the ratio is chi-squared(1) (3.84 at 95 %);
    a red noise whitened is differenced, and a differenced hinge is a step, whose value
    is 7.35. The simulated value with the noise taken as known lies near 3.84 for white
    noise and well above it for a day's correlation time; the noise level's degrees of
    freedom raise it further where the record holds few correlation times."""
    t = np.arange(0.0, 30 * DAY, 600.0)
    crit = {}
    for name, ou, tau in (("white", 0.0, 600.0), ("day", 1.0, DAY)):
        rng = np.random.default_rng(4)
        noise = (simulate_ou(rng, t, ou, tau) if ou else 0.0) + rng.normal(0.0, 1.0, t.size)
        y = noise + 1.0 * np.maximum(t - 14.2 * DAY, 0) / DAY
        named, resid, change = _named(t, y[:, None], 14.2 * DAY)
        like = break_likelihood(t, resid, named, change)
        crit[name] = (like.critical_value(0.95, known_noise=True), like.critical_value(0.95),
                      like.noise[0][1])
    white, with_dof, nu = crit["white"]
    assert 2.8 <= white <= 4.5 and with_dof == pytest.approx(white, rel=0.1) and nu > 200, crit
    known, with_dof, nu = crit["day"]
    assert known >= 1.2 * white and with_dof > known + 1.0 and nu < 20, crit


def test_noise_dof():
    """Half the effective count of independent hourly means, less the three coefficients."""
    t = np.arange(720) * 3600.0
    assert noise_dof((0.0, 3600.0, 1.0, False), t) == 0.5 * 717
    # a day's correlation on hourly means: (1 - phi) / (1 + phi) of the 720
    phi = np.exp(-1 / 24)
    assert noise_dof((1.0, DAY, 0.0, False), t) == pytest.approx(
        0.5 * (720 * (1 - phi) / (1 + phi) - 3))
    assert noise_dof((1.0, 1e9, 0.0, False), t) == 1.0


def test_a_break_inside_a_gap_is_judged_by_both_sides():
    """A rate change of 2 nT/day in the middle of a two-day gap (white noise of 1 nT):
    the data on both sides place it by where their lines meet; the interval holds the
    true time although no sample lies within a day of it, and is not pushed to the
    gap's edges."""
    rng = np.random.default_rng(6)
    t = np.arange(0.0, 20 * DAY, 600.0)
    truth = 9.0 * DAY
    y = 2.0 * np.maximum(t - truth, 0) / DAY + rng.normal(0.0, 1.0, t.size)
    keep = (t < 8 * DAY) | (t >= 10 * DAY)
    t, y = t[keep], y[keep]
    named, resid, change = _named(t, y[:, None])
    lo, hi = break_time_interval(t, resid, named, change)
    assert lo < truth <= hi, (lo / DAY, named / DAY, hi / DAY)
    assert 7 * DAY <= lo and hi <= 11 * DAY, (lo / DAY, hi / DAY)


def test_bad_input():
    t = np.arange(0.0, 10 * DAY, 600.0)
    with pytest.raises(ValueError, match="2 values for 1 components"):
        break_time_interval(t, np.zeros(t.size), 5 * DAY, [1.0, 2.0])
    with pytest.raises(ValueError, match="level"):
        break_time_interval(t, np.zeros(t.size), 5 * DAY, [1.0], level=1.0)
    with pytest.raises(ValueError, match="finite"):
        break_time_interval(t, np.zeros(t.size), np.nan, [1.0])
    with pytest.raises(ValueError, match="rows"):
        break_time_interval(t, np.zeros(t.size - 1), 5 * DAY, [1.0])
    # too short to place a break away from the ends
    assert break_time_interval(t[:60], np.zeros(60), t[30], [1.0]) is None


def test_report_account_and_figure_carry_the_break_interval(tmp_path):
    """A simulated month (T89 model, Kp, Dst, local time, ULF waves, substorms, red model
    error of 2 nT; 10-min samples) with a rate change of 1 nT/day in Hp and He at day
    12.4: discovery names one drift with its break, REPORT.json carries the break's
    ``time_ci95`` holding the true time, the account's drift line states it, and the
    figure shades it on the drift's components (Hn has none)."""
    import json

    import pandas as pd

    from magcal.discover import discover_gap
    from magcal.discover.plots import plot_gap
    from magcal.simulate.gaps import COMPONENTS, LON_DEG, make_background

    bg = make_background(3, cadence_s=600.0)
    m = bg.month
    day = bg.t_s / DAY
    bend = np.outer(np.maximum(day - 12.4, 0.0), [1.0, 1.0, 0.0])
    index = pd.DatetimeIndex(m.times, name="time").tz_localize("UTC")
    model = pd.DataFrame(m.model_nT, index=index, columns=list(COMPONENTS))
    meas = model + np.array([4.0, -3.0, 2.0]) + bend + bg.benign
    cov = pd.DataFrame({"temperature": m.temperature_C, "kp": m.kp, "dst": m.dst}, index=index)
    res = discover_gap(meas, model, cov, longitude_deg=LON_DEG)
    drifts = [e for e in res.effects if e.name == "drift" and e.effect.t_break_s is not None]
    assert len(drifts) == 1 and set(drifts[0].components) >= {"Hp", "He"}, res.account()
    drift = drifts[0]
    truth = index[0] + pd.Timedelta(days=12.4)
    doc = json.loads(json.dumps(res.to_json()))
    p = next(e for e in doc["effects"] if "break_time" in e["parameters"])["parameters"]
    after, by = (pd.Timestamp(v) for v in p["time_ci95"])
    assert p["time_ci95_s"] == [after.timestamp(), by.timestamp()]
    assert after < pd.Timestamp(p["break_time"]) <= by
    assert after < truth <= by, (p["break_time"], p["time_ci95"])
    line = next(x for x in res.account() if "rate change at" in x)
    assert f"95 %: after {after:%Y-%m-%d %H:%M}, by {by:%Y-%m-%d %H:%M} UTC)" in line, line
    fig = plot_gap(res, tmp_path / "gap.png")
    t0 = res.times_s[0]
    want = [(v - t0) / DAY for v in drift.time_ci95_s]
    for i, c in enumerate(res.components):
        spans = [patch.get_patch_transform().transform(patch.get_path().vertices)[:, 0]
                 for patch in fig.axes[2 * i].patches]
        shaded = any(np.isclose(min(x), want[0]) and np.isclose(max(x), want[1])
                     for x in spans)
        assert shaded == (c in drift.components), (c, spans)
