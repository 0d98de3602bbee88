"""Tsyganenko model drivers (the IRBEM ``omnivals`` inputs): readers and interpolation.

Every reader returns the same table: one row per source record, the 16 IRBEM input
columns :data:`DRIVER_COLUMNS` in this order (NaN where the source lacks a quantity),
and a tz-aware UTC :class:`pandas.DatetimeIndex` named ``time``. Kp is held in exact
thirds (5/3 for ``2-``); :func:`drivers_at` converts it to the one-decimal form IRBEM
needs.

:func:`read_drivers` detects the format from the content:

``qin_denton``
    Qin-Denton hourly text (ViRBO; a commented JSON header gives the column layout).
``omni2``
    OMNI2 hourly text (``omni2_YYYY.dat``: year, day of year, hour, then 52+ words).
    Fill values (999.9, 9999., 99.99, 99, 99999) become NaN and are counted.
``hdf5``
    HDF5 with one dataset per IRBEM input and ``UTC`` ISO strings (SpacePy's
    ``OMNItest.h5`` layout).
``csv``
    CONTRACTS §0 CSV: ``time`` plus columns named as IRBEM inputs (``Kp, Dst, dens,
    velo, Pdyn, ByIMF, BzIMF, G1..G3, W1..W6``; case-insensitive).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pandas as pd

from magcal.errors import InputError, not_a_file_error
from magcal.timeconv import utc_ns
from magcal.indices.kp import kp_to_irbem, snap_to_thirds

#: The 16 IRBEM ``omnivals`` keys, in IRBEM's order (all are required by spacepy).
DRIVER_COLUMNS = ("Kp", "Dst", "dens", "velo", "Pdyn", "ByIMF", "BzIMF",
                  "G1", "G2", "G3", "W1", "W2", "W3", "W4", "W5", "W6")

DRIVER_FORMATS = ("qin_denton", "omni2", "hdf5", "csv")

#: Other names for driver quantities seen in files (lower case -> IRBEM name).
_ALIASES = {"vsw": "velo", "v": "velo", "speed": "velo", "den_p": "dens", "n": "dens",
            "density": "dens", "np": "dens", "by": "ByIMF", "bz": "BzIMF",
            "by_gsm": "ByIMF", "bz_gsm": "BzIMF", "pdyn_npa": "Pdyn"}

#: OMNI2 hourly words (0-based) holding the driver quantities, with their fill values.
#: Kp is stored x10 (53 = 5+).
_OMNI2_COLUMNS = {"ByIMF": (15, 999.9), "BzIMF": (16, 999.9), "dens": (23, 999.9),
                  "velo": (24, 9999.0), "Pdyn": (28, 99.99), "Kp": (38, 99.0),
                  "Dst": (40, 99999.0)}

#: Qin-Denton layout used when a file has no readable JSON header (0-based columns).
_QD_DEFAULT = {"ByIMF": 7, "BzIMF": 8, "velo": 9, "dens": 10, "Pdyn": 11, "G1": 12,
               "G2": 13, "G3": 14, "Kp": 23, "Dst": 25, "W1": 32, "W2": 33, "W3": 34,
               "W4": 35, "W5": 36, "W6": 37}
_QD_NAMES = {"ByIMF": "ByIMF", "BzIMF": "BzIMF", "Vsw": "velo", "Den_P": "dens",
             "Pdyn": "Pdyn", "Kp": "Kp", "Dst": "Dst"}


# ---------------------------------------------------------------------------- public
def detect_drivers_format(path: str | os.PathLike) -> str:
    """Name of the driver file format (one of :data:`DRIVER_FORMATS`), from the content."""
    p = Path(path)
    if not p.is_file():
        raise not_a_file_error(p)
    with open(p, "rb") as handle:
        magic = handle.read(8)
    if magic == b"\x89HDF\r\n\x1a\n":
        return "hdf5"
    lines = _read_lines(p)[:400]
    text = "\n".join(lines)
    if "Qin-Denton" in text or ("OriginFile" in text and "START_COLUMN" in text):
        return "qin_denton"
    first = next((ln for ln in lines if ln.strip() and not ln.startswith("#")), "")
    if first.split(",")[0].strip() == "time":
        return "csv"
    tok = first.split()
    if len(tok) >= 41 and _is_int(tok[0]) and _is_int(tok[1]) and _is_int(tok[2]):
        return "omni2"
    if len(tok) >= 38 and "T" in tok[0] and _is_int(tok[1]):
        return "qin_denton"
    raise InputError("unknown driver file format (expected Qin-Denton hourly text, OMNI2 "
                     "hourly text, HDF5 like OMNItest.h5, or CSV 'time,Pdyn,Dst,...')",
                     file=p)


def read_drivers(path) -> pd.DataFrame:
    """Read Tsyganenko model drivers from any supported file (format from the content).

    Parameters
    ----------
    path : path-like or sequence of path-like
        Qin-Denton text, OMNI2 hourly text, HDF5 or CSV (see the module docstring).
        Several files (e.g. daily Qin-Denton files) are read and joined in the given
        order; their records must be strictly increasing across files.

    Returns
    -------
    pandas.DataFrame
        Columns exactly :data:`DRIVER_COLUMNS` (float; Kp in exact thirds, Dst and IMF in
        nT, dens in cm^-3, velo in km/s, Pdyn in nPa), index a strictly increasing
        tz-aware UTC DatetimeIndex named ``time``. ``attrs``: ``source_format``,
        ``file``, ``repairs`` (fill values turned into NaN, per column) and
        ``n_missing`` (NaN count per column, including quantities the source lacks).

    Raises
    ------
    InputError
        Unknown format or an unparsable line (the message names the file and line).

    Examples
    --------
    >>> import tempfile, pathlib
    >>> p = pathlib.Path(tempfile.mkdtemp()) / "drv.csv"
    >>> _ = p.write_text("time,Pdyn,Dst,Kp\\n2012-09-01T00:00:00,1.01,14,1.7\\n")
    >>> d = read_drivers(p)
    >>> float(d["Pdyn"].iloc[0]), float(d["Dst"].iloc[0]), round(3 * float(d["Kp"].iloc[0]))
    (1.01, 14.0, 5)
    """
    if not isinstance(path, (str, os.PathLike)):
        return _join_frames([read_drivers(one) for one in path])
    p = Path(path)
    fmt = detect_drivers_format(p)
    reader = {"qin_denton": _read_qin_denton, "omni2": _read_omni2, "hdf5": _read_hdf5,
              "csv": _read_csv}[fmt]
    index, columns, repairs = reader(p)
    return _make_frame(p, fmt, index, columns, repairs)


def _join_frames(frames: list) -> pd.DataFrame:
    if not frames:
        raise InputError("no driver files given")
    for before, after in zip(frames, frames[1:]):
        if after.index[0] <= before.index[-1]:
            raise InputError(f"records not strictly increasing across files: "
                             f"{after.index[0].isoformat()} follows "
                             f"{before.index[-1].isoformat()}", file=after.attrs["file"])
    joined = pd.concat(frames)
    formats = sorted({f.attrs["source_format"] for f in frames})
    joined.attrs = {"source_format": formats[0] if len(formats) == 1 else formats,
                    "file": [f.attrs["file"] for f in frames],
                    "repairs": [dict(r, file=f.attrs["file"]) for f in frames
                                for r in f.attrs["repairs"]],
                    "n_missing": {k: int(v) for k, v in joined.isna().sum().items()}}
    return joined


def drivers_at(drivers: pd.DataFrame, times, max_gap_s: float = 3 * 3600) -> dict:
    """IRBEM ``omnivals`` for the requested times, interpolated from a driver table.

    Each quantity is interpolated linearly in time between its neighbouring valid
    (non-NaN) records; Kp is taken as a step function (the value of the latest valid
    record at or before the time). A time gets NaN when it lies outside the range of a
    quantity's valid records or when its bracketing valid records are more than
    ``max_gap_s`` apart.

    Parameters
    ----------
    drivers : pandas.DataFrame
        As returned by :func:`read_drivers` (missing columns are treated as all NaN).
    times : array_like of datetime
        Query times (naive values are taken as UTC).
    max_gap_s : float
        Longest interval between valid records that is bridged, in seconds.

    Returns
    -------
    dict of str to numpy.ndarray
        All 16 keys of :data:`DRIVER_COLUMNS`, each a float array with one value per
        time. ``Kp`` is in the OMNI one-decimal form IRBEM expects (2- = 1.7), see
        :func:`magcal.indices.kp.kp_to_irbem`.

    Examples
    --------
    >>> idx = pd.DatetimeIndex(["2012-09-01T00:00", "2012-09-01T01:00"], tz="UTC", name="time")
    >>> d = pd.DataFrame({"Pdyn": [1.0, 2.0], "Kp": [5/3, 2.0]}, index=idx)
    >>> v = drivers_at(d, ["2012-09-01T00:30", "2012-09-01T02:00"])
    >>> v["Pdyn"], v["Kp"], len(v)
    (array([1.5, nan]), array([1.7, nan]), 16)
    """
    if max_gap_s < 0:
        raise ValueError("max_gap_s must be >= 0")
    t = utc_ns(times)
    rec = utc_ns(drivers.index)
    if rec.size > 1 and np.any(np.diff(rec) <= 0):
        raise InputError("driver records must be strictly increasing in time")
    gap_ns = int(round(max_gap_s * 1e9))
    out = {}
    for name in DRIVER_COLUMNS:
        if name not in drivers.columns:
            out[name] = np.full(t.shape, np.nan)
            continue
        values = np.asarray(drivers[name].to_numpy(), dtype=float)
        out[name] = _interp_gapped(rec, values, t, gap_ns, step=(name == "Kp"))
    out["Kp"] = kp_to_irbem(out["Kp"])
    return out


# ---------------------------------------------------------------------------- core
def _interp_gapped(rec_ns: np.ndarray, values: np.ndarray, t_ns: np.ndarray, gap_ns: int,
                   step: bool) -> np.ndarray:
    """Linear (or step) interpolation that leaves NaN across long gaps and outside."""
    good = np.isfinite(values)
    tr, vr = rec_ns[good], values[good]
    out = np.full(t_ns.shape, np.nan)
    if tr.size == 0:
        return out
    k = np.searchsorted(tr, t_ns, side="right") - 1
    inside = (k >= 0) & (t_ns <= tr[-1])
    kc = np.clip(k, 0, tr.size - 1)
    exact = inside & (tr[kc] == t_ns)
    k1 = np.clip(kc + 1, 0, tr.size - 1)
    between = inside & ~exact & (k1 > kc) & ((tr[k1] - tr[kc]) <= gap_ns)
    out[exact] = vr[kc[exact]]
    if step:
        out[between] = vr[kc[between]]
    else:
        span = (tr[k1[between]] - tr[kc[between]]).astype(float)
        frac = (t_ns[between] - tr[kc[between]]).astype(float) / span
        out[between] = vr[kc[between]] + frac * (vr[k1[between]] - vr[kc[between]])
    return out


# ---------------------------------------------------------------------------- readers
def _read_lines(p: Path) -> list[str]:
    try:
        return p.read_text(encoding="utf-8", errors="replace").splitlines()
    except OSError as exc:
        raise InputError(f"cannot read file ({exc.strerror})", file=p) from None


def _is_int(token: str) -> bool:
    try:
        int(token)
    except ValueError:
        return False
    return True


def _qd_layout(lines: list[str]) -> dict[str, int]:
    """Column of each driver in a Qin-Denton file, from its commented JSON header."""
    header = "\n".join(ln[1:] for ln in lines if ln.startswith("#"))
    start = header.find("{")
    if start < 0:
        return dict(_QD_DEFAULT)
    try:
        meta, _ = json.JSONDecoder().raw_decode(header[start:])
    except json.JSONDecodeError:
        return dict(_QD_DEFAULT)
    layout = {}
    for key, spec in meta.items():
        if not isinstance(spec, dict) or "START_COLUMN" not in spec:
            continue
        col = int(spec["START_COLUMN"])
        if key in _QD_NAMES:
            layout[_QD_NAMES[key]] = col
        elif key in ("G", "W"):
            for j, element in enumerate(spec.get("ELEMENT_NAMES", [])):
                if element in DRIVER_COLUMNS:
                    layout[element] = col + j
    return layout if "Pdyn" in layout else dict(_QD_DEFAULT)


def _read_qin_denton(p: Path):
    lines = _read_lines(p)
    layout = _qd_layout(lines)
    need = max(layout.values()) + 1
    times, rows = [], []
    for lineno, line in enumerate(lines, start=1):
        if not line.strip() or line.startswith("#"):
            continue
        tok = line.split()
        try:
            if len(tok) < need:
                raise ValueError(f"expected at least {need} fields, found {len(tok)}")
            stamp = pd.Timestamp(tok[0])
            rows.append([float(tok[layout[c]]) if c in layout else np.nan
                         for c in DRIVER_COLUMNS])
        except ValueError as exc:
            raise InputError(f"line {lineno}: not a Qin-Denton data line ({exc})",
                             file=p) from None
        times.append(stamp.tz_localize("UTC") if stamp.tzinfo is None else stamp)
    data = np.asarray(rows, dtype=float).reshape(-1, len(DRIVER_COLUMNS))
    columns = {c: data[:, j] for j, c in enumerate(DRIVER_COLUMNS)}
    repairs = []
    for name, values in columns.items():
        fill = np.abs(values) >= 1e30
        if fill.any():
            values[fill] = np.nan
            repairs.append({"what": "fill value replaced by NaN", "column": name,
                            "count": int(fill.sum())})
    return times, columns, repairs


def _read_omni2(p: Path):
    times, rows = [], []
    need = max(col for col, _ in _OMNI2_COLUMNS.values()) + 1
    for lineno, line in enumerate(_read_lines(p), start=1):
        if not line.strip():
            continue
        tok = line.split()
        try:
            if len(tok) < need:
                raise ValueError(f"expected at least {need} fields, found {len(tok)}")
            year, doy, hour = int(tok[0]), int(tok[1]), int(tok[2])
            if not (1 <= doy <= 366 and 0 <= hour <= 23 and 1900 <= year <= 2200):
                raise ValueError(f"year {year} day {doy} hour {hour} out of range")
            rows.append([float(tok[col]) for col, _ in _OMNI2_COLUMNS.values()])
        except ValueError as exc:
            raise InputError(f"line {lineno}: not an OMNI2 hourly data line ({exc})",
                             file=p) from None
        times.append(pd.Timestamp(year=year, month=1, day=1, tz="UTC")
                     + pd.Timedelta(days=doy - 1, hours=hour))
    data = np.asarray(rows, dtype=float).reshape(-1, len(_OMNI2_COLUMNS))
    columns, repairs = {}, []
    for j, (name, (_, fill_value)) in enumerate(_OMNI2_COLUMNS.items()):
        values = data[:, j].copy()
        fill = np.isclose(values, fill_value, rtol=0, atol=1e-6 * fill_value)
        values[fill] = np.nan
        if fill.any():
            repairs.append({"what": "fill value replaced by NaN", "column": name,
                            "count": int(fill.sum())})
        columns[name] = values
    columns["Kp"] = columns["Kp"] / 10.0
    return times, columns, repairs


def _read_hdf5(p: Path):
    import h5py

    try:
        handle = h5py.File(p, "r")
    except OSError as exc:
        raise InputError(f"cannot open HDF5 file ({exc})", file=p) from None
    with handle:
        if "UTC" not in handle:
            raise InputError("HDF5 driver file has no 'UTC' dataset (expected the "
                             "OMNItest.h5 layout)", file=p, column="UTC")
        raw = handle["UTC"][()]
        stamps = [s.decode() if isinstance(s, bytes) else str(s) for s in raw]
        columns = {name: _as_float64(handle[name][()])
                   for name in DRIVER_COLUMNS if name in handle}
    parsed = pd.to_datetime(pd.Series(stamps).str.strip(), utc=True, format="ISO8601",
                            errors="coerce")
    if parsed.isna().any():
        k = int(np.flatnonzero(parsed.isna().to_numpy())[0])
        raise InputError(f"record {k}: cannot parse UTC {stamps[k]!r}", file=p, column="UTC")
    repairs = []
    for name, values in columns.items():
        fill = (np.abs(values) >= 1e30) | (values == -9999.0)
        if fill.any():
            values[fill] = np.nan
            repairs.append({"what": "fill value replaced by NaN", "column": name,
                            "count": int(fill.sum())})
    return list(parsed), columns, repairs


def _as_float64(values) -> np.ndarray:
    """float64 copy; float32 values are taken at their shortest decimal form (37.8, not
    37.799999237...), which is what the file's writer meant."""
    arr = np.asarray(values)
    if arr.dtype == np.float32:
        return arr.astype(str).astype(np.float64)
    return arr.astype(np.float64)


