"""Instrument files of any supported format, detected by content, as one kind of frame.

Every verb and :func:`magcal.chain.run_chain` read their inputs through :func:`read_any`,
which looks at a file's first bytes (not its name) and dispatches:

========================  ==============================================================
format                    recognised by
========================  ==============================================================
``csv``                   text (optionally gzip-compressed) whose header starts with
                          ``time`` (CONTRACTS §0)
``goes-netcdf``           HDF5/netCDF4 signature and GOES-R MAG L2 variables
                          (``b_epn``, ``b_ob_sensor``, ...): hires and 1-min averages
``cdf``                   CDF signature (ISTP files, magcal's own CDF products, ELFIN
                          FGS)
``netcdf``                HDF5/netCDF4 signature, ``Conventions = CF-...`` and a CF time
                          variable (magcal's own netCDF products, CF time series)
========================  ==============================================================

Anything else is an :class:`~magcal.errors.InputError` naming the file and the formats
supported. :func:`write_any` writes a frame as CSV, ISTP CDF or CF-1.8 netCDF4
(``magcal convert``).

The frame returned is the CONTRACTS §0 layout: a tz-aware UTC ``DatetimeIndex`` named
``time``, flat columns (``<sensor>_x``, ``Hp,He,Hn``, ``b1,b2,b3``, scalars), with
``attrs["format"]``, ``attrs["source"]`` and ``attrs["repairs"]``.
"""

from __future__ import annotations

import gzip
import os
from pathlib import Path

import numpy as np
import pandas as pd

from magcal.errors import InputError, not_a_file_error

#: Formats :func:`read_any` understands, for messages and ``--format`` choices.
FORMATS = ("csv", "goes-netcdf", "cdf", "netcdf")
_SUPPORTED = ("supported: CSV with a 'time' header (plain or gzip), GOES-R MAG L2 netCDF4 "
              "(hires or 1-min averages), ISTP CDF, CF netCDF4 time series")
_HDF5_MAGIC = b"\x89HDF\r\n\x1a\n"
_NETCDF3_MAGIC = (b"CDF\x01", b"CDF\x02", b"CDF\x05")
_CDF_MAGIC = (b"\xcd\xf3\x00\x01", b"\xcd\xf2\x60\x02", b"\xcc\xcc\x00\x01", b"\x00\x00\xff\xff")
_GOES_VARIABLES = ("b_epn", "b_ob_sensor", "b_ib_sensor", "b_gse")


def _head(path: Path, n: int = 512) -> bytes:
    try:
        with open(path, "rb") as handle:
            return handle.read(n)
    except OSError as exc:
        raise InputError(f"cannot read ({exc.strerror})", file=path) from None


def _text_head(raw: bytes, path: Path) -> str | None:
    """The first line of a text file (gzip allowed), or None if it is not text."""
    if raw[:2] == b"\x1f\x8b":
        try:
            with gzip.open(path, "rb") as handle:
                raw = handle.read(512)
        except (OSError, EOFError):
            return None
    if b"\x00" in raw:
        return None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        # a multi-byte character cut at the end of the block is still text
        try:
            text = raw[:-3].decode("utf-8")
        except UnicodeDecodeError:
            return None
    return text.lstrip("\ufeff").splitlines()[0] if text.strip() else ""


def _hdf5_variables(path: Path) -> set[str]:
    import h5py

    try:
        with h5py.File(path, "r") as handle:
            return set(handle.keys())
    except OSError as exc:
        raise InputError(f"HDF5/netCDF4 signature but unreadable ({exc})", file=path) from None


