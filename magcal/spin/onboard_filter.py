"""The Galileo on-board recursive filter (Kivelson et al. 1992, Eqs. 1-3) and its inverse.

    V_out[j] = (1 - A) V_out[j-1] + A V_in[j]                       (1)
    T(f) = pi W / ((1 + pi W) - exp(-i pi f / f_n))                 (2)
    A = pi W / (1 + pi W),  W = f_c / f_n,  f_n = 1 / (2 dt)        (3)

With A = 1/4 at 30 samples/s the corner is f_c = 1.59 Hz.
"""

from __future__ import annotations

import numpy as np
from scipy.signal import lfilter


def recursive_filter(x, a: float, initial=None) -> np.ndarray:
    """Apply Eq. 1 along the first axis.

    Parameters
    ----------
    x : array_like, shape (n, ...)
        Input samples ``V_in``.
    a : float
        Filter constant ``A`` (0 < A <= 1).
    initial : array_like, optional
        ``V_out[-1]``, the output before the first sample (default: the first input,
        i.e. the filter starts settled).

    Examples
    --------
    >>> recursive_filter([4.0, 0.0, 0.0], 0.25).tolist()
    [4.0, 3.0, 2.25]
    """
    x = np.asarray(x, dtype=float)
    if not 0 < a <= 1:
        raise ValueError("filter constant A must be in (0, 1]")
    prev = x[0] if initial is None else np.asarray(initial, dtype=float)
    zi = np.asarray((1 - a) * prev, dtype=float)[None, ...]
    y, _ = lfilter([a], [1.0, -(1.0 - a)], x, axis=0, zi=zi)
    return y


def inverse_recursive_filter(y, a: float, initial=None) -> np.ndarray:
    """Recover ``V_in`` from ``V_out`` (the paper's snapshot processing).

    ``V_in[j] = (V_out[j] - (1 - A) V_out[j-1]) / A`` with ``V_out[-1] = initial``
    (default: ``y[0]``, matching :func:`recursive_filter`'s default).

    Examples
    --------
    >>> import numpy as np
    >>> x = np.array([1.0, 5.0, -2.0, 3.0])
    >>> inverse_recursive_filter(recursive_filter(x, 0.25), 0.25).round(12).tolist()
    [1.0, 5.0, -2.0, 3.0]
    """
    y = np.asarray(y, dtype=float)
    prev = np.empty_like(y)
    prev[1:] = y[:-1]
    if initial is None:
        # recursive_filter's default start: V_out[-1] = V_in[0], so y[0] = V_in[0]
        prev[0] = y[0]
    else:
        prev[0] = initial
    return (y - (1.0 - a) * prev) / a


def filter_constant(corner_hz: float, sample_rate_hz: float) -> float:
    """``A`` for a corner frequency (Eq. 3).

    Examples
    --------
    >>> round(filter_constant(corner_frequency(0.25, 30.0), 30.0), 12)
    0.25
    """
    w = corner_hz / (sample_rate_hz / 2.0)
    return np.pi * w / (1.0 + np.pi * w)


def corner_frequency(a: float, sample_rate_hz: float) -> float:
    """Corner frequency ``f_c`` of filter constant ``A`` (Eq. 3 solved for W).

    Examples
    --------
    >>> round(corner_frequency(0.25, 30.0), 3)
    1.592
    """
    w = a / (1.0 - a) / np.pi
    return w * sample_rate_hz / 2.0


def transfer_function(f_hz, a: float, sample_rate_hz: float) -> np.ndarray:
    """Complex response ``T(f)`` of Eq. 2.

    Examples
    --------
    >>> import numpy as np
    >>> round(float(abs(transfer_function(0.0, 0.25, 30.0))), 12)
    1.0
    """
    f = np.asarray(f_hz, dtype=float)
    fn = sample_rate_hz / 2.0
    piw = a / (1.0 - a)
    return piw / ((1.0 + piw) - np.exp(-1j * np.pi * f / fn))
