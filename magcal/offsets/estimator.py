"""DC offsets against a field model on quiet days (SOSMAG paper §5.3).

Data minus model in Hpen, at 1-min resolution, restricted to samples with
``Kp <= kp_max`` (default 1.0; Kp in thirds, so 1+ = 4/3 is excluded), summarised per
sliding window (28 days stepped by 7) by the median per component. Windows with too
little quiet data are kept in the product with NaN and a reason.

A window's median is trusted only when the samples it uses cover enough of the window:
at least :data:`MIN_DAY_COVERAGE` of its days and :data:`MIN_LT_COVERAGE` of the 24
local-time hours (see :func:`magcal.offsets.windows.window_coverage`); thinner windows
get NaN and the reason. A record far shorter than the window (less than
:data:`SHORT_RECORD_FRACTION` of it) is said in every window's reason and in
``OffsetTable.warnings``.

Sudden level changes of the offset (a sensor reset, a heater switched) are looked for
in the used samples' day values (:mod:`magcal.offsets.levels`): each is named in the
warnings, in the ``reason`` of the valid windows straddling it (``caution: level change
of ... inside the window``) and in ``OffsetTable.level_changes``; the window medians are
left as they are (CONTRACTS §2), and ``offsets apply`` flags the samples interpolated
across a change. With ``split_at_level_changes`` (opt-in) the windows are instead cut at
each change found, so that no offset mixes both levels (:class:`OffsetEstimator`).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from magcal.errors import InputError
from magcal.offsets.apply import apply_offsets
from magcal.offsets.table import COMPONENTS, OffsetTable
from magcal.offsets.defaults import MIN_DAY_COVERAGE, MIN_LT_COVERAGE, MIN_PIECE_DAYS
from magcal.offsets.windows import (DAY_NS, split_windows, thin_coverage_reason,
                                    window_coverage, window_grid, window_statistics)

#: Kp values within this of ``kp_max`` count as equal (thirds stored as floats).
KP_TOLERANCE = 1e-6
#: A record spanning less than this fraction of the window is "far shorter" than it.
SHORT_RECORD_FRACTION = 0.25


def _duration_text(days: float) -> str:
    """A span in the unit a reader would use (``7 min``, ``5.0 h``, ``3.2 days``)."""
    if days < 2 / 24:
        return f"{days * 1440:.0f} min"
    if days < 2:
        return f"{days * 24:.1f} h"
    return f"{days:.1f} days"


def short_record_warning(span_days: float, window_days: float) -> str:
    """Warning when the record is far shorter than the window ('' otherwise).

    Examples
    --------
    >>> short_record_warning(7 / 1440, 28)
    'record spans 7 min, far shorter than the 28-day window'
    >>> short_record_warning(30, 28)
    ''
    """
    if span_days >= SHORT_RECORD_FRACTION * window_days:
        return ""
    return (f"record spans {_duration_text(span_days)}, far shorter than the "
            f"{window_days:g}-day window")


def with_caution(reason: str, caution: str) -> str:
    """``reason`` of a valid window with ``caution`` (``caution: ...``) put first, other
    cautions kept.

    Examples
    --------
    >>> with_caution("", "caution: a")
    'caution: a'
    >>> with_caution("caution: b", "caution: a")
    'caution: a; b'
    """
    if not reason:
        return caution
    return f"{caution}; {reason.removeprefix('caution: ')}"


def piece_note(change, columns=("Hp", "He", "Hn")) -> str:
    """How a piece of a window split at ``change`` says so in its ``reason``: the words
    of :func:`magcal.offsets.levels.change_caution` (``level change of ... nT at DAY
    inside the window``), so that an OFFSETS.csv read without its JSON sidecar still
    names the change (:func:`magcal.offsets.levels.changes_from_reasons`).

    Examples
    --------
    >>> from types import SimpleNamespace
    >>> ch = SimpleNamespace(time=np.datetime64("2019-12-12", "ns"), size_nT=[3.0, -2, 1.5])
    >>> piece_note(ch)
    'cut at the level change of Hp +3.00, He -2.00, Hn +1.50 nT at 2019-12-12 inside the window'
    """
    sizes = ", ".join(f"{c} {s:+.2f}" for c, s in zip(columns, change.size_nT))
    return (f"cut at the level change of {sizes} nT at {np.datetime64(change.time, 'D')} "
            "inside the window")


def split_warning(change, columns=("Hp", "He", "Hn")) -> str:
    """The record-level warning naming ``change`` when the windows are split at it."""
    return (f"level change of the offset: {change.describe(columns)}; the windows are "
            "split at it (each side's offsets from its own samples; samples inside its "
            "95 % time interval get quality bit offset_near_level_change)")


def quiet_mask(kp, kp_max: float = 1.0) -> np.ndarray:
    """True where ``kp <= kp_max`` (NaN Kp is never quiet).

    Examples
    --------
    >>> quiet_mask([0.0, 1.0, 4 / 3, float("nan")], 1.0)
    array([ True,  True, False, False])
    """
    k = np.asarray(kp, dtype=float)
    with np.errstate(invalid="ignore"):
        return np.isfinite(k) & (k <= kp_max + KP_TOLERANCE)


class OffsetEstimator:
    """Sliding-window median offsets of data minus model over quiet samples.

    Parameters
    ----------
    kp_max : float
        Largest Kp admitted (default 1.0).
    window_days, step_days : float
        Window length and step (default 28 and 7).
    min_used : int
        Fewest quiet samples for a valid window (default 720: 12 h of 1-min data).
    origin : datetime64 or str, optional
        Start of the first window (default: midnight UTC of the first sample).
    method : {"median", "lt_balanced"}
        ``median`` (CONTRACTS §2): median over the quiet samples. ``lt_balanced``: mean
        over 24 local-time bins of the per-bin medians (needs ``lon_deg`` in
        :meth:`fit`); insensitive to an uneven local-time spread of the quiet samples
        when the data carry a local-time field the model lacks.
    min_day_fraction : float
        Fewest of the window's days, as a fraction, that must hold used samples
        (default :data:`MIN_DAY_COVERAGE`); thinner windows are NaN with the reason.
    min_lt_fraction : float
        Fewest of the 24 local-time hours, as a fraction, that must hold used samples
        (default :data:`MIN_LT_COVERAGE`; checked when :meth:`fit` gets ``lon_deg``).
    level_changes : bool
        Look for sudden level changes of the offset in the record
        (:func:`magcal.offsets.levels.detect_level_changes`, default True): each is named
        in :attr:`warnings_`, in the ``reason`` of the valid windows straddling it, and in
        ``OffsetTable.level_changes``. The offsets themselves do not change.
    split_at_level_changes : bool
        Opt-in (default False: the product of CONTRACTS §2, unchanged). Cut the window
        grid at each level change found (at its ``time``, the midnight starting the first
        day at the new level): a window straddling a change becomes ``[start, change)``
        and ``[change, end)`` (:func:`magcal.offsets.windows.split_windows`), each piece
        with its own median, standard error and degrees of freedom from its own samples
        and its centre in its own middle, and judged by the same rules as any window
        (``min_used``, day and local-time coverage); a piece shorter than
        ``min_piece_days`` is NaN with the reason. The table's ``segment`` (column
        ``segment`` of OFFSETS.csv, written only then) numbers the rows 0 before the
        first change, 1 after it, ...; ``offsets apply`` then interpolates only within a
        segment and holds a segment's end values out to the change
        (:func:`magcal.offsets.apply.apply_offsets`). Without a change found, the
        offsets are the unsplit ones and ``segment`` is all 0. Why opt-in: the
        detection is a test at 1 % per record, and a false change cuts the windows
        around it for nothing (the offsets then rest on fewer days there).
    min_piece_days : float
        Shortest piece of a split window that keeps its offset (default
        :data:`MIN_PIECE_DAYS`; only with ``split_at_level_changes``).

    Attributes
    ----------
    table_ : OffsetTable
        The fitted windows.
    warnings_ : tuple of str
        Record-level warnings (e.g. a record far shorter than the window).
    span_days_ : float
        Length of the record (last minus first time plus one sample spacing), days.
    level_changes_ : tuple of LevelChange
        Level changes found (:mod:`magcal.offsets.levels`), in time order.
    level_test_ : dict
        How the level changes were looked for (``tested``, ``threshold``, ...).

    Notes
    -----
    Split against default (``benchmarks/bench_offsets_segments.py``, 30 records of
    90-182 days per cell, a 3 nT model miss, quiet data in 3-hour Kp blocks; RMS error
    of the applied offset in Hp over the 14 days either side of the step, records where
    the step was found): a 5 nT step under a 1-hour miss 1.38 -> 0.60 nT (found in
    30/30), a 3 nT step 0.87 -> 0.47 nT (21/30); under a 6-hour miss 5 nT 1.42 -> 0.83
    (19/30), 3 nT 0.95 -> 0.79 nT (12/30), where a component whose step is small
    against the miss (Hn, 1.2 nT) gets worse (0.56 -> 0.76 nT): the pieces rest on
    fewer days. Records without a change found are unchanged (every record without a
    step under a 1-hour to 1-day miss, drift or wander included; 2 of 30 under a 5-day
    miss named a false change, and their worst RMS rose by 0.42 nT). The pieces' 95 %
    intervals held the truth at their centres in about 95 % of cases at every length
    from 3 days, so the minimum piece length is set by noise, not coverage: the median
    error of a piece of 3-7 days is twice that of one of 10-28 days. Holding the
    longer pieces' values out to the change is free for a constant offset (the error
    fell with the minimum up to 14 days, by up to 8 % in Hn) but costs the drift over the
    distance (with a 0.04 nT/day drift the Hp error was least at 5-10 days and 7 % worse
    at 21): at :data:`MIN_PIECE_DAYS` = 7 the Hp error was within 3 % of the best
    minimum in every cell.

    Examples
    --------
    >>> import numpy as np
    >>> t = np.datetime64("2019-11-01", "ns") + np.arange(30 * 1440) * np.timedelta64(60, "s")
    >>> model = np.zeros((t.size, 3))
    >>> data = model + [14.8, 38.4, -89.8]
    >>> est = OffsetEstimator().fit(t, data, model, kp=np.zeros(t.size))
    >>> est.table_.offset_nT.round(1).tolist()
    [[14.8, 38.4, -89.8], [14.8, 38.4, -89.8]]
    """

    def __init__(self, kp_max: float = 1.0, window_days: float = 28.0, step_days: float = 7.0,
                 min_used: int = 720, origin=None, method: str = "median",
                 min_day_fraction: float = MIN_DAY_COVERAGE,
                 min_lt_fraction: float = MIN_LT_COVERAGE, level_changes: bool = True,
                 split_at_level_changes: bool = False,
                 min_piece_days: float = MIN_PIECE_DAYS):
        self.kp_max = kp_max
        self.window_days = window_days
        self.step_days = step_days
        self.min_used = min_used
        self.origin = origin
        self.method = method
        self.min_day_fraction = min_day_fraction
        self.min_lt_fraction = min_lt_fraction
        self.level_changes = level_changes
        self.split_at_level_changes = split_at_level_changes
        self.min_piece_days = min_piece_days

    def get_params(self) -> dict:
        """Constructor parameters (JSON-ready)."""
        origin = None if self.origin is None else str(np.datetime64(self.origin, "s"))
        return {"kp_max": self.kp_max, "window_days": self.window_days,
                "step_days": self.step_days, "min_used": self.min_used, "origin": origin,
                "method": self.method, "min_day_fraction": self.min_day_fraction,
                "min_lt_fraction": self.min_lt_fraction, "level_changes": self.level_changes,
                "split_at_level_changes": self.split_at_level_changes,
                "min_piece_days": self.min_piece_days}

    def fit(self, times, data_hpen, model_hpen, kp, lon_deg=None,
            provenance: dict | None = None, span_days: float | None = None):
        """Estimate the offsets.

        Parameters
        ----------
        times : array_like of datetime64, shape (n,)
            Increasing sample times (1-min averages).
        data_hpen, model_hpen : array_like, shape (n, 3)
            Measured and model field in Hpen, nT.
        kp : array_like, shape (n,)
            Kp at each sample (Kp units, thirds).
        lon_deg : float or array_like, optional
            Geographic longitude (for ``method="lt_balanced"``).
        provenance : dict, optional
            Provenance record to carry in the table.
        span_days : float, optional
            Length of the record before averaging (default: from ``times``, last minus
            first plus one spacing).

        Returns
        -------
        self
        """
        t = np.asarray(times).astype("datetime64[ns]").astype(np.int64)
        data = np.asarray(data_hpen, dtype=float)
        model = np.asarray(model_hpen, dtype=float)
        kp = np.asarray(kp, dtype=float)
        if data.shape != model.shape or data.ndim != 2 or data.shape[0] != t.size:
            raise InputError(f"data {data.shape}, model {model.shape} and {t.size} times "
                             "do not match")
        if kp.shape != (t.size,):
            raise InputError(f"{kp.size} Kp values for {t.size} times")
        if t.size == 0:
            raise InputError("no samples to fit offsets to")
        if np.any(np.diff(t) <= 0):
            raise InputError("times must be strictly increasing")
        origin = None if self.origin is None else int(
            np.datetime64(self.origin, "ns").astype(np.int64))
        starts, ends = window_grid(int(t[0]), int(t[-1]), self.window_days, self.step_days,
                                   origin)
        if self.method not in ("median", "lt_balanced"):
            raise InputError(f"unknown offset method {self.method!r}")
        lt = None
        if lon_deg is not None:
            from magcal.offsets.diagnostics import local_time_hours

            lt = local_time_hours(t.astype("datetime64[ns]"), lon_deg)
        elif self.method == "lt_balanced":
            raise InputError("method 'lt_balanced' needs the longitude")
        diff = data - model
        used = quiet_mask(kp, self.kp_max) & np.all(np.isfinite(diff), axis=1)
        if span_days is None:
            step = float(np.median(np.diff(t))) if t.size > 1 else 0.0
            span_days = (t[-1] - t[0] + step) / DAY_NS
        self.span_days_ = float(span_days)
        warning = short_record_warning(self.span_days_, self.window_days)
        self.warnings_ = (warning,) if warning else ()
        self._look_for_level_changes(t[used], diff[used])
        segment, whole = None, None
        if self.split_at_level_changes:
            cuts = [np.datetime64(c.time, "ns").astype(np.int64) for c in self.level_changes_]
            whole = (starts, ends)
            starts, ends, segment, source = split_windows(starts, ends, cuts)
            whole = (whole[0][source], whole[1][source])
        stats = window_statistics(t, diff, used, starts, ends, self.min_used,
                                  local_time_h=lt if self.method == "lt_balanced" else None,
                                  columns=COMPONENTS)
        cover = window_coverage(t, used, starts, ends, local_time_h=lt)
        reasons = self._judge_coverage(stats, cover, warning)
        if segment is None:
            self._caution_straddling(starts, ends, stats, reasons)
        else:
            self._judge_pieces(starts, ends, whole, stats, reasons)
        centre = starts + (ends - starts) // 2
        self.table_ = OffsetTable(
            center=centre.astype("datetime64[ns]"), start=starts.astype("datetime64[ns]"),
            end=ends.astype("datetime64[ns]"), offset_nT=stats["median"],
            std_nT=stats["std"], mad_nT=stats["mad"], n_used=stats["n_used"],
            n_available=stats["n_available"], fraction_used=stats["fraction_used"],
            reason=tuple(reasons), parameters=self.get_params(),
            provenance=dict(provenance or {}), days_covered=cover["days_covered"],
            lt_hours_covered=cover["lt_hours_covered"], warnings=self.warnings_,
            se_nT=stats["se"], dof=stats["dof"], level_changes=self.level_changes_,
            level_test=self.level_test_, segment=segment)
        self.n_quiet_ = int(np.count_nonzero(quiet_mask(kp, self.kp_max)))
        return self

    def _judge_coverage(self, stats: dict, cover: dict, warning: str) -> list:
        """Set windows with thin coverage to NaN and return every window's reason."""
        reasons = []
        for i, why in enumerate(stats["reason"]):
            if not why:
                why = thin_coverage_reason(
                    int(cover["days_covered"][i]), float(cover["window_days"][i]),
                    int(cover["lt_hours_covered"][i]), self.min_day_fraction,
                    self.min_lt_fraction)
                if why:
                    stats["median"][i] = np.nan
            if warning:
                why = f"{why}; {warning}" if why else f"caution: {warning}"
            reasons.append(why)
        return reasons

    def _look_for_level_changes(self, t_used, diff_used):
        """Level changes in the used samples, and a warning naming each."""
        from magcal.offsets.levels import change_warning, detect_level_changes

        self.level_changes_, self.level_test_ = (), {"tested": False, "why": "not asked"}
        if not self.level_changes:
            return
        changes, self.level_test_ = detect_level_changes(t_used, diff_used)
        self.level_changes_ = tuple(changes)
        if self.split_at_level_changes:
            self.warnings_ += tuple(split_warning(c) for c in changes)
        else:
            self.warnings_ += tuple(change_warning(c, self.step_days) for c in changes)

    def _caution_straddling(self, starts, ends, stats, reasons):
        """A caution in the reason of each valid window straddling a level change."""
        from magcal.offsets.levels import change_caution, straddling_windows

        if not self.level_changes_:
            return
        for i, inside in enumerate(straddling_windows(starts, ends, self.level_changes_)):
            if np.all(np.isfinite(stats["median"][i])):
                for c in reversed(inside):
                    reasons[i] = with_caution(reasons[i], change_caution(c))

    def _judge_pieces(self, starts, ends, whole, stats, reasons):
        """The pieces of windows split at a level change (``whole``: the bounds of the
        window each row comes from): NaN with the reason when shorter than
        ``min_piece_days``, else a caution naming the change (in the words
        :func:`magcal.offsets.levels.changes_from_reasons` reads back)."""
        for i in np.flatnonzero((starts != whole[0]) | (ends != whole[1])):
            at = [c for c in self.level_changes_
                  if np.datetime64(c.time, "ns").astype(np.int64) in (starts[i], ends[i])
                  and whole[0][i] < np.datetime64(c.time, "ns").astype(np.int64) < whole[1][i]]
            note = " and ".join(piece_note(c) for c in at)
            days = (ends[i] - starts[i]) / DAY_NS
            if days < self.min_piece_days:
                stats["median"][i] = np.nan
                why = (f"piece of {days:g} day{'' if days == 1 else 's'}, shorter than "
                       f"{self.min_piece_days:g}, of a window {note}")
                reasons[i] = f"{why}; {reasons[i]}" if reasons[i] else why
            elif np.all(np.isfinite(stats["median"][i])):
                reasons[i] = with_caution(reasons[i], f"caution: window {note}")
            else:
                reasons[i] = f"{reasons[i]}; window {note}"

    def apply(self, times, data_hpen):
        """Corrected data, the offsets used, and the flag (see :mod:`magcal.offsets.apply`)."""
        if not hasattr(self, "table_"):
            raise InputError("OffsetEstimator.apply called before fit")
        return apply_offsets(times, data_hpen, self.table_)


