"""Coverage of a drift break's 95 % time interval (:mod:`magcal.discover.break_time`)
and of the variants it was chosen over, on seeded records of red plus white noise.

Each record: 30 days of 10-min samples, per component an Ornstein-Uhlenbeck process
(std ``ou``, correlation time ``tau``) plus 1 nT white noise, and a hinge of the given
rate changes (nT/day) at a random time in the middle 40 % of the record. The break is
named as the discovery loop names it (the strongest of
:func:`magcal.discover.scan.change_points` ``kind="slope"``, a least-squares search if
none), the level, rate and rate change refitted by least squares, and the interval
computed from the residual. Printed per case and variant: the share of intervals that
hold the true time and their median width (h), beside the 95th percentile of the named
time's error (h).

Variants: ``delivered`` (the simulated critical value with the noise level's degrees of
freedom), ``known-noise`` (the simulated value, the noise taken as known), ``chi2``
(3.84, Hansen 2017), ``step`` (7.35, the step's value), ``lrv-ols`` (the step
interval's recipe: least squares on hourly means scaled by the long-run variance, at
3.84).

Run: ``python benchmarks/bench_break_time.py [n_records] [first_seed] [case ...]``
(development seeds 0-399 and 1000-1399, held out 2000-2399).
"""

from __future__ import annotations

import sys
import time

import numpy as np

from magcal.alignment.noise import simulate_ou
from magcal.discover.break_time import break_likelihood
from magcal.discover.scan import _hourly_bins, change_points
from magcal.discover.selection import integrated_autocorr_time

DAY = 86400.0
H = 3600.0

#: name: (rate changes nT/day, OU std nT, OU correlation time s, extra)
CASES = {
    "0.6 white": ([0.6], 0.3, 600.0, {}),
    "0.5x3 2nT 2h": ([0.5, 0.5, 0.5], 2.0, 2 * H, {}),
    "0.7x3 2nT 2h": ([0.7, 0.7, 0.7], 2.0, 2 * H, {}),
    "1,1 6h": ([1.0, 1.0], 1.0, 6 * H, {}),
    "0.3 6h": ([0.3], 1.0, 6 * H, {}),
    "1.5,0 12h gap": ([1.5, 0.0], 1.0, 12 * H, {"gap": (DAY, 2 * DAY)}),
    "1 1d": ([1.0], 1.0, DAY, {}),
    "2,-1 1d": ([2.0, -1.0], 1.0, DAY, {}),
    "0.8 2d": ([0.8], 1.0, 2 * DAY, {}),
    # held-out shapes (not used to choose the method)
    "0.8,-0.4,0.2 3h": ([0.8, -0.4, 0.2], 1.5, 3 * H, {}),
    "1.2 18h 5% missing": ([1.2], 1.5, 18 * H, {"missing": 0.05}),
}


def draw(seed, rates, ou, tau, extra, days=30.0, dt=600.0):
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, days * DAY, dt)
    truth = rng.uniform(0.3, 0.7) * days * DAY
    y = np.column_stack([simulate_ou(rng, t, ou, tau) + rng.normal(0.0, 1.0, t.size)
                         for _ in rates])
    y += np.outer(np.maximum(t - truth, 0.0) / DAY, rates)
    if "gap" in extra:
        keep = (t < truth - extra["gap"][0]) | (t >= truth + extra["gap"][1])
        t, y = t[keep], y[keep]
    if "missing" in extra:
        y[rng.uniform(size=t.size) < extra["missing"]] = np.nan
    points = change_points(t, y, kind="slope")
    named = max(points, key=lambda p: p[2])[0] if points else _least_squares_break(t, y)
    x = np.column_stack([np.ones_like(t), (t - t.mean()) / DAY, np.maximum(t - named, 0) / DAY])
    resid = np.full_like(y, np.nan)
    change = []
    for c in range(y.shape[1]):
        ok = np.isfinite(y[:, c])
        beta = np.linalg.lstsq(x[ok], y[ok, c], rcond=None)[0]
        resid[:, c] = y[:, c] - x @ beta
        change.append(beta[2])
    return t, resid, named, np.array(change), truth


def _least_squares_break(t, y):
    starts, means = _hourly_bins(t, y, H)
    ok = np.all(np.isfinite(means), axis=1)
    tb, yb = starts[ok] + H / 2, means[ok]
    cand = starts[6:-6]
    gain = _ols_gain(tb, yb, cand, np.ones(yb.shape[1]))
    return float(cand[int(np.argmax(gain))])


def _ols_gain(tb, yb, cand, scale):
    x0 = np.column_stack([np.ones_like(tb), (tb - tb.mean()) / DAY])
    q, _ = np.linalg.qr(x0)
    h = np.maximum(tb[:, None] - cand[None, :], 0.0) / DAY
    rh = h - q @ (q.T @ h)
    out = np.zeros(cand.size)
    for c in range(yb.shape[1]):
        ry = yb[:, c] - q @ (q.T @ yb[:, c])
        out += (rh.T @ ry) ** 2 / np.maximum(np.sum(rh ** 2, axis=0), 1e-300) / scale[c]
    return out


def lrv_ols_covers(t, resid, named, change, truth, crit=3.84):
    """The step interval's recipe for the hinge: True when the truth is kept."""
    y = resid + np.outer(np.maximum(t - named, 0.0) / DAY, change)
    starts, means = _hourly_bins(t, y, H)
    _, noise = _hourly_bins(t, resid, H)
    ok = np.all(np.isfinite(means), axis=1)
    lrv = np.array([np.var(noise[ok, c]) * integrated_autocorr_time(noise[ok, c])
                    for c in range(y.shape[1])])
    cand = np.concatenate([starts[6:-6], [truth]])
    gain = _ols_gain(starts[ok] + H / 2, means[ok], cand, lrv)
    return gain.max() - gain[-1] <= crit


def run(case, n, seed0):
    rates, ou, tau, extra = CASES[case]
    rows = []
    for seed in range(seed0, seed0 + n):
        t, resid, named, change, truth = draw(seed, rates, ou, tau, extra)
        like = break_likelihood(t, resid, named, change, seed=seed)
        row = [abs(named - truth) / H]
        for crit in (like.critical_value(0.95), like.critical_value(0.95, known_noise=True),
                     3.84, 7.35):
            lo, hi = like.interval(crit)
            row += [lo < truth <= hi, (hi - lo) / H]
        row.append(lrv_ols_covers(t, resid, named, change, truth))
        rows.append(row)
    a = np.array(rows, dtype=float)
    cells = [f"{a[:, 1 + 2 * i].mean():.3f} {np.median(a[:, 2 + 2 * i]):4.0f} h"
             for i in range(4)]
    return (f"{case:20s} {np.quantile(a[:, 0], 0.95):5.0f} h  " + "  ".join(cells)
            + f"  {a[:, -1].mean():.3f}")


def main(argv):
    n = int(argv[1]) if len(argv) > 1 else 400
    seed0 = int(argv[2]) if len(argv) > 2 else 1000
    cases = argv[3:] or list(CASES)
    print(f"{n} records per case, seeds {seed0}-{seed0 + n - 1}; coverage and median width")
    print(f"{'case':20s} {'err95':>7s}  {'delivered':>14s}  {'known-noise':>14s}  "
          f"{'chi2 3.84':>14s}  {'step 7.35':>14s}  lrv-ols")
    for case in cases:
        t0 = time.perf_counter()
        line = run(case, n, seed0)
        print(line, f"({time.perf_counter() - t0:.0f} s)", flush=True)


if __name__ == "__main__":
    main(sys.argv)
