"""The validated container for multi-sensor vector time series.

:class:`VectorSeries` wraps a pandas DataFrame with a UTC :class:`~pandas.DatetimeIndex`
and ``(sensor, component)`` columns, plus units, metadata (frame, cadence, spacecraft)
and a provenance list that grows by one entry per processing step. Validation happens
once, at the edge (:func:`validate_frame` / :meth:`VectorSeries.from_frame`); every
repair it makes is counted and recorded, nothing is dropped silently.

Gaps are first-class: :meth:`VectorSeries.gaps` lists them and
:meth:`VectorSeries.resample` puts the data on a regular grid without ever
interpolating across a gap longer than a stated limit.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Iterable, Mapping

import numpy as np
import pandas as pd

from magcal.errors import InputError
from magcal.io.csv import FILL_MAGNITUDE, read_csv_frame
from magcal.provenance import utc_now_iso

#: Component names recognised in flat CSV headers, in their canonical order.
COMPONENT_SETS = (("x", "y", "z"), ("Hp", "He", "Hn"), ("b1", "b2", "b3"),
                  ("X", "Y", "Z"), ("r", "t", "n"))
SENSOR_NAME = re.compile(r"^[a-z0-9_]+$")
#: Scalar (non-vector) columns kept beside the vectors.
AUX_COLUMNS = ("phase", "flip", "lon_deg", "lat_deg", "r_re", "temperature", "kp", "dst")


@dataclass(frozen=True)
class Repair:
    """One counted repair made while validating input."""

    what: str
    count: int
    detail: str = ""


@dataclass(frozen=True)
class ValidationReport:
    """What :func:`validate_frame` found and did."""

    n_rows_in: int
    n_rows_out: int
    cadence_s: float
    repairs: tuple[Repair, ...] = ()
    nan_runs: int = 0
    longest_nan_run: int = 0

    def as_dict(self) -> dict:
        return {"n_rows_in": self.n_rows_in, "n_rows_out": self.n_rows_out,
                "cadence_s": self.cadence_s, "nan_runs": self.nan_runs,
                "longest_nan_run": self.longest_nan_run,
                "repairs": [r.__dict__ for r in self.repairs]}


def cadence_of(index: pd.DatetimeIndex) -> float:
    """Nominal cadence in seconds: the median spacing of the samples (NaN if < 2 samples)."""
    if len(index) < 2:
        return float("nan")
    return float(np.median(np.diff(pd.DatetimeIndex(index).as_unit("ns").asi8))) / 1e9


def nan_runs(mask: np.ndarray) -> np.ndarray:
    """Lengths of the runs of ``True`` in a boolean mask.

    Examples
    --------
    >>> nan_runs(np.array([0, 1, 1, 0, 1], dtype=bool)).tolist()
    [2, 1]
    """
    m = np.concatenate([[False], np.asarray(mask, dtype=bool), [False]])
    edges = np.flatnonzero(np.diff(m.astype(np.int8)))
    return edges[1::2] - edges[::2]


def validate_frame(frame: pd.DataFrame, *, on_unsorted: str = "raise",
                   on_duplicate: str = "raise", mixed_cadence: str = "raise",
                   cadence_tolerance: float = 0.05, source=None
                   ) -> tuple[pd.DataFrame, ValidationReport]:
    """Validate a time-indexed frame; repair only what the caller allows, and count it.

    Parameters
    ----------
    frame : pandas.DataFrame
        Index convertible to UTC datetimes; numeric columns.
    on_unsorted : {"raise", "sort"}
        Times out of order: error, or sort (counted).
    on_duplicate : {"raise", "drop"}
        Repeated times: error, or keep the first of identical rows (counted; repeated times
        with different values are always an error).
    mixed_cadence : {"raise", "allow"}
        Spacings that are not whole multiples of the nominal cadence (within
        ``cadence_tolerance`` of it): error, or accept (counted). Gaps that are whole
        multiples are not a mixed cadence.
    source : str, optional
        File name for messages.

    Returns
    -------
    frame : pandas.DataFrame
        Validated copy, fill values (-1e31 family, -9999) replaced by NaN.
    report : ValidationReport

    Examples
    --------
    >>> t = pd.date_range("2019-03-04", periods=4, freq="1s", tz="UTC")
    >>> df = pd.DataFrame({"x": [1.0, -1e31, 3.0, 4.0]}, index=t)
    >>> clean, rep = validate_frame(df)
    >>> rep.repairs[0].what, rep.repairs[0].count, rep.cadence_s
    ('fill value replaced by NaN', 1, 1.0)
    """
    repairs: list[Repair] = []
    df = frame.copy()
    n_in = len(df)
    if n_in == 0:
        raise InputError("no samples", file=source)
    try:
        index = pd.DatetimeIndex(df.index)
    except (TypeError, ValueError) as exc:
        raise InputError(f"index is not a time index: {exc}", file=source) from None
    index = index.tz_localize("UTC") if index.tz is None else index.tz_convert("UTC")
    # pandas >= 3 may hold microseconds; every integer-time computation here uses ns.
    df.index = index.as_unit("ns").rename("time")
    if not df.index.is_monotonic_increasing:
        if on_unsorted != "sort":
            k = int(np.flatnonzero(np.diff(df.index.asi8) < 0)[0]) + 1
            raise InputError(f"time goes backwards at sample {k} ({df.index[k].isoformat()})",
                             file=source, row=k)
        order = np.argsort(df.index.asi8, kind="stable")
        moved = int(np.count_nonzero(order != np.arange(n_in)))
        df = df.iloc[order]
        repairs.append(Repair("sorted out-of-order samples", moved))
    dup = df.index.duplicated(keep="first")
    if dup.any():
        same = df[df.index.duplicated(keep=False)].groupby(level=0).nunique(dropna=False)
        if on_duplicate != "drop" or (same > 1).to_numpy().any():
            k = int(np.flatnonzero(dup)[0])
            raise InputError(f"duplicate time {df.index[k].isoformat()} at sample {k}",
                             file=source, row=k)
        df = df[~dup]
        repairs.append(Repair("dropped exact duplicate samples", int(dup.sum())))
    values = df.to_numpy(dtype=float, copy=True)
    fill = (np.abs(values) >= FILL_MAGNITUDE) | (values == -9999.0)
    if fill.any():
        values[fill] = np.nan
        df = pd.DataFrame(values, index=df.index, columns=df.columns)
        repairs.append(Repair("fill value replaced by NaN", int(fill.sum())))
    cadence = cadence_of(df.index)
    if len(df) > 2 and np.isfinite(cadence) and cadence > 0:
        ratio = np.diff(df.index.asi8) / 1e9 / cadence
        off = np.abs(ratio - np.round(ratio)) > cadence_tolerance
        off |= ratio < 1 - cadence_tolerance
        if off.any():
            if mixed_cadence != "allow":
                k = int(np.flatnonzero(off)[0]) + 1
                raise InputError(
                    f"mixed cadence: spacing {ratio[k - 1] * cadence:g} s at sample {k} is not a "
                    f"multiple of the nominal {cadence:g} s ({int(off.sum())} such spacings); "
                    "resample first", file=source, row=k)
            repairs.append(Repair("accepted off-cadence spacings", int(off.sum())))
    runs = nan_runs(np.isnan(df.to_numpy(dtype=float)).any(axis=1))
    report = ValidationReport(n_rows_in=n_in, n_rows_out=len(df), cadence_s=cadence,
                              repairs=tuple(repairs), nan_runs=int(runs.size),
                              longest_nan_run=int(runs.max()) if runs.size else 0)
    return df, report


def _split_flat_columns(columns: Iterable[str]) -> tuple[list[tuple[str, str]], list[str]]:
    """Map flat CSV column names to (sensor, component) pairs; the rest are aux columns."""
    cols = list(columns)
    pairs: list[tuple[str, str]] = []
    used: set[str] = set()
    for comps in COMPONENT_SETS:
        if all(c in cols for c in comps):
            pairs += [("", c) for c in comps]
            used |= set(comps)
            break
    sensors: dict[str, list[str]] = {}
    for name in cols:
        if name in used or name in AUX_COLUMNS or "_" not in name:
            continue
        sensor, comp = name.rsplit("_", 1)
        sensors.setdefault(sensor, []).append(comp)
    for sensor, comps in sensors.items():
        for comp_set in COMPONENT_SETS:
            if all(c in comps for c in comp_set):
                pairs += [(sensor, c) for c in comp_set]
                used |= {f"{sensor}_{c}" for c in comp_set}
                break
    aux = [c for c in cols if c not in used]
    return pairs, aux


@dataclass(frozen=True)
class VectorSeries:
    """Multi-sensor vector time series with units, metadata and provenance.

    Build one with :meth:`from_frame`, :meth:`from_arrays` or :meth:`read_csv`; the
    constructor trusts its arguments (they come from those validated paths).

    Attributes
    ----------
    data : pandas.DataFrame
        UTC DatetimeIndex named ``time``; columns a 2-level MultiIndex
        ``(sensor, component)``. A single-vector series uses sensor ``""``.
    aux : pandas.DataFrame
        Scalar columns on the same index (e.g. ``phase``, ``flip``, ``lon_deg``).
    units : str
        Unit of the vector values (``"nT"`` unless stated).
    meta : Mapping
        ``frame``, ``spacecraft``, ``cadence_s``, ``source`` and any other metadata.
    provenance : tuple of dict
        Processing steps in order (validation repairs first).

    Examples
    --------
    >>> t = pd.date_range("2019-03-04", periods=3, freq="1s", tz="UTC")
    >>> vs = VectorSeries.from_arrays(t, {"fgmo": np.ones((3, 3))}, frame="OSRF")
    >>> vs.sensors, vs.cadence_s, vs["fgmo"].shape
    (('fgmo',), 1.0, (3, 3))
    """

    data: pd.DataFrame
    aux: pd.DataFrame
    units: str = "nT"
    meta: Mapping = field(default_factory=dict)
    provenance: tuple = ()

    # --- construction -------------------------------------------------------------
    @classmethod
    def from_frame(cls, frame: pd.DataFrame, *, frame_name: str | None = None,
                   spacecraft: str | None = None, units: str = "nT", source=None,
                   **validate_kwargs) -> "VectorSeries":
        """Validate a flat frame (``<sensor>_x`` ..., ``Hp,He,Hn``, ``b1,b2,b3``) and wrap it.

        Extra keyword arguments go to :func:`validate_frame` (repair policies).
        """
        if isinstance(frame.columns, pd.MultiIndex):
            pairs = [tuple(c) for c in frame.columns]
            vec = frame
            aux = pd.DataFrame(index=frame.index)
        else:
            pairs, aux_cols = _split_flat_columns(frame.columns)
            if not pairs:
                raise InputError(
                    "no vector columns: expected <sensor>_x,<sensor>_y,<sensor>_z, "
                    f"Hp,He,Hn or b1,b2,b3; found {', '.join(map(str, frame.columns))}",
                    file=source, row=1)
            names = [f"{s}_{c}" if s else c for s, c in pairs]
            vec = frame[names]
            aux = frame[aux_cols]
        for sensor, _ in pairs:
            if sensor and not SENSOR_NAME.match(sensor):
                raise InputError(f"sensor name {sensor!r} must be lowercase letters, digits, _",
                                 file=source, row=1)
        joined = pd.concat([vec.set_axis(range(len(pairs)), axis=1),
                            aux.set_axis(range(len(pairs), len(pairs) + aux.shape[1]), axis=1)],
                           axis=1)
        clean, report = validate_frame(joined, source=source, **validate_kwargs)
        data = clean.iloc[:, :len(pairs)].copy()
        data.columns = pd.MultiIndex.from_tuples(pairs, names=["sensor", "component"])
        aux_clean = clean.iloc[:, len(pairs):].copy()
        aux_clean.columns = list(aux.columns)
        meta = {"frame": frame_name, "spacecraft": spacecraft, "cadence_s": report.cadence_s,
                "source": None if source is None else str(source)}
        step = {"step": "validate", "time_utc": utc_now_iso(), **report.as_dict()}
        return cls(data=data, aux=aux_clean, units=units, meta=meta, provenance=(step,))

    @classmethod
    def from_arrays(cls, times, vectors: Mapping[str, np.ndarray], *,
                    components: tuple[str, str, str] = ("x", "y", "z"),
                    aux: Mapping[str, np.ndarray] | None = None, frame: str | None = None,
                    spacecraft: str | None = None, units: str = "nT") -> "VectorSeries":
        """Build from a time array and ``{sensor: (n, 3) array}`` (validated)."""
        index = pd.DatetimeIndex(times)
        cols = {}
        for sensor, arr in vectors.items():
            arr = np.asarray(arr, dtype=float)
            if arr.ndim != 2 or arr.shape != (len(index), 3):
                raise InputError(f"sensor {sensor!r}: expected shape ({len(index)}, 3), "
                                 f"got {arr.shape}")
            for k, comp in enumerate(components):
                cols[(sensor, comp)] = arr[:, k]
        for name, arr in (aux or {}).items():
            cols[("__aux__", name)] = np.asarray(arr, dtype=float)
        flat = pd.DataFrame(cols, index=index)
        vec = flat.drop(columns="__aux__", level=0, errors="ignore")
        vec.columns = pd.MultiIndex.from_tuples(list(vec.columns), names=["sensor", "component"])
        out = cls.from_frame(vec, frame_name=frame, spacecraft=spacecraft, units=units)
        if aux:
            aux_df = pd.DataFrame({k: np.asarray(v, dtype=float) for k, v in aux.items()},
                                  index=out.data.index)
            out = cls(out.data, aux_df, out.units, out.meta, out.provenance)
        return out

    @classmethod
    def read_csv(cls, path, *, frame_name: str | None = None, spacecraft: str | None = None,
                 **validate_kwargs) -> "VectorSeries":
        """Read a CONTRACTS §0 CSV file (multi-sensor, Hpen or spinning layout)."""
        df = read_csv_frame(path)
        out = cls.from_frame(df, frame_name=frame_name, spacecraft=spacecraft, source=path,
                             **validate_kwargs)
        reads = [{"step": "read_csv", "file": str(path), "repairs": df.attrs.get("repairs", [])}]
        return out.replace(provenance=tuple(reads) + out.provenance)

    # --- access ---------------------------------------------------------------------
    @property
    def times(self) -> pd.DatetimeIndex:
        return self.data.index

    @property
    def sensors(self) -> tuple[str, ...]:
        return tuple(dict.fromkeys(self.data.columns.get_level_values(0)))

    @property
    def components(self) -> tuple[str, ...]:
        return tuple(dict.fromkeys(self.data.columns.get_level_values(1)))

    @property
    def cadence_s(self) -> float:
        return cadence_of(self.times)

    def __len__(self) -> int:
        return len(self.data)

    def __getitem__(self, sensor: str) -> np.ndarray:
        if sensor not in self.sensors:
            raise InputError(f"sensor {sensor!r} not in data (have {', '.join(self.sensors)})",
                             file=self.meta.get("source"), column=sensor)
        return self.data[sensor].to_numpy(dtype=float)

    def vector(self) -> np.ndarray:
        """The (n, 3) array of a single-vector series."""
        if len(self.sensors) != 1:
            raise ValueError(f"series has {len(self.sensors)} sensors; use series[sensor]")
        return self[self.sensors[0]]

    def seconds(self, since=None) -> np.ndarray:
        """Sample times in seconds since ``since`` (default: the first sample)."""
        t0 = self.times[0] if since is None else pd.Timestamp(since)
        return (self.times.asi8 - t0.value) / 1e9

    # --- derived series -------------------------------------------------------------
    def replace(self, **changes) -> "VectorSeries":
        fields = {"data": self.data, "aux": self.aux, "units": self.units, "meta": self.meta,
                  "provenance": self.provenance}
        fields.update(changes)
        return VectorSeries(**fields)

    def with_step(self, step: str, **parameters) -> "VectorSeries":
        """Return a copy with one more provenance entry (call after the step succeeded)."""
        entry = {"step": step, "time_utc": utc_now_iso(), "parameters": parameters}
        return self.replace(provenance=self.provenance + (entry,))

    def with_vectors(self, vectors: Mapping[str, np.ndarray], step: str,
                     components: tuple[str, ...] | None = None, **parameters) -> "VectorSeries":
        """New series on the same times with the given sensors' vectors and a provenance step."""
        comps = components or self.components[:3]
        cols = {}
        for sensor, arr in vectors.items():
            arr = np.asarray(arr, dtype=float)
            if arr.shape != (len(self), 3):
                raise ValueError(f"{sensor}: expected ({len(self)}, 3), got {arr.shape}")
            for k, comp in enumerate(comps):
                cols[(sensor, comp)] = arr[:, k]
        data = pd.DataFrame(cols, index=self.times)
        data.columns = pd.MultiIndex.from_tuples(list(cols), names=["sensor", "component"])
        return self.replace(data=data).with_step(step, **parameters)

    def select(self, sensors: Iterable[str]) -> "VectorSeries":
        sensors = list(sensors)
        for s in sensors:
            self[s]  # raises a clear error for a missing sensor
        return self.replace(data=self.data[sensors])

    def slice(self, start=None, end=None) -> "VectorSeries":
        """Samples with ``start <= t < end`` (either bound optional)."""
        t = self.times.asi8
        lo = -np.inf if start is None else pd.Timestamp(start, tz="UTC").value
        hi = np.inf if end is None else pd.Timestamp(end, tz="UTC").value
        keep = (t >= lo) & (t < hi)
        return self.replace(data=self.data[keep], aux=self.aux[keep])

    def gaps(self, min_gap_s: float | None = None) -> pd.DataFrame:
        """Gaps: spacings longer than ``min_gap_s`` (default 1.5 cadences) and NaN runs.

        Returns a frame with ``start``, ``end`` (last good sample before, first after),
        ``duration_s`` and ``kind`` (``"missing samples"`` or ``"NaN"``).
        """
        cadence = self.cadence_s
        limit = 1.5 * cadence if min_gap_s is None else float(min_gap_s)
        t = self.times
        rows = []
        if len(t) > 1:
            dt = np.diff(t.asi8) / 1e9
            for k in np.flatnonzero(dt > limit):
                rows.append((t[k], t[k + 1], dt[k], "missing samples"))
        bad = np.isnan(self.data.to_numpy(dtype=float)).any(axis=1)
        m = np.concatenate([[False], bad, [False]])
        edges = np.flatnonzero(np.diff(m.astype(np.int8)))
        for a, b in zip(edges[::2], edges[1::2]):
            before = t[a - 1] if a > 0 else t[a]
            after = t[b] if b < len(t) else t[b - 1]
            rows.append((before, after, (after - before).total_seconds(), "NaN"))
        return pd.DataFrame(rows, columns=["start", "end", "duration_s", "kind"])

    def resample(self, cadence_s: float, *, max_gap_s: float, method: str = "mean",
                 origin=None) -> "VectorSeries":
        """Put every sensor on a common regular grid without bridging long gaps.

        Parameters
        ----------
        cadence_s : float
            Grid spacing in seconds.
        max_gap_s : float
            Longest gap (seconds between valid samples) that may be bridged by linear
            interpolation (``method="interp"``); longer gaps stay NaN. With
            ``method="mean"`` a grid cell is the mean of the samples inside it and cells
            with no valid sample are NaN (``max_gap_s`` then bounds the interpolation
            of empty cells, default none).
        method : {"mean", "interp"}
            Bin averaging (for down-sampling) or linear interpolation (for re-gridding).
        origin : timestamp, optional
            Grid origin; default the first sample floored to the cadence.

        Examples
        --------
        >>> t = pd.date_range("2019-03-04", periods=120, freq="1s", tz="UTC")
        >>> vs = VectorSeries.from_arrays(t, {"a": np.tile(np.arange(120.0)[:, None], 3)})
        >>> m = vs.resample(60, max_gap_s=0)
        >>> m["a"][:, 0].tolist()
        [29.5, 89.5]
        """
        step_ns = int(round(cadence_s * 1e9))
        if step_ns <= 0:
            raise InputError(f"cadence must be positive, got {cadence_s} s")
        t = self.times.asi8
        t0 = (t[0] // step_ns) * step_ns if origin is None else pd.Timestamp(origin).value
        n_out = int((t[-1] - t0) // step_ns) + 1
        grid = t0 + step_ns * np.arange(n_out, dtype=np.int64)
        values = self.data.to_numpy(dtype=float)
        out = np.full((n_out, values.shape[1]), np.nan)
        if method == "mean":
            cell = (t - t0) // step_ns
            for j in range(values.shape[1]):
                ok = np.isfinite(values[:, j])
                s = np.bincount(cell[ok], weights=values[ok, j], minlength=n_out)
                c = np.bincount(cell[ok], minlength=n_out)
                with np.errstate(invalid="ignore", divide="ignore"):
                    out[:, j] = np.where(c > 0, s / np.maximum(c, 1), np.nan)
            centre_shift = 0
        elif method == "interp":
            for j in range(values.shape[1]):
                ok = np.isfinite(values[:, j])
                tv, vv = t[ok], values[ok, j]
                if tv.size < 2:
                    continue
                out[:, j] = np.interp(grid, tv, vv, left=np.nan, right=np.nan)
                k = np.clip(np.searchsorted(tv, grid), 1, tv.size - 1)
                span = (tv[k] - tv[k - 1]) / 1e9
                exact = (tv[k] == grid) | (tv[k - 1] == grid)
                out[(span > max_gap_s) & ~exact, j] = np.nan
            centre_shift = 0
        else:
            raise InputError(f"unknown resample method {method!r} (use 'mean' or 'interp')")
        index = pd.DatetimeIndex(grid + centre_shift, tz="UTC", name="time").as_unit("ns")
        data = pd.DataFrame(out, index=index, columns=self.data.columns)
        aux = (self.aux.reindex(index, method="nearest",
                                tolerance=pd.Timedelta(step_ns // 2, "ns"))
               if self.aux.shape[1] else pd.DataFrame(index=index))
        meta = dict(self.meta, cadence_s=float(cadence_s))
        return self.replace(data=data, aux=aux, meta=meta).with_step(
            "resample", cadence_s=float(cadence_s), max_gap_s=float(max_gap_s), method=method,
            n_in=len(self), n_out=n_out, n_empty=int(np.isnan(out).any(axis=1).sum()))

    def to_frame(self) -> pd.DataFrame:
        """Flat CONTRACTS §0 frame: ``<sensor>_<comp>`` (or bare components) then aux columns."""
        names = [f"{s}_{c}" if s else c for s, c in self.data.columns]
        flat = self.data.set_axis(names, axis=1)
        return pd.concat([flat, self.aux], axis=1) if self.aux.shape[1] else flat
