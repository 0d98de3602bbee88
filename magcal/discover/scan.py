"""Scans that fix the non-linear hyper-parameters of ``step`` and ``periodic`` candidates.

Both work on the current residual (measured minus model minus effects so far):

* :func:`scan_step` - the split time that maximises the between-segment sum of squares
  (a multi-component CUSUM), away from the ends of the record;
* :func:`scan_periods` - peaks of the periodogram summed over components, ranked by
  their height over the local (red-noise) background, excluding the longest periods
  (a trend) and the diurnal harmonics (the ``diurnal`` term's job).
"""

from __future__ import annotations

import numpy as np

DAY_S = 86400.0


def n_period_trials(span_s: float, min_period_s: float = 3600.0,
                    min_cycles: float = 3.0) -> float:
    """Number of independent frequencies :func:`scan_periods` searches (look-elsewhere)."""
    return max(span_s / min_period_s - min_cycles, 1.0)


def n_step_trials(span_s: float, resolution_s: float = 3 * 3600.0) -> float:
    """Effective number of independent step times a scan tries (look-elsewhere)."""
    return max(span_s / resolution_s, 1.0)


def scan_step(times_s, residual, margin_s: float = 0.25 * DAY_S):
    """Best single step time in a residual.

    Parameters
    ----------
    times_s : array_like, shape (n,)
        Increasing sample times in seconds.
    residual : array_like, shape (n, m)
        Residual in nT; NaN entries are ignored.
    margin_s : float
        No step closer than this to either end.

    Returns
    -------
    t_step_s : float or None
        Time of the first sample after the step (None if the record is too short, e.g.
        a window that falls inside a gap of the data).
    size_nT : ndarray (m,)
        Mean after minus mean before, per component.
    statistic : float
        Between-segment sum of squares (nT^2) summed over components.

    Examples
    --------
    >>> t = np.arange(1000.0) * 60
    >>> r = np.where(t >= 30000, 2.0, 0.0)[:, None]
    >>> ts, size, _ = scan_step(t, r, margin_s=600)
    >>> ts, size.round(6)
    (30000.0, array([2.]))
    """
    t = np.asarray(times_s, dtype=float)
    r = np.asarray(residual, dtype=float)
    if r.ndim == 1:
        r = r[:, None]
    if t.size < 2:
        return None, np.zeros(r.shape[1]), 0.0
    between, n1, n2, s1, s2 = _split_sums(r)
    after = t[1:]
    allowed = (after - t[0] >= margin_s) & (t[-1] - after >= margin_s)
    if not allowed.any():
        return None, np.zeros(r.shape[1]), 0.0
    between = np.where(allowed, between, -1.0)
    k = int(np.argmax(between))
    with np.errstate(invalid="ignore", divide="ignore"):
        size = s2[k] / n2[k] - s1[k] / n1[k]
    return float(after[k]), np.nan_to_num(size), float(between[k])


def split_gain(residual) -> np.ndarray:
    """Between-segment sum of squares of every split of ``residual`` (n, m) into its
    first ``j`` samples and the rest, ``j = 1 .. n - 1``, summed over the columns (NaN
    entries ignored): what a step after sample ``j`` explains (nT^2, or in the columns'
    units).

    Examples
    --------
    >>> split_gain(np.array([[0.0], [0.0], [2.0], [2.0]])).round(6).tolist()
    [1.333333, 4.0, 1.333333]
    """
    r = np.asarray(residual, dtype=float)
    return _split_sums(r[:, None] if r.ndim == 1 else r)[0]


def _split_sums(r: np.ndarray):
    """``(gain, n1, n2, s1, s2)``: :func:`split_gain` and the counts and sums before
    and after every split, per column."""
    ok = np.isfinite(r)
    cn = np.cumsum(ok, axis=0).astype(float)
    cs = np.cumsum(np.where(ok, r, 0.0), axis=0)
    n1, s1 = cn[:-1], cs[:-1]
    n2, s2 = cn[-1] - n1, cs[-1] - s1
    with np.errstate(invalid="ignore", divide="ignore"):
        between = n1 * n2 / np.maximum(cn[-1], 1) * (s1 / n1 - s2 / n2) ** 2
    return np.where(np.isfinite(between), between, 0.0).sum(axis=1), n1, n2, s1, s2


