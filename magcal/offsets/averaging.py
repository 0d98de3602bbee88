"""Averaging to the comparison cadence without bridging gaps.

The DC offsets are determined from data averaged to 1 min (SOSMAG paper §5.3). A bin
average uses only the samples inside that bin, and a bin counts only when enough of it
is covered: a bin cut by a data gap is dropped, never filled from its neighbours.
"""

from __future__ import annotations

import numpy as np

from magcal.errors import InputError


def average_to_cadence(times, values, cadence_s: float = 60.0, min_fraction: float = 0.5,
                       sample_spacing_s: float | None = None):
    """Average samples into bins of ``cadence_s``, dropping under-covered bins.

    Parameters
    ----------
    times : array_like of datetime64, shape (n,)
        Strictly increasing UTC sample times.
    values : array_like, shape (n,) or (n, m)
        Samples; NaN samples do not count.
    cadence_s : float
        Bin length in seconds; bins are aligned to multiples of ``cadence_s`` since
        1970-01-01 (whole minutes for 60 s).
    min_fraction : float
        A bin is kept if at least this fraction of its expected samples (``cadence_s /
        sample_spacing_s``) are finite in every column.
    sample_spacing_s : float, optional
        Nominal input spacing; default the median spacing of ``times``.

    Returns
    -------
    bin_times : ndarray of datetime64[ns], shape (k,)
        Bin centres (start + cadence/2) of the kept bins.
    means : ndarray, shape (k,) or (k, m)
    counts : ndarray of int, shape (k,)
        Finite samples averaged per bin.

    Notes
    -----
    Input already at the cadence or coarser (median spacing >= ``cadence_s``) is
    returned unchanged with counts of 1.

    Examples
    --------
    >>> import numpy as np
    >>> t = np.datetime64("2019-11-01T00:00", "ns") + np.arange(180) * np.timedelta64(1, "s")
    >>> v = np.arange(180.0)
    >>> v[70:100] = np.nan                      # half of minute 2 is missing
    >>> bt, m, c = average_to_cadence(t, v, 60, min_fraction=0.75)
    >>> [str(x)[11:19] for x in bt], m, c
    (['00:00:30', '00:02:30'], array([ 29.5, 149.5]), array([60, 60]))
    """
    t = np.asarray(times).astype("datetime64[ns]")
    v = np.asarray(values, dtype=float)
    one_d = v.ndim == 1
    v2 = v[:, None] if one_d else v
    if v2.shape[0] != t.size:
        raise InputError(f"{v2.shape[0]} values for {t.size} times")
    if t.size == 0:
        return t, v.copy(), np.zeros(0, dtype=np.int64)
    ns = t.astype(np.int64)
    if t.size > 1 and np.any(np.diff(ns) <= 0):
        raise InputError("times must be strictly increasing")
    step = int(round(cadence_s * 1e9))
    if step <= 0:
        raise InputError("cadence_s must be positive")
    spacing = (float(np.median(np.diff(ns))) if sample_spacing_s is None
               else sample_spacing_s * 1e9) if t.size > 1 else float(step)
    if spacing >= step * 0.999:
        counts = np.all(np.isfinite(v2), axis=1).astype(np.int64)
        return t.copy(), v.copy(), counts
    cell = ns // step
    finite = np.all(np.isfinite(v2), axis=1)
    cell_f, v_f = cell[finite], v2[finite]
    uniq, start, counts = np.unique(cell_f, return_index=True, return_counts=True)
    sums = np.add.reduceat(v_f, start, axis=0) if uniq.size else np.zeros((0, v2.shape[1]))
    expected = step / spacing
    keep = counts >= min_fraction * expected
    means = sums[keep] / counts[keep, None]
    centres = (uniq[keep] * step + step // 2).astype("datetime64[ns]")
    return centres, (means[:, 0] if one_d else means), counts[keep]
