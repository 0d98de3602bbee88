"""Time helpers shared by the index and driver readers."""

from __future__ import annotations

import numpy as np
import pandas as pd


def to_utc_index(times) -> pd.DatetimeIndex:
    """Any array of times as a tz-aware UTC :class:`pandas.DatetimeIndex` in ns.

    Naive inputs (``datetime64``, naive timestamps, ISO strings without offset) are taken
    as UTC; aware inputs are converted to UTC.

    Examples
    --------
    >>> to_utc_index(["2019-11-02T03:00"])[0]
    Timestamp('2019-11-02 03:00:00+0000', tz='UTC')
    """
    if isinstance(times, (str, pd.Timestamp, np.datetime64)) or np.isscalar(times):
        times = [times]
    if not isinstance(times, pd.DatetimeIndex):
        values = np.asarray(times)
        if values.dtype.kind in "OUS":
            times = pd.to_datetime(pd.Series(values.ravel(), dtype=object), format="ISO8601")
        else:
            times = pd.to_datetime(values.ravel())
    index = pd.DatetimeIndex(times)
    if index.tz is None:
        index = index.tz_localize("UTC")
    else:
        index = index.tz_convert("UTC")
    return index.as_unit("ns")


def utc_ns(times) -> np.ndarray:
    """Nanoseconds since 1970-01-01 UTC (int64) for any array of times."""
    return to_utc_index(times).asi8
