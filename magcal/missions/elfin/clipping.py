"""Counts held at the end of the sensor's range (saturation): find them per zone.

A fluxgate whose field exceeds its range returns its full-scale value: on a spinning
sensor the tops of the spin sine are cut flat, and every cut sample reads the *same*
number. A sampled sine with ELFIN's noise (about 500 counts) never repeats its extreme
exactly, so a zone extreme that several samples share is a clipped one. Left in, a
clipped zone fits like no other: on 2022-01-12 zone 4 with one axis cut at 90 % of its
peak (29 % of the samples) the delivered scalar residual goes 6.2 -> 680 nT; the spin
model of :func:`~magcal.missions.elfin.timing.check_timing` absorbs the flat tops as
harmonics and does not flag them.

Pure NumPy; counts in any unit.
"""

from __future__ import annotations

import numpy as np


def clipped_samples(counts, *, min_count: int = 3, limit: float | None = None) -> np.ndarray:
    """Samples (n,) where any axis reads its clipped extreme.

    Parameters
    ----------
    counts : array_like (n, k)
        Raw readings of one zone (NaN for fill: never flagged here).
    min_count : int
        An axis's maximum (or minimum) over the samples given is a clipped value when at
        least this many samples read exactly it (one real peak is one sample).
    limit : float, optional
        The instrument's full scale, if known: ``|counts| >= limit`` is clipped too.

    Returns
    -------
    ndarray of bool

    Examples
    --------
    >>> t = np.arange(0.0, 30.0, 0.1)
    >>> c = np.column_stack([np.cos(2.2 * t), np.sin(2.2 * t)]) * 1e6 + 0.3 * t[:, None]
    >>> bool(clipped_samples(c).any())
    False
    >>> c[:, 0] = np.minimum(c[:, 0], 0.9e6)          # the tops of one axis cut flat
    >>> int(clipped_samples(c).sum())
    44
    """
    c = np.asarray(counts, dtype=float)
    c = c.reshape(len(c), -1)
    out = np.zeros(len(c), bool)
    if limit is not None:
        with np.errstate(invalid="ignore"):
            out |= np.any(np.abs(c) >= limit, axis=1)
    for col in c.T:
        finite = np.isfinite(col)
        if not finite.any():
            continue
        for extreme in (col[finite].max(), col[finite].min()):
            at = col == extreme
            if at.sum() >= min_count:
                out |= at
    return out
