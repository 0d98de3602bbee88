"""ELFIN level-1 CDF files: fluxgate survey counts and the state (orbit, attitude, Sun).

Read through the generic CDF reader :func:`magcal.io.cdf.read_cdf`. Credit: ELFIN SOC
(PI V. Angelopoulos, UCLA), "Open Data for Scientific Use".
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np
import pandas as pd

from magcal.errors import InputError
from magcal.io.cdf import read_cdf
from magcal.timeconv import utc_index


def read_elfin_fgs(path: str | os.PathLike) -> pd.DataFrame:
    """ELFIN level-1 fluxgate survey data (``ela_l1_fgs_*.cdf``/``elb_...``).

    The values are raw sensor-frame readings in **counts**, not nT (the file's
    ``UNITS`` attribute says nT, but scale factors and offsets come from calibration,
    e.g. against IGRF in low Earth orbit).

    Parameters
    ----------
    path : path-like
        The CDF file.

    Returns
    -------
    pandas.DataFrame
        Columns ``b1, b2, b3`` (float, counts; NaN for fill), index the sample times
        (tz-aware UTC DatetimeIndex named ``time``). ``attrs``: ``units`` ("counts"),
        ``probe``, ``file``, ``n_fill``.

    Raises
    ------
    InputError
        If the file holds no ``*_fgs`` / ``*_fgs_time`` pair.
    """
    p = Path(path)
    data = read_cdf(p)
    name = next((n for n in data if re.fullmatch(r"el[ab]_fgs", n)), None)
    if name is None or f"{name}_time" not in data:
        raise InputError("not an ELFIN FGS file: no 'ela_fgs'/'elb_fgs' variable with its "
                         "'_time'", file=p)
    values = np.asarray(data[name], dtype=float).reshape(-1, 3)
    index = utc_index(data[f"{name}_time"], name="time")
    frame = pd.DataFrame(values, index=index, columns=["b1", "b2", "b3"])
    frame.attrs.update({"units": "counts", "probe": name[:3], "file": str(p),
                        "n_fill": int(data.fill_counts[name]),
                        "note": "raw sensor-frame counts; the file's UNITS attribute "
                                "says nT but the values are not calibrated"})
    return frame


def read_elfin_state(path: str | os.PathLike) -> pd.DataFrame:
    """ELFIN level-1 state file (``ela_l1_state_defn_*.cdf``): orbit, attitude, Sun flag.

    Parameters
    ----------
    path : path-like
        The CDF file.

    Returns
    -------
    pandas.DataFrame
        One row per state record (1 s), tz-aware UTC index named ``time``; columns
        ``pos_gei_x/_y/_z`` (km), ``vel_gei_x/_y/_z`` (km/s), ``spin_axis_gei_x/_y/_z``
        (unit vector of the spin axis in GEI, linearly interpolated from the 1-min
        attitude solutions and renormalised; NaN outside them) and ``sun`` (1 in
        sunlight, 0 in eclipse, NaN for fill). ``attrs["units"]`` maps columns to units.
    """
    p = Path(path)
    data = read_cdf(p)
    probe = next((n[:3] for n in data if re.fullmatch(r"el[ab]_pos_gei", n)), None)
    if probe is None:
        raise InputError("not an ELFIN state file: no 'ela_pos_gei'/'elb_pos_gei'", file=p)
    index = utc_index(data[f"{probe}_state_time"], name="time")
    cols = {}
    for kind in ("pos", "vel"):
        arr = np.asarray(data[f"{probe}_{kind}_gei"], dtype=float).reshape(-1, 3)
        for j, axis in enumerate("xyz"):
            cols[f"{kind}_gei_{axis}"] = arr[:, j]
    att_name, att_time = f"{probe}_att_gei", f"{probe}_att_time"
    if att_name in data and att_time in data and len(data[att_time]):
        att = np.asarray(data[att_name], dtype=float).reshape(-1, 3)
        t_att = utc_index(data[att_time], name="time").asi8
        t = index.asi8
        inside = (t >= t_att[0]) & (t <= t_att[-1])
        interp = np.column_stack([np.interp(t, t_att, att[:, j]) for j in range(3)])
        interp /= np.linalg.norm(interp, axis=1, keepdims=True)
        interp[~inside] = np.nan
    else:
        interp = np.full((len(index), 3), np.nan)
    for j, axis in enumerate("xyz"):
        cols[f"spin_axis_gei_{axis}"] = interp[:, j]
    sun_name = f"{probe}_sun"
    sun = (np.asarray(data[sun_name], dtype=float) if sun_name in data
           else np.full(len(index), np.nan))
    sun[(sun != 0) & (sun != 1)] = np.nan
    cols["sun"] = sun
    frame = pd.DataFrame(cols, index=index)
    units = {c: ("km" if c.startswith("pos") else "km/s" if c.startswith("vel") else "1")
             for c in frame.columns}
    frame.attrs.update({"units": units, "probe": probe, "file": str(p)})
    return frame


def ns_index(frame: pd.DataFrame, name: str = "frame") -> pd.DataFrame:
    """``frame`` with a UTC ``DatetimeIndex`` held in nanoseconds (the same frame if it
    is one already).

    The ELFIN steps compute seconds as ``index.asi8 / 1e9``; pandas 3 builds indexes in
    microseconds (``pd.date_range``, parsed strings), which would make every time 1000
    times too short (zones merged, spline knots misplaced) without an error. A naive
    index is taken as UTC.

    Raises
    ------
    InputError
        If the index is not a time index.

    Examples
    --------
    >>> idx = pd.date_range("2022-01-12", periods=3, freq="1s", unit="us")
    >>> out = ns_index(pd.DataFrame({"b1": [1.0, 2.0, 3.0]}, index=idx))
    >>> str(out.index.dtype), float(np.diff(out.index.asi8)[0] / 1e9)
    ('datetime64[ns, UTC]', 1.0)
    """
    if not isinstance(frame.index, pd.DatetimeIndex):
        raise InputError(f"{name}: the index is not a time index "
                         f"({type(frame.index).__name__})")
    if frame.index.tz is not None and frame.index.unit == "ns":
        return frame
    return frame.set_axis(utc_index(frame.index, name=frame.index.name), axis=0)