def detect_format(path: str | os.PathLike) -> str:
    """Name the format of a file from its content.

    Parameters
    ----------
    path : path-like
        The file.

    Returns
    -------
    str
        One of :data:`FORMATS`.

    Raises
    ------
    InputError
        Missing file, empty file, or content of no supported format (the message names
        the file and the formats supported).

    Examples
    --------
    >>> import tempfile, pathlib
    >>> p = pathlib.Path(tempfile.mkdtemp()) / "a.dat"
    >>> _ = p.write_text("time,Hp,He,Hn\\n2019-03-04T00:00:00,1,2,3\\n")
    >>> detect_format(p)
    'csv'
    """
    p = Path(path)
    if not p.is_file():
        raise not_a_file_error(p)
    raw = _head(p)
    if not raw:
        raise InputError(f"empty file; {_SUPPORTED}", file=p)
    if raw.startswith(_HDF5_MAGIC):
        names = _hdf5_variables(p)
        if any(v in names for v in _GOES_VARIABLES):
            return "goes-netcdf"
        from magcal.io.netcdf import is_magcal_netcdf

        if is_magcal_netcdf(p):
            return "netcdf"
        raise InputError("netCDF4/HDF5 file without GOES-R MAG L2 variables "
                         f"({', '.join(_GOES_VARIABLES)}); {_SUPPORTED}", file=p)
    if raw[:4] in _NETCDF3_MAGIC:
        raise InputError(f"classic netCDF-3 file; {_SUPPORTED}", file=p)
    if raw[:4] in _CDF_MAGIC:
        return "cdf"
    first = _text_head(raw, p)
    if first is None:
        raise InputError(f"binary content of no supported format; {_SUPPORTED}", file=p)
    if first.split(",")[0].strip().strip('"').lower() == "time":
        return "csv"
    shown = first[:60] + ("..." if len(first) > 60 else "")
    raise InputError(f"text whose first line ({shown!r}) is not a CSV header starting with "
                     f"'time'; {_SUPPORTED}", file=p, row=1)


def first_time(path: str | os.PathLike) -> pd.Timestamp | None:
    """The first sample's time of a CSV file (plain or gzip) from its first data line,
    without reading the rest; None for other formats or a line that does not parse
    (the reader will say why, later).

    Examples
    --------
    >>> import tempfile, pathlib
    >>> p = pathlib.Path(tempfile.mkdtemp()) / "d.csv"
    >>> _ = p.write_text("time,x\\n2019-11-02T00:00:00Z,1\\n")
    >>> str(first_time(p))
    '2019-11-02 00:00:00+00:00'
    """
    p = Path(path)
    try:
        opener = gzip.open if _head(p, 2) == b"\x1f\x8b" else open
        with opener(p, "rb") as handle:
            head = handle.readline()
            line = handle.readline()
    except (OSError, EOFError, InputError):
        return None
    if not head.lstrip(b"\xef\xbb\xbf").startswith(b"time"):
        return None
    try:
        stamp = pd.Timestamp(line.split(b",", 1)[0].decode("utf-8").strip())
    except (ValueError, UnicodeDecodeError):
        return None
    return stamp.tz_localize("UTC") if stamp.tzinfo is None else stamp.tz_convert("UTC")


def in_time_order(files: list) -> list:
    """``files`` sorted by their first sample (:func:`first_time`); a file whose first
    time cannot be peeked keeps its place after the file before it in name order. An
    archive's file names need not sort in time (a reprocessed day renamed, another
    naming scheme): the fit phase takes the first days of data, not of names."""
    keys, last = [], pd.Timestamp.min.tz_localize("UTC")
    for k, f in enumerate(files):
        t = first_time(f)
        last = t if t is not None else last
        keys.append((last, t is None, k))
    return [files[k] for *_, k in sorted(keys)]


def read_any(path: str | os.PathLike, fmt: str | None = None,
             required=None) -> pd.DataFrame:
    """Read one instrument file of any supported format into a CONTRACTS §0 frame.

    Parameters
    ----------
    path : path-like
        The file.
    fmt : str, optional
        One of :data:`FORMATS`; detected from the content when omitted or ``"auto"``.
    required : iterable of str, optional
        Columns that must be present (checked for every format).

    Returns
    -------
    pandas.DataFrame
        UTC index named ``time``; ``attrs``: ``format``, ``source`` (list of files),
        ``repairs``.

    Raises
    ------
    InputError
        Unsupported or unreadable content, or a required column missing.
    """
    p = Path(path)
    kind = detect_format(p) if fmt in (None, "auto") else fmt
    if kind not in FORMATS:
        raise InputError(f"unknown format {fmt!r}; {_SUPPORTED}", file=p)
    if kind == "csv":
        from magcal.io.csv import read_csv_frame

        frame = read_csv_frame(p, required=required)
    elif kind == "goes-netcdf":
        from magcal.missions.goes import read_goes_mag

        frame = read_goes_mag(p)
    elif kind == "netcdf":
        from magcal.io.netcdf import read_netcdf_frame

        frame = read_netcdf_frame(p)
        frame.attrs.pop("provenance", None)
        frame = frame[[c for c in frame.columns if frame[c].dtype.kind in "fiu"]]
    else:
        frame = read_cdf_frame(p)
    if required is not None:
        missing = [c for c in required if c not in frame.columns]
        if missing:
            raise InputError(f"missing column(s) {', '.join(missing)} (the {kind} file has "
                             f"{', '.join(map(str, frame.columns))})", file=p,
                             column=missing[0])
    frame.attrs["format"] = kind
    frame.attrs.setdefault("source", [str(p)])
    if isinstance(frame.attrs["source"], str):
        frame.attrs["source"] = [frame.attrs["source"]]
    frame.attrs.setdefault("repairs", [])
    return frame


