"""Residual diagnostics: data minus model versus local time per month (paper Fig. 19)."""

from __future__ import annotations

import numpy as np

from magcal.frames.localtime import local_time_hours  # noqa: F401 - re-exported


def residual_by_local_time(times, diff, lon_deg, selected=None, bin_hours: float = 1.0,
                           min_count: int = 10):
    """Mean of data minus model per month and local-time bin.

    Parameters
    ----------
    times : array_like of datetime64, shape (n,)
    diff : array_like, shape (n, m)
    lon_deg : float or array_like
    selected : array_like of bool, optional
        Samples to use (e.g. the quiet ones); default all finite.
    bin_hours : float
    min_count : int
        Bins with fewer samples are NaN.

    Returns
    -------
    months : list of str
        ``YYYY-MM`` per curve.
    lt_centres : ndarray, shape (b,)
    means : ndarray, shape (len(months), b, m)
    counts : ndarray of int, shape (len(months), b)
    """
    t = np.asarray(times).astype("datetime64[ns]")
    d = np.asarray(diff, dtype=float)
    d = d[:, None] if d.ndim == 1 else d
    ok = np.all(np.isfinite(d), axis=1)
    if selected is not None:
        ok &= np.asarray(selected, dtype=bool)
    nbin = int(round(24.0 / bin_hours))
    lt = local_time_hours(t, lon_deg)
    b = np.minimum((lt / bin_hours).astype(int), nbin - 1)
    month = t.astype("datetime64[M]")
    months = np.unique(month[ok])
    means = np.full((months.size, nbin, d.shape[1]), np.nan)
    counts = np.zeros((months.size, nbin), dtype=np.int64)
    for i, mth in enumerate(months):
        sel = ok & (month == mth)
        cnt = np.bincount(b[sel], minlength=nbin)
        for j in range(d.shape[1]):
            s = np.bincount(b[sel], weights=d[sel, j], minlength=nbin)
            with np.errstate(invalid="ignore", divide="ignore"):
                means[i, :, j] = np.where(cnt >= min_count, s / np.maximum(cnt, 1), np.nan)
        counts[i] = cnt
    centres = (np.arange(nbin) + 0.5) * bin_hours
    return [str(m) for m in months], centres, means, counts


def peak_to_peak(means) -> np.ndarray:
    """Peak-to-peak of each local-time curve per component, ignoring NaN bins."""
    m = np.asarray(means, dtype=float)
    return np.nanmax(m, axis=-2) - np.nanmin(m, axis=-2)
