"""CSV time series per CONTRACTS §0.

Files have a header; the first column is ``time`` (ISO-8601 UTC, optional fractional
seconds, optional ``Z``); rows are strictly increasing in time; values are in nT unless
a column says otherwise; missing values are empty cells or ``NaN``.

Row numbers in error messages are line numbers of the file (the header is line 1), so
``sed -n 12p file.csv`` shows the offending line.
"""

from __future__ import annotations

import gzip
import json
import lzma
import os
import re
import zlib
from pathlib import Path
from typing import Iterable

import numpy as np
import pandas as pd

from magcal.errors import InputError, not_a_file_error
from magcal.io.atomic import atomic_path

#: Values that instrument files use for "no data"; converted to NaN and counted.
FILL_VALUES = (-1e31, -9999.0)
#: Anything at or beyond this magnitude is treated as the -1e31 family of fills.
FILL_MAGNITUDE = 1e30

_MISSING_TOKENS = {"", "nan", "NaN", "NAN", "null", "NULL", "NA", "N/A"}


def _line(index: int, lines=None) -> int:
    """File line number of data row ``index`` (0-based); the header is line 1.

    ``lines`` (from :func:`read_text_table`, ``table.attrs["lines"]``) maps rows to
    lines when blank lines were skipped; without it row ``k`` is line ``k + 2``.
    """
    return int(lines[index]) if lines is not None else int(index) + 2


#: The span of nanosecond time stamps (numpy/pandas ``datetime64[ns]``).
_FIRST_NS = pd.Timestamp("1677-09-22", tz="UTC")
_LAST_NS = pd.Timestamp("2262-04-11", tz="UTC")
#: A time of day followed by a UTC offset (``+01:00``, ``-0500``, ``+02``).
_OFFSET = re.compile(r"\d{2}:\d{2}(?::\d{2}(?:[.,]\d*)?)?\s*([+-])(\d{2}):?(\d{2})?$")
#: A leap second (second 60) in a time of day.
_LEAP = re.compile(r"(?:^|[T ])\d{2}:\d{2}:60(?:[.,]\d*)?(?:Z|[+-]\d{2}(?::?\d{2})?)?$")


def _check_utc_stamps(raw: pd.Series, *, file=None, column: str = "time",
                      lines=None) -> None:
    """Refuse leap-second stamps and times with a non-zero UTC offset, naming the row."""
    suspect = raw.str.contains(r":60|\d[+-]\d{2}(?::?\d{2})?$", regex=True).to_numpy()
    if not suspect.any():
        return
    for k in np.flatnonzero(suspect):
        stamp = raw.iloc[k]
        if _LEAP.search(stamp):
            raise InputError(f"leap second in {stamp!r}: times are UTC without leap seconds "
                             "(as numpy and pandas count them); drop or merge that sample",
                             file=file, row=_line(k, lines), column=column)
        found = _OFFSET.search(stamp)
        if found and (int(found.group(2)) or int(found.group(3) or 0)):
            raise InputError(f"time {stamp!r} carries the UTC offset "
                             f"{found.group(1)}{found.group(2)}:{found.group(3) or '00'}; "
                             "times must be UTC ('Z', '+00:00' or no suffix)", file=file,
                             row=_line(k, lines), column=column)