def _labels(data, name: str, k: int) -> list[str]:
    ptr = data.var_attrs.get(name, {}).get("LABL_PTR_1")
    if ptr and ptr in data.variables:
        labels = [str(v).strip() for v in np.asarray(data[ptr]).ravel()]
        if len(labels) == k:
            return labels
    return [str(i + 1) for i in range(k)]


def read_cdf_frame(path: str | os.PathLike) -> pd.DataFrame:
    """An ISTP CDF file as a frame: the data variables on the first epoch variable.

    Vector variables become ``<name>_<label>`` columns (labels from ``LABL_PTR_1``; the
    variable ``B`` of magcal's own products gives bare ``Hp,He,Hn`` or ``x,y,z``);
    ELFIN FGS files give ``b1,b2,b3`` counts (see
    :func:`magcal.missions.elfin.files.read_elfin_fgs`).

    Raises
    ------
    InputError
        No epoch variable, or no data variable on it.
    """
    import re

    from magcal.io.cdf import read_cdf
    from magcal.missions.elfin.files import read_elfin_fgs
    from magcal.timeconv import utc_index

    p = Path(path)
    data = read_cdf(p)
    if any(re.fullmatch(r"el[ab]_fgs", n) for n in data):
        return read_elfin_fgs(p)
    epochs = [n for n, v in data.variables.items()
              if np.asarray(v).dtype.kind == "M" and np.asarray(v).ndim == 1]
    if not epochs:
        raise InputError("CDF file without an epoch variable (CDF_EPOCH, CDF_EPOCH16 or "
                         "CDF_TIME_TT2000)", file=p)
    epoch = "Epoch" if "Epoch" in epochs else epochs[0]
    n = np.asarray(data[epoch]).size
    columns: dict[str, np.ndarray] = {}
    for name, values in data.variables.items():
        attrs = data.var_attrs.get(name, {})
        arr = np.asarray(values)
        if name == epoch or arr.dtype.kind not in "fiu" or arr.shape[:1] != (n,):
            continue
        if attrs.get("DEPEND_0", epoch) != epoch or attrs.get("VAR_TYPE", "data") != "data":
            continue
        if arr.ndim == 1:
            columns[name] = arr.astype(float)
        elif arr.ndim == 2:
            for k, label in enumerate(_labels(data, name, arr.shape[1])):
                columns[label if name == "B" else f"{name}_{label}"] = arr[:, k].astype(float)
    if not columns:
        raise InputError(f"no numeric data variable depends on {epoch!r}", file=p,
                         column=epoch)
    frame = pd.DataFrame(columns, index=utc_index(data[epoch], name="time"))
    bad = frame.index.isna()
    repairs = []
    if bad.any():
        frame = frame[~bad]
        repairs.append({"what": "records without a valid epoch dropped", "column": epoch,
                        "count": int(bad.sum())})
    fills = {k: int(v) for k, v in data.fill_counts.items() if v and k in columns}
    repairs += [{"what": "fill value replaced by NaN", "column": k, "count": v}
                for k, v in fills.items()]
    frame.attrs.update({"source": [str(p)], "repairs": repairs})
    return frame


def _vector_groups(columns) -> tuple[dict[str, list[str]], list[str]]:
    """Group flat columns into CDF vector variables (``B`` for bare components)."""
    from magcal.timeseries import _split_flat_columns

    pairs, aux = _split_flat_columns(columns)
    groups: dict[str, list[str]] = {}
    for sensor, comp in pairs:
        groups.setdefault(sensor or "B", []).append(comp)
    return groups, aux


