"""CSV time series per CONTRACTS §0.

Files have a header; the first column is ``time`` (ISO-8601 UTC, optional fractional
seconds, optional ``Z``); rows are strictly increasing in time; values are in nT unless
a column says otherwise; missing values are empty cells or ``NaN``.

Row numbers in error messages are line numbers of the file (the header is line 1), so
``sed -n 12p file.csv`` shows the offending line.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Iterable

import numpy as np
import pandas as pd

from magcal.errors import InputError
from magcal.io.atomic import atomic_path

#: Values that instrument files use for "no data"; converted to NaN and counted.
FILL_VALUES = (-1e31, -9999.0)
#: Anything at or beyond this magnitude is treated as the -1e31 family of fills.
FILL_MAGNITUDE = 1e30

_MISSING_TOKENS = {"", "nan", "NaN", "NAN", "null", "NULL", "NA", "N/A"}


def _line(index: int) -> int:
    """File line number of data row ``index`` (0-based); the header is line 1."""
    return int(index) + 2


def parse_times(values: Iterable[str], *, file=None, column: str = "time") -> pd.DatetimeIndex:
    """Parse ISO-8601 UTC strings into a tz-aware DatetimeIndex, naming the first bad row.

    Examples
    --------
    >>> parse_times(["2019-03-04T15:10:00", "2019-03-04T15:10:00.5Z"])[1]
    Timestamp('2019-03-04 15:10:00.500000+0000', tz='UTC')
    """
    raw = pd.Series(list(values), dtype="object").astype(str).str.strip()
    parsed = pd.to_datetime(raw, utc=True, format="ISO8601", errors="coerce")
    bad = parsed.isna().to_numpy()
    if bad.any():
        first = int(np.flatnonzero(bad)[0])
        raise InputError(f"cannot parse time {raw.iloc[first]!r} as ISO-8601 UTC",
                         file=file, row=_line(first), column=column)
    index = pd.DatetimeIndex(parsed, name="time")
    return index.as_unit("ns")


def check_increasing(index: pd.DatetimeIndex, *, file=None) -> None:
    """Raise :class:`InputError` at the first row whose time is not after the previous one."""
    if len(index) < 2:
        return
    steps = np.diff(index.asi8)
    bad = np.flatnonzero(steps <= 0)
    if bad.size:
        k = int(bad[0]) + 1
        what = "duplicate time" if steps[k - 1] == 0 else "time goes backwards"
        raise InputError(
            f"{what}: {index[k].isoformat()} follows {index[k - 1].isoformat()} "
            "(rows must be strictly increasing in time)", file=file, row=_line(k), column="time")


def _to_float(column: pd.Series, name: str, file) -> np.ndarray:
    text = column.astype("object")
    values = pd.to_numeric(text, errors="coerce").to_numpy(dtype=float)
    unparsed = np.isnan(values) & ~text.isna().to_numpy()
    if unparsed.any():
        stripped = text.astype(str).str.strip()
        unparsed &= ~stripped.isin(_MISSING_TOKENS).to_numpy()
    if unparsed.any():
        first = int(np.flatnonzero(unparsed)[0])
        raise InputError(f"not a number: {text.iloc[first]!r}", file=file, row=_line(first),
                         column=name)
    return values


def replace_fill_values(values: np.ndarray) -> tuple[np.ndarray, int]:
    """Return a copy with fill values (-1e31 family, -9999) as NaN, and how many there were."""
    out = np.array(values, dtype=float, copy=True)
    fill = (np.abs(out) >= FILL_MAGNITUDE) | (out == -9999.0)
    out[fill] = np.nan
    return out, int(fill.sum())


def read_csv_frame(path: str | os.PathLike, required: Iterable[str] | None = None,
                   *, numeric: bool = True) -> pd.DataFrame:
    """Read a CONTRACTS §0 time-series CSV into a validated DataFrame.

    Parameters
    ----------
    path : path-like
        The CSV file.
    required : iterable of str, optional
        Columns that must be present (besides ``time``).
    numeric : bool
        Convert every column to float (default). Fill values become NaN.

    Returns
    -------
    pandas.DataFrame
        Index: tz-aware UTC :class:`pandas.DatetimeIndex` named ``time``. Columns as in
        the file. ``df.attrs["repairs"]`` lists each counted repair (fill values turned
        into NaN), ``df.attrs["source"]`` the file and ``df.attrs["n_missing"]`` the NaN
        count per column.

    Raises
    ------
    InputError
        Missing file, no ``time`` first column, unparsable time or number (with the line
        number), times not strictly increasing, missing required column, no data rows.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> p = pathlib.Path(tempfile.mkdtemp()) / "b.csv"
    >>> _ = p.write_text("time,Hp,He,Hn\\n2019-03-04T00:00:00,1,2,-9999\\n")
    >>> df = read_csv_frame(p, required=["Hp", "He", "Hn"])
    >>> float(df["Hp"].iloc[0]), bool(np.isnan(df["Hn"].iloc[0]))
    (1.0, True)
    >>> df.attrs["repairs"][0]["count"]
    1
    """
    p = Path(path)
    if not p.is_file():
        raise InputError("file not found", file=p)
    try:
        table = pd.read_csv(p, dtype=str, keep_default_na=False, skipinitialspace=True)
    except pd.errors.EmptyDataError:
        raise InputError("file is empty (expected a header line starting with 'time')",
                         file=p) from None
    except pd.errors.ParserError as exc:
        raise InputError(f"not a valid CSV table: {exc}", file=p) from None
    columns = [str(c).strip() for c in table.columns]
    if not columns or columns[0] != "time":
        raise InputError(f"first column must be 'time', found {columns[0] if columns else None!r}",
                         file=p, row=1)
    dup = pd.Index(columns)[pd.Index(columns).duplicated()]
    if len(dup):
        raise InputError(f"duplicate column {dup[0]!r} in header", file=p, row=1)
    table.columns = columns
    missing = [c for c in (required or ()) if c not in columns]
    if missing:
        raise InputError(f"missing required column(s) {', '.join(missing)}; "
                         f"header has {', '.join(columns)}", file=p, row=1, column=missing[0])
    if len(table) == 0:
        raise InputError("no data rows", file=p)
    index = parse_times(table["time"], file=p)
    check_increasing(index, file=p)
    data = {}
    repairs = []
    for name in columns[1:]:
        if not numeric:
            data[name] = table[name].to_numpy()
            continue
        values = _to_float(table[name], name, p)
        values, n_fill = replace_fill_values(values)
        if n_fill:
            repairs.append({"what": "fill value replaced by NaN", "column": name,
                            "count": n_fill})
        data[name] = values
    frame = pd.DataFrame(data, index=index)
    frame.attrs["source"] = str(p)
    frame.attrs["repairs"] = repairs
    if numeric:
        frame.attrs["n_missing"] = {k: int(v) for k, v in frame.isna().sum().items()}
    return frame


def format_times(index: pd.DatetimeIndex) -> np.ndarray:
    """ISO-8601 strings without time zone, with the fewest fractional digits that are exact."""
    ns = pd.DatetimeIndex(index).tz_convert("UTC").tz_localize(None).as_unit("ns").asi8
    values = ns.view("datetime64[ns]")
    for unit, step in (("s", 10**9), ("ms", 10**6), ("us", 10**3), ("ns", 1)):
        if np.all(ns % step == 0):
            return np.datetime_as_string(values, unit=unit)
    raise AssertionError("unreachable")  # pragma: no cover


def write_csv_frame(path: str | os.PathLike, frame: pd.DataFrame,
                    float_format: str | None = "%.4f",
                    provenance: dict | None = None) -> Path:
    """Write a DataFrame with a UTC DatetimeIndex as a CONTRACTS §0 CSV, atomically.

    Parameters
    ----------
    path : path-like
        Output file.
    frame : pandas.DataFrame
        Index: DatetimeIndex (tz-aware UTC or naive UTC), strictly increasing.
    float_format : str or None
        printf-style format for floats (default 0.1 pT resolution for nT values).
        ``None`` writes full precision.
    provenance : dict, optional
        Written beside the CSV as ``<path>.provenance.json`` (a CSV has no room for it).

    Returns
    -------
    pathlib.Path
        The written path.
    """
    if not isinstance(frame.index, pd.DatetimeIndex):
        raise TypeError("frame must have a DatetimeIndex")
    index = frame.index if frame.index.tz is not None else frame.index.tz_localize("UTC")
    check_increasing(index)
    out = frame.copy()
    out.index = pd.Index(format_times(index), name="time")
    with atomic_path(path) as tmp:
        out.to_csv(tmp, float_format=float_format, na_rep="NaN", index_label="time")
        if provenance is not None:
            side = Path(str(path) + ".provenance.json")
            with atomic_path(side) as tmp_side:
                tmp_side.write_text(json.dumps(provenance, indent=2, default=str) + "\n")
    return Path(path)