def fit_offsets(times, data_hpen, lon_deg, lat_deg, r_re, kp, model: str = "T89",
                drivers=None, kp_max: float = 1.0, window_days: float = 28.0,
                step_days: float = 7.0, min_used: int = 720, method: str = "median",
                cadence_s: float = 60.0, min_day_fraction: float = MIN_DAY_COVERAGE,
                min_lt_fraction: float = MIN_LT_COVERAGE,
                n_jobs: int | None = None, cache_dir=None, provenance: dict | None = None,
                split_at_level_changes: bool = False):
    """Whole offset step: 1-min averages, model field, quiet selection, windows.

    Parameters
    ----------
    times, data_hpen : AC-cleaned data (any cadence) in Hpen.
    lon_deg, lat_deg, r_re : position (scalars or per sample).
    kp : Kp per sample (array) or a time-indexed Kp Series (3-hour interval starts).
    model, drivers, n_jobs, cache_dir : see :func:`magcal.models.field.model_field_hpen`.
    kp_max, window_days, step_days, min_used, method, min_day_fraction, min_lt_fraction,
    split_at_level_changes : see :class:`OffsetEstimator`.
    cadence_s : averaging cadence (60 s).

    Returns
    -------
    table : OffsetTable
    details : dict
        ``times`` (1-min), ``data``, ``model``, ``kp``, ``quiet`` arrays and the model
        report (``model_report``), for diagnostics and plots.
    """
    from magcal.models.field import model_field_hpen
    from magcal.offsets.averaging import average_to_cadence

    t = np.asarray(times).astype("datetime64[ns]")
    data = np.asarray(data_hpen, dtype=float)
    pos = [np.asarray(v, dtype=float) for v in (lon_deg, lat_deg, r_re)]
    columns = [data] + [p[:, None] for p in pos if p.ndim]
    stacked = np.concatenate(columns, axis=1) if len(columns) > 1 else data
    t1, avg, _ = average_to_cadence(t, stacked, cadence_s)
    d1 = avg[:, :3]
    extra = iter(avg[:, 3:].T)
    lon1, lat1, r1 = (next(extra) if p.ndim else p for p in pos)
    if hasattr(kp, "index"):
        from magcal.indices import kp_at

        kp1 = kp_at(kp, t1)
    else:
        kp_arr = np.asarray(kp, dtype=float)
        if kp_arr.ndim == 0:
            kp1 = np.full(t1.size, float(kp_arr))
        else:
            if kp_arr.size != t.size:
                raise InputError(f"{kp_arr.size} Kp values for {t.size} times")
            idx = np.clip(np.searchsorted(t, t1), 0, t.size - 1)
            kp1 = kp_arr[idx]
    if drivers is not None and hasattr(drivers, "index"):
        from magcal.indices import drivers_at

        drivers = drivers_at(drivers, t1)
    res = model_field_hpen(t1, lon1, lat1, r1, model=model, kp=kp1, drivers=drivers,
                           cadence_s=None, n_jobs=n_jobs, cache_dir=cache_dir)
    est = OffsetEstimator(kp_max=kp_max, window_days=window_days, step_days=step_days,
                          min_used=min_used, method=method,
                          min_day_fraction=min_day_fraction, min_lt_fraction=min_lt_fraction,
                          split_at_level_changes=split_at_level_changes)
    prov = dict(provenance or {})
    prov.setdefault("model_field", res.summary())
    t_ns = t.astype(np.int64)
    spacing = float(np.median(np.diff(t_ns))) if t.size > 1 else cadence_s * 1e9
    est.fit(t1, d1, res.b_hpen_nT, kp1, lon_deg=lon1, provenance=prov,
            span_days=(t_ns[-1] - t_ns[0] + spacing) / DAY_NS if t.size else 0.0)
    table = est.table_
    params = dict(table.parameters, model=model, cadence_s=cadence_s)
    table = dataclasses.replace(table, parameters=params)
    return table, {"times": t1, "data": d1, "model": res.b_hpen_nT, "kp": kp1,
                   "quiet": quiet_mask(kp1, kp_max), "lon_deg": lon1,
                   "model_report": res.summary()}


