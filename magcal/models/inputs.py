"""Inputs of the model field at the spacecraft: position, Kp and solar-wind drivers.

One home for what ``magcal model``, ``magcal offsets fit`` and the chain runner need
before a model can be evaluated: the spacecraft position (a geostationary longitude,
or ``lon_deg, lat_deg, r_re`` columns of the data), the Kp series and, for T96, T01 and
TS04, the solar-wind drivers. Every problem is an :class:`~magcal.errors.InputError`
naming the file, row or column.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from magcal.errors import InputError

if TYPE_CHECKING:  # pragma: no cover
    import pandas as pd

#: Geocentric distance of a geostationary spacecraft in Earth radii.
GEO_R_RE = 6.6
#: Columns that give the position per sample (geographic, degrees and Earth radii).
POSITION_COLUMNS = ("lon_deg", "lat_deg", "r_re")
#: Models that need solar-wind drivers besides Kp.
DRIVEN_MODELS = ("T96", "T01", "T04")
#: Models this module knows (IGRF alone, or IGRF plus a Tsyganenko model).
MODELS = ("IGRF", "T89") + DRIVEN_MODELS


@dataclass(frozen=True)
class ModelInputs:
    """Everything the model field needs besides the sample times.

    Attributes
    ----------
    lon_deg, lat_deg, r_re : float or ndarray
        Geographic position: scalars for a geostationary spacecraft, else one value
        per row of the data.
    kp : pandas.Series
        Kp in thirds, indexed by the start of each 3-hour interval (see
        :func:`magcal.indices.read_kp`).
    drivers : pandas.DataFrame or None
        Hourly IRBEM inputs (see :func:`magcal.indices.read_drivers`), None without
        a drivers file.
    model : str
        ``IGRF``, ``T89``, ``T96``, ``T01`` or ``T04``.
    files : tuple of str
        The input files read (Kp, then drivers), for provenance.
    """

    lon_deg: float | np.ndarray
    lat_deg: float | np.ndarray
    r_re: float | np.ndarray
    kp: pd.Series
    drivers: pd.DataFrame | None
    model: str
    files: tuple = ()

    def position(self) -> tuple:
        """``(lon_deg, lat_deg, r_re)`` as given to the model field functions."""
        return self.lon_deg, self.lat_deg, self.r_re


def frame_source(frame) -> str | None:
    """The file a frame was read from, for messages (``attrs["source"]``: str or list)."""
    src = frame.attrs.get("source")
    if isinstance(src, (list, tuple)):
        return ", ".join(map(str, src)) if src else None
    return None if src is None else str(src)


def _check_column(values: np.ndarray, name: str, lo: float, hi: float, src) -> None:
    """Raise at the first finite value of a position column outside ``[lo, hi]``."""
    with np.errstate(invalid="ignore"):
        bad = np.isfinite(values) & ((values < lo) | (values > hi))
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        raise InputError(f"{name} = {values[k]:g} outside [{lo:g}, {hi:g}]", file=src,
                         row=k + 2, column=name)


def position_from(frame: pd.DataFrame, longitude_deg: float | None = None) -> tuple:
    """Spacecraft position for the rows of ``frame``.

    Parameters
    ----------
    frame : pandas.DataFrame
        The data, as read by :func:`magcal.io.formats.read_any` (``attrs["source"]``
        names the file in errors).
    longitude_deg : float, optional
        Geostationary longitude in degrees east; the spacecraft is then at latitude 0
        and ``GEO_R_RE`` Earth radii. Without it the frame needs the columns
        ``lon_deg, lat_deg, r_re``.

    Returns
    -------
    tuple
        ``(lon_deg, lat_deg, r_re)``: floats for a geostationary longitude, else arrays
        with one value per row.

    Raises
    ------
    InputError
        Longitude not an angle, missing position columns, latitude outside
        [-90, 90] or a radius below 1 Earth radius.

    Examples
    --------
    >>> import pandas as pd
    >>> position_from(pd.DataFrame({"Hp": [1.0]}), longitude_deg=128.2)
    (128.2, 0.0, 6.6)
    """
    src = frame_source(frame)
    if longitude_deg is not None:
        lon = float(longitude_deg)
        if not np.isfinite(lon) or not -360.0 <= lon <= 360.0:
            raise InputError(f"longitude {longitude_deg} is not an angle in degrees")
        return lon, 0.0, GEO_R_RE
    missing = [c for c in POSITION_COLUMNS if c not in frame.columns]
    if missing:
        raise InputError("give a geostationary longitude (--longitude) or columns "
                         f"lon_deg,lat_deg,r_re (missing {', '.join(missing)})", file=src,
                         column=missing[0])
    lon, lat, r = (frame[c].to_numpy(dtype=float) for c in POSITION_COLUMNS)
    _check_column(lon, "lon_deg", -360.0, 360.0, src)
    _check_column(lat, "lat_deg", -90.0, 90.0, src)
    _check_column(r, "r_re", 1.0, 1000.0, src)
    return lon, lat, r


def model_inputs(frame: pd.DataFrame, *, longitude_deg: float | None,
                 kp_path: str | os.PathLike, drivers_path: str | os.PathLike | None = None,
                 model: str = "T89") -> ModelInputs:
    """Read and check the model inputs for the rows of ``frame``.

    Parameters
    ----------
    frame : pandas.DataFrame
        The data (its position columns are used without ``longitude_deg``).
    longitude_deg : float or None
        Geostationary longitude (see :func:`position_from`).
    kp_path : path-like
        Kp file in any format :func:`magcal.indices.read_kp` detects.
    drivers_path : path-like, optional
        Solar-wind drivers (:func:`magcal.indices.read_drivers`); required by T96, T01
        and T04.
    model : str
        ``IGRF``, ``T89`` (default), ``T96``, ``T01`` or ``T04``.

    Returns
    -------
    ModelInputs

    Raises
    ------
    InputError
        Unknown model, bad position, unreadable Kp or drivers file, a driven model
        without drivers, or a Kp file that does not cover the data (T89).
    """
    from magcal.indices import kp_at, read_drivers, read_kp

    name = str(model).upper()
    if name not in MODELS:
        raise InputError(f"unknown model {model!r} (expected one of {', '.join(MODELS)})")
    lon, lat, r = position_from(frame, longitude_deg)
    kp = read_kp(Path(kp_path))
    files = [str(kp_path)]
    drivers = None
    if drivers_path is not None:
        drivers = read_drivers(Path(drivers_path))
        files.append(str(drivers_path))
    elif name in DRIVEN_MODELS:
        raise InputError(f"model {name} needs --drivers (a solar-wind drivers file)")
    if name == "T89" and len(frame) and np.all(np.isnan(kp_at(kp, frame.index))):
        first, last = frame.index[0], frame.index[-1]
        raise InputError(f"the Kp file does not cover the data times ({first.isoformat()} "
                         f"to {last.isoformat()})", file=kp_path)
    return ModelInputs(lon_deg=lon, lat_deg=lat, r_re=r, kp=kp, drivers=drivers, model=name,
                       files=tuple(files))


def model_field_for(frame: pd.DataFrame, inputs: ModelInputs, *, cadence_s: float | None = 60.0,
                    n_jobs: int | None = None, cache_dir=None):
    """Model field in Hpen at the rows of ``frame`` (the ``magcal model`` product).

    Kp is looked up per sample (:func:`magcal.indices.kp_at`) and the drivers are
    interpolated to the samples (:func:`magcal.indices.drivers_at`) before
    :func:`magcal.models.field.model_field_hpen` evaluates the model.

    Parameters
    ----------
    frame : pandas.DataFrame
        Data with a UTC DatetimeIndex.
    inputs : ModelInputs
        From :func:`model_inputs`.
    cadence_s, n_jobs, cache_dir
        See :func:`magcal.models.field.model_field_hpen`.

    Returns
    -------
    magcal.models.field.ModelFieldResult
        Its provenance lists the input files under ``inputs`` (data file first).
    """
    from magcal.indices import drivers_at, kp_at
    from magcal.models.field import model_field_hpen

    times = frame.index.tz_convert("UTC").tz_localize(None).to_numpy()
    drv = drivers_at(inputs.drivers, frame.index) if inputs.drivers is not None else None
    res = model_field_hpen(times, *inputs.position(), model=inputs.model,
                           kp=kp_at(inputs.kp, frame.index), drivers=drv,
                           cadence_s=cadence_s, n_jobs=n_jobs, cache_dir=cache_dir)
    src = frame.attrs.get("source") or []
    src = [src] if isinstance(src, str) else list(src)
    res.provenance["inputs"] = [str(s) for s in src] + list(inputs.files)
    res.provenance["report"] = res.summary()
    return res
