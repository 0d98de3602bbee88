"""Small statistics shared by every stage."""

from __future__ import annotations

import numpy as np


def finite_rms(values) -> float:
    """Root mean square over all finite entries (NaN when there is none).

    Examples
    --------
    >>> finite_rms(np.array([[3.0, 4.0], [np.nan, 0.0]]))
    2.886751345948129
    """
    x = np.asarray(values, dtype=float)
    x = x[np.isfinite(x)]
    return float(np.sqrt(np.mean(x ** 2))) if x.size else float("nan")


#: A normal distribution's standard deviation over its median absolute deviation,
#: ``1 / Phi^-1(3/4)`` (scipy's ``median_abs_deviation(scale="normal")``).
MAD_TO_SIGMA = 1.482602218505602


def normal_mad(values, axis=0) -> np.ndarray:
    """Median absolute deviation scaled to a normal standard deviation, along ``axis``.

    The same numbers as ``scipy.stats.median_abs_deviation(values, axis=axis,
    scale="normal")``; written here because importing ``scipy.stats`` costs the
    chain's driver about half a second, for this one function.

    Examples
    --------
    >>> float(normal_mad(np.array([1.0, 2.0, 3.0, 4.0, 100.0])))
    1.482602218505602
    """
    x = np.asarray(values, dtype=float)
    med = np.median(x, axis=axis, keepdims=True)
    return np.median(np.abs(x - med), axis=axis) * MAD_TO_SIGMA


def student_interval(value, std, dof, level: float = 0.95):
    """Two-sided ``level`` interval ``value -/+ t(dof) * std``, elementwise.

    For a standard error estimated with ``dof`` degrees of freedom (a block jackknife
    over few effective blocks): the normal quantile would cover less often than
    stated. ``dof`` is capped at 1e7 (the normal limit).

    Returns
    -------
    lo, hi : ndarray

    Examples
    --------
    >>> lo, hi = student_interval([1.0], [0.5], [4.0])
    >>> round(float(hi[0] - 1.0), 4)  # t_0.975(4) = 2.7764
    1.3882
    """
    from scipy.stats import t as student_t  # not at import: it costs the driver 0.5 s

    value = np.asarray(value, dtype=float)
    std = np.asarray(std, dtype=float)
    q = student_t.ppf(0.5 + level / 2.0, np.minimum(np.asarray(dof, dtype=float), 1e7))
    return value - q * std, value + q * std


#: Standard normal 0.975 quantile.
NORMAL_975 = 1.959963984540054


def student_scale(dof) -> float:
    """``t_0.975(dof) / z_0.975``: the factor that makes ``1.96 std`` Student's 95 %
    interval for a std estimated on ``dof`` degrees of freedom, so that a stated std
    read with the normal quantile (reports, downstream propagation) covers as claimed.

    Examples
    --------
    >>> round(student_scale(20), 4)  # t_0.975(20) = 2.0860
    1.0643
    """
    _, hi = student_interval(0.0, 1.0, dof)
    return float(hi) / NORMAL_975
