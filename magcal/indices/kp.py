"""The planetary 3-hour index Kp: readers for the common file formats and helpers.

Kp is on a scale of thirds: ``1-`` = 2/3, ``1o`` = 1, ``1+`` = 4/3. Everything in
magcal holds Kp as a float in exact thirds (``5/3`` for ``2-``); only the IRBEM boundary
uses the OMNI-style one-decimal values (``1.7``), see :func:`kp_to_irbem`.

:func:`read_kp` detects the format from the content:

``gfz_text``
    GFZ ``Kp_ap_Ap_SN_F107`` text (one line per day, Kp1..Kp8 as decimals, -1 = missing).
``gfz_kp_def``
    GFZ definitive Kp as CSV (``,Bartels_solar_rotation_num,...,Kp,...``; one row per
    3-hour interval), e.g. as saved by pysat.
``celestrak``
    CelesTrak space-weather text (``DATATYPE CssiSpaceWeather``): Kp x10 rounded, e.g.
    ``17`` = 2-; only ``OBSERVED`` rows are used, predicted sections are dropped and
    counted.
``noaa_dgd``
    NOAA SWPC Daily Geomagnetic Data (``DGD.txt``): the estimated planetary K columns;
    ``-1`` = missing.
``csv``
    Plain CSV ``time,kp`` (CONTRACTS §0 times, start of each 3-hour interval), kp as a
    decimal number or in thirds notation (``1+``, ``2-``, ``3o``).
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np
import pandas as pd

from magcal.errors import InputError, not_a_file_error
from magcal.timeconv import utc_ns

#: Length of one Kp interval in nanoseconds.
INTERVAL_NS = 3 * 3600 * 10**9
#: Largest distance (in thirds) between a decimal value and the thirds scale that is
#: still accepted as that third (covers 1.3, 1.33, 1.7, 1.67).
THIRDS_TOLERANCE = 0.15

KP_FORMATS = ("gfz_text", "gfz_kp_def", "celestrak", "noaa_dgd", "csv")

_THIRDS_TOKEN = re.compile(r"^([0-9])\s*([+\-o])$")
_SUFFIX = {0: "o", 1: "+", 2: "-"}


# ---------------------------------------------------------------------------- scale
def snap_to_thirds(values, *, what: str = "Kp") -> np.ndarray:
    """Round decimal Kp values to the exact thirds scale.

    Parameters
    ----------
    values : array_like
        Kp as decimals (``1.333``, ``1.3``, ``1.7``, ``2``); NaN stays NaN.
    what : str
        Name used in the error message.

    Returns
    -------
    numpy.ndarray
        ``round(3 * kp) / 3``.

    Raises
    ------
    InputError
        If a value is farther than :data:`THIRDS_TOLERANCE` thirds from the scale or
        outside 0..9.

    Examples
    --------
    >>> snap_to_thirds([1.3, 1.7, 2.0]) * 3
    array([4., 5., 6.])
    """
    kp = np.asarray(values, dtype=float)
    thirds = np.round(3.0 * kp)
    finite = np.isfinite(kp)
    off = finite & (np.abs(3.0 * kp - thirds) > THIRDS_TOLERANCE)
    off |= finite & ((thirds < 0) | (thirds > 27))
    if off.any():
        bad = float(kp[off].ravel()[0])  # a plain number in the message, not np.float64(..)
        raise InputError(f"{what} value {bad:.6g} is not on the Kp scale of thirds 0..9 "
                         "(e.g. 1.333 or 1.3 for 1+, 1.667 or 1.7 for 2-)")
    return thirds / 3.0


def parse_kp_token(token: str) -> float:
    """One Kp value from text: a decimal number or thirds notation.

    Empty strings and ``NaN`` give NaN. Raises :class:`ValueError` for anything else
    that is not a Kp value.

    Examples
    --------
    >>> parse_kp_token("1+"), parse_kp_token("2-"), parse_kp_token("3o")
    (1.3333333333333333, 1.6666666666666667, 3.0)
    >>> parse_kp_token("1.7")
    1.6666666666666667
    """
    text = str(token).strip()
    if text == "" or text.lower() in {"nan", "null", "na", "n/a"}:
        return float("nan")
    match = _THIRDS_TOKEN.match(text)
    if match:
        base, sign = int(match.group(1)), match.group(2)
        value = base + {"+": 1, "-": -1, "o": 0}[sign] / 3.0
        if not 0.0 <= value <= 9.0:
            raise ValueError(f"{text!r} is outside the Kp scale 0o..9o")
        return value
    try:
        number = float(text)
    except ValueError:
        raise ValueError(f"{text!r} is neither a number nor Kp thirds notation "
                         "(like 1+, 2-, 3o)") from None
    try:
        return float(snap_to_thirds(number))
    except InputError as exc:
        raise ValueError(exc.message) from None


def kp_to_irbem(kp) -> np.ndarray:
    """Kp in the OMNI-style one-decimal form that IRBEM expects.

    IRBEM multiplies Kp by 10 and picks the T89 activity level by integer thresholds,
    so ``2-`` must be passed as 1.7, ``2o`` as 2.0 and ``2+`` as 2.3 (see
    DEPENDENCY-NOTES); 5/3 would land in the wrong level.

    Parameters
    ----------
    kp : array_like
        Kp in thirds (exact or one-decimal); NaN stays NaN.

    Returns
    -------
    numpy.ndarray
        Values ``n + {0, 0.3, 0.7}``.

    Examples
    --------
    >>> kp_to_irbem([5/3, 2.0, 7/3, 0.0, 1/3])
    array([1.7, 2. , 2.3, 0. , 0.3])
    """
    thirds = np.round(3.0 * snap_to_thirds(kp))
    finite = np.isfinite(thirds)
    t = np.where(finite, thirds, 0).astype(np.int64)
    base = (t + 1) // 3                      # 5 (2-) -> 2, 4 (1+) -> 1, 3 (1o) -> 1
    frac = np.choose(t % 3, [0.0, 0.3, -0.3])
    out = np.round(base + frac, 1)
    return np.where(finite, out, np.nan)


def kp_thirds_label(kp) -> list[str]:
    """Kp values as thirds labels (``"1+"``, ``"2-"``, ``"0o"``; NaN gives ``"nan"``).

    Examples
    --------
    >>> kp_thirds_label([4/3, 5/3, 0.0, 1.7])
    ['1+', '2-', '0o', '2-']
    """
    thirds = np.round(3.0 * snap_to_thirds(np.atleast_1d(kp)))
    labels = []
    for t in thirds.ravel():
        if not np.isfinite(t):
            labels.append("nan")
            continue
        t = int(t)
        labels.append(f"{(t + 1) // 3}{_SUFFIX[t % 3]}")
    return labels


# ---------------------------------------------------------------------------- lookup
def kp_at(kp: pd.Series, times) -> np.ndarray:
    """Kp of the 3-hour interval containing each time.

    Parameters
    ----------
    kp : pandas.Series
        As returned by :func:`read_kp`: index = start of each interval (UTC).
    times : array_like of datetime
        Query times (naive values are taken as UTC).

    Returns
    -------
    numpy.ndarray
        Float Kp per time; NaN before the first interval, after the end of the last one,
        in intervals missing from ``kp`` and where ``kp`` is NaN.

    Examples
    --------
    >>> s = pd.Series([1.0, 4/3], index=pd.DatetimeIndex(
    ...     ["2019-11-02T00:00", "2019-11-02T03:00"], tz="UTC", name="time"), name="kp")
    >>> kp_at(s, ["2019-11-02T02:59", "2019-11-02T05:59:59", "2019-11-02T06:00"])
    array([1.        , 1.33333333,        nan])
    """
    starts = utc_ns(kp.index)
    if starts.size > 1 and np.any(np.diff(starts) <= 0):
        raise InputError("Kp index must be strictly increasing")
    values = np.asarray(kp.to_numpy(), dtype=float)
    t = utc_ns(times)
    k = np.searchsorted(starts, t, side="right") - 1
    ok = (k >= 0) & (k < starts.size)
    kc = np.clip(k, 0, max(starts.size - 1, 0))
    if starts.size:
        ok &= t < starts[kc] + INTERVAL_NS
    out = np.full(t.shape, np.nan)
    if starts.size:
        out[ok] = values[kc[ok]]
    return out


# ---------------------------------------------------------------------------- readers
def detect_kp_format(path: str | os.PathLike) -> str:
    """Name of the Kp file format (one of :data:`KP_FORMATS`), from the content.

    Raises
    ------
    InputError
        If the file is missing or no known format matches.
    """
    p = Path(path)
    if not p.is_file():
        raise not_a_file_error(p)
    head = _read_lines(p)[:80]
    text = "\n".join(head)
    if "CssiSpaceWeather" in text or "BEGIN OBSERVED" in text:
        return "celestrak"
    if "Daily Geomagnetic Data" in text or re.search(r"Planetary\s*-*\s*$", text, re.M):
        return "noaa_dgd"
    if re.search(r"^#\s*YYY\s+MM\s+DD\s+days\s+days_m", text, re.M) or "Kp_ap_Ap_SN_F107" in text:
        return "gfz_text"
    first = next((ln for ln in head if ln.strip()), "")
    header = [c.strip() for c in first.split(",")]
    if len(header) >= 2:
        lower = [c.lower() for c in header]
        if header[0] == "time" and "kp" in lower:
            return "csv"
        if "Kp" in header and (header[0] == "" or "Bartels_solar_rotation_num" in header):
            return "gfz_kp_def"
    data = [ln.split() for ln in head if ln.strip() and not ln.lstrip().startswith("#")]
    if data and all(len(d) >= 28 and _looks_gfz_text_row(d) for d in data[:5]):
        return "gfz_text"
    raise InputError("unknown Kp file format (expected GFZ Kp_ap_Ap_SN_F107 text, GFZ Kp_def "
                     "CSV, CelesTrak space-weather text, NOAA DGD or CSV 'time,kp')", file=p)


def read_kp(path: str | os.PathLike) -> pd.Series:
    """Read a Kp file in any supported format (detected from the content).

    Parameters
    ----------
    path : path-like
        The file (see the module docstring for the formats).

    Returns
    -------
    pandas.Series
        Name ``"kp"``, float Kp in exact thirds, index = start of each 3-hour interval
        (tz-aware UTC :class:`pandas.DatetimeIndex` named ``"time"``), strictly
        increasing. Missing values are NaN; predicted/flagged rows are not included.
        ``series.attrs`` holds ``source_format``, ``file``, ``n_intervals``,
        ``n_missing`` (NaN values), ``n_dropped_predicted`` (rows outside the observed
        section or marked predicted) and ``n_dropped_flagged`` (rows with a negative
        Kp flag in a format where that marks non-observed data).

    Raises
    ------
    InputError
        Unknown format, or a line that cannot be parsed (the message names the file
        and line).

    Examples
    --------
    >>> import tempfile, pathlib
    >>> p = pathlib.Path(tempfile.mkdtemp()) / "kp.csv"
    >>> _ = p.write_text("time,kp\\n2019-11-02T00:00:00,1+\\n2019-11-02T03:00:00,2-\\n")
    >>> kp = read_kp(p)
    >>> kp_thirds_label(kp), kp.attrs["source_format"]
    (['1+', '2-'], 'csv')
    """
    p = Path(path)
    fmt = detect_kp_format(p)
    reader = {"gfz_text": _read_gfz_text, "gfz_kp_def": _read_gfz_kp_def,
              "celestrak": _read_celestrak, "noaa_dgd": _read_noaa_dgd,
              "csv": _read_plain_csv}[fmt]
    starts, values, counts = reader(p)
    return _make_series(p, fmt, starts, values, counts)


def write_kp_csv(path: str | os.PathLike, kp: pd.Series, *, thirds: bool = False) -> Path:
    """Write Kp as a plain CSV ``time,kp`` (atomically).

    Parameters
    ----------
    path : path-like
        Output file.
    kp : pandas.Series
        Kp with a UTC DatetimeIndex of interval starts.
    thirds : bool
        Write thirds labels (``1+``) instead of decimals (full precision).
    """
    from magcal.io.atomic import atomic_path
    from magcal.io.csv import format_times

    index = pd.DatetimeIndex(kp.index)
    index = index.tz_localize("UTC") if index.tz is None else index
    times = format_times(index)
    if thirds:
        cells = ["" if lab == "nan" else lab for lab in kp_thirds_label(kp.to_numpy())]
    else:
        cells = ["" if not np.isfinite(v) else repr(float(v)) for v in kp.to_numpy(float)]
    lines = ["time,kp"] + [f"{t},{c}" for t, c in zip(times, cells)]
    with atomic_path(path) as tmp:
        tmp.write_text("\n".join(lines) + "\n")
    return Path(path)


# ---------------------------------------------------------------------------- internals
def _read_lines(p: Path) -> list[str]:
    try:
        return p.read_text(encoding="utf-8", errors="replace").splitlines()
    except OSError as exc:
        raise InputError(f"cannot read file ({exc.strerror})", file=p) from None


def _looks_gfz_text_row(tokens: list[str]) -> bool:
    try:
        int(tokens[0]), int(tokens[1]), int(tokens[2]), float(tokens[4])
    except ValueError:
        return False
    return "." in tokens[4]


def _day_start_ns(year: int, month: int, day: int, p: Path, lineno: int) -> int:
    try:
        return pd.Timestamp(year=year, month=month, day=day, tz="UTC").as_unit("ns").value
    except ValueError:
        raise InputError(f"line {lineno}: invalid date {year:04d}-{month:02d}-{day:02d}",
                         file=p) from None


def _daily_rows(starts: list, values: list, day_ns: int, kps) -> None:
    for j, v in enumerate(kps):
        starts.append(day_ns + j * INTERVAL_NS)
        values.append(v)


def _read_gfz_text(p: Path):
    starts, values = [], []
    counts = {"n_preliminary_days": 0}
    for lineno, line in enumerate(_read_lines(p), start=1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        tok = line.split()
        try:
            if len(tok) < 15:
                raise ValueError(f"expected at least 15 fields, found {len(tok)}")
            y, m, d = int(tok[0]), int(tok[1]), int(tok[2])
            kps = [float(x) for x in tok[7:15]]
            definitive = int(tok[27]) if len(tok) >= 28 else None
        except ValueError as exc:
            raise InputError(f"line {lineno}: not a GFZ Kp_ap_Ap_SN_F107 data line ({exc})",
                             file=p) from None
        kps = [np.nan if v < 0 else v for v in kps]
        kps = _snap_line(kps, p, lineno)
        if definitive == 0:
            counts["n_preliminary_days"] += 1
        _daily_rows(starts, values, _day_start_ns(y, m, d, p, lineno), kps)
    return starts, values, counts


def _read_celestrak(p: Path):
    starts, values = [], []
    counts = {"n_dropped_predicted": 0, "n_dropped_flagged": 0}
    section = None
    saw_section = False
    for lineno, line in enumerate(_read_lines(p), start=1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        if s.startswith("BEGIN "):
            section, saw_section = s[6:].strip(), True
            continue
        if s.startswith("END "):
            section = None
            continue
        tok = s.split()
        if not tok[0].isdigit() or len(tok[0]) != 4:
            continue                         # header keywords (DATATYPE, VERSION, ...)
        if saw_section and section != "OBSERVED":
            counts["n_dropped_predicted"] += 1
            continue
        try:
            if len(tok) < 13:
                raise ValueError(f"expected at least 13 fields, found {len(tok)}")
            y, m, d = int(tok[0]), int(tok[1]), int(tok[2])
            kp10 = [int(x) for x in tok[5:13]]
        except ValueError as exc:
            raise InputError(f"line {lineno}: not a CelesTrak space-weather data line ({exc})",
                             file=p) from None
        if any(v < 0 for v in kp10):
            counts["n_dropped_flagged"] += 1
            continue
        kps = _snap_line([v / 10.0 for v in kp10], p, lineno)
        _daily_rows(starts, values, _day_start_ns(y, m, d, p, lineno), kps)
    return starts, values, counts


def _read_noaa_dgd(p: Path):
    starts, values = [], []
    counts = {}
    for lineno, line in enumerate(_read_lines(p), start=1):
        s = line.strip()
        if not s or s.startswith(("#", ":")):
            continue
        tok = s.split()
        try:
            y, m, d = int(tok[0]), int(tok[1]), int(tok[2])
            kps = [float(x) for x in tok[-8:]]
            if len(tok) < 12:
                raise ValueError(f"expected at least 12 fields, found {len(tok)}")
        except (ValueError, IndexError) as exc:
            raise InputError(f"line {lineno}: not a NOAA DGD data line ({exc})", file=p) from None
        kps = [np.nan if v < 0 else v for v in kps]
        kps = _snap_line(kps, p, lineno)
        _daily_rows(starts, values, _day_start_ns(y, m, d, p, lineno), kps)
    return starts, values, counts


def _read_gfz_kp_def(p: Path):
    from magcal.io.csv import parse_times, read_text_table

    table, columns = read_text_table(p, unnamed_first="time")
    if "Kp" not in columns:
        raise InputError("no Kp column in the GFZ Kp_def header", file=p, row=1)
    parsed = parse_times(table[columns[0]], file=p, column=columns[0])
    values = []
    for k, cell in enumerate(table["Kp"]):
        try:
            v = parse_kp_token(cell)
        except ValueError as exc:
            raise InputError(f"line {k + 2}: {exc}", file=p, column="Kp") from None
        values.append(np.nan if v < 0 else v)
    return list(pd.DatetimeIndex(parsed).as_unit("ns").asi8), values, {}


def _read_plain_csv(p: Path):
    from magcal.io.csv import read_csv_frame

    frame = read_csv_frame(p, numeric=False)
    col = next(c for c in frame.columns if c.lower() == "kp")
    values = []
    for k, cell in enumerate(frame[col]):
        try:
            values.append(parse_kp_token(cell))
        except ValueError as exc:
            raise InputError(str(exc), file=p, row=k + 2, column=col) from None
    return list(frame.index.asi8), values, {}


def _snap_line(values, p: Path, lineno: int) -> list[float]:
    try:
        return list(snap_to_thirds(values))
    except InputError as exc:
        raise InputError(f"line {lineno}: {exc.message}", file=p) from None


def _make_series(p: Path, fmt: str, starts, values, counts: dict) -> pd.Series:
    if not starts:
        raise InputError(f"no Kp data found (read as {fmt})", file=p)
    ns = np.asarray(starts, dtype=np.int64)
    steps = np.diff(ns)
    bad = np.flatnonzero(steps <= 0)
    if bad.size:
        k = int(bad[0]) + 1
        when = pd.Timestamp(ns[k], tz="UTC").isoformat()
        raise InputError(f"Kp intervals not strictly increasing at {when} (duplicate or "
                         "out-of-order day)", file=p)
    if np.any(ns % INTERVAL_NS != 0):
        k = int(np.flatnonzero(ns % INTERVAL_NS)[0])
        when = pd.Timestamp(ns[k], tz="UTC").isoformat()
        raise InputError(f"Kp interval start {when} is not on a 3-hour boundary "
                         "(times must be the start of each interval: 00, 03, ..., 21 UT)",
                         file=p)
    index = pd.DatetimeIndex(ns.view("datetime64[ns]"), name="time").tz_localize("UTC")
    series = pd.Series(np.asarray(values, dtype=float), index=index, name="kp")
    attrs = {"source_format": fmt, "file": str(p), "n_intervals": int(series.size),
             "n_missing": int(series.isna().sum()), "n_dropped_predicted": 0,
             "n_dropped_flagged": 0}
    attrs.update({k: int(v) for k, v in counts.items()})
    series.attrs.update(attrs)
    return series
