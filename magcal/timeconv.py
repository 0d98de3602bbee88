"""UTC time conversions used across magcal: one place, one convention.

Naive inputs (``datetime64``, naive timestamps, ISO strings without an offset) are taken
as UTC; aware inputs are converted to UTC. Everything is nanosecond resolution (pandas 3
may otherwise pick microseconds).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from magcal.errors import InputError


def utc_index(times, *, name: str | None = None, allow_nat: bool = True) -> pd.DatetimeIndex:
    """Any time or array of times as a tz-aware UTC :class:`pandas.DatetimeIndex` in ns.

    Parameters
    ----------
    times : scalar or array_like
        ``datetime64``, datetimes, pandas timestamps/index/Series or ISO-8601 strings.
    name : str, optional
        Name of the returned index.
    allow_nat : bool
        False raises :class:`~magcal.errors.InputError` on a missing time.

    Examples
    --------
    >>> idx = utc_index(["2019-11-02T03:00", "2019-11-02T04:00+01:00"])
    >>> [str(t) for t in idx], str(idx.dtype)
    (['2019-11-02 03:00:00+00:00', '2019-11-02 03:00:00+00:00'], 'datetime64[ns, UTC]')
    """
    if isinstance(times, pd.Series):
        times = (pd.DatetimeIndex(times) if isinstance(times.dtype, pd.DatetimeTZDtype)
                 else times.to_numpy())
    if isinstance(times, (str, pd.Timestamp, np.datetime64)) or np.isscalar(times):
        times = [times]
    try:
        if isinstance(times, pd.DatetimeIndex):
            index = times
        else:
            values = np.asarray(times)
            if values.dtype.kind in "OUS":
                index = pd.DatetimeIndex(pd.to_datetime(
                    pd.Series(values.ravel(), dtype=object), format="ISO8601", utc=True))
            else:
                index = pd.DatetimeIndex(pd.to_datetime(values.ravel()))
    except (ValueError, TypeError) as exc:
        raise InputError(f"times are not dates: {exc}") from None
    index = index.tz_localize("UTC") if index.tz is None else index.tz_convert("UTC")
    index = index.as_unit("ns")
    if not allow_nat and index.hasnans:
        raise InputError("times contain NaT (missing time)")
    return index.rename(name) if name is not None else index


def as_datetime64(times) -> np.ndarray:
    """Times as a 1-D naive-UTC ``datetime64[ns]`` array (no copy when already one).

    Examples
    --------
    >>> as_datetime64(["2019-11-01T01:00:30+01:00"])
    array(['2019-11-01T00:00:30.000000000'], dtype='datetime64[ns]')
    """
    arr = times if isinstance(times, np.ndarray) else None
    if arr is not None and arr.dtype.kind == "M":
        return np.atleast_1d(arr).astype("datetime64[ns]", copy=False)
    return utc_index(times).tz_localize(None).to_numpy()


def utc_ns(times) -> np.ndarray:
    """Nanoseconds since 1970-01-01 UTC (int64).

    Examples
    --------
    >>> int(utc_ns("1970-01-01T00:00:01")[0])
    1000000000
    """
    return utc_index(times).asi8


def epoch_seconds(times) -> np.ndarray:
    """Seconds since 1970-01-01 UTC as float64.

    Examples
    --------
    >>> float(epoch_seconds(["1970-01-01T00:01:00.5"])[0])
    60.5
    """
    return utc_ns(times) / 1e9
