"""Sliding-window statistics of data minus model (the core of the offset estimate).

Windows of ``window_days`` stepped by ``step_days`` (28 and 7 in the SOSMAG paper). Per
window and component: median (the offset), standard deviation, and the median absolute
deviation scaled to a standard deviation (scipy's ``scale="normal"``), over the selected
(quiet) samples in ``[start, end)``. The times are sorted once and every window is a pair of
``searchsorted`` bounds, so a year of 1-min data takes a fraction of a second.
"""

from __future__ import annotations

import math
from typing import NamedTuple

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


def split_windows(starts_ns, ends_ns, cuts_ns):
    """The window grid cut at ``cuts_ns`` (level changes): a window ``[start, end)`` holding
    a cut strictly inside becomes its pieces ``[start, cut)``, ``[cut, end)`` (at each cut
    inside it), so that no window mixes the levels either side of a cut.

    Rows come in centre order with their segment (the number of cuts at or before the
    row's start: 0 before the first cut, 1 after it, ...) and the index of the window
    they came from. Windows are all one length, so an uncut window's centre lies at
    least half a window from a cut while a piece's lies within half a window of one: no
    piece shares a centre with an uncut window. Pieces may share a centre with another
    piece (two cuts inside one window make the same middle piece of each window holding
    both); the longest is kept, as ``read_offsets_csv`` and ``offsets apply`` need
    strictly increasing centres.

    Parameters
    ----------
    starts_ns, ends_ns : array_like of int64, shape (k,)
        Window bounds (:func:`window_grid`).
    cuts_ns : array_like of int64
        Cut times, increasing.

    Returns
    -------
    starts, ends : ndarray of int64, shape (k2,)
    segment : ndarray of int64, shape (k2,)
    source : ndarray of int64, shape (k2,)
        Index of the window each row comes from.

    Examples
    --------
    Weekly 28-day windows, a cut on day 30: the three windows holding it (days 7-35,
    14-42, 21-49) are cut; the pieces before it end at day 30, those after start there.

    >>> s, e = window_grid(0, 45 * DAY_NS - 1, 28, 7)
    >>> s2, e2, seg, src = split_windows(s, e, [30 * DAY_NS])
    >>> [(int(a // DAY_NS), int(b // DAY_NS)) for a, b in zip(s2, e2)]
    [(0, 28), (7, 30), (14, 30), (21, 30), (30, 35), (30, 42), (30, 49)]
    >>> seg.tolist(), src.tolist()
    ([0, 0, 0, 0, 1, 1, 1], [0, 1, 2, 3, 1, 2, 3])
    """
    starts = np.asarray(starts_ns, dtype=np.int64)
    ends = np.asarray(ends_ns, dtype=np.int64)
    cuts = np.unique(np.asarray(cuts_ns, dtype=np.int64))
    rows = []
    for i, (a, b) in enumerate(zip(starts, ends)):
        inside = cuts[(cuts > a) & (cuts < b)]
        edges = np.concatenate([[a], inside, [b]])
        for lo, hi in zip(edges[:-1], edges[1:]):
            rows.append((int(lo), int(hi), i))
    centre = np.array([lo + (hi - lo) // 2 for lo, hi, _ in rows], dtype=np.int64)
    length = np.array([hi - lo for lo, hi, _ in rows], dtype=np.int64)
    order = np.lexsort((-length, centre))
    keep = [k for n, k in enumerate(order) if n == 0 or centre[k] != centre[order[n - 1]]]
    s2 = np.array([rows[k][0] for k in keep], dtype=np.int64)
    e2 = np.array([rows[k][1] for k in keep], dtype=np.int64)
    src = np.array([rows[k][2] for k in keep], dtype=np.int64)
    return s2, e2, np.searchsorted(cuts, s2, side="right").astype(np.int64), src


def window_statistics(t_ns, diff, selected, starts_ns, ends_ns, min_used: int = 720,
                      local_time_h=None, lt_bins: int = 24, min_per_bin: int = 5,
                      columns=None, pool_min_pairs: int | None = 10) -> dict:
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
    pool_min_pairs : int or None
        The windows' standard errors use the day-to-day correlation pooled over all
        windows (:func:`pooled_lag_correlation`) when the record holds at least this
        many pairs of consecutive days (and twice as many as any one window); None:
        each window's own, always.

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
    layouts = {}
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
        days, b = day_batches(t_use[lo[i]:hi[i]], x)
        layouts[i] = (days, b, int(t_use[lo[i]] // DAY_NS))
        reasons.append("")
    pooled = (None if pool_min_pairs is None else
              pooled_lag_correlation(list(layouts.values()), pool_min_pairs))
    for i, (days, b, _) in layouts.items():
        se[i], dof[i] = batch_se_dof(days, b, pooled=pooled)
        if pooled is not None:
            se[i], dof[i] = _unlike_the_record(days, b, pooled, se[i], dof[i])
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
    small-sample bias ``(1 + 3 r) / n_batches`` (Kendall 1954), within [0, 0.9]
    (:func:`window_statistics` takes the correlation pooled over the record instead when
    the record holds enough days, :func:`batch_error_and_dof`). A model
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
                        min_fraction: float = 0.1,
                        pooled=None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`batch_standard_error` and the degrees of freedom its interval needs.

    Alone (``pooled`` None), from the window's own lag correlation ``r``: ``n_batches``
    correlated batch values hold about ``n_eff = n_batches (1 - r) / (1 + r)``
    independent ones (the same AR(1) factor), and the standard error's own scatter is
    that of a variance estimated on ``n_eff - 1`` degrees of freedom (at least
    :data:`DOF_FLOOR`). Only consecutive calendar days are lag one
    (:func:`window_lag_correlation`); across gaps the AR(1) factor is scaled by the
    variance of the mean of the days present over that of as many consecutive days
    (:func:`ar1_moments`), since days further apart correlate less.

    With ``pooled`` (:func:`pooled_lag_correlation`, which :func:`window_statistics`
    passes when the record holds enough consecutive-day pairs): the day-to-day
    correlation is the model miss's, not one window's, and 28 days estimate it poorly
    (its scatter over 8-28 batches left the intervals of a 5-day miss at 2 degrees of
    freedom, twice as wide as needed). With the record's correlation the standard error
    is the one for these days: ``se^2 = s^2 var(mean) / E[s^2]`` (the sample variance of
    correlated days falls short of their variance), on the Satterthwaite degrees of
    freedom of ``s^2``, ``nu = 2 E[s^2]^2 / var(s^2)``, lowered by the pooled
    correlation's own scatter: ``1 / dof = 1 / nu + var(log se^2) / 2`` with that
    variance from Bartlett's covariance of the lag estimates over the record's days.

    The 95 % interval ``offset +- t(0.975, dof) se``
    (:func:`magcal.stats.student_interval`) is what OFFSETS.csv's ``*_dof`` columns
    serve. Measured through :class:`~magcal.offsets.OffsetEstimator` on records of 3-6
    months (10-23 windows each) of an AR(1) model miss of 3 nT plus 0.5 nT white noise,
    70 % of samples quiet, truth offset constant; "a week missing": one random week of
    each 28 days without data, "8 scattered days": only 8 random days of each 28. 60
    records per case (about 3000 intervals of overlapping windows, so the coverage's sd
    is about 1 %): the share of 95 % intervals holding the true offset, with their
    median half-width in brackets (nT; the last column is 1.96 times the actual RMS
    error, what an interval that knew the error's size would take):

    ===========================  ===============  ===============  =======
    miss                         1.96 se          t(dof) se        1.96 rms
    ===========================  ===============  ===============  =======
    tau 1 h                      95.1 % (0.35)    96.2 % (0.37)    0.33
    tau 6 h                      94.0 % (0.82)    95.6 % (0.88)    0.81
    tau 12 h                     92.8 % (1.11)    95.0 % (1.21)    1.16
    tau 2 days                   90.5 % (2.00)    94.6 % (2.51)    2.17
    tau 5 days                   88.1 % (3.00)    96.2 % (4.86)    3.38
    tau 6 h, a week missing      93.5 % (0.93)    95.5 % (1.03)    0.94
    tau 2 days, a week missing   91.4 % (2.32)    96.8 % (3.29)    2.49
    tau 6 h, 8 scattered days    93.1 % (1.31)    96.9 % (1.75)    1.34
    tau 2 days, 8 scattered      87.8 % (2.41)    96.9 % (4.68)    2.79
    ===========================  ===============  ===============  =======

    Scattered days hold few consecutive pairs, so the pooled correlation is least sure
    there and those intervals are the widest for their need (1.7 times 1.96 rms). A
    single 28-day window has nothing to pool and keeps its own correlation (94-95 % of
    600 intervals for 6-hour and 2-day misses, 93 % at 2.2 times 1.96 rms for a 5-day
    miss).

    Parameters
    ----------
    t_ns : array_like of int64, shape (n,)
    x : array_like, shape (n, m)
    pooled : DayCorrelation, optional
        The record's day correlation (:func:`pooled_lag_correlation`); None: the
        window's own.

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
    x = np.asarray(x, dtype=float)
    x = x[:, None] if x.ndim == 1 else x
    days, b = day_batches(t_ns, x, batch_ns, min_fraction)
    return batch_se_dof(days, b, min_batches, pooled=pooled)


def day_batches(t_ns, x, batch_ns: int = DAY_NS, min_fraction: float = 0.1):
    """Day batches of a window: each day's index (counted from the first sample's day)
    and median, for the days holding at least ``min_fraction`` of the fullest day's
    samples.

    Returns
    -------
    days : ndarray of int, shape (nb,)
    medians : ndarray, shape (nb, m)

    Examples
    --------
    >>> t = np.array([0, 1, 2, 3 * DAY_NS, 3 * DAY_NS + 1])
    >>> days, b = day_batches(t, np.array([1.0, 2.0, 3.0, 7.0, 8.0]), min_fraction=0.5)
    >>> days.tolist(), b[:, 0].tolist()
    ([0, 3], [2.0, 7.5])
    """
    return batches_with_counts(t_ns, x, batch_ns, min_fraction)[:2]


def batches_with_counts(t_ns, x, batch_ns: int = DAY_NS, min_fraction: float = 0.1,
                        origin_ns: int | None = None):
    """:func:`day_batches` with each kept batch's number of samples; batches counted
    from ``origin_ns`` (default: the first sample; 0 gives calendar days since 1970,
    as :mod:`magcal.offsets.levels` takes them).

    Returns
    -------
    days : ndarray of int, shape (nb,)
    medians : ndarray, shape (nb, m)
    counts : ndarray of float, shape (nb,)
    """
    x = np.asarray(x, dtype=float)
    x = x[:, None] if x.ndim == 1 else x
    days, good = _kept_batches(t_ns, batch_ns, min_fraction, origin_ns)
    return (days,
            np.array([np.median(x[g], axis=0) for g in good]).reshape(len(good), x.shape[1]),
            np.array([g.size for g in good], dtype=float))


def batch_days_counts(t_ns, batch_ns: int = DAY_NS, min_fraction: float = 0.1,
                      origin_ns: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The batches :func:`batches_with_counts` keeps and their numbers of samples,
    without their medians (for values taken otherwise, e.g.
    :func:`magcal.offsets.levels.hourly_day_values`).

    Examples
    --------
    >>> DAY = 86_400 * 10 ** 9
    >>> days, counts = batch_days_counts([0, 1, 2, DAY, 2 * DAY, 2 * DAY + 1], origin_ns=0)
    >>> days.tolist(), counts.tolist()
    ([0, 1, 2], [3.0, 1.0, 2.0])
    """
    days, good = _kept_batches(t_ns, batch_ns, min_fraction, origin_ns)
    return days, np.array([g.size for g in good], dtype=float)


def _kept_batches(t_ns, batch_ns, min_fraction, origin_ns):
    """Batch numbers and sample indices of the batches holding at least ``min_fraction``
    of the fullest one's samples (samples in time order)."""
    t = np.asarray(t_ns, dtype=np.int64)
    if t.size == 0:
        return np.zeros(0, dtype=np.int64), []
    day = (t - (t[0] if origin_ns is None else int(origin_ns))) // int(batch_ns)
    edges = np.flatnonzero(np.diff(day)) + 1
    groups = np.split(np.arange(t.size), edges)
    sizes = np.array([g.size for g in groups])
    good = [g for g, s in zip(groups, sizes) if s >= min_fraction * sizes.max()]
    return np.array([day[g[0]] for g in good], dtype=np.int64), good


def batch_se_dof(days, b, min_batches: int = 3,
                 pooled=None) -> tuple[np.ndarray, np.ndarray]:
    """Standard error and degrees of freedom of the mean of day batch values ``b``
    (n, m) on days ``days`` (:func:`batch_error_and_dof`, ``pooled`` as there).

    Examples
    --------
    Four days alternating +1, -1 (anti-correlated, ``r`` clipped to 0): ``sd / 2`` on
    3 degrees of freedom.

    >>> se, dof = batch_se_dof([0, 1, 2, 3], [[1.0], [-1.0], [1.0], [-1.0]])
    >>> se.round(3), dof
    (array([0.577]), array([3.]))
    """
    days = np.asarray(days, dtype=np.int64)
    b = np.asarray(b, dtype=float)
    nan = np.full(b.shape[1], np.nan)
    nb = b.shape[0]
    if nb < min_batches:
        return nan, nan.copy()
    sd = np.std(b, axis=0, ddof=1)
    if pooled is not None:
        se, dof = nan.copy(), nan.copy()
        for j in range(sd.size):
            # log(var(mean) / E[s2]) at the estimate and at each lag estimate moved
            moments = [ar1_moments(days, r, c1) for c1, r in zip(pooled.c1[:, j],
                                                                  pooled.r[:, j])]
            logf = np.log([mean_var / s2_mean for mean_var, s2_mean, _ in moments])
            grad = (logf[1:] - logf[0]) / pooled.step
            var_logf = float(grad @ pooled.cov[j] @ grad)
            se[j] = sd[j] * math.exp(0.5 * logf[0])
            dof[j] = max(1.0 / (1.0 / moments[0][2] + 0.5 * var_logf), DOF_FLOOR)
        return se, np.where(np.isfinite(se), dof, np.nan)
    r1 = window_lag_correlation(days, b)
    r = np.clip(r1 + (1.0 + 3.0 * np.clip(r1, 0.0, None)) / nb, 0.0, 0.9)
    factor = (1.0 + r) / (1.0 - r)
    if days[-1] - days[0] + 1 > nb:  # gaps: days apart by more than one correlate less
        factor = factor * np.array([ar1_moments(days, rj)[0] / ar1_moments(np.arange(nb), rj)[0]
                                    for rj in r])
    se = sd / np.sqrt(nb) * np.sqrt(factor)
    dof = np.maximum(nb / factor - 1.0, DOF_FLOOR)
    return se, np.where(np.isfinite(se), dof, np.nan)


#: A window whose own lag-one correlation exceeds the record's by more than this many of
#: its standard errors keeps its own standard error where that is larger
#: (:func:`_unlike_the_record`). 2 left windows straddling a 3 nT step at 80 %
#: coverage; 0 widened every interval (a 5-day miss's by 6 %, a drifting offset's by 50 %).
UNLIKE_Z = 1.0


def _unlike_the_record(days, b, pooled, se, dof) -> tuple[np.ndarray, np.ndarray]:
    """The window's own standard error and dof where its days follow each other far
    more than the record's do, and that error is the larger.

    The pooled correlation describes the model miss over the record; a window whose day
    values hold a level change (an offset step inside it) or a trend of its own has a
    lag-one correlation well above it, and there the window median departs from the
    window's truth by more than the pooled error says. On records of 3-6 months with a
    3 nT step under a 6-hour miss, the windows straddling the step held their truth in
    79 % of cases with the pooled error, 83 % with this test and 86 % with their own
    error alone (the pooled error's other windows: 95 %). The test: the
    window's lag-one correlation about its mean above the pooled ``c1`` by
    :data:`UNLIKE_Z` times ``sqrt((1 - c1^2) / pairs)`` (Bartlett)."""
    days = np.asarray(days, dtype=np.int64)
    b = np.asarray(b, dtype=float)
    pairs = int(np.sum(np.diff(days) == 1))
    if pairs < 2:
        return se, dof
    c1 = np.clip(pooled.c1[0], -0.99, 0.99)
    unlike = window_lag_correlation(days, b) > c1 + UNLIKE_Z * np.sqrt((1 - c1 ** 2) / pairs)
    if not unlike.any():
        return se, dof
    own_se, own_dof = batch_se_dof(days, b)
    use = unlike & (own_se > se)
    return np.where(use, own_se, se), np.where(use, own_dof, dof)


def window_lag_correlation(days, b) -> np.ndarray:
    """Lag-one correlation of one window's day batch values about their mean, over the
    pairs of consecutive calendar days only (days apart by a gap are not lag one), scaled
    by ``(n - 1) / pairs`` so that a window without gaps gives the plain ``sum(c_t
    c_t+1) / sum(c_t^2)``; 0 without a consecutive pair.

    Examples
    --------
    Days 0, 1, 2 then 10, 11, 12: the values climb within each stretch; the step from
    day 2 to day 10 is not a lag-one pair.

    >>> b = np.array([[0.0], [1.0], [2.0], [0.0], [1.0], [2.0]])
    >>> window_lag_correlation([0, 1, 2, 10, 11, 12], b).round(3)
    array([0.])
    """
    days = np.asarray(days, dtype=np.int64)
    b = np.asarray(b, dtype=float)
    c = b - b.mean(axis=0)
    lag1 = np.diff(days) == 1
    pairs = int(lag1.sum())
    if pairs == 0:
        return np.zeros(b.shape[1])
    with np.errstate(invalid="ignore", divide="ignore"):
        r1 = np.sum((c[1:] * c[:-1])[lag1], axis=0) / np.sum(c ** 2, axis=0)
    return np.nan_to_num(r1) * (days.size - 1) / pairs


def ar1_moments(days, r: float, c1: float | None = None) -> tuple[float, float, float]:
    """For unit-variance day values on ``days`` whose correlation at a lag of ``k >= 1``
    days is ``c1 r ** (k - 1)`` (AR(1) when ``c1`` is None, i.e. ``c1 = r``): the variance
    of their mean, the expected sample variance (ddof=1) and its degrees of freedom
    (``2 E[s2]^2 / var(s2)``, Satterthwaite).

    Examples
    --------
    Independent days: 1/n, 1 and n - 1.

    >>> ar1_moments(np.arange(10), 0.0)
    (0.1, 1.0, 9.0)
    """
    d = np.asarray(days, dtype=np.int64)
    n = d.size
    corr = np.eye(n) + (float(r) if c1 is None else float(c1)) * _lag_shape(d, r)
    a = np.eye(n) - 1.0 / n
    ar = a @ corr
    tr_ar = float(np.trace(ar))
    return (float(corr.sum()) / n ** 2, tr_ar / (n - 1),
            tr_ar ** 2 / float(np.sum(ar * ar.T)))


def _detrender(days) -> np.ndarray:
    """The matrix taking day values on ``days`` to their residuals from a straight line."""
    d = np.asarray(days, dtype=float)
    x = np.stack([np.ones(d.size), d - d.mean()], axis=1)
    return np.eye(d.size) - x @ np.linalg.pinv(x)


def _lag_shape(days, r: float) -> np.ndarray:
    """``r ** (|d_i - d_j| - 1)`` off the diagonal, 0 on it."""
    d = np.asarray(days, dtype=np.int64)
    lag = np.abs(d[:, None] - d[None, :])
    return np.where(lag > 0, float(r) ** np.maximum(lag - 1, 0).astype(float), 0.0)


#: Step of the pooled lag correlations over which the standard error's sensitivity to
#: them is taken (for its degrees of freedom).
_STEP = 0.01


class DayCorrelation(NamedTuple):
    """A record's pooled day-to-day correlation (:func:`pooled_lag_correlation`).

    Attributes
    ----------
    c1, r : ndarray, shape (3, m)
        The correlation is ``c1 r ** (k - 1)`` at a lag of ``k >= 1`` days; row 0 as
        estimated, rows 1 and 2 with the lag-one and the lag-two correlation estimate
        moved by ``step`` (the standard error's sensitivity to them).
    cov : ndarray, shape (m, 2, 2)
        Covariance of the lag-one and lag-two correlation estimates.
    step : float
    """

    c1: np.ndarray
    r: np.ndarray
    cov: np.ndarray
    step: float


def pooled_lag_correlation(layouts, min_pairs: int = 10):
    """Day-to-day correlation of a record's day batch values, pooled over its windows.

    The model miss's memory from one day to the next is a property of the instrument
    and the model, not of one window, and a 28-day window's own lag correlation (8-28
    day values) scatters so much that its intervals must be wide. Pooled over every
    window of a record of months it is known well enough to use in each window
    (:func:`batch_error_and_dof`).

    The correlation at a lag of ``k >= 1`` days is modelled as ``c1 r ** (k - 1)``: a
    day's value is a median over a day of a miss correlated over hours to days, whose
    first lag exceeds the decay from one lag to the next (a 2-day miss: 0.70 at one
    day, 0.40 at two, where AR(1) from the first lag would give 0.49 and intervals a
    quarter wider than needed). The decay ``r`` is capped at the AR(1) value of the
    first lag: without the cap a record whose lag-two estimate scattered high read as a
    slow component and the standard errors of a 1-hour miss scattered 2.2-fold.

    Each window's day values are taken about a straight line through them (a drifting
    offset does not read as correlation: centred on the mean, a 5 nT offset wander over
    180 days made the intervals of a 1-hour miss 2.4 times as wide as needed, 1.4 times
    about the line). The products of values one and two calendar days apart (days
    apart by a gap are never lag one) and the squares are summed over all windows;
    ``(c1, r)`` are the values whose expected ratios over the same day layouts, line
    fit and gaps included, equal the observed ones (method of moments). Their
    covariance is Bartlett's over the record's distinct days.

    Parameters
    ----------
    layouts : list of tuple
        ``(days, b, first_day)`` per window: :func:`day_batches` and the calendar day
        (days since the epoch) of ``days == 0``.
    min_pairs : int
        The record is pooled when it holds at least this many distinct pairs of
        consecutive days and at least twice as many as the fullest window (so the pooled
        correlation rests on twice the pairs any one window's would: a single 28-day
        window, or a 5-week record, keeps each window's own).

    Returns
    -------
    DayCorrelation or None
        None when the record is not pooled.

    Examples
    --------
    Twenty weeks of days whose values follow each other (each day half the last plus
    noise: lag-one correlation 0.5, these 140 days give 0.63): one window alone is not
    pooled, the record is.

    >>> rng = np.random.default_rng(0)
    >>> v = np.zeros(140)
    >>> for i in range(1, 140):
    ...     v[i] = 0.5 * v[i - 1] + rng.standard_normal()
    >>> days = np.arange(28)
    >>> print(pooled_lag_correlation([(days, v[:28, None], 0)]))
    None
    >>> pc = pooled_lag_correlation([(days, v[w:w + 28, None], w) for w in range(0, 113, 7)])
    >>> float(pc.c1[0, 0].round(2)), float(pc.r[0, 0].round(2))
    (0.63, 0.63)
    """
    pair_days, all_days = set(), set()
    most = 0
    num1 = num2 = den = 0.0
    mats, layout_count = {}, {}  # windows with the same days share their matrices
    for days, b, first_day in layouts:
        days = np.asarray(days, dtype=np.int64)
        if days.size < 3:
            continue
        a = _detrender(days)
        c = a @ b
        gap = np.abs(days[:, None] - days[None, :])
        lag1 = np.diff(days) == 1
        most = max(most, int(lag1.sum()))
        pair_days.update((first_day + days[:-1][lag1]).tolist())
        all_days.update((first_day + days).tolist())
        one, two = (gap == 1) / 2.0, (gap == 2) / 2.0
        num1 = num1 + np.einsum("ij,ik,jk->k", one, c, c)
        num2 = num2 + np.einsum("ij,ik,jk->k", two, c, c)
        den = den + np.sum(c ** 2, axis=0)
        key = tuple(days - days[0])
        if key in layout_count:
            layout_count[key] += 1
        else:
            layout_count[key] = 1
            mats[key] = (days, a, a @ one @ a, a @ two @ a)
    if len(pair_days) < max(min_pairs, 2 * most):
        return None
    with np.errstate(invalid="ignore", divide="ignore"):
        rho1, rho2 = np.nan_to_num(num1 / den), np.nan_to_num(num2 / den)
    cache = {}

    def moments(r):
        """Sums over windows of tr(m R) for R = I + c1 S(r), m = A, M1, M2: the constant
        and the c1 coefficient of each (the expected squares and lag products)."""
        if r not in cache:
            out = np.zeros((3, 2))
            for key, (days, a, m1, m2) in mats.items():
                shape = _lag_shape(days, r)
                for row, m in enumerate((a, m1, m2)):
                    out[row] += layout_count[key] * np.array((np.trace(m), np.sum(m * shape)))
            cache[r] = out
        return cache[r]

    def ratio_at(r, c1, row):
        (s0, s1), (q0, q1) = moments(r)[0], moments(r)[row]
        return (q0 + c1 * q1) / (s0 + c1 * s1)

    def c1_for(r, target):
        (s0, s1), (p0, p1) = moments(r)[0], moments(r)[1]
        return min(max((target * s0 - p0) / (p1 - target * s1), 0.0), 0.9)

    def bisect(f, lo, hi):
        """The root of an increasing ``f`` in [lo, hi] (an end when there is none)."""
        for _ in range(24):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if f(mid) < 0 else (lo, mid)
        return 0.5 * (lo + hi)

    def solve(rho1, rho2):
        r_ar1 = bisect(lambda r: ratio_at(r, r, 1) - rho1, 0.0, 0.9)
        r = bisect(lambda r: ratio_at(r, c1_for(r, rho1), 2) - rho2, 0.0, r_ar1)
        return c1_for(r, rho1), r

    m = rho1.size
    c1_out, r_out = np.empty((3, m)), np.empty((3, m))
    cov = np.empty((m, 2, 2))
    for j in range(m):
        for row, (d1, d2) in enumerate(((0.0, 0.0), (_STEP, 0.0), (0.0, _STEP))):
            c1_out[row, j], r_out[row, j] = solve(rho1[j] + d1, rho2[j] + d2)
        cov[j] = _bartlett_cov(c1_out[0, j], r_out[0, j], len(all_days))
    return DayCorrelation(c1_out, r_out, cov, _STEP)


def _bartlett_cov(c1: float, r: float, n_days: int, lags: int = 400) -> np.ndarray:
    """Bartlett's large-sample covariance of the lag-one and lag-two correlation
    estimates of ``n_days`` values correlated ``c1 r ** (k - 1)`` at lag ``k >= 1``."""
    k = np.arange(-lags, lags + 1)
    rho = np.where(k == 0, 1.0, c1 * float(r) ** np.maximum(np.abs(k) - 1, 0))

    def at(shift):
        return np.interp(k + shift, k, rho, left=0.0, right=0.0)

    out = np.empty((2, 2))
    for i in (1, 2):
        for j in (1, 2):
            w = (at(i) * at(j) + at(-i) * at(j) + 2 * rho[lags + i] * rho[lags + j] * rho ** 2
                 - 2 * rho[lags + i] * rho * at(j) - 2 * rho[lags + j] * rho * at(i))
            out[i - 1, j - 1] = w.sum() / n_days
    return out
