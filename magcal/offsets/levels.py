"""Level changes of the offset: sudden steps (a sensor reset, a heater switched) found in
the record's day values.

The sliding-window medians and their linear interpolation assume an offset that varies
slowly against the window step. A sudden change breaks that silently: windows
straddling it report a median mixing both levels, and the interpolation spreads the
change over weeks. This module looks for such changes on the record's *day values* (for
each UTC day the mean of its hours' medians of the selected residual,
:func:`hourly_day_values`: robust to a spike as a median, and the mean of the miss over
the day's selected hours that the covariance below describes).

At each day ``k`` the values of the ``half_width`` days either side are fitted by
generalised least squares with a local no-change model plus a step from day ``k`` (plus
any change already found there). The local model is a line and a curvature where the
record needs them: a linear drift is in the line and is never a step, and a slow wander
(months) is locally close to a parabola, which in a window symmetric about ``k`` leaves
nothing in the step. But a step in the middle of a line is told from the line's slope by
half the days, so where the record holds no slow trend (:func:`trend_p_value`: cosines
of months over the record, judged against a level and one step, so that a change not
yet found does not read as a trend), would show one clearly enough
(:func:`drift_detectability`) and its day values are not correlated over days (where the
modelled correlation, on which a level-only fit leans harder, is least well known), the
local model is a level only, which about halves the step's standard error.

The day values' covariance is the record's pooled day-to-day correlation
(:func:`magcal.offsets.windows.pooled_lag_correlation`, the model of the model miss the
windows' standard errors use), spread over the pairs of days by when in each day the
selected samples fall (:class:`QuietHours`: with quiet data in whole Kp blocks two
consecutive day values lie hours or nearly two days apart, and under a miss correlated
over days their difference is that much less or more variable), scaled by a variance taken
from the local fits without the step (their median, so a change not yet found inflates
only its own days'). The components' t-statistics at each day are combined as
``t^T R^-1 t`` (``R`` the components' correlation: the model miss is often shared, and
a change in several components at once is what a reset or a heater makes), and the
largest over days is compared with the same maximum simulated under no change on the
record's own days and correlation (a Monte Carlo look-elsewhere correction with a fixed
seed, so the result is reproducible). Changes are added one at a time, strongest first,
each in the others' presence; after each, the correlation is re-estimated with the
changes taken out (a step inside a window reads as day-to-day correlation).

Why local and not one line through the record: a slow wander of the offset (a 120-day
swing of a few nT) is no step, and against one line it reads as several. The price is
power: the step is told from the local line by the days either side alone, so under a
model miss correlated over hours to days only changes of a few nT are found (the
CHANGELOG has the measured rates); a change too small to find here is also small against
the windows' own standard errors.

Each change gets its day (the first day at the new level), a 95 % time interval from
the likelihood ratio of the split day (Hansen 2000, critical value
:func:`magcal.discover.step_time.lr_critical_value`), and its size per component with a
standard error.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from magcal.offsets.windows import (DAY_NS, _lag_shape, batch_days_counts,
                                    pooled_lag_correlation)

#: Days either side of a candidate day that its local fit uses. Wider finds smaller
#: changes (28 days: 2 nT under a 1-hour miss twice as often) but lets a 120-day wander
#: of 4 nT read as a step in 2-3 % of records (none of 100 at 21 days).
HALF_WIDTH_DAYS = 21
#: Fewest days with data on each side of a candidate day.
MIN_SIDE_DAYS = 5
#: False-detection probability per record of the test under the modelled noise. The
#: noise is modelled, not known (a miss correlated over days is the least well), so the
#: level is set below the 5 % a record may carry.
ALPHA = 0.01
#: Draws of the Monte Carlo look-elsewhere correction.
N_SIM = 2000
#: Most changes looked for in one record.
MAX_CHANGES = 5
_SEED = 20191212


@dataclass(frozen=True)
class LevelChange:
    """A level change of the offset found in the record.

    Attributes
    ----------
    time : numpy.datetime64
        Start (UTC midnight) of the first day at the new level: the change happened
        within about a day before it or during that day.
    time_lo, time_hi : numpy.datetime64
        95 % interval of the change's time: after ``time_lo``, before ``time_hi``.
    size_nT, se_nT : ndarray, shape (m,)
        Size (new minus old level) per component and its 1-sigma standard error.
    z : float
        Largest ``|size / se|`` over the components.
    p_value : float
        Chance of a maximum as large anywhere in a record without a change (look-elsewhere
        corrected, Monte Carlo).
    """

    time: np.datetime64
    time_lo: np.datetime64
    time_hi: np.datetime64
    size_nT: np.ndarray
    se_nT: np.ndarray
    z: float
    p_value: float

    def describe(self, columns=("Hp", "He", "Hn")) -> str:
        """``Hp +1.02 +- 0.15, ... nT at 2019-12-12 (95 %: 2019-12-11 .. 2019-12-13)``."""
        sizes = ", ".join(f"{c} {s:+.2f} +- {e:.2f}"
                          for c, s, e in zip(columns, self.size_nT, self.se_nT))
        return (f"{sizes} nT at {_day(self.time)} (95 %: {_day(self.time_lo)} .. "
                f"{_day(self.time_hi)})")

    def to_dict(self, columns=("Hp", "He", "Hn")) -> dict:
        """JSON-ready record (times ISO UTC)."""
        return {"time": str(np.datetime64(self.time, "s")),
                "time_ci95": [str(np.datetime64(self.time_lo, "s")),
                              str(np.datetime64(self.time_hi, "s"))],
                "size_nT": {c: round(float(v), 4) for c, v in zip(columns, self.size_nT)},
                "se_nT": {c: round(float(v), 4) for c, v in zip(columns, self.se_nT)},
                "z": round(float(self.z), 2), "p_value": round(float(self.p_value), 4)}

    @classmethod
    def from_dict(cls, d: dict, columns=("Hp", "He", "Hn")) -> "LevelChange":
        """The inverse of :meth:`to_dict`."""
        lo, hi = d.get("time_ci95", [d["time"], d["time"]])
        return cls(np.datetime64(d["time"], "ns"), np.datetime64(lo, "ns"),
                   np.datetime64(hi, "ns"),
                   np.array([float(d.get("size_nT", {}).get(c, np.nan)) for c in columns]),
                   np.array([float(d.get("se_nT", {}).get(c, np.nan)) for c in columns]),
                   float(d.get("z", np.nan)), float(d.get("p_value", np.nan)))


def _day(t) -> str:
    return str(np.datetime64(t, "D"))


#: Largest ratio of two days' modelled variances (:func:`day_variance_scale`): bounds
#: the weight one full day can take over a sparse one when the fit of the variances
#: scatters.
MAX_VARIANCE_RATIO = 30.0


def day_variance_scale(days, values, counts, max_ratio: float = MAX_VARIANCE_RATIO):
    """Standard deviation (relative, median 1) of each day value, modelled as
    ``a + b / n`` in the day's number ``n`` of samples.

    A day value is a median of the day's selected samples; under a model miss
    correlated over hours, a day holding 3 quiet hours averages a few of its swings and
    one holding 20 hours many, so the first is far noisier (the ``b / n`` part), while a
    miss correlated over days moves the whole day alike however many samples it holds
    (the ``a`` part). ``a`` and ``b`` are fitted, shared by the components (each
    normalised by its own mean), to the squared second differences ``y_d - (y_{d-1} +
    y_{d+1}) / 2`` of consecutive days, whose expectation is ``a g + b (1 / n_d + (1 /
    n_{d-1} + 1 / n_{d+1}) / 4)`` (``g`` constant): second differences, so a drift or a
    wander does not enter, nor a step beyond the two days beside it. Squared
    differences are capped at 25 times their median (a day spoilt by a disturbance the
    selection missed does not set the fit).

    Examples
    --------
    >>> rng = np.random.default_rng(1)
    >>> counts = np.tile([30.0, 300.0], 200)
    >>> values = rng.standard_normal((400, 1)) * np.sqrt(0.2 + 30.0 / counts)[:, None]
    >>> sd = day_variance_scale(np.arange(400), values, counts)
    >>> bool(1.6 < sd[0] / sd[1] < 2.5)  # truth 2
    True
    """
    days = np.asarray(days, dtype=np.int64)
    n = days.size
    flat = np.ones(n)
    if n < 5:
        return flat
    inv = 1.0 / np.asarray(counts, dtype=float)
    mid = np.flatnonzero((days[1:-1] - days[:-2] == 1) & (days[2:] - days[1:-1] == 1)) + 1
    if mid.size < 10:
        return flat
    e2 = (values[mid] - 0.5 * (values[mid - 1] + values[mid + 1])) ** 2
    e2 = e2 / np.maximum(e2.mean(axis=0), 1e-300)
    e2 = np.minimum(e2, 25.0 * np.median(e2, axis=0))
    h = inv[mid] + 0.25 * (inv[mid - 1] + inv[mid + 1])
    m = values.shape[1]
    design = np.tile(np.stack([np.full(mid.size, 1.5), h], axis=1), (m, 1))
    coef, *_ = np.linalg.lstsq(design, e2.T.ravel(), rcond=None)
    a, b = float(coef[0]), max(float(coef[1]), 0.0)
    if not a > 0.0:
        a = b * float(np.min(inv)) / max_ratio if b > 0 else 1.0
    var = a + b * inv
    var = np.clip(var, var.max() / max_ratio, None)
    return np.sqrt(var / np.median(var))


def record_day_correlation(days, values, window_days: int = 28, step_days: int = 7,
                           min_pairs: int = 10):
    """The pooled day-to-day correlation (:func:`pooled_lag_correlation`) of the record's
    day values over windows of ``window_days`` stepped by ``step_days``; None when the
    record is too short to pool."""
    days = np.asarray(days, dtype=np.int64)
    if days.size < 3:
        return None
    layouts = []
    for w0 in range(int(days[0]), int(days[-1]) + 1, step_days):
        inside = (days >= w0) & (days < w0 + window_days)
        if inside.sum() >= 3:
            layouts.append((days[inside] - w0, values[inside], w0))
        if w0 + window_days > days[-1]:
            break
    return pooled_lag_correlation(layouts, min_pairs)


def _factor(corr) -> np.ndarray:
    """A square root ``L`` of a correlation matrix (``L L^T = corr``): its Cholesky factor,
    or, where the modelled correlation is not positive definite on the record's days
    (``c1 r ** (k - 1)`` on scattered days can fail to be), that of its eigenvalues
    raised to a thousandth of the largest."""
    try:
        return np.linalg.cholesky(corr)
    except np.linalg.LinAlgError:
        lam, vec = np.linalg.eigh(corr)
        lam = np.clip(lam, 1e-3 * lam.max(), None)
        return np.linalg.cholesky((vec * lam) @ vec.T)


#: Bins per UTC day in which :class:`QuietHours` counts the selected samples.
QUIET_HOUR_BINS = 24
#: Shortest correlation time (days) :class:`QuietHours` gives the model miss: below it
#: two days' values are uncorrelated however close their quiet hours.
MIN_TAU_DAYS = 0.02


def day_bins(t_ns, bins: int = QUIET_HOUR_BINS) -> tuple[np.ndarray, np.ndarray]:
    """Each time's UTC day (calendar days since 1970) and its bin of the day (0 ..
    ``bins - 1``): the one rule by which :class:`QuietHours` lays out the selected
    samples and :func:`hourly_day_values` takes their medians, so that the day values
    are the quantity the covariance describes."""
    t = np.asarray(t_ns, dtype=np.int64)
    day = t // DAY_NS
    return day, np.minimum(((t - day * DAY_NS) * bins) // DAY_NS, bins - 1)


class QuietHours:
    """When in each UTC day the selected samples fall, and the day values' correlation it
    implies.

    A day value sums up its selected samples, and with quiet data in whole
    3-hour Kp blocks a day may hold only its last hours and the next only its first (its
    value then lies hours from the previous one) or the reverse (nearly two days). Under
    a model miss correlated over days the difference of two consecutive day values is
    then far less or far more variable than the pooled lag-one correlation says on
    average, and the largest step statistic over a record's days is drawn to the pairs
    far apart, more often than the Monte Carlo of evenly spaced days allows.

    Here each day value is modelled as the mean, over its selected samples (counted in
    :data:`QUIET_HOUR_BINS` bins of the day), of a miss correlated ``exp(-|dt| / tau)``
    in time, mixed with a part independent from day to day: the correlation of days
    ``i != j`` is ``s K_ij / sqrt(K_ii K_jj)`` with ``K`` the kernel averaged over the
    two days' bins. ``tau`` and ``s`` are set by the pooled day correlation ``c1 r **
    (k - 1)`` (:func:`record_day_correlation`): ``exp(-1 / tau) = r`` (the decay of
    full-day means of such a miss) and ``s`` such that the correlation averaged over
    the record's pairs of consecutive days is ``c1``; where the decay cannot give a
    lag-one correlation that large, ``tau`` is lengthened until it does (``s = 1``).
    The model keeps the pooled correlation's lag-one mean and decay, and gives each
    pair of days the share its quiet hours imply; ``s <= 1`` keeps it positive definite.

    Parameters
    ----------
    days : array_like of int, shape (n,)
        The record's days (calendar days since 1970).
    weights : array_like, shape (n, QUIET_HOUR_BINS)
        Each day's share of its selected samples in each bin of the day (rows sum to 1).

    Examples
    --------
    Two days holding only their last 3 hours, then one holding only its first 3: under a
    5-day miss (pooled lag-one correlation 0.87, decay 0.82) the third day's value lies
    hours from the second's and the second's a day from the first's.

    >>> w = np.zeros((3, 24))
    >>> w[0, 21:], w[1, 21:], w[2, :3] = 1 / 3, 1 / 3, 1 / 3
    >>> corr = QuietHours([0, 1, 2], w).correlation(np.array([0, 1, 2]), 0.87, 0.82)
    >>> corr.round(2)
    array([[1.  , 0.79, 0.78],
           [0.79, 1.  , 0.95],
           [0.78, 0.95, 1.  ]])
    """

    def __init__(self, days, weights):
        self.days = np.asarray(days, dtype=np.int64)
        self.weights = np.asarray(weights, dtype=float)
        self._u = (np.arange(self.weights.shape[1]) + 0.5) / self.weights.shape[1] - 0.5
        first = np.flatnonzero(np.diff(self.days) == 1)
        self._pairs = (first, first + 1)
        self._models: dict = {}  # (c1, r) -> (tau, s): this record's, set on first use

    @classmethod
    def from_times(cls, t_ns, days, bins: int = QUIET_HOUR_BINS) -> "QuietHours":
        """The layout of the selected samples at ``t_ns`` on the record's ``days`` (those
        :func:`magcal.offsets.windows.batch_days_counts` kept)."""
        day, b = day_bins(t_ns, bins)
        days = np.asarray(days, dtype=np.int64)
        i = np.searchsorted(days, day)
        keep = (i < days.size) & (days[np.minimum(i, days.size - 1)] == day)
        w = np.zeros((days.size, bins))
        np.add.at(w, (i[keep], b[keep]), 1.0)
        return cls(days, w / np.maximum(w.sum(axis=1, keepdims=True), 1e-300))

    def _terms(self, idx, tau):
        """Log of each day's bin means of ``exp(+-u / tau)`` and its own kernel mean."""
        w = self.weights[idx]
        up = np.log(np.maximum(w @ np.exp(self._u / tau - 0.5 / tau), 1e-300)) + 0.5 / tau
        down = np.log(np.maximum(w @ np.exp(-self._u / tau - 0.5 / tau), 1e-300)) + 0.5 / tau
        own = np.einsum("ia,ab,ib->i", w,
                        np.exp(-np.abs(self._u[:, None] - self._u[None, :]) / tau), w)
        return up, down, own

    def _shape(self, idx, tau):
        """``K_ij / sqrt(K_ii K_jj)`` on the days ``self.days[idx]`` (1 on the diagonal)."""
        d = self.days[idx]
        up, down, own = self._terms(idx, tau)
        lag = d[None, :] - d[:, None]
        # i before j: exp(-(d_j + u_b - d_i - u_a) / tau) = e^{-lag/tau} e^{u_a/tau} e^{-u_b/tau}
        log_k = np.where(lag > 0, up[:, None] + down[None, :], down[:, None] + up[None, :])
        log_k = log_k - np.abs(lag) / tau - 0.5 * np.log(np.outer(own, own))
        return np.where(lag == 0, 1.0, np.exp(np.minimum(log_k, 0.0)))

    def _lag_one(self, tau) -> float:
        """The modelled correlation (``s = 1``) averaged over the record's pairs of
        consecutive days."""
        a, b = self._pairs
        ua, _, own_a = self._terms(a, tau)
        _, db, own_b = self._terms(b, tau)
        log_k = ua + db - 1.0 / tau - 0.5 * np.log(own_a * own_b)
        return float(np.mean(np.exp(np.minimum(log_k, 0.0))))

    def _model(self, c1, r):
        """``(tau, s)`` of the pooled day correlation ``(c1, r)``."""
        key = (float(c1), float(r))
        if key not in self._models:
            tau = MIN_TAU_DAYS if r <= np.exp(-1.0 / MIN_TAU_DAYS) else -1.0 / np.log(r)
            if self._pairs[0].size == 0 or c1 <= 0.0:
                self._models[key] = (tau, 0.0)
                return self._models[key]
            have = self._lag_one(tau)
            if have < c1:  # lengthen tau until the lag-one mean is c1
                lo, hi = np.log(tau), np.log(1e4)
                if self._lag_one(np.exp(hi)) < c1:
                    lo = hi
                for _ in range(40):
                    mid = 0.5 * (lo + hi)
                    lo, hi = (mid, hi) if self._lag_one(np.exp(mid)) < c1 else (lo, mid)
                tau = float(np.exp(hi))
                have = self._lag_one(tau)
            self._models[key] = (tau, min(c1 / max(have, 1e-300), 1.0))
        return self._models[key]

    def correlation(self, d, c1, r) -> np.ndarray:
        """The modelled correlation (len(d), len(d)) of the day values on days ``d`` (a
        sorted subset of the record's) under the pooled day correlation ``(c1, r)``."""
        idx = np.searchsorted(self.days, np.asarray(d, dtype=np.int64))
        tau, s = self._model(c1, r)
        out = s * self._shape(idx, tau)
        np.fill_diagonal(out, 1.0)
        return out