def fit_offsets_frame(frame, inputs, *, kp_max: float = 1.0, window_days: float = 28.0,
                      step_days: float = 7.0, min_used: int = 720, method: str = "median",
                      min_day_fraction: float = MIN_DAY_COVERAGE,
                      min_lt_fraction: float = MIN_LT_COVERAGE, cadence_s: float = 60.0,
                      n_jobs: int | None = None, cache_dir=None,
                      provenance: dict | None = None, split_at_level_changes: bool = False):
    """The ``offsets fit`` product for a validated data frame and its model inputs.

    Parameters
    ----------
    frame : pandas.DataFrame
        ``Hp, He, Hn`` with a UTC DatetimeIndex (:func:`magcal.io.formats.read_any`).
    inputs : magcal.models.inputs.ModelInputs
        Position, Kp and drivers (:func:`magcal.models.inputs.model_inputs`).
    kp_max, window_days, step_days, min_used, method, min_day_fraction, min_lt_fraction,
    cadence_s, n_jobs, cache_dir, provenance, split_at_level_changes
        See :func:`fit_offsets` and :class:`OffsetEstimator`.

    Returns
    -------
    table : OffsetTable
    details : dict
        As :func:`fit_offsets`.

    Raises
    ------
    InputError
        Kp threshold outside [0, 9], coverage fractions outside [0, 1], or missing
        ``Hp, He, Hn`` columns.
    """
    from magcal.models.inputs import frame_source

    if not 0 <= kp_max <= 9:
        raise InputError(f"kp_max {kp_max} outside [0, 9]")
    for name, value in (("min_day_fraction", min_day_fraction),
                        ("min_lt_fraction", min_lt_fraction)):
        if not 0 <= value <= 1:
            raise InputError(f"{name} {value} outside [0, 1]")
    missing = [c for c in ("Hp", "He", "Hn") if c not in frame.columns]
    if missing:
        raise InputError(f"missing column(s) {', '.join(missing)}",
                         file=frame_source(frame), column=missing[0])
    times = frame.index.tz_convert("UTC").tz_localize(None).to_numpy()
    return fit_offsets(times, frame[["Hp", "He", "Hn"]].to_numpy(), *inputs.position(),
                       inputs.kp, model=inputs.model, drivers=inputs.drivers, kp_max=kp_max,
                       window_days=window_days, step_days=step_days, min_used=min_used,
                       method=method, cadence_s=cadence_s, min_day_fraction=min_day_fraction,
                       min_lt_fraction=min_lt_fraction, n_jobs=n_jobs, cache_dir=cache_dir,
                       provenance=provenance, split_at_level_changes=split_at_level_changes)