def parse_times(values: Iterable[str], *, file=None, column: str = "time",
                lines=None) -> pd.DatetimeIndex:
    """Parse ISO-8601 UTC strings into a tz-aware DatetimeIndex, naming the first bad row.

    Leap-second stamps (``23:59:60``) and times with a non-zero UTC offset are refused:
    magcal's times are UTC without leap seconds, and a file mixing offsets is not the
    CSV contract's.

    Examples
    --------
    >>> parse_times(["2019-03-04T15:10:00", "2019-03-04T15:10:00.5Z"])[1]
    Timestamp('2019-03-04 15:10:00.500000+0000', tz='UTC')
    """
    raw = pd.Series(list(values), dtype="object").astype(str).str.strip()
    _check_utc_stamps(raw, file=file, column=column, lines=lines)
    parsed = pd.to_datetime(raw, utc=True, format="ISO8601", errors="coerce")
    with np.errstate(invalid="ignore"):
        outside = ((parsed < _FIRST_NS) | (parsed > _LAST_NS)).to_numpy()
    if outside.any():
        first = int(np.flatnonzero(outside)[0])
        raise InputError(f"time {raw.iloc[first]!r} is outside {_FIRST_NS.year}-"
                         f"{_LAST_NS.year}", file=file, row=_line(first, lines), column=column)
    bad = parsed.isna().to_numpy()
    if bad.any():
        first = int(np.flatnonzero(bad)[0])
        raise InputError(f"cannot parse time {raw.iloc[first]!r} as ISO-8601 UTC",
                         file=file, row=_line(first, lines), column=column)
    index = pd.DatetimeIndex(parsed, name="time")
    return index.as_unit("ns")


def check_increasing(index: pd.DatetimeIndex, *, file=None, lines=None) -> None:
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
            "(rows must be strictly increasing in time)", file=file, row=_line(k, lines),
            column="time")


def _to_float(column: pd.Series, name: str, file, lines=None) -> np.ndarray:
    text = column.astype("object")
    values = pd.to_numeric(text, errors="coerce").to_numpy(dtype=float)
    unparsed = np.isnan(values) & ~text.isna().to_numpy()
    if unparsed.any():
        stripped = text.astype(str).str.strip()
        unparsed &= ~stripped.isin(_MISSING_TOKENS).to_numpy()
    if unparsed.any():
        first = int(np.flatnonzero(unparsed)[0])
        raise InputError(f"not a number: {text.iloc[first]!r}", file=file,
                         row=_line(first, lines),
                         column=name)
    return values


def replace_fill_values(values: np.ndarray) -> tuple[np.ndarray, int]:
    """Return a copy with fill values (-1e31 family, -9999) as NaN, and how many there were."""
    out = np.array(values, dtype=float, copy=True)
    fill = (np.abs(out) >= FILL_MAGNITUDE) | (out == -9999.0)
    out[fill] = np.nan
    return out, int(fill.sum())


def _read_bytes(p: Path) -> bytes:
    """The file's bytes, decompressed by the name's suffix (``.gz``, ``.bz2``, ``.xz``)."""
    import bz2

    opener = {".gz": gzip.open, ".bz2": bz2.open, ".xz": lzma.open}.get(p.suffix.lower(), open)
    try:
        with opener(p, "rb") as handle:
            return handle.read()
    except (EOFError, zlib.error, lzma.LZMAError, gzip.BadGzipFile, ValueError) as exc:
        raise InputError(f"compressed file is damaged or cut short ({exc})", file=p) from None
    except OSError as exc:
        raise InputError(f"cannot read the file ({exc})", file=p) from None


def _check_text(raw: bytes, p: Path) -> None:
    """Refuse bytes that are not UTF-8 text, naming the line of the first bad byte."""
    try:
        raw.decode("utf-8")
        pos = raw.find(b"\x00")
    except UnicodeDecodeError as exc:
        pos = exc.start
    if pos >= 0:
        raise InputError(f"not a text CSV file: byte 0x{raw[pos]:02x} is not UTF-8 text "
                         "(binary file?)", file=p, row=raw[:pos].count(b"\n") + 1)


def _field_counts(raw: bytes) -> tuple[np.ndarray, np.ndarray]:
    """Fields per line (commas + 1) and whether each line is blank, without quoting."""
    arr = np.frombuffer(raw, dtype=np.uint8)
    ends = np.flatnonzero(arr == 10)
    if not raw.endswith(b"\n"):
        ends = np.append(ends, arr.size)
    starts = np.concatenate([[0], ends[:-1] + 1])
    commas = np.searchsorted(ends, np.flatnonzero(arr == 44))
    fields = np.bincount(commas, minlength=ends.size) + 1
    blank = np.zeros(ends.size, dtype=bool)
    for k in np.flatnonzero(fields == 1):              # few: whitespace-only lines
        blank[k] = not raw[starts[k]:ends[k]].strip()
    return fields, blank