def _uniform_grid(times_s, residual):
    t = np.asarray(times_s, dtype=float)
    dt = float(np.median(np.diff(t))) if t.size > 1 else 1.0
    idx = np.round((t - t[0]) / dt).astype(int)
    r = np.asarray(residual, dtype=float)
    if r.ndim == 1:
        r = r[:, None]
    grid = np.zeros((idx[-1] + 1, r.shape[1]))
    ok = np.isfinite(r)
    centred = np.where(ok, r - np.nanmean(np.where(ok, r, np.nan), axis=0), 0.0)
    grid[idx] = centred
    return grid, dt


def periodogram(times_s, residual, oversample: int = 4):
    """Amplitude periodogram of a residual on its median-cadence grid.

    Returns
    -------
    freq_hz : ndarray (k,)
    amplitude_nT : ndarray (k, m)
        Amplitude of a sinusoid that would produce each peak (NaN gaps count as zero).

    Examples
    --------
    >>> t = np.arange(0, 86400 * 4, 60.0)
    >>> f, a = periodogram(t, 3 * np.cos(2 * np.pi * t / 21600.0)[:, None])
    >>> round(float(1 / f[np.argmax(a[:, 0])]) / 3600, 3), round(float(a.max()), 2)
    (6.0, 3.0)
    """
    grid, dt = _uniform_grid(times_s, residual)
    n = grid.shape[0]
    nfft = int(oversample) * n
    spec = np.fft.rfft(grid, nfft, axis=0)
    freq = np.fft.rfftfreq(nfft, dt)
    amp = 2 * np.abs(spec) / n
    return freq[1:], amp[1:]


def scan_periods(times_s, residual, *, exclude_daily: bool = True, n_peaks: int = 3,
                 min_cycles: float = 3.0, min_period_s: float = 3600.0,
                 background_bins: int = 40):
    """Candidate periods: periodogram peaks that stand out of the local background.

    Parameters
    ----------
    times_s, residual
        As in :func:`scan_step`.
    exclude_daily : bool
        Skip the neighbourhood of 1..8 cycles per day (the diurnal term covers them).
    n_peaks : int
        How many candidates to return.
    min_cycles : float
        Longest period considered, as a fraction of the record: span / min_cycles.
    min_period_s : float
        Shortest period considered (faster signals are ULF waves or spin tones).
    background_bins : int
        Half-width (in oversampled bins) of the running median used as the background.

    Returns
    -------
    list of (period_s, ratio)
        Best first; ``ratio`` is the summed power over the local median power.
    """
    t = np.asarray(times_s, dtype=float)
    span = t[-1] - t[0]
    if span <= 0:
        return []
    freq, amp = periodogram(t, residual)
    power = (amp ** 2).sum(axis=1)
    ok = (freq >= min_cycles / span) & (freq <= 1.0 / min_period_s)
    if exclude_daily:
        for k in range(1, 9):
            ok &= np.abs(freq - k / DAY_S) > 2.0 / span
    # local background: median in a sliding window (log-spaced data are not needed here)
    from scipy.ndimage import median_filter

    background = median_filter(power, size=2 * background_bins + 1, mode="nearest")
    ratio = np.where(ok & (background > 0), power / np.where(background > 0, background, 1), 0)
    # local maxima only
    peak = np.zeros_like(ratio, dtype=bool)
    peak[1:-1] = (ratio[1:-1] >= ratio[:-2]) & (ratio[1:-1] >= ratio[2:]) & (ratio[1:-1] > 0)
    cand = np.flatnonzero(peak)
    cand = cand[np.argsort(ratio[cand])[::-1]]
    out = []
    resolution = 1.0 / span
    for k in cand:
        f = freq[k]
        if any(abs(f - 1.0 / p) < 2 * resolution for p, _ in out):
            continue
        out.append((float(1.0 / f), float(ratio[k])))
        if len(out) >= n_peaks:
            break
    return out