def write_any(path: str | os.PathLike, frame: pd.DataFrame, fmt: str,
              provenance: dict | None = None) -> Path:
    """Write a CONTRACTS §0 frame as ``csv``, ISTP ``cdf`` or CF-1.8 ``netcdf`` (atomically).

    Examples
    --------
    >>> import tempfile, pathlib
    >>> d = pathlib.Path(tempfile.mkdtemp())
    >>> t = pd.date_range("2019-03-04", periods=2, freq="1s", tz="UTC", name="time")
    >>> f = pd.DataFrame({"Hp": [1.0, 2.0], "He": [3.0, 4.0], "Hn": [5.0, np.nan]}, index=t)
    >>> back = read_any(write_any(d / "a.cdf", f, "cdf"))
    >>> back[["Hp", "He", "Hn"]].to_numpy().tolist()
    [[1.0, 3.0, 5.0], [2.0, 4.0, nan]]
    """
    target = Path(path)
    if fmt == "csv":
        from magcal.io.csv import write_csv_frame

        return write_csv_frame(target, frame, provenance=provenance)
    if fmt == "netcdf":
        from magcal.io.netcdf import write_netcdf_frame

        names = ", ".join(Path(s).name for s in frame.attrs.get("source", [])) or "magcal"
        return write_netcdf_frame(target, frame, provenance=provenance,
                                  title=f"converted by magcal from {names}")
    if fmt != "cdf":
        raise InputError(f"cannot write format {fmt!r} (use csv, cdf or netcdf)", file=target)
    from magcal.io.cdf import write_cdf_product

    groups, aux = _vector_groups(frame.columns)
    variables = {}
    for name, comps in groups.items():
        cols = [c if name == "B" else f"{name}_{c}" for c in comps]
        variables[name] = (frame[cols].to_numpy(dtype=float),
                           {"UNITS": "nT", "labels": list(comps),
                            "CATDESC": f"magnetic field {name} ({', '.join(comps)})"})
    for col in aux:
        unit = "deg" if col.endswith("_deg") else ("RE" if col.endswith("_re") else " ")
        variables[col] = (frame[col].to_numpy(dtype=float), {"UNITS": unit})
    source = ", ".join(Path(s).name for s in frame.attrs.get("source", [])) or "magcal"
    globals_ = {"Project": "magcal", "Source_name": "magcal>converted",
                "Data_type": "converted>Converted", "Descriptor": "MAG>Magnetometer",
                "Logical_source_description": f"converted from {source}",
                "PI_name": "unknown", "PI_affiliation": "unknown",
                "Mission_group": "magcal", "TEXT": f"Converted by magcal from {source}"}
    return write_cdf_product(target, frame.index, variables, globals_, provenance=provenance)


def convert_files(inputs, output: str | os.PathLike, fmt: str, *,
                  input_format: str = "auto") -> pd.DataFrame:
    """Read files of any supported format, join them in time order and write ``output``.

    Returns the frame written (``attrs["formats"]`` lists the input formats). Exact
    duplicate samples of overlapping files are dropped and counted in the provenance;
    conflicting values at one time are an error naming the time.
    """
    from magcal.provenance import make_provenance

    paths = [Path(p) for p in inputs]
    frames = [read_any(p, input_format) for p in paths]
    from magcal.timeseries import validate_frame

    joined = pd.concat(frames, axis=0, sort=False).sort_index(kind="stable")
    repairs = [dict(r, file=str(p)) for f, p in zip(frames, paths)
               for r in f.attrs.get("repairs", [])]
    # the same duplicate policy as the chain's input: exact copies dropped and counted,
    # different values at one time refused
    joined, report = validate_frame(joined, on_duplicate="drop", mixed_cadence="allow",
                                    source=paths[0])
    repairs += [dict(r.__dict__, column="time") for r in report.repairs]
    joined.attrs["formats"] = [f.attrs.get("format", "?") for f in frames]
    joined.attrs["source"] = [str(p) for p in paths]
    prov = make_provenance("convert", {"format": fmt, "repairs": repairs}, inputs=paths)
    write_any(output, joined, fmt, provenance=prov)
    return joined