def _quoted_field_counts(text: str) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_field_counts` for files with quoted fields (slower, exact)."""
    import csv as stdcsv
    import io

    fields, blank = [], []
    reader = stdcsv.reader(io.StringIO(text))
    last = 0
    for row in reader:
        for _ in range(reader.line_num - last - 1):       # lines inside a quoted field
            fields.append(0)
            blank.append(True)
        fields.append(len(row))
        blank.append(not row or (len(row) == 1 and not row[0].strip()))
        last = reader.line_num
    return np.asarray(fields, dtype=np.int64), np.asarray(blank, dtype=bool)


def _check_shape(raw: bytes, text: str, p: Path) -> np.ndarray:
    """Every non-blank line must have as many fields as the header; return the line
    numbers (1-based) of the data rows."""
    fields, blank = _quoted_field_counts(text) if b'"' in raw else _field_counts(raw)
    lines = np.flatnonzero(~blank)
    if lines.size == 0:
        raise InputError("file is empty (expected a header line starting with 'time')",
                         file=p)
    want = int(fields[lines[0]])
    bad = lines[fields[lines] != want]
    if bad.size:
        k = int(bad[0])
        what = "line cut short?" if fields[k] < want else "a separator too many?"
        raise InputError(f"{int(fields[k])} fields where the header has {want} ({what})",
                         file=p, row=k + 1)
    return lines[1:] + 1


def _without_truncated_last_line(raw: bytes) -> tuple[bytes, str | None]:
    """A file cut short while it was written ends in a partial line without its line
    break: drop that line (returned, to be reported) when it has fewer fields than the
    header. A short line that ends with a line break is an error of the file, as any
    other (:func:`_check_shape`)."""
    if raw.endswith((b"\n", b"\r")) or b'"' in raw:
        return raw, None
    cut = raw.rfind(b"\n")
    if cut < 0:
        return raw, None
    header = raw[:raw.find(b"\n")]
    last = raw[cut + 1:]
    if last.strip() and last.count(b",") < header.count(b","):
        return raw[:cut + 1], last.decode("utf-8", "replace")
    return raw, None


def read_text_table(path: str | os.PathLike,
                    unnamed_first: str | None = None) -> tuple[pd.DataFrame, list[str]]:
    """Read a CSV file as a table of stripped strings, checking its shape.

    The one place magcal's CSV readers turn a file into cells: UTF-8 (a byte-order mark
    is skipped), compression from the file name (``.gz``, ``.bz2``, ``.xz``), every
    cell a string with empty cells as ``""``, every line with as many fields as the
    header. A last line without its line break and with fewer fields than the header
    (a file cut short while written) is dropped and returned in
    ``table.attrs["dropped_truncated_last_line"]``;
    ``table.attrs["unterminated_last_line"]`` says whether the kept last line lacks its
    line break; ``table.attrs["dropped_empty_last_column"]`` whether an unnamed, empty
    last column (every line ending with a comma) was dropped.

    Parameters
    ----------
    path : path-like
        The file.
    unnamed_first : str, optional
        Name given to a first column whose header cell is empty (a written index, as
        in GFZ's Kp_def files); without it an empty name is an error.

    Returns
    -------
    table : pandas.DataFrame
        Columns as in the header (names stripped), cells as strings.
    columns : list of str
        The header's names, stripped.

    Raises
    ------
    InputError
        Missing, empty, damaged, binary or non-UTF-8 file (naming the line of the
        first bad byte), a line with more or fewer fields than the header (naming the
        line), a header with a duplicated or empty name.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> p = pathlib.Path(tempfile.mkdtemp()) / "t.csv"
    >>> _ = p.write_text("time, Hp\\n2019-03-04T00:00:00,\\n")
    >>> table, columns = read_text_table(p)
    >>> columns, table["Hp"].tolist()
    (['time', 'Hp'], [''])
    >>> _ = p.write_text("time,Hp\\n2019-03-04T00:00:00\\n")
    >>> read_text_table(p)
    Traceback (most recent call last):
    ...
    magcal.errors.InputError: ...: row 2: 1 fields where the header has 2 (line cut short?)
    """
    p = Path(path)
    if not p.is_file():
        raise not_a_file_error(p)
    raw = _read_bytes(p)
    if raw.startswith(b"\xef\xbb\xbf"):
        raw = raw[3:]
    if not raw.strip():
        raise InputError("file is empty (expected a header line starting with 'time')",
                         file=p)
    _check_text(raw, p)
    raw, cut = _without_truncated_last_line(raw)
    text = raw.decode("utf-8")
    lines = _check_shape(raw, text, p)
    import io

    try:
        cells = pd.read_csv(io.StringIO(text), header=None, dtype=str, keep_default_na=False,
                            skipinitialspace=True)
    except pd.errors.ParserError as exc:
        raise InputError(f"not a valid CSV table: {exc}", file=p) from None
    columns = [str(c).strip() for c in cells.iloc[0].tolist()]
    if unnamed_first is not None and not columns[0]:
        columns[0] = unnamed_first
    trailing = len(columns) > 1 and not columns[-1] and not cells.iloc[1:, -1].str.strip().any()
    if trailing:                                       # every line ends with a comma
        cells, columns = cells.iloc[:, :-1], columns[:-1]
    for k, name in enumerate(columns):
        if not name:
            raise InputError(f"column {k + 1} of the header has no name", file=p, row=1)
        if name in columns[:k]:
            raise InputError(f"duplicate column {name!r} in header", file=p, row=1,
                             column=name)
    table = cells.iloc[1:].reset_index(drop=True)
    table.columns = columns
    table.attrs["unterminated_last_line"] = len(table) > 0 and not raw.endswith((b"\n", b"\r"))
    table.attrs["dropped_empty_last_column"] = trailing
    table.attrs["dropped_truncated_last_line"] = cut
    # file line of each row, kept only when blank lines shift them (pandas deep-copies
    # attrs on every operation, so the plain case stores nothing)
    plain = lines.size != len(table) or np.array_equal(lines, np.arange(len(table)) + 2)
    table.attrs["lines"] = None if plain else lines.tolist()
    return table, columns


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
        into NaN, infinities included), ``df.attrs["source"]`` the file and
        ``df.attrs["n_missing"]`` the NaN count per column (empty cells, ``NaN`` and
        fills).

    Raises
    ------
    InputError
        Missing, empty, binary or non-UTF-8 file; a header with a duplicated or empty
        column name; a row with more or fewer fields than the header; no ``time`` first
        column; an unparsable time (including leap-second stamps ``:60`` and times with a
        non-zero UTC offset) or number; times not strictly increasing; missing required
        column; no data rows. Every message names the file, and the line and column
        where there is one.

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
    table, columns = read_text_table(p)
    if not columns or columns[0] != "time":
        raise InputError(f"first column must be 'time', found {columns[0] if columns else None!r}",
                         file=p, row=1)
    missing = [c for c in (required or ()) if c not in columns]
    if missing:
        raise InputError(f"missing required column(s) {', '.join(missing)}; "
                         f"header has {', '.join(columns)}", file=p, row=1, column=missing[0])
    if len(table) == 0:
        raise InputError("no data rows", file=p)
    lines = table.attrs.get("lines")
    index = parse_times(table["time"], file=p, lines=lines)
    check_increasing(index, file=p, lines=lines)
    data = {}
    repairs = []
    for name in columns[1:]:
        if not numeric:
            data[name] = table[name].to_numpy()
            continue
        values = _to_float(table[name], name, p, lines)
        values, n_fill = replace_fill_values(values)
        if n_fill:
            repairs.append({"what": "fill value replaced by NaN", "column": name,
                            "count": n_fill})
        data[name] = values
    if table.attrs.get("dropped_empty_last_column"):
        repairs.append({"what": "unnamed empty last column dropped (lines end with a comma)",
                        "column": None, "count": 1})
    if table.attrs.get("dropped_truncated_last_line"):
        repairs.append({"what": "dropped a truncated last line (the file was cut short: "
                                f"{table.attrs['dropped_truncated_last_line'][:40]!r})",
                        "column": None, "count": 1})
    if table.attrs.get("unterminated_last_line"):
        repairs.append({"what": "last line kept although it has no line break (the file "
                                "may be cut short there)", "column": None,
                        "row": _line(len(table) - 1, lines), "count": 1})
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


#: Extensions pandas' writer compresses by (``compression="infer"``).
COMPRESSED_SUFFIXES = frozenset({".gz", ".bz2", ".xz", ".zip", ".zst", ".tar"})

#: Rows formatted per call of :func:`csv_text` (bounds the temporary Python objects).
CSV_CHUNK_ROWS = 50_000


def csv_text(times, frame: pd.DataFrame, float_format: str) -> str | None:
    """The text ``frame.to_csv(float_format=..., na_rep="NaN", index_label="time")``
    writes with the index replaced by the strings ``times``, or None where it could
    differ (a column neither float nor integer, a name that needs quoting).

    One printf-style format per chunk of rows does the whole table in C: 5x faster
    than pandas' writer, which formats each float through Python (a day of 1 s data,
    7 columns: 1 s). Same bytes: pandas formats with the same ``%`` operator.

    Examples
    --------
    >>> frame = pd.DataFrame({"Hp": [1.23456, np.nan], "q": [0, 3]})
    >>> print(csv_text(np.array(["2019-11-01T00:00:00", "2019-11-01T00:00:01"]), frame,
    ...                "%.4f"), end="")
    time,Hp,q
    2019-11-01T00:00:00,1.2346,0
    2019-11-01T00:00:01,NaN,3
    """
    names = list(frame.columns)
    if (len(set(names)) != len(names)
            or any(not isinstance(c, str) or re.search(r'[,"\r\n]', c) for c in names)):
        return None
    kinds = [frame[c].dtype.kind for c in names]
    if any(k not in "fiu" for k in kinds):
        return None
    end = os.linesep
    row = "%s" + "".join("," + (float_format if k == "f" else "%d") for k in kinds) + end
    columns = [np.asarray(times, dtype=object)] + [frame[c].to_numpy() for c in names]
    parts = []
    for start in range(0, len(frame), CSV_CHUNK_ROWS):
        stop = min(start + CSV_CHUNK_ROWS, len(frame))
        cells = np.empty((stop - start, len(columns)), dtype=object)
        for j, col in enumerate(columns):
            cells[:, j] = col[start:stop]
        parts.append((row * (stop - start)) % tuple(cells.ravel().tolist()))
    # %-formatting writes NaN as "nan" (any sign); pandas' na_rep is "NaN"
    return ",".join(["time", *names]) + end + "".join(parts).replace("nan", "NaN")


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
    times = format_times(index)
    # pandas compresses by the file's extension; the fast text is written plain
    plain = Path(path).suffix.lower() not in COMPRESSED_SUFFIXES
    text = csv_text(times, frame, float_format) if plain and float_format else None
    with atomic_path(path) as tmp:
        if text is not None:
            with open(tmp, "w", encoding="utf-8", newline="") as handle:
                handle.write(text)
        else:
            out = frame.copy()
            out.index = pd.Index(times, name="time")
            out.to_csv(tmp, float_format=float_format, na_rep="NaN", index_label="time")
        if provenance is not None:
            side = Path(str(path) + ".provenance.json")
            with atomic_path(side) as tmp_side:
                tmp_side.write_text(json.dumps(provenance, indent=2, default=str) + "\n")
    return Path(path)
