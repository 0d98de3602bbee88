"""magcal's products in the field's formats: CSV, CF-1.8 netCDF4 or ISTP CDF, chosen by
name, with the same columns as variables of the same names (CONTRACTS §7.1).

:func:`write_product` writes a frame (UTC DatetimeIndex, any columns) in one of
:data:`PRODUCT_FORMATS`; :func:`read_product` reads any of them back into the same
frame. Column units and descriptions come from :mod:`magcal.io.variables`, so a column a
stage adds (``quality``, ``Hp_se``...) is described in every format at once.

Examples
--------
>>> import tempfile, pathlib
>>> t = pd.date_range("2019-03-04", periods=2, freq="1s", tz="UTC", name="time")
>>> f = pd.DataFrame({"Hp": [1.0, np.nan], "quality": [0, 4]}, index=t)
>>> d = pathlib.Path(tempfile.mkdtemp())
>>> back = read_product(write_product(d / "a.cdf", f, "cdf"))
>>> back["Hp"].tolist(), back["quality"].tolist()
([1.0, nan], [0, 4])
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pandas as pd

from magcal.errors import InputError
from magcal.io.variables import describe

#: Formats a product can be written in (``[output] format``).
PRODUCT_FORMATS = ("csv", "netcdf", "cdf")
#: File suffix of each product format.
SUFFIX = {"csv": ".csv", "netcdf": ".nc", "cdf": ".cdf"}
#: The product format of each input format (``[output] format = "auto"``).
FAMILY = {"csv": "csv", "goes-netcdf": "netcdf", "netcdf": "netcdf", "cdf": "cdf"}
#: Columns written as ISTP support data (flags, text, other times) rather than data.
SUPPORT_COLUMNS = ("quality", "offset_flag", "reason", "start", "end")
#: Physical range of field values (nT) written as VALIDMIN/VALIDMAX.
FIELD_RANGE_NT = (-100_000.0, 100_000.0)


def format_from_suffix(path: str | os.PathLike) -> str:
    """The product format of a file name (``.csv``, ``.nc``, ``.cdf``)."""
    suffix = Path(path).suffix.lower()
    for fmt, s in SUFFIX.items():
        if s == suffix:
            return fmt
    raise InputError(f"cannot tell the product format from the suffix {suffix!r} (use "
                     f"{', '.join(SUFFIX.values())})", file=Path(path))


def write_product(path: str | os.PathLike, frame: pd.DataFrame, fmt: str | None = None, *,
                  title: str = "magcal product", provenance: dict | None = None,
                  float_format: str = "%.6f") -> Path:
    """Write a product frame as CSV, CF netCDF4 or ISTP CDF, atomically.

    Parameters
    ----------
    path : path-like
    frame : pandas.DataFrame
        UTC DatetimeIndex (its name names the time dimension/column), any columns.
    fmt : {"csv", "netcdf", "cdf"}, optional
        Default: from the file suffix.
    title : str
        Description of the product (netCDF ``title``, CDF ``Logical_source_description``).
    provenance : dict, optional
        CSV: ``<path>.provenance.json`` beside it; netCDF/CDF: a global attribute.
    float_format : str
        CSV only: printf format of floats (binary formats keep full float64).

    Returns
    -------
    pathlib.Path
    """
    fmt = fmt or format_from_suffix(path)
    if fmt == "csv":
        from magcal.io.csv import write_csv_frame

        out = frame.copy()
        out.index = out.index.rename("time")
        return write_csv_frame(path, out, float_format=float_format, provenance=provenance)
    if fmt == "netcdf":
        from magcal.io.netcdf import write_netcdf_frame

        return write_netcdf_frame(path, frame, title=title, provenance=provenance)
    if fmt == "cdf":
        return write_cdf_frame(path, frame, title=title, provenance=provenance)
    raise InputError(f"unknown product format {fmt!r} (use {', '.join(PRODUCT_FORMATS)})",
                     file=Path(path))


def cdf_attributes(column: str, values: np.ndarray) -> dict:
    """ISTP variable attributes of a product column (the rest are filled in by
    :func:`magcal.io.cdf.write_cdf_product`)."""
    meta = describe(column)
    units = meta.get("units", " ")
    attrs = {"FIELDNAM": column, "CATDESC": meta.get("long_name", column)[:80],
             "UNITS": " " if units == "1" else units, "LABLAXIS": column,
             "DISPLAY_TYPE": "time_series"}
    if column in SUPPORT_COLUMNS or values.dtype.kind in "MUO":
        attrs["VAR_TYPE"] = "support_data"
    if column == "quality":
        attrs.update({"VALIDMIN": np.int32(0),
                      "VALIDMAX": np.int32(sum(meta["flag_masks"])),
                      "FLAG_MASKS": [int(m) for m in meta["flag_masks"]],
                      "FLAG_MEANINGS": meta["flag_meanings"],
                      "VAR_NOTES": meta["long_name"]})
    elif units == "nT" and values.dtype.kind == "f":
        attrs.update({"VALIDMIN": FIELD_RANGE_NT[0], "VALIDMAX": FIELD_RANGE_NT[1]})
    return attrs


def _cdf_values(series: pd.Series) -> np.ndarray:
    from magcal.io.netcdf import INT_FILL

    dtype = series.dtype
    if isinstance(dtype, pd.DatetimeTZDtype):
        return series.dt.tz_convert("UTC").dt.tz_localize(None).to_numpy("datetime64[ns]")
    if dtype.kind == "M":
        return series.to_numpy("datetime64[ns]")
    if dtype.kind == "O" or isinstance(dtype, pd.StringDtype):
        return np.array(["" if v is None or v is pd.NA else str(v) for v in series],
                        dtype=object)
    if pd.api.types.is_bool_dtype(dtype):
        return series.to_numpy(dtype=np.int8)
    if pd.api.types.is_integer_dtype(dtype):
        if series.isna().any():
            return series.to_numpy(dtype=np.int64, na_value=INT_FILL)
        values = series.to_numpy()
        return values.astype(np.int32) if series.name == "quality" else values
    return series.to_numpy(dtype=np.float64)


def write_cdf_frame(path: str | os.PathLike, frame: pd.DataFrame, *,
                    title: str = "magcal product", provenance: dict | None = None) -> Path:
    """Write a product frame as an ISTP CDF: ``Epoch`` (TT2000) from the index, every
    column a scalar variable of the same name (the index, when not named ``time``, also
    as a TT2000 variable of its name)."""
    from magcal.io.cdf import write_cdf_product

    if not isinstance(frame.index, pd.DatetimeIndex):
        raise TypeError("frame must have a DatetimeIndex")
    variables = {}
    if frame.index.name not in (None, "time"):
        name = str(frame.index.name)
        variables[name] = (_cdf_values(frame.index.to_series()),
                           {**cdf_attributes(name, np.array([], "M8[ns]")),
                            "VAR_TYPE": "support_data"})
    for column in frame.columns:
        values = _cdf_values(frame[column])
        variables[str(column)] = (values, cdf_attributes(str(column), values))
    globals_ = {"Project": "magcal", "Source_name": "magcal>magcal products",
                "Data_type": "product>magcal product", "Descriptor": "MAG>Magnetometer",
                "Logical_source_description": title, "PI_name": "unknown",
                "PI_affiliation": "unknown", "Mission_group": "magcal",
                "TEXT": f"{title}; written by magcal (columns as variables of the same names)"}
    # uncompressed: the same bytes for the same data (cdflib's gzip headers hold the
    # time of writing) and a 10 Hz day written 5x faster
    return write_cdf_product(path, frame.index, variables, globals_, provenance=provenance,
                             compress=0)


def read_product(path: str | os.PathLike) -> pd.DataFrame:
    """Read a product written by :func:`write_product` (format from the suffix) into
    its frame: UTC index, every column (flags as integers, texts as str)."""
    p = Path(path)
    fmt = format_from_suffix(p)
    if fmt == "netcdf":
        from magcal.io.netcdf import read_netcdf_frame

        return read_netcdf_frame(p)
    if fmt == "csv":
        from magcal.io.csv import read_csv_frame

        return read_csv_frame(p)
    return _read_cdf_product(p)


def _read_cdf_product(p: Path) -> pd.DataFrame:
    import json

    from magcal.io.cdf import read_cdf

    data = read_cdf(p)
    index = pd.DatetimeIndex(data["Epoch"], name="time").tz_localize("UTC")
    n = len(index)
    out = {}
    for name, values in data.variables.items():
        attrs = data.var_attrs.get(name, {})
        arr = np.asarray(values)
        if name == "Epoch" or attrs.get("DEPEND_0") != "Epoch" or arr.shape != (n,):
            continue
        if arr.dtype.kind == "M":
            out[name] = pd.DatetimeIndex(arr).tz_localize("UTC")
        elif arr.dtype.kind in "US":
            out[name] = [str(v).rstrip() for v in arr]
        elif data.fill_counts.get(name) and attrs.get("UNITS") != "nT" and \
                np.asarray(attrs.get("FILLVAL", 0)).dtype.kind in "iu":
            col = pd.array(np.where(np.isnan(arr), 0, arr).astype(np.int64), dtype="Int64")
            col[np.isnan(arr)] = pd.NA
            out[name] = col
        else:
            out[name] = arr
    frame = pd.DataFrame(out, index=index)
    for name in [c for c in frame.columns if frame[c].dtype.kind == "M"
                 or isinstance(frame[c].dtype, pd.DatetimeTZDtype)]:
        if name not in ("start", "end"):
            frame = frame.set_index(name, drop=True)
            break
    prov = data.global_attrs.get("Provenance")
    if prov:
        frame.attrs["provenance"] = json.loads(prov)
    frame.attrs["source"] = [str(p)]
    return frame