def _read_csv(p: Path):
    from magcal.io.csv import read_csv_frame

    frame = read_csv_frame(p)
    lookup = {c.lower(): c for c in DRIVER_COLUMNS}
    columns = {}
    for col in frame.columns:
        key = col.strip().lower()
        name = lookup.get(key) or _ALIASES.get(key)
        if name is None:
            continue
        if name in columns:
            raise InputError(f"two columns give {name}", file=p, row=1, column=col)
        columns[name] = frame[col].to_numpy(dtype=float)
    if not columns:
        raise InputError("no driver columns found; expected some of "
                         + ", ".join(DRIVER_COLUMNS), file=p, row=1)
    return list(frame.index), columns, list(frame.attrs.get("repairs", []))


def _make_frame(p: Path, fmt: str, times, columns: dict, repairs: list) -> pd.DataFrame:
    if len(times) == 0:
        raise InputError(f"no driver records found (read as {fmt})", file=p)
    index = pd.DatetimeIndex(times, name="time")
    index = index.tz_localize("UTC") if index.tz is None else index.tz_convert("UTC")
    index = index.as_unit("ns")
    steps = np.diff(index.asi8)
    if np.any(steps <= 0):
        k = int(np.flatnonzero(steps <= 0)[0]) + 1
        raise InputError(f"records not strictly increasing in time at {index[k].isoformat()}",
                         file=p)
    n = len(index)
    data = {name: np.asarray(columns.get(name, np.full(n, np.nan)), dtype=float)
            for name in DRIVER_COLUMNS}
    try:
        data["Kp"] = snap_to_thirds(data["Kp"])
    except InputError as exc:
        raise InputError(exc.message, file=p, column="Kp") from None
    frame = pd.DataFrame(data, index=index, columns=list(DRIVER_COLUMNS))
    frame.attrs.update({"source_format": fmt, "file": str(p), "repairs": repairs,
                        "n_missing": {k: int(v) for k, v in frame.isna().sum().items()}})
    return frame