def joint_step_time(times_s, residual, *, bin_s: float = 3600.0,
                    margin_s: float = 0.25 * DAY_S) -> float | None:
    """Time of one step shared by every column of ``residual``: the split that explains
    the most of the columns' variance together, each weighted by its long-run noise
    variance.

    Each component's own change point (:func:`change_points`) places a step that several
    components share only as well as that component's signal allows; in red noise a
    2 nT step alone is placed up to days off. Scanned together, the components' signals
    add up. As in :func:`change_points`, the split is found on the ``bin_s`` means of
    the bins that hold data (joined across gaps: a step across a gap sits at its end)
    and then refined to the sample within two bins (:func:`scan_step`).

    Returns
    -------
    float or None
        Time of the first sample after the step (s); None if the record is too short.

    Examples
    --------
    >>> rng = np.random.default_rng(1)
    >>> t = np.arange(0, 10 * 86400, 60.0)
    >>> r = np.outer(t >= 4.2 * 86400, [1.5, -1.5]) + rng.normal(0, 1, (t.size, 2))
    >>> round(joint_step_time(t, r) / 86400, 2)
    4.2
    >>> gap = (t < 4 * 86400) | (t >= 5 * 86400)          # the step inside a day's gap
    >>> round(joint_step_time(t[gap], r[gap]) / 86400, 2)  # at the gap's end
    5.0
    """
    t, r, starts, means, margin = _binned(times_s, residual, bin_s, margin_s)
    ok = np.all(np.isfinite(means), axis=1)
    bins = np.flatnonzero(ok)
    if bins.size < 2 * margin + 2:
        return None
    weight = np.array([1.0 / np.sqrt(_long_run_variance(means[ok, c], _day_lags(bin_s)))
                       for c in range(r.shape[1])])
    after, _, _ = scan_step(np.arange(bins.size, dtype=float), means[ok] * weight,
                            margin_s=margin)
    if after is None:
        return None
    return _step_sample(t, r * weight, starts, ok, int(bins[int(after)]), bin_s)


def _day_lags(bin_s: float) -> int:
    """Lags of a day (at least 3) in bins of ``bin_s``: the long-run variance's window."""
    return max(int(DAY_S / bin_s), 3)


def _binned(times_s, residual, bin_s: float, margin_s: float):
    """``(t, r, bin starts, (k, m) bin means, margin in bins)`` of a residual, for the
    change-point scans."""
    t = np.asarray(times_s, dtype=float)
    r = np.asarray(residual, dtype=float)
    if r.ndim == 1:
        r = r[:, None]
    starts, means = _hourly_bins(t, r, bin_s)
    return t, r, starts, means, max(int(np.ceil(margin_s / bin_s)), 2)


def _step_sample(t, r, starts, ok, k: int, bin_s: float) -> float:
    """Time of the first sample after a step placed before bin ``k`` (of the bins
    ``ok`` that hold data): at the end of a gap the change is across, else refined to
    the sample within two bins (:func:`scan_step` of the columns of ``r``)."""
    if not ok[k - 1]:  # the change is across a gap: at its end
        return float(t[np.searchsorted(t, starts[k])])
    lo, hi = max(k - 2, 1), min(k + 2, len(ok) - 1)
    sel = (t >= starts[lo - 1]) & (t < starts[hi] + bin_s)
    ts, _, _ = scan_step(t[sel], r[sel], margin_s=bin_s)
    return float(ts) if ts is not None else float(starts[k])


def _hourly_bins(times_s, residual, bin_s: float):
    """Means of each component over bins of ``bin_s``: (bin start times, (k, m) means)."""
    t = np.asarray(times_s, dtype=float)
    r = np.asarray(residual, dtype=float)
    if r.ndim == 1:
        r = r[:, None]
    idx = np.floor((t - t[0]) / bin_s).astype(int)
    nb = int(idx[-1]) + 1
    ok = np.isfinite(r)
    means = np.full((nb, r.shape[1]), np.nan)
    for c in range(r.shape[1]):
        cnt = np.bincount(idx[ok[:, c]], minlength=nb)
        tot = np.bincount(idx[ok[:, c]], weights=r[ok[:, c], c], minlength=nb)
        with np.errstate(invalid="ignore", divide="ignore"):
            means[:, c] = np.where(cnt > 0, tot / np.maximum(cnt, 1), np.nan)
    return t[0] + np.arange(nb) * bin_s, means


def _long_run_variance(x: np.ndarray, smooth_bins: int) -> float:
    """Variance of a binned series about its running median, times its integrated
    autocorrelation time (the variance that matters for the mean of a segment)."""
    from scipy.ndimage import median_filter

    from magcal.discover.selection import integrated_autocorr_time

    from scipy.stats import median_abs_deviation

    detail = x - median_filter(x, size=smooth_bins, mode="nearest")
    var = float(max(median_abs_deviation(detail, scale="normal"), 1e-12) ** 2)
    return var * integrated_autocorr_time(detail)