def hourly_day_values(t_ns, x, days, bins: int = QUIET_HOUR_BINS) -> np.ndarray:
    """Each of ``days``' value (n_days, m): the mean, weighted by their numbers of
    samples, of the medians of the day's samples in each of ``bins`` bins of the day.

    The day values' covariance (:class:`QuietHours`) is that of the mean of the model
    miss over the day's selected hours. A median over the whole day is not that mean
    where the miss moves within the day and the day holds hours apart (quiet Kp blocks
    at either end of it): it follows the blocks holding more samples, by an amount that
    differs from day to day, a noise the covariance lacks. The median within each hour
    still keeps a spike out of the day value.

    Examples
    --------
    A day holding 3 hours at 0 nT and 5 at 4 nT: its median is 4, the mean of its
    hours' medians 2.5.

    >>> t = (np.r_[np.arange(3), 12 + np.arange(5)] * 3600 + 60) * 10 ** 9
    >>> x = np.r_[np.zeros(3), np.full(5, 4.0)]
    >>> hourly_day_values(t, x, [0])
    array([[2.5]])
    """
    t = np.asarray(t_ns, dtype=np.int64)
    x = np.asarray(x, dtype=float)
    x = x[:, None] if x.ndim == 1 else x
    days = np.asarray(days, dtype=np.int64)
    if t.size == 0 or days.size == 0:
        return np.full((days.size, x.shape[1]), np.nan)
    day, b = day_bins(t, bins)
    key = day * bins + b
    order = np.argsort(key, kind="stable")
    key, xs = key[order], x[order]
    edges = np.flatnonzero(np.diff(key)) + 1
    starts = np.r_[0, edges]
    med = np.array([np.median(g, axis=0) for g in np.split(xs, edges)]).reshape(-1, x.shape[1])
    n = np.diff(np.r_[starts, key.size]).astype(float)
    i = np.searchsorted(days, key[starts] // bins)
    keep = (i < days.size) & (days[np.minimum(i, max(days.size - 1, 0))] == key[starts] // bins)
    total = np.zeros((days.size, x.shape[1]))
    weight = np.zeros(days.size)
    np.add.at(total, i[keep], med[keep] * n[keep, None])
    np.add.at(weight, i[keep], n[keep])
    return total / np.maximum(weight, 1e-300)[:, None]


def _cov_factor(d, c1, r, sd, layout=None) -> np.ndarray:
    """A square root of the day values' covariance on days ``d``: each day's relative
    standard deviation ``sd`` (:func:`day_variance_scale`) times the pooled correlation
    ``1`` on the diagonal and ``c1 r ** (k - 1)`` at a lag of ``k`` days, or, given the
    record's :class:`QuietHours` ``layout``, the correlation its quiet hours imply."""
    if layout is None:
        corr = np.eye(d.size) + c1 * _lag_shape(d, r)
    else:
        corr = layout.correlation(d, c1, r)
    return (np.ones(d.size) if sd is None else np.asarray(sd, float))[:, None] * _factor(corr)


def _null_columns(d, k, half_width, degree=2) -> list:
    """The local no-change model on days ``d`` about day ``k``: a level, a slope (a drift
    is never a step) and a curvature. In a window symmetric about ``k`` the curvature is
    orthogonal to the step and costs it nothing; where the record's end cuts the window
    short it keeps a slow wander's curvature out of the step."""
    u = (d - k) / half_width
    return [np.ones(d.size), u, u ** 2][:degree + 1]


class _Fits:
    """GLS fits of the local model (:func:`_null_columns`) plus a step at each candidate
    day, one component: the step, its variance factor, its weights on the day values
    (for the Monte Carlo), and the noise variance (the median over the candidate days of
    the fits without the step, unless given)."""

    def __init__(self, days, y, c1, r, candidates, known, half_width, sigma2=None,
                 sd=None, degree=2, layout=None):
        self.weights = []  # (index slice, weight vector of the step on y[slice])
        delta, var, s2, dof = [], [], [], []
        for k in candidates:
            lo = np.searchsorted(days, k - half_width)
            hi = np.searchsorted(days, k + half_width)
            d = days[lo:hi]
            cols = _null_columns(d, k, half_width, degree)
            cols.insert(1, (d >= k).astype(float))
            cols += [(d >= kk).astype(float) for kk in known
                     if d[0] < kk <= d[-1] and kk != k]
            x = np.stack(cols, axis=1)
            chol = _cov_factor(d, c1, r, None if sd is None else sd[lo:hi], layout)
            xw = np.linalg.solve(chol, x)
            yw = np.linalg.solve(chol, y[lo:hi])
            q, rr = np.linalg.qr(xw)
            inv = np.linalg.inv(rr)
            cov = inv @ inv.T
            w = np.linalg.solve(chol.T, q @ inv.T[:, 1])  # step = w @ y[lo:hi]
            beta = inv @ (q.T @ yw)
            # the null fit (without the step) for the noise variance
            x0 = np.delete(xw, 1, axis=1)
            res0 = yw - x0 @ np.linalg.lstsq(x0, yw, rcond=None)[0]
            self.weights.append((slice(lo, hi), w))
            delta.append(beta[1])
            var.append(cov[1, 1])
            s2.append(float(res0 @ res0) / max(d.size - x0.shape[1], 1))
            dof.append(d.size - x0.shape[1])
        self.delta, self.var = np.array(delta), np.array(var)
        if sigma2 is None:
            # the median over days: windows holding a change not yet found inflate
            # their own estimate, not the record's; scaled to the chi-square's mean
            from scipy.stats import chi2

            nu = float(np.median(dof)) if dof else 1.0
            sigma2 = float(np.median(s2)) * nu / chi2.median(nu) if s2 else np.nan
        self.sigma2 = sigma2

    @property
    def se(self):
        return np.sqrt(self.sigma2 * self.var)

    @property
    def t(self):
        return self.delta / self.se

    def simulated_t(self, z):
        """t-statistics (n_sim, n_candidates) of noise draws ``z`` (n_sim, n) with unit
        variance and this component's correlation."""
        out = np.empty((z.shape[0], len(self.weights)))
        for i, (sl, w) in enumerate(self.weights):
            out[:, i] = z[:, sl] @ w
        return out / np.sqrt(self.var)


def _candidates(days, known, min_side):
    """Split days (first day at the new level) with ``min_side`` days of data each side
    and not within ``min_side`` days of a change already found."""
    if days.size < 2 * min_side:
        return np.zeros(0, dtype=np.int64)
    cand = days[min_side:days.size - min_side + 1]
    for kk in known:
        cand = cand[np.abs(cand - kk) >= min_side]
    return cand


def _null_max(days, corrs, fits_by_comp, mix, n_sim, seed, sd=None, layout=None):
    """The statistic's largest value over candidate days in ``n_sim`` records without a
    change: noise with each component's day correlation (on the record's quiet hours,
    given its :class:`QuietHours` ``layout``), the components mixed by the Cholesky
    factor ``mix`` of their correlation."""
    rng = np.random.default_rng(seed)
    m = len(fits_by_comp)
    u = rng.standard_normal((n_sim, days.size, m)) @ mix.T
    ts = []
    for j, ((c1, r), fits) in enumerate(zip(corrs, fits_by_comp)):
        chol = _cov_factor(days, c1, r, sd, layout)
        ts.append(fits.simulated_t(u[:, :, j] @ chol.T))
    return _statistic(np.stack(ts, axis=-1), mix).max(axis=1)


def _statistic(t, mix):
    """``t^T R^-1 t`` over the components (last axis) of t-statistics ``t``, with ``R``
    the components' correlation (``mix`` its Cholesky factor): chi-square with ``m``
    degrees of freedom at one day under no change."""
    white = np.linalg.solve(mix, np.moveaxis(t, -1, 0).reshape(mix.shape[0], -1))
    return np.sum(white ** 2, axis=0).reshape(t.shape[:-1])


def component_correlation(days, values, corrs, window_days: int = 28,
                          sd=None, layout=None) -> np.ndarray:
    """Correlation (m, m) of the components' day values, from their residuals about a
    straight line through each ``window_days`` stretch of the record, whitened with each
    component's day correlation ``corrs`` (``[(c1, r), ...]``).

    The model miss is often shared by the components, and a change in several at once
    is judged against that. Whitened, the residuals are nearly independent from day to
    day, so the estimate rests on every day; unwhitened, a miss correlated over days left
    few independent values, the estimate scattered (0.3 between independent components
    under a 5-day miss) and a wrong correlation inflated the statistic (7 of 60 records
    without a change named one)."""
    days = np.asarray(days, dtype=np.int64)
    m = values.shape[1]
    acc = np.zeros((m, m))
    for w0 in range(int(days[0]), int(days[-1]) + 1, window_days):
        inside = (days >= w0) & (days < w0 + window_days)
        if inside.sum() < 4:
            continue
        d = days[inside]
        x = np.stack([np.ones(d.size), (d - d.mean()) / window_days], axis=1)
        res = np.empty((d.size, m))
        for j, (c1, r) in enumerate(corrs):
            chol = _cov_factor(d, c1, r, None if sd is None else sd[inside], layout)
            xw, yw = np.linalg.solve(chol, x), np.linalg.solve(chol, values[inside, j])
            res[:, j] = yw - xw @ np.linalg.lstsq(xw, yw, rcond=None)[0]
        acc += res.T @ res
    sd = np.sqrt(np.diag(acc))
    if not np.all(sd > 0):
        return np.eye(m)
    return np.clip(acc / np.outer(sd, sd), -0.95, 0.95) * (1 - np.eye(m)) + np.eye(m)


def _time_interval(days, y, corrs, sigma2, k_hat, known, half_width, comps, level=0.95,
                   sd=None, degree=2, layout=None):
    """Split days whose likelihood ratio against ``k_hat`` stays under the critical value,
    on the fixed data window of ``k_hat`` (the step's components ``comps``)."""
    from magcal.discover.step_time import lr_critical_value

    lo = np.searchsorted(days, k_hat - half_width)
    hi = np.searchsorted(days, k_hat + half_width)
    d = days[lo:hi]
    others = [kk for kk in known if d[0] < kk <= d[-1] and kk != k_hat]
    splits = d[1:]
    lr = np.zeros(splits.size)
    for j in comps:
        c1, r = corrs[j]
        chol = _cov_factor(d, c1, r, None if sd is None else sd[lo:hi], layout)
        yw = np.linalg.solve(chol, y[lo:hi, j])
        base = _null_columns(d, k_hat, half_width, degree) + [(d >= kk) * 1.0 for kk in others]
        sse = []
        for k in splits:
            xw = np.linalg.solve(chol, np.stack(base + [(d >= k) * 1.0], axis=1))
            res = yw - xw @ np.linalg.lstsq(xw, yw, rcond=None)[0]
            sse.append(float(res @ res) / sigma2[j])
        lr += np.array(sse)
    lr -= lr.min()
    kept = splits[lr <= lr_critical_value(level)]
    return int(kept.min()), int(kept.max())


def detect_level_changes(t_ns, x, *, half_width: int = HALF_WIDTH_DAYS,
                         min_side: int = MIN_SIDE_DAYS, alpha: float = ALPHA,
                         n_sim: int = N_SIM, max_changes: int = MAX_CHANGES,
                         seed: int = _SEED, weigh_days: bool = False,
                         local_model: str = "auto") -> tuple[list, dict]:
    """Level changes of the offset in the selected residual ``x`` (data minus model).

    Parameters
    ----------
    t_ns : array_like of int64, shape (n,)
        Times (ns) of the selected (quiet) samples, sorted.
    x : array_like, shape (n, m)
        Their data minus model (nT).
    half_width : int
        Days either side of a candidate day in its local fit.
    min_side : int
        Fewest days with data each side of a candidate day.
    alpha : float
        Chance of naming a change in a record without one, under the modelled noise
        (look-elsewhere corrected).
    n_sim : int
        Monte Carlo draws of the no-change maximum.
    max_changes : int
        Most changes named.
    seed : int
        Seed of the Monte Carlo (the result is reproducible).
    weigh_days : bool
        Weigh the day values by their modelled variances (:func:`day_variance_scale`:
        a day holding few selected samples is noisier). Off by default: with quiet data
        in whole 3-hour Kp blocks the days' counts vary too little for the weights to
        gain power, and their scatter added false changes.
    local_model : {"auto", "trend", "level"}
        The local no-change model of each candidate day: a level, slope and curvature
        (``"trend"``), a level only (``"level"``), or (``"auto"``) the level only where
        the record shows no slow trend (:func:`trend_p_value` above :data:`TREND_P`) and
        would show one clearly enough (:func:`drift_detectability` at least
        :data:`MIN_DRIFT_DETECTABILITY`) and the day values' lag-one correlation is at
        most :data:`MAX_LEVEL_ONLY_C1`, else the trend model.

    Returns
    -------
    changes : list of LevelChange
        In time order.
    info : dict
        ``tested`` (bool: False when the record is too short to pool the day
        correlation or to split), ``threshold`` (the value of ``t^T R^-1 t`` a change
        must exceed, the first round's), ``n_days``, ``half_width_days``, ``alpha``,
        ``n_changes``, ``local_model`` (``"level"`` or ``"level, slope, curvature"``),
        ``trend_p_value`` and ``drift_detectability`` (when judged), ``why`` (when not
        tested).
    """
    t = np.asarray(t_ns, dtype=np.int64)
    x = np.asarray(x, dtype=float)
    x = x[:, None] if x.ndim == 1 else x
    ok = np.all(np.isfinite(x), axis=1)
    # each UTC day's value (calendar days since 1970): the mean of its hours' medians
    days, counts = batch_days_counts(t[ok], origin_ns=0)
    y = hourly_day_values(t[ok], x[ok], days)
    info = {"tested": False, "n_days": int(days.size), "threshold": None,
            "half_width_days": half_width, "alpha": alpha}
    known: list[int] = []
    sizes: dict = {}
    changes = []
    pooled = record_day_correlation(days, y)
    if pooled is None or _candidates(days, known, min_side).size == 0:
        info["why"] = "record too short to look for level changes"
        return changes, info
    if local_model not in ("auto", "trend", "level"):
        raise ValueError(f"local_model must be 'auto', 'trend' or 'level', not {local_model!r}")
    info["tested"] = True
    m = y.shape[1]
    sd = day_variance_scale(days, y, counts) if weigh_days else None
    layout = QuietHours.from_times(t[ok], days)

    def search(degree, known, sizes, pooled):
        """Changes added one at a time, strongest first, under the local model of
        ``degree``; the first round's threshold."""
        known, sizes, first = list(known), dict(sizes), None
        for _ in range(max_changes + 1):
            corrs = _component_corrs(pooled)
            mix = _factor(component_correlation(days, _without(days, y, sizes), corrs,
                                                sd=sd, layout=layout))
            cand = _candidates(days, known, min_side)
            if cand.size == 0:
                break
            fits = [_Fits(days, y[:, j], *corrs[j], cand, known, half_width, sd=sd,
                          degree=degree, layout=layout) for j in range(m)]
            null = _null_max(days, corrs, fits, mix, n_sim, seed, sd=sd, layout=layout)
            thr = float(np.quantile(null, 1.0 - alpha))
            first = thr if first is None else first
            stat = _statistic(np.stack([f.t for f in fits], axis=1), mix)
            i = int(np.argmax(stat))
            if stat[i] <= thr or len(known) >= max_changes:
                break
            known.append(int(cand[i]))
            sizes[known[-1]] = np.array([f.delta[i] for f in fits])
            # the correlation with the changes found taken out of the day values
            pooled = record_day_correlation(days, _without(days, y, sizes)) or pooled
        return known, sizes, pooled, first

    pooled0 = pooled
    degree = 0 if local_model == "level" else 2
    known, sizes, pooled, thr = search(degree, known, sizes, pooled0)
    if local_model == "auto":
        corrs = _component_corrs(pooled)
        p_trend = trend_p_value(days, _without(days, y, sizes), corrs, min_side, sd=sd,
                                layout=layout)
        info["trend_p_value"] = round(p_trend, 4)
        ratio = drift_detectability(days, corrs, _candidates(days, [], min_side),
                                    half_width, sd=sd, layout=layout)
        info["drift_detectability"] = round(ratio, 3)
        memory = max(c[0] for c in corrs)
        if (p_trend > TREND_P and ratio >= MIN_DRIFT_DETECTABILITY
                and memory <= MAX_LEVEL_ONLY_C1):
            degree = 0
            known, sizes, pooled, thr = search(0, [], {}, pooled0)
    info["local_model"] = ("level", "", "level, slope, curvature")[degree]
    info["threshold"] = None if thr is None else round(thr, 3)
    # final sizes, errors and intervals, each change in the others' presence
    corrs = _component_corrs(pooled)
    mix = _factor(component_correlation(days, _without(days, y, sizes), corrs, sd=sd,
                                        layout=layout))
    for kk in sorted(known):
        rest = [k for k in known if k != kk]
        # the record's noise variance (over every candidate day, the others' changes
        # in), then the change's own fit
        full = [_Fits(days, y[:, j], *corrs[j], _candidates(days, rest, min_side), rest,
                      half_width, sd=sd, degree=degree, layout=layout) for j in range(m)]
        sigma2 = [f.sigma2 for f in full]
        fits = [_Fits(days, y[:, j], *corrs[j], np.array([kk]), rest, half_width,
                      sigma2=sigma2[j], sd=sd, degree=degree, layout=layout)
                for j in range(m)]
        size = np.array([f.delta[0] for f in fits])
        se = np.array([f.se[0] for f in fits])
        zc = np.abs(size / se)
        comps = [j for j in range(m) if zc[j] >= 2.0] or [int(np.argmax(zc))]
        k_lo, k_hi = _time_interval(days, y, corrs, sigma2, kk, rest, half_width, comps,
                                    sd=sd, degree=degree, layout=layout)
        null = _null_max(days, corrs, full, mix, n_sim, seed, sd=sd, layout=layout)
        stat = float(_statistic(zc * np.sign(size), mix))
        changes.append(LevelChange(
            time=_midnight(kk), time_lo=_midnight(min(k_lo, kk) - 1),
            time_hi=_midnight(max(k_hi, kk) + 1), size_nT=size, se_nT=se,
            z=float(zc.max()), p_value=float((1 + np.sum(null >= stat)) / (1 + n_sim))))
    info["n_changes"] = len(changes)
    return changes, info


#: A record whose day values (its changes taken out) hold a slow trend with a p-value
#: under this (:func:`trend_p_value`) has its candidate days fitted with a local line and
#: curvature; above it, with a local level only (about half the step's standard error:
#: a step in the middle of a line is told from the line's slope by half the days).
#: Generous: a trend missed reads as steps in the level-only fits.
TREND_P = 0.3
#: Least :func:`drift_detectability` at which a record may have its candidate days fitted
#: with a local level only: a drift the level-only fits read as a step of 1 standard
#: error then stands 3 standard errors out in the trend test.
MIN_DRIFT_DETECTABILITY = 3.0
#: Largest lag-one day correlation (any component) at which a record may have its
#: candidate days fitted with a local level only. Above it (a model miss correlated over
#: days) the modelled day correlation, which the level-only fit leans on harder than
#: the local line does, is the least well known, and level-only fits named changes in
#: records without one.
MAX_LEVEL_ONLY_C1 = 0.65
#: Steps :func:`trend_p_value` allows in the no-trend model (changes not yet found).
TREND_STEPS = 1
#: Shortest half-period (days) of the cosines :func:`trend_p_value` fits.
TREND_HALF_PERIOD_DAYS = 30.0


def _trend_basis(days, half_period: float) -> np.ndarray:
    """The slow-trend cosines over the record (n, n_cos): half-periods of at least
    ``half_period`` days, at least one."""
    span = float(days[-1] - days[0]) or 1.0
    u = (days - days[0]) / span
    return np.stack([np.cos(np.pi * k * u)
                     for k in range(1, max(1, int(span // half_period)) + 1)], axis=1)


def trend_p_value(days, values, corrs, min_side: int = MIN_SIDE_DAYS, sd=None,
                  half_period: float = TREND_HALF_PERIOD_DAYS,
                  n_steps: int = TREND_STEPS, layout=None) -> float:
    """P-value of a slow trend in the day values ``values`` against a level and one step.

    The trend is a sum of cosines over the record with half-periods of at least
    ``half_period`` days (a drift, a wander of months); it is judged by generalised
    least squares with each component's day correlation ``corrs`` (``[(c1, r), ...]``)
    and relative day errors ``sd``, both in the no-trend model and the trend model, a
    step at the day that fits best (chosen in the no-trend model: a change not yet
    found projects on the slowest cosines and would otherwise read as a trend). The
    statistic is the drop in the sum of squares over the components, against the
    chi-square with as many degrees of freedom as cosines times components (the noise
    variance from the trend model's residuals).
    """
    days = np.asarray(days, dtype=np.int64)
    n, m = values.shape
    trend = _trend_basis(days, half_period)
    n_cos = trend.shape[1]
    cand = days[min_side:n - min_side + 1]
    whit = []
    for j, (c1, r) in enumerate(corrs):
        chol = _cov_factor(days, c1, r, sd, layout)
        whit.append((np.linalg.solve(chol, np.ones(n)), np.linalg.solve(chol, values[:, j]),
                     np.linalg.solve(chol, trend),
                     np.linalg.solve(chol, (days[:, None] >= cand[None, :]) * 1.0)))
    # the best steps of the no-trend model, one at a time, summed over components
    chosen: list[int] = []
    for _ in range(n_steps if cand.size else 0):
        score = np.zeros(cand.size)
        for one, yw, _, steps in whit:
            q = np.linalg.qr(np.stack([one] + [steps[:, k] for k in chosen], axis=1))[0]
            sp = steps - q @ (q.T @ steps)
            ry = yw - q @ (q.T @ yw)
            score += (sp.T @ ry) ** 2 / np.maximum(np.sum(sp ** 2, axis=0), 1e-12) / (ry @ ry)
        score[chosen] = -1.0
        chosen.append(int(np.argmax(score)))
    drop = 0.0
    for one, yw, tw, steps in whit:
        x0 = np.stack([one] + [steps[:, k] for k in chosen], axis=1)
        x1 = np.concatenate([x0, tw], axis=1)
        r0 = yw - x0 @ np.linalg.lstsq(x0, yw, rcond=None)[0]
        r1 = yw - x1 @ np.linalg.lstsq(x1, yw, rcond=None)[0]
        s2 = float(r1 @ r1) / max(n - x1.shape[1], 1)
        drop += (float(r0 @ r0) - float(r1 @ r1)) / s2
    from scipy.stats import chi2

    return float(chi2.sf(drop, n_cos * m))


def drift_detectability(days, corrs, candidates, half_width, sd=None,
                        half_period: float = TREND_HALF_PERIOD_DAYS,
                        n_steps: int = TREND_STEPS, layout=None) -> float:
    """How much better :func:`trend_p_value` sees a linear drift than a level-only local
    fit reads it as a step: the ratio, in the worst component, of the drift's standard
    score in the trend test (against a level and a step at mid-record) to its mean
    standard score in the level-only local step estimates (their median over the
    candidate days), both under the modelled day covariance.

    A level-only local fit reads a drift of ``D`` nT/day as a step of about ``D`` times
    the half-width; the trend test guards against that only where it sees the same
    drift much more clearly than the local fits read it as a step. How much more
    depends on the record's length, gaps, days and day correlation, so it is computed
    for each record rather than assumed.
    """
    days = np.asarray(days, dtype=np.int64)
    n = days.size
    trend = _trend_basis(days, half_period)
    slope = (days - days.mean()).astype(float)
    steps = [(days >= days[(i * n) // (n_steps + 1)]) * 1.0 for i in range(1, n_steps + 1)]
    worst = np.inf
    for c1, r in corrs:
        chol = _cov_factor(days, c1, r, sd, layout)
        x0 = np.linalg.solve(chol, np.stack([np.ones(n)] + steps, axis=1))
        q0 = np.linalg.qr(x0)[0]
        sw = np.linalg.solve(chol, slope)
        sw -= q0 @ (q0.T @ sw)
        tw = np.linalg.solve(chol, trend)
        tw -= q0 @ (q0.T @ tw)
        qt = np.linalg.qr(tw)[0]
        seen = float(np.linalg.norm(qt.T @ sw))  # the drift's score per nT/day
        fits = _Fits(days, np.zeros(n), c1, r, candidates, [], half_width, sigma2=1.0,
                     sd=sd, degree=0, layout=layout)
        local = np.median([abs(w @ (days[sl] - k)) / np.sqrt(v)
                           for (sl, w), v, k in zip(fits.weights, fits.var, candidates)])
        worst = min(worst, seen / max(local, 1e-12))
    return float(worst)


def _component_corrs(pooled) -> list:
    """``[(c1, r), ...]`` per component of a pooled day correlation, as estimated."""
    return [(float(c1), float(r)) for c1, r in zip(pooled.c1[0], pooled.r[0])]


def _without(days, y, sizes: dict) -> np.ndarray:
    """Day values ``y`` with the changes ``{first day: size}`` taken out."""
    out = np.array(y, dtype=float)
    for kk, size in sizes.items():
        out -= np.outer(days >= kk, size)
    return out


def _midnight(day: int) -> np.datetime64:
    return np.datetime64(int(day) * DAY_NS, "ns")


def straddling_windows(starts, ends, changes) -> list:
    """For each window ``[start, end)`` the changes strictly inside it (a change at the
    window's start is not inside)."""
    s = np.asarray(starts).astype("datetime64[ns]").astype(np.int64)
    e = np.asarray(ends).astype("datetime64[ns]").astype(np.int64)
    out = []
    for a, b in zip(s, e):
        out.append([c for c in changes
                    if a < np.datetime64(c.time, "ns").astype(np.int64) < b])
    return out


def change_caution(change, columns=("Hp", "He", "Hn")) -> str:
    """The ``reason`` caution of a valid window straddling ``change``."""
    sizes = ", ".join(f"{c} {s:+.2f}" for c, s in zip(columns, change.size_nT))
    return f"caution: level change of {sizes} nT at {_day(change.time)} inside the window"


def change_warning(change, step_days: float = 7.0, columns=("Hp", "He", "Hn")) -> str:
    """The record-level warning naming ``change``."""
    return (f"level change of the offset: {change.describe(columns)}; the windows "
            "straddling it mix both levels and 'offsets apply' interpolates across it "
            f"(over {step_days:g} days or more; quality bit "
            "offset_interpolated_across_level_change)")


_CAUTION = re.compile(r"level change of (?P<sizes>[^;]*?) nT at (?P<day>\d{4}-\d{2}-\d{2})"
                      r" inside the window")


def changes_from_reasons(reasons, columns=("Hp", "He", "Hn")) -> tuple:
    """Level changes named in windows' ``reason`` cautions (:func:`change_caution`), for
    an OFFSETS.csv read without its JSON sidecar: their days and sizes, no errors.

    Examples
    --------
    >>> got = changes_from_reasons(["", "caution: level change of Hp +1.00, He -0.50, "
    ...                             "Hn +0.25 nT at 2019-12-12 inside the window"])
    >>> str(got[0].time), got[0].size_nT.tolist()
    ('2019-12-12T00:00:00.000000000', [1.0, -0.5, 0.25])
    """
    seen = {}
    for reason in reasons:
        for match in _CAUTION.finditer(str(reason)):
            day = match["day"]
            if day in seen:
                continue
            sizes = dict(part.split() for part in match["sizes"].split(", "))
            t = np.datetime64(day, "ns")
            seen[day] = LevelChange(t, t - np.timedelta64(1, "D"), t + np.timedelta64(1, "D"),
                                    np.array([float(sizes.get(c, "nan")) for c in columns]),
                                    np.full(len(columns), np.nan), np.nan, np.nan)
    return tuple(seen[d] for d in sorted(seen))
