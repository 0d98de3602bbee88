"""How well the data place a named step in time: a confidence interval for its time.

The interval inverts the likelihood ratio of the step's time (Hansen 2000): every split
whose fit of the data falls short of the best split's by less than a critical value is
kept. The data are the step's components of the final residual with the fitted step
added back, averaged over hourly bins (joined across gaps, as the step scans see them)
and scaled by each component's long-run noise variance, so that the loss of fit is a
likelihood ratio whatever the noise's colour. Under a step small against the noise, the
ratio at the true time tends to ``max_s (2 W(s) - |s|)`` for a two-sided Brownian motion
``W``, whose distribution function is ``(1 - exp(-x / 2))^2``: 7.35 at 95 %.

Why this and not a bootstrap of the residual shifted around the step: the noise near
the true step is what misplaces it, and a shifted copy puts other noise there, so the
shifted replicates scatter less than the named time does (it covered too rarely on
simulated months, see the CHANGELOG); the likelihood-ratio set keeps a second split the
data nearly favour, wherever it is. The long-run variance is taken over every time
scale: detrended over a day (as the change-point penalty is), it missed the slow wander
that moves a step by a day or more.
"""

from __future__ import annotations

import math

import numpy as np

from magcal.discover.scan import DAY_S, _binned, _hourly_bins, split_gain
from magcal.discover.selection import integrated_autocorr_time


def lr_critical_value(level: float = 0.95) -> float:
    """Critical value of the step time's likelihood ratio at confidence ``level``:
    the ``level`` quantile of ``max_s (2 W(s) - |s|)``, ``-2 log(1 - sqrt(level))``.

    Examples
    --------
    >>> round(lr_critical_value(0.95), 2)
    7.35
    """
    if not 0.0 < level < 1.0:
        raise ValueError(f"level must be in (0, 1), got {level}")
    return -2.0 * math.log(1.0 - math.sqrt(level))


def step_time_interval(times_s, residual, t_step_s: float, size_nT, *, level: float = 0.95,
                       bin_s: float = 3600.0,
                       margin_s: float = 0.25 * DAY_S) -> tuple[float, float] | None:
    """Confidence interval of a step's time from the residual left after fitting it.

    Parameters
    ----------
    times_s : array_like, shape (n,)
        Increasing sample times (s).
    residual : array_like, shape (n, m)
        The final residual (nT) in the step's ``m`` components, NaN where missing: the
        noise once every named effect, the step included, is taken out.
    t_step_s : float
        The named step time (first sample after the step, s).
    size_nT : array_like, shape (m,)
        The fitted step size per component (nT).
    level : float
        Confidence level.
    bin_s : float
        Bin width (s); the interval is resolved to a bin on each side.
    margin_s : float
        No split closer than this to either end (as the step scans).

    Returns
    -------
    (lo_s, hi_s) or None
        The step happened after ``lo_s`` and at or before ``hi_s`` (s): from the start of
        the bin before the earliest split kept (a change inside a bin moves its mean only
        in part; across a gap, the last bin before it) to the end of the first bin after
        the latest split kept. Always holds ``t_step_s`` (``lo_s < t_step_s <= hi_s``).
        None when the record is too short to place a step.

    Examples
    --------
    A 2 nT step in two components over white noise of 1 nT: placed to within hours.

    >>> rng = np.random.default_rng(3)
    >>> t = np.arange(0, 20 * 86400, 60.0)
    >>> noise = rng.normal(0, 1, (t.size, 2))
    >>> lo, hi = step_time_interval(t, noise, 8.5 * 86400, [2.0, -2.0])
    >>> lo <= 8.5 * 86400 <= hi, (hi - lo) / 3600 <= 4
    (True, True)
    """
    crit = lr_critical_value(level)
    t, r, starts, means, margin = _binned(times_s, residual, bin_s, margin_s)
    size = np.asarray(size_nT, dtype=float).reshape(-1)
    if size.size != r.shape[1]:
        raise ValueError(f"size_nT has {size.size} values for {r.shape[1]} components")
    ok = np.all(np.isfinite(means), axis=1)
    bins = np.flatnonzero(ok)
    n = bins.size
    if n < 2 * margin + 2:
        return None
    # the step's mean in each bin: its share of the bin's samples (those with every
    # component) at or after the step
    valid = np.all(np.isfinite(r), axis=1)
    share = _hourly_bins(t, np.where(valid, t >= t_step_s, np.nan), bin_s)[1][bins, 0]
    noise = means[bins]
    # long-run variance of the binned noise over every time scale (no detrending: the
    # slow wander of red model error is what misplaces a step by days)
    lrv = np.array([max(float(np.var(noise[:, c])), 1e-24)
                    * integrated_autocorr_time(noise[:, c]) for c in range(r.shape[1])])
    # between-segment sum of squares of every split (j bins before it), in units of the
    # long-run variance: the gain in log-likelihood (x2) of a step there
    gain = split_gain((noise + np.outer(share, size)) / np.sqrt(lrv))
    split = np.arange(1, n)
    allowed = (split >= margin) & (n - 1 - split >= margin)
    gain = np.where(allowed, gain, -np.inf)
    kept = split[gain >= gain.max() - crit]
    lo = float(starts[bins[kept.min() - 1]])
    hi = float(starts[bins[kept.max()]] + bin_s)
    # the named time itself: the step happened after the bin before it
    return min(lo, float(t_step_s) - bin_s), max(hi, float(t_step_s))
