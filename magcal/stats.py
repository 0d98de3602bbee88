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