def change_points(times_s, residual, *, kind: str = "step", bin_s: float = 3600.0,
                  penalty: float = 3.0, max_points: int = 3,
                  margin_s: float = 0.25 * DAY_S) -> list[tuple[float, int, float]]:
    """Change points of every component of a residual, found with ``ruptures``.

    The residual is averaged over ``bin_s`` bins and each component is segmented by
    binary segmentation: ``kind="step"`` with the ``l2`` cost (changes of level),
    ``kind="slope"`` with the continuous piecewise-linear cost (changes of drift rate).
    The penalty per change point is ``penalty * s2 * log(k)`` with ``k`` bins and ``s2``
    the long-run variance of the binned noise (MAD about a one-day running median times
    its integrated autocorrelation time), so red noise does not pass for a change.
    The candidates found here are then tested by the discovery's own criterion.

    Returns
    -------
    list of (t_s, component, strength)
        Change times (seconds, start of the first bin after the change; for steps refined
        to the sample), the component index and the variance of the binned series the
        change explains over the whole record, in units of the long-run noise variance
        (to rank them): the ``max_points`` strongest per component, in time order.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> t = np.arange(0, 20 * 86400, 60.0)
    >>> r = np.column_stack([rng.normal(0, 1, t.size), np.where(t >= 7.5 * 86400, 2.0, 0.0)
    ...                      + rng.normal(0, 1, t.size)])
    >>> [(round(ts / 86400, 2), c) for ts, c, _ in change_points(t, r)]
    [(7.5, 1)]
    """
    import ruptures as rpt

    from magcal.discover.costs import CumsumCLinear, CumsumL2

    t, r, starts, means, margin = _binned(times_s, residual, bin_s, margin_s)
    nb = means.shape[0]
    if nb < 2 * margin + 2:
        return []
    out = []
    for c in range(r.shape[1]):
        x = means[:, c]
        ok = np.isfinite(x)
        if ok.sum() < 2 * margin + 2:
            continue
        if kind == "step":
            # steps on the bins that hold data, joined across gaps: interpolating a
            # step across a gap of days makes a ramp that Binseg cuts into several
            # steps; joined, the step sits at the gap's end
            bins = np.flatnonzero(ok)
            x = x[ok]
        else:  # a drift's hinge needs true time: bridge gaps linearly
            bins = np.arange(nb)
            x = np.interp(bins, np.flatnonzero(ok), x[ok])
        s2 = _long_run_variance(x, _day_lags(bin_s))
        cost = CumsumL2() if kind == "step" else CumsumCLinear()
        algo = rpt.Binseg(custom_cost=cost, min_size=margin, jump=1 if kind == "step" else 2)
        found = algo.fit(x[:, None]).predict(pen=penalty * s2 * np.log(x.size))[:-1]
        found_c = []
        for k in found:
            if kind == "step":
                h = (np.arange(x.size) >= k).astype(float)
                t_c = _step_sample(t, r[:, c:c + 1], starts, ok, int(bins[k]), bin_s)
            else:
                t_c, j = _refine_hinge(starts, x, k, margin)
                h = np.maximum(np.arange(nb) - j, 0.0)
            h = h - h.mean()
            strength = float(h @ (x - x.mean())) ** 2 / float(h @ h) / s2
            found_c.append((t_c, c, strength))
        found_c.sort(key=lambda p: -p[2])
        out += sorted(found_c[:max_points])
    return out


def _refine_hinge(starts, x, k: int, margin: int, half_width: int = 24):
    """Break (time, bin) near bin ``k`` whose hinge ``max(t - t_b, 0)`` best fits the
    binned series ``x`` with a free level (the segmentation places it only roughly)."""
    nb = x.size
    xc = x - x.mean()
    best, t_best, j_best = -1.0, float(starts[k]), k
    for j in range(max(k - half_width, margin), min(k + half_width, nb - margin) + 1):
        h = np.maximum(np.arange(nb) - j, 0.0)
        h -= h.mean()
        hh = float(h @ h)
        if hh <= 0:
            continue
        explained = float(h @ xc) ** 2 / hh
        if explained > best:
            best, t_best, j_best = explained, float(starts[j]), j
    return t_best, j_best
