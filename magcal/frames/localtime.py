"""Local time and its harmonics: shared by offsets, alignment and discovery.

Local (mean solar) time at an east longitude is ``UT + lon / 15`` hours, modulo 24. A
field fixed in local time is written as a Fourier series in it
(:func:`harmonic_basis`).
"""

from __future__ import annotations

import numpy as np

DAY_S = 86400.0


def local_time_hours(times, lon_deg=None) -> np.ndarray:
    """Local (mean solar) time in hours, ``UT + lon / 15`` modulo 24.

    Parameters
    ----------
    times : array_like of datetime64, or float seconds since 00:00 UT of some day
    lon_deg : float or array_like, optional
        East longitude; without it the result is UT (hours).

    Examples
    --------
    >>> local_time_hours(np.array(["2019-11-01T03:00"], dtype="datetime64[ns]"), 128.2)
    array([11.54666667])
    """
    t = np.asarray(times)
    if np.issubdtype(t.dtype, np.datetime64):
        t = t.astype("datetime64[ns]")
        ut_h = (t - t.astype("datetime64[D]")).astype(np.int64) / 3.6e12
    else:
        ut_h = np.mod(np.asarray(t, dtype=float), DAY_S) / 3600.0
    lon = 0.0 if lon_deg is None else np.asarray(lon_deg, dtype=float)
    return np.mod(ut_h + lon / 15.0, 24.0)


def harmonic_basis(lt_h, n_harmonics: int) -> np.ndarray:
    """Columns ``cos(k phi), sin(k phi)``, ``k = 1..K``, ``phi = 2 pi LT / 24``.

    Returns
    -------
    ndarray, shape (n, 2K)

    Examples
    --------
    >>> harmonic_basis(np.array([0.0, 6.0]), 1).round(12) + 0.0
    array([[1., 0.],
           [0., 1.]])
    """
    phi = 2.0 * np.pi * np.asarray(lt_h, dtype=float) / 24.0
    cols = []
    for k in range(1, int(n_harmonics) + 1):
        cols += [np.cos(k * phi), np.sin(k * phi)]
    return np.stack(cols, axis=1) if cols else np.zeros((phi.size, 0))
