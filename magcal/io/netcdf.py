"""magcal's products as CF-1.8 netCDF4 files (through h5netcdf), and reading them back.

Every column of a frame becomes a variable of the same name on the index's dimension
(``time`` for time series, ``center`` for the offset windows), compressed (zlib level 1
with shuffle: fast to write, about a third of the float64 bytes for field data), with
``units``, ``long_name`` and ``standard_name`` where CF has one (:mod:`magcal.io.variables`).
Times are CF time: int64 ``nanoseconds since 1970-01-01T00:00:00Z`` (exact at any
cadence). The ``quality`` column is a CF flag variable (``flag_masks``,
``flag_meanings``). The provenance is the ``provenance`` global attribute (JSON text)
beside ``Conventions``, ``title``, ``history``, ``source`` and ``magcal_version``.

The writer writes no timestamp into the file: the same frame gives the same bytes
(reruns leave byte-identical products).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pandas as pd

from magcal._version import __version__
from magcal.errors import InputError
from magcal.io.atomic import atomic_path
from magcal.io.variables import describe

#: Units of CF time variables written.
TIME_UNITS = "nanoseconds since 1970-01-01T00:00:00Z"
#: Fill of integer variables (the int64 ISTP fill, the same as in CDF products).
INT_FILL = np.int64(-9223372036854775808)
_COMPRESSION = {"compression": "gzip", "compression_opts": 1, "shuffle": True}


def _utc_ns(values) -> np.ndarray:
    t = pd.DatetimeIndex(values)
    if t.tz is not None:
        t = t.tz_convert("UTC").tz_localize(None)
    if t.isna().any():
        raise ValueError("times must not be NaT")
    return t.as_unit("ns").asi8


def _column_data(series: pd.Series):
    """``(array, fill)`` of one column: float (NaN fill), int (INT_FILL for NA),
    datetime (int64 ns), or str."""
    dtype = series.dtype
    if isinstance(dtype, pd.DatetimeTZDtype) or dtype.kind == "M":
        return _utc_ns(series), None, "time"
    if dtype.kind == "O" or isinstance(dtype, pd.StringDtype):
        return np.array(["" if v is None or v is pd.NA else str(v) for v in series],
                        dtype=object), None, "str"
    if pd.api.types.is_bool_dtype(dtype):
        return series.to_numpy(dtype=np.int8), None, "int"
    if pd.api.types.is_integer_dtype(dtype):
        if series.isna().any():
            return series.to_numpy(dtype=np.int64, na_value=INT_FILL), INT_FILL, "int"
        return series.to_numpy(), None, "int"
    return series.to_numpy(dtype=np.float64), np.float64(np.nan), "float"


def write_netcdf_frame(path: str | os.PathLike, frame: pd.DataFrame, *,
                       title: str = "magcal product", provenance: dict | None = None,
                       attrs: dict | None = None) -> Path:
    """Write a frame with a UTC DatetimeIndex as a CF-1.8 netCDF4 file, atomically.

    Parameters
    ----------
    path : path-like
    frame : pandas.DataFrame
        Index: DatetimeIndex (tz-aware or naive UTC); its name (default ``time``) names
        the dimension. Columns: float, integer (nullable allowed), datetime or text.
    title : str
        The ``title`` global attribute.
    provenance : dict, optional
        Stored as JSON text in the ``provenance`` global attribute.
    attrs : dict, optional
        Per-column attribute overrides (``{column: {attr: value}}``).

    Returns
    -------
    pathlib.Path

    Examples
    --------
    >>> import tempfile, pathlib, xarray as xr
    >>> t = pd.date_range("2019-03-04", periods=3, freq="100ms", tz="UTC", name="time")
    >>> f = pd.DataFrame({"Hp": [1.0, np.nan, 3.0], "quality": [0, 4, 0]}, index=t)
    >>> p = write_netcdf_frame(pathlib.Path(tempfile.mkdtemp()) / "a.nc", f)
    >>> with xr.open_dataset(p, engine="h5netcdf") as ds:
    ...     print(ds["Hp"].attrs["units"], ds["quality"].attrs["flag_meanings"].split()[2])
    nT fill_or_nonfinite
    """
    import h5netcdf

    from magcal.io.jsonio import to_jsonable

    if not isinstance(frame.index, pd.DatetimeIndex):
        raise TypeError("frame must have a DatetimeIndex")
    dim = frame.index.name or "time"
    t = _utc_ns(frame.index)
    if len(t) > 1 and not (np.diff(t) > 0).all():
        raise ValueError("times must be strictly increasing")
    overrides = attrs or {}
    n = len(t)
    chunk = (min(max(n, 1), 262_144),)
    # small tables (the offset windows): contiguous, without the chunk index overhead
    packing = {"chunks": chunk, **_COMPRESSION} if n >= 4096 else {}
    target = Path(path)
    with atomic_path(target) as tmp:
        with h5netcdf.File(tmp, "w", track_order=True) as f:
            f.attrs["Conventions"] = "CF-1.8"
            f.attrs["title"] = title
            f.attrs["institution"] = "magcal (spacemagcal)"
            f.attrs["source"] = "magcal " + __version__
            f.attrs["history"] = f"written by magcal {__version__}"
            f.attrs["magcal_version"] = __version__
            if provenance is not None:
                f.attrs["provenance"] = json.dumps(to_jsonable(dict(provenance)),
                                                   sort_keys=True)
            f.dimensions[dim] = n
            v = f.create_variable(dim, (dim,), np.int64, data=t, **packing)
            v.attrs.update({"units": TIME_UNITS, "calendar": "standard", "axis": "T",
                            **describe(dim), "standard_name": "time",
                            **overrides.get(dim, {})})
            for column in frame.columns:
                name = str(column)
                data, fill, kind = _column_data(frame[column])
                meta = {**describe(name), **overrides.get(name, {})}
                if kind == "str":
                    import h5py

                    v = f.create_variable(name, (dim,), h5py.string_dtype(), data=data)
                    meta.pop("units", None)
                elif kind == "time":
                    v = f.create_variable(name, (dim,), np.int64, data=data, **packing)
                    meta.update({"units": TIME_UNITS, "calendar": "standard"})
                else:
                    if "flag_masks" in meta:
                        data = data.astype(np.int32)
                        meta["flag_masks"] = np.asarray(meta["flag_masks"], dtype=np.int32)
                    if "flag_values" in meta:  # CF: of the variable's type
                        meta["flag_values"] = np.asarray(meta["flag_values"], dtype=data.dtype)
                    v = f.create_variable(name, (dim,), data.dtype, data=data,
                                          fillvalue=fill, **packing)
                v.attrs.update(meta)
    return target


def is_magcal_netcdf(path: str | os.PathLike) -> bool:
    """Whether an HDF5 file is a CF netCDF4 file with a time dimension (magcal's own
    products, or any CF time series on one dimension)."""
    import h5py

    with h5py.File(path, "r") as f:
        conv = f.attrs.get("Conventions", b"")
        conv = conv.decode() if isinstance(conv, bytes) else str(conv)
        return conv.startswith("CF") and any(
            "since" in _text(f[k].attrs.get("units", "")) for k in f.keys()
            if hasattr(f[k], "shape") and len(f[k].shape) == 1)


def _text(value) -> str:
    return value.decode() if isinstance(value, bytes) else str(value)


def _decode_time(values: np.ndarray, units: str, where: Path) -> np.ndarray:
    step, _, origin = units.partition(" since ")
    factor = {"nanoseconds": 1, "microseconds": 1_000, "milliseconds": 1_000_000,
              "seconds": 1_000_000_000, "minutes": 60_000_000_000,
              "hours": 3_600_000_000_000, "days": 86_400_000_000_000}.get(step.strip())
    if factor is None or not origin:
        raise InputError(f"time units {units!r} not understood", file=where)
    t0 = pd.Timestamp(origin.strip().replace("Z", "")).as_unit("ns").value
    if values.dtype.kind in "iu":
        return (values.astype(np.int64) * factor + t0).astype("datetime64[ns]")
    return (np.round(values * factor) + t0).astype(np.int64).astype("datetime64[ns]")


def read_netcdf_frame(path: str | os.PathLike, columns=None) -> pd.DataFrame:
    """A CF netCDF4 time series (magcal's products) as a frame on its time dimension.

    Every 1-D variable on the dimension becomes a column of the same name (fills as NaN
    for floats, ``<NA>`` for integers; CF time variables as UTC datetimes; the
    ``quality`` flag as integers). ``attrs``: ``provenance`` (dict) when present.

    Raises
    ------
    InputError
        No CF time variable, or unreadable file.
    """
    import h5py

    p = Path(path)
    try:
        f = h5py.File(p, "r")
    except OSError as exc:
        raise InputError(f"unreadable netCDF4 file ({exc})", file=p) from None
    with f:
        dims = [k for k in f.keys() if isinstance(f[k], h5py.Dataset) and f[k].ndim == 1
                and "since" in _text(f[k].attrs.get("units", ""))
                and _text(f[k].attrs.get("standard_name", "time")) == "time"]
        if not dims:
            raise InputError("netCDF4 file without a CF time variable", file=p)
        dim = "time" if "time" in dims else dims[0]
        n = f[dim].shape[0]
        index = pd.DatetimeIndex(_decode_time(f[dim][()], _text(f[dim].attrs["units"]), p),
                                 name=dim).tz_localize("UTC")
        out = {}
        for name, ds in f.items():
            if name == dim or not isinstance(ds, h5py.Dataset) or ds.shape != (n,):
                continue
            if columns is not None and name not in columns:
                continue
            values = ds[()]
            units = _text(ds.attrs.get("units", ""))
            fill = ds.attrs.get("_FillValue")
            if values.dtype.kind in "OS":
                out[name] = [_text(v) for v in values]
            elif "since" in units:
                out[name] = pd.DatetimeIndex(_decode_time(values, units, p)).tz_localize("UTC")
            elif values.dtype.kind in "iu":
                col = pd.array(values, dtype="Int64")
                if fill is not None:
                    col[values == fill] = pd.NA
                out[name] = col if col.isna().any() else values
            else:
                out[name] = values.astype(float)
        prov = f.attrs.get("provenance")
    frame = pd.DataFrame(out, index=index)
    if prov is not None:
        frame.attrs["provenance"] = json.loads(_text(prov))
    frame.attrs["source"] = [str(p)]
    return frame
