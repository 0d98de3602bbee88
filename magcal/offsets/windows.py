"""Sliding-window statistics of data minus model (the core of the offset estimate).

Windows of ``window_days`` stepped by ``step_days`` (28 and 7 in the SOSMAG paper). Per
window and component: median (the offset), standard deviation, and the median absolute
deviation scaled to a standard deviation (scipy's ``scale="normal"``), over the selected
(quiet) samples in ``[start, end)``. The times are sorted once and every window is a pair of
``searchsorted`` bounds, so a year of 1-min data takes a fraction of a second.
"""

from __future__ import annotations

import math

import numpy as np

from magcal.errors import InputError
from magcal.stats import normal_mad

DAY_NS = 86_400 * 10**9
#: Fewest degrees of freedom :func:`batch_error_and_dof` states. A model miss correlated
#: over most of a window leaves under two effective days; t on one degree of freedom
#: (12.7) then made the 95 % intervals of 28-day windows with a 5-day miss 2.4 times as
#: wide as on two (4.3), which held the truth as often (94.8 % of 600 either way).
DOF_FLOOR = 2.0
#: Local-time bins (one hour each) over which a window's coverage is counted.
LT_BINS = 24


def window_grid(first_ns: int, last_ns: int, window_days: float = 28.0,
                step_days: float = 7.0, origin_ns: int | None = None):
    """Start and end times (int64 ns) of the sliding windows covering ``[first, last]``.

    Windows start at ``origin_ns`` (default: midnight UTC of the first sample) and every
    ``step_days`` after it; the last window is the first whose end passes ``last_ns``, so
    every sample lies in at least one window.

    Examples
    --------
    >>> s, e = window_grid(0, 30 * DAY_NS - 1, 28, 7)
    >>> (s // DAY_NS).tolist(), (e // DAY_NS).tolist()
    ([0, 7], [28, 35])
    """
    for name, value in (("window_days", window_days), ("step_days", step_days)):
        if not (math.isfinite(value) and value > 0):  # NaN or inf: no window grid
            raise InputError(f"{name} must be a finite number > 0, got {value!r}")
    win = int(round(window_days * DAY_NS))
    step = int(round(step_days * DAY_NS))
    origin = (first_ns // DAY_NS) * DAY_NS if origin_ns is None else int(origin_ns)
    if origin > first_ns:
        raise InputError("the window origin must not be after the first sample")
    span = last_ns - origin
    k = max(0, math.ceil((span + 1 - win) / step)) if span + 1 > win else 0
    starts = origin + step * np.arange(k + 1, dtype=np.int64)
    return starts, starts + win


def window_statistics(t_ns, diff, selected, starts_ns, ends_ns, min_used: int = 720,
                      local_time_h=None, lt_bins: int = 24, min_per_bin: int = 5,
                      columns=None) -> dict:
    """Per-window median, std and scaled MAD of ``diff`` over the selected samples.

    Parameters
    ----------
    t_ns : array_like of int64, shape (n,)
        Sample times in ns, non-decreasing.
    diff : array_like, shape (n, m)
        Data minus model; rows with any NaN are not available.
    selected : array_like of bool, shape (n,)
        Samples allowed into the statistics (e.g. Kp <= kp_max).
    starts_ns, ends_ns : array_like of int64, shape (k,)
        Window bounds ``[start, end)``.
    min_used : int
        Windows with fewer selected samples get NaN statistics and a reason.
    local_time_h : array_like, shape (n,), optional
        If given, the offset is *local-time balanced*: the mean over ``lt_bins``
        local-time bins of the per-bin medians, so an uneven spread of quiet samples over
        local time does not leak a local-time field into the offset. Windows with a bin
        holding fewer than ``min_per_bin`` selected samples get NaN and a reason. The
        default (None) is the plain median of CONTRACTS §2.
    columns : sequence of str, optional
        Names of the ``diff`` columns, for the reason of a window without data when some
        columns do have data there (default: ``0, 1, ...``).

    Returns
    -------
    dict
        ``median, std, mad, se, dof`` (k, m) (``se``, ``dof``:
        :func:`batch_error_and_dof`); ``n_used, n_available`` (k,) int; ``fraction_used``
        (k,) = n_used / n_available; ``reason`` list of str ('' when fine).

    Examples
    --------
    >>> import numpy as np
    >>> t = np.arange(10) * DAY_NS
    >>> d = np.arange(10.0)[:, None]
    >>> st = window_statistics(t, d, np.arange(10) % 2 == 0, [0, 5 * DAY_NS],
    ...                        [5 * DAY_NS, 10 * DAY_NS], min_used=2)
    >>> st["median"][:, 0], st["n_used"], st["fraction_used"]
    (array([2., 7.]), array([3, 2]), array([0.6, 0.4]))
    """
    t = np.asarray(t_ns, dtype=np.int64)
    d = np.asarray(diff, dtype=float)
    d = d[:, None] if d.ndim == 1 else d
    sel = np.asarray(selected, dtype=bool)
    if not (t.shape[0] == d.shape[0] == sel.shape[0]):
        raise InputError("times, differences and selection differ in length")
    if t.size > 1 and np.any(np.diff(t) < 0):
        raise InputError("times must be sorted")
    starts = np.asarray(starts_ns, dtype=np.int64)
    ends = np.asarray(ends_ns, dtype=np.int64)
    avail = np.all(np.isfinite(d), axis=1)
    t_av = t[avail]
    use = sel[avail]
    t_use, d_use = t_av[use], d[avail][use]
    if local_time_h is not None:
        lt = np.asarray(local_time_h, dtype=float)
        if lt.shape[0] != t.shape[0]:
            raise InputError("local_time_h differs in length from the times")
        lt_bin = np.minimum((np.mod(lt[avail][use], 24.0) / 24.0 * lt_bins).astype(int),
                            lt_bins - 1)
    n_av = np.searchsorted(t_av, ends) - np.searchsorted(t_av, starts)
    first, last = np.searchsorted(t, starts), np.searchsorted(t, ends)
    lo, hi = np.searchsorted(t_use, starts), np.searchsorted(t_use, ends)
    n_used = hi - lo
    k, m = starts.size, d.shape[1]
    median = np.full((k, m), np.nan)
    std = np.full((k, m), np.nan)
    mad = np.full((k, m), np.nan)
    se = np.full((k, m), np.nan)
    dof = np.full((k, m), np.nan)
    reasons = []
    for i in range(k):
        if n_av[i] == 0:
            reasons.append(no_data_reason(d[first[i]:last[i]], columns))
            continue
        if n_used[i] < max(int(min_used), 1):
            reasons.append(f"too few quiet samples: n_used={int(n_used[i])} < "
                           f"min_used={int(min_used)}")
            continue
        x = d_use[lo[i]:hi[i]]
        med = np.median(x, axis=0)
        if local_time_h is not None:
            b = lt_bin[lo[i]:hi[i]]
            counts = np.bincount(b, minlength=lt_bins)
            if counts.min() < min_per_bin:
                reasons.append(f"local-time coverage too poor: {int(np.sum(counts < min_per_bin))}"
                               f" of {lt_bins} bins with < {min_per_bin} quiet samples")
                continue
            order = np.argsort(b, kind="stable")
            groups = np.split(x[order], np.cumsum(counts)[:-1])
            median[i] = np.mean([np.median(g, axis=0) for g in groups], axis=0)
        else:
            median[i] = med
        std[i] = np.std(x, axis=0, ddof=1) if n_used[i] > 1 else 0.0
        mad[i] = normal_mad(x, axis=0)
        se[i], dof[i] = batch_error_and_dof(t_use[lo[i]:hi[i]], x)
        reasons.append("")
    with np.errstate(invalid="ignore", divide="ignore"):
        frac = np.where(n_av > 0, n_used / np.maximum(n_av, 1), np.nan)
    return {"median": median, "std": std, "mad": mad, "se": se, "dof": dof,
            "n_used": n_used.astype(np.int64),
            "n_available": n_av.astype(np.int64), "fraction_used": frac, "reason": reasons}


def no_data_reason(diff_window, columns=None) -> str:
    """Why a window has no available sample (a sample needs every column finite): plain
    "no data in window", or naming the columns without a finite value there when other
    columns have some (e.g. an all-NaN ``Hp`` column; the window then has no sample).

    Examples
    --------
    >>> import numpy as np
    >>> no_data_reason(np.array([[np.nan, 1.0, 2.0]] * 3), ["Hp", "He", "Hn"])
    'no data in window: column Hp has no finite value'
    >>> no_data_reason(np.full((0, 3), np.nan), ["Hp", "He", "Hn"])
    'no data in window'
    """
    d = np.asarray(diff_window, dtype=float)
    d = d[:, None] if d.ndim == 1 else d
    names = [str(c) for c in (range(d.shape[1]) if columns is None else columns)]
    empty = ~np.isfinite(d).any(axis=0)
    if d.shape[0] == 0 or empty.all():
        return "no data in window"
    which = ", ".join(names[j] for j in np.flatnonzero(empty))
    many = int(empty.sum()) > 1
    return (f"no data in window: column{'s' if many else ''} {which} "
            f"ha{'ve' if many else 's'} no finite value")


def window_coverage(t_ns, selected, starts_ns, ends_ns, local_time_h=None,
                    lt_bins: int = LT_BINS) -> dict:
    """How many of each window's days and local-time hours hold selected samples.

    A median over a window stands for the whole window only if the samples it uses are
    spread over the window's days (a slow drift is averaged, not sampled once) and over
    local time (a local-time field the model lacks averages out instead of biasing the
    offset). This counts both; the thresholds are applied by the caller.

    Parameters
    ----------
    t_ns : array_like of int64, shape (n,)
        Sample times in ns, non-decreasing.
    selected : array_like of bool, shape (n,)
        Samples used by the window statistics (quiet and with data and model).
    starts_ns, ends_ns : array_like of int64, shape (k,)
        Window bounds ``[start, end)``.
    local_time_h : array_like, shape (n,), optional
        Local time of each sample in hours; without it ``lt_hours_covered`` is -1.
    lt_bins : int
        Number of equal local-time bins (default 24, one hour each).

    Returns
    -------
    dict
        ``days_covered`` (k,) int: distinct UTC days with a selected sample;
        ``window_days`` (k,) float: window length in days; ``lt_hours_covered`` (k,)
        int: local-time bins with a selected sample (-1 without local time).

    Examples
    --------
    >>> import numpy as np
    >>> t = np.array([0, 1, 2 * DAY_NS, 9 * DAY_NS]) + 3600 * 10**9
    >>> cov = window_coverage(t, [True, True, True, False], [0], [28 * DAY_NS],
    ...                       local_time_h=[1.0, 1.5, 13.0, 5.0])
    >>> cov["days_covered"].tolist(), cov["lt_hours_covered"].tolist()
    ([2], [2])
    """
    t = np.asarray(t_ns, dtype=np.int64)
    sel = np.asarray(selected, dtype=bool)
    if t.shape != sel.shape:
        raise InputError("times and selection differ in length")
    starts = np.asarray(starts_ns, dtype=np.int64)
    ends = np.asarray(ends_ns, dtype=np.int64)
    t_sel = t[sel]
    day = np.floor_divide(t_sel, DAY_NS)
    lt_bin = None
    if local_time_h is not None:
        lt = np.asarray(local_time_h, dtype=float)
        if lt.shape != t.shape:
            raise InputError("local_time_h differs in length from the times")
        lt_bin = np.minimum((np.mod(lt[sel], 24.0) / 24.0 * lt_bins).astype(int), lt_bins - 1)
    lo, hi = np.searchsorted(t_sel, starts), np.searchsorted(t_sel, ends)
    days = np.array([np.unique(day[a:b]).size for a, b in zip(lo, hi)], dtype=np.int64)
    if lt_bin is None:
        hours = np.full(starts.size, -1, dtype=np.int64)
    else:
        hours = np.array([np.unique(lt_bin[a:b]).size for a, b in zip(lo, hi)],
                         dtype=np.int64)
    return {"days_covered": days, "window_days": (ends - starts) / DAY_NS,
            "lt_hours_covered": hours}


def thin_coverage_reason(days_covered: int, window_days: float, lt_hours_covered: int,
                         min_day_fraction: float, min_lt_fraction: float,
                         lt_bins: int = LT_BINS) -> str:
    """Why a window's coverage is too thin to trust ('' when it is not).

    Examples
    --------
    >>> thin_coverage_reason(1, 28.0, 20, 0.25, 0.5)
    'coverage too thin to trust: used samples on 1 of 28 days (< 25%)'
    >>> thin_coverage_reason(20, 28.0, -1, 0.25, 0.5)
    ''
    """
    parts = []
    if days_covered < min_day_fraction * window_days:
        parts.append(f"used samples on {days_covered} of {window_days:g} days "
                     f"(< {min_day_fraction:.0%})")
    if lt_hours_covered >= 0 and lt_hours_covered < min_lt_fraction * lt_bins:
        where = "in" if parts else "used samples in"
        parts.append(f"{where} {lt_hours_covered} of {lt_bins} local-time hours "
                     f"(< {min_lt_fraction:.0%})")
    return ("coverage too thin to trust: " + " and ".join(parts)) if parts else ""


def batch_standard_error(t_ns, x, batch_ns: int = DAY_NS, min_batches: int = 3,
                         min_fraction: float = 0.1) -> np.ndarray:
    """Standard error (1 sigma) of a window's offset under correlated residuals.

    The residual of data minus model is correlated over hours (the model misses slowly
    varying fields), so the spread over ``sqrt(n)`` says nothing about how well the
    offset is known. Batch means: the window is cut into days, each day's median is one
    batch value, and the standard error is ``sd(batches) / sqrt(n_batches)`` inflated by
    ``sqrt((1 + r) / (1 - r))``, the variance factor of the mean of an AR(1) series of
    days, with ``r`` the lag-one correlation of consecutive days' values plus its
    small-sample bias ``(1 + 3 r) / n_batches`` (Kendall 1954), within [0, 0.9]. A model
    miss that stays correlated over days makes every later day's value follow the
    earlier ones; ``sqrt(1 + 2 r1)`` (the first lag alone, unbiased) held the truth in
    75 % of 28-day windows whose miss had a 2-day correlation time (now 91 %). Days
    holding under ``min_fraction`` of the fullest day's samples are left out; fewer than
    ``min_batches`` days give NaN. The standard error is itself estimated from a few
    batches, so an interval needs Student's t on :func:`batch_error_and_dof`'s degrees
    of freedom, not the normal 1.96 (which held the truth in 87-94 % of the windows
    measured there).

    Parameters
    ----------
    t_ns : array_like of int64, shape (n,)
    x : array_like, shape (n, m)

    Returns
    -------
    ndarray, shape (m,)

    Examples
    --------
    Ten days whose values climb 0, 1, ..., 9: sd / sqrt(10) = 0.957, and consecutive
    days are correlated (r1 = 0.7, 0.9 with its bias), so it is inflated by sqrt(19).

    >>> t = np.arange(10 * 24) * (DAY_NS // 24)
    >>> x = np.repeat(np.arange(10.0), 24)[:, None]
    >>> batch_standard_error(t, x).round(3)
    array([4.173])
    """
    return batch_error_and_dof(t_ns, x, batch_ns, min_batches, min_fraction)[0]


def batch_error_and_dof(t_ns, x, batch_ns: int = DAY_NS, min_batches: int = 3,
                        min_fraction: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """:func:`batch_standard_error` and the degrees of freedom its interval needs.

    ``n_batches`` correlated batch values hold about ``n_eff = n_batches (1 - r) /
    (1 + r)`` independent ones (the same AR(1) factor), and the standard error's own
    scatter is that of a variance estimated on ``n_eff - 1`` degrees of freedom (at
    least :data:`DOF_FLOOR`). The 95 % interval ``offset +- t(0.975, dof) se``
    (:func:`magcal.stats.student_interval`) is what OFFSETS.csv's ``*_dof`` columns
    serve. Measured over 200 seeded 28-day windows of an AR(1) model miss of 3 nT plus
    0.5 nT white noise, 70 % of samples quiet, three components each (600 intervals per
    case, binomial sd 0.9 %): the share of 95 % intervals holding the true offset, with
    their median half-width in brackets (nT; the last column is 1.96 times the actual
    RMS error, what an interval that knew the error's size would take):

    ===========================  ===============  ===============  =======
    miss                         1.96 se          t(dof) se        1.96 rms
    ===========================  ===============  ===============  =======
    tau 1 h                      93.2 % (0.35)    94.2 % (0.37)    0.35
    tau 6 h                      92.7 % (0.80)    94.3 % (0.85)    0.82
    tau 12 h                     92.5 % (1.15)    94.0 % (1.26)    1.15
    tau 2 days                   91.5 % (2.32)    95.5 % (3.37)    2.23
    tau 5 days                   87.3 % (3.11)    93.3 % (6.77)    3.28
    tau 6 h, a week missing      94.2 % (0.93)    95.3 % (1.01)    0.89
    tau 2 days, a week missing   90.2 % (2.34)    93.2 % (3.68)    2.32
    tau 6 h, 8 scattered days    93.7 % (1.42)    96.7 % (1.84)    1.36
    tau 2 days, 8 scattered      86.8 % (2.27)    92.3 % (3.18)    2.72
    ===========================  ===============  ===============  =======

    The rest of the shortfall is the lag correlation's own scatter over 8-28 batches,
    which ``n_eff`` does not count.

    Returns
    -------
    se : ndarray, shape (m,)
        NaN where :func:`batch_standard_error` gives NaN.
    dof : ndarray, shape (m,)
        NaN where ``se`` is.

    Examples
    --------
    Days alternating -1, +1 are anti-correlated (``r`` clipped to 0), so all 28 count:
    27 degrees of freedom. Ten days climbing 0, 1, ..., 9 (``r`` = 0.9, see
    :func:`batch_standard_error`) hold about half a day's worth: the floor, 2.

    >>> t = np.arange(28 * 24) * (DAY_NS // 24)
    >>> se, dof = batch_error_and_dof(t, np.repeat(np.tile([-1.0, 1.0], 14), 24))
    >>> float(dof[0])
    27.0
    >>> t = np.arange(10 * 24) * (DAY_NS // 24)
    >>> float(batch_error_and_dof(t, np.repeat(np.arange(10.0), 24))[1][0])
    2.0
    """
    t = np.asarray(t_ns, dtype=np.int64)
    x = np.asarray(x, dtype=float)
    x = x[:, None] if x.ndim == 1 else x
    nan = np.full(x.shape[1], np.nan)
    if t.size == 0:
        return nan, nan.copy()
    day = (t - t[0]) // int(batch_ns)
    edges = np.flatnonzero(np.diff(day)) + 1
    groups = np.split(np.arange(t.size), edges)
    sizes = np.array([g.size for g in groups])
    good = [g for g, s in zip(groups, sizes) if s >= min_fraction * sizes.max()]
    if len(good) < min_batches:
        return nan, nan.copy()
    b = np.array([np.median(x[g], axis=0) for g in good])
    nb = b.shape[0]
    sd = np.std(b, axis=0, ddof=1)
    c = b - b.mean(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        r1 = np.sum(c[1:] * c[:-1], axis=0) / np.sum(c ** 2, axis=0)
    r1 = np.nan_to_num(r1)
    r = np.clip(r1 + (1.0 + 3.0 * np.clip(r1, 0.0, None)) / nb, 0.0, 0.9)
    se = sd / np.sqrt(nb) * np.sqrt((1.0 + r) / (1.0 - r))
    dof = np.maximum(nb * (1.0 - r) / (1.0 + r) - 1.0, DOF_FLOOR)
    return se, np.where(np.isfinite(se), dof, np.nan)
