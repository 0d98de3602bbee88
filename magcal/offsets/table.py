"""The offset product: one row per sliding window (CONTRACTS §2 ``OFFSETS.csv``).

Columns, in this order: ``center,start,end,Hp,He,Hn,Hp_std,He_std,Hn_std,n_used,
fraction_used`` (the contract), then ``Hp_mad,He_mad,Hn_mad`` (median absolute
deviation scaled to a standard deviation), ``n_available`` (samples with data and model
in the window), ``reason`` (why the window is NaN; empty for a valid window, or
``caution: ...`` when a valid window carries a warning such as a record far shorter
than the window), ``days_covered`` (UTC days of the window holding used samples) and
``lt_hours_covered`` (of the 24 local-time hours; empty when the longitude is unknown),
``Hp_se,He_se,Hn_se`` (1-sigma standard errors, CONTRACTS §7.1) and ``Hp_dof,He_dof,
Hn_dof`` (their degrees of freedom: the 95 % interval is ``offset +- t(0.975, dof) se``).
Provenance is written beside the CSV as ``<file>.provenance.json``, with the level changes
of the offset found in the record (``level_changes``, :mod:`magcal.offsets.levels`) and how
they were looked for (``level_change_test``); :func:`read_offsets_csv` reads them back
(or, without the sidecar, from the windows' ``reason`` cautions).

A product fitted with ``split_at_level_changes`` (:class:`~magcal.offsets.OffsetEstimator`)
has one more column, last: ``segment`` (int: 0 before the first level change, 1 after
it, ...), by which ``offsets apply`` interpolates within a segment only. The column is
written only then, so the default product is the same file as before the option
existed, and a reader that does not know the column reads it as before; a file without
it is applied as one segment (as it always was).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field as dc_field
from pathlib import Path

import numpy as np
import pandas as pd

from magcal.errors import InputError
from magcal.io.atomic import atomic_path
from magcal.io.jsonio import product_dict, to_jsonable

COMPONENTS = ("Hp", "He", "Hn")
CONTRACT_COLUMNS = ("center", "start", "end", "Hp", "He", "Hn", "Hp_std", "He_std", "Hn_std",
                    "n_used", "fraction_used")
EXTRA_COLUMNS = ("Hp_mad", "He_mad", "Hn_mad", "n_available", "reason", "days_covered",
                 "lt_hours_covered", "Hp_se", "He_se", "Hn_se", "Hp_dof", "He_dof", "Hn_dof")


@dataclass(frozen=True)
class OffsetTable:
    """DC offsets per sliding window.

    Attributes
    ----------
    center, start, end : ndarray of datetime64[ns], shape (k,)
        Window centre and bounds ``[start, end)``.
    offset_nT, std_nT, mad_nT : ndarray, shape (k, 3)
        Median of data minus model (Hp, He, Hn), its standard deviation and scaled MAD
        over the selected samples; NaN for windows with too little data.
    n_used, n_available : ndarray of int, shape (k,)
    fraction_used : ndarray, shape (k,)
    reason : tuple of str
        Why a window is NaN; '' or ``caution: ...`` for valid windows.
    parameters : dict
    provenance : dict
    days_covered, lt_hours_covered : ndarray of int, shape (k,), optional
        Days of the window and local-time hours (of 24) holding used samples; -1 where
        unknown.
    warnings : tuple of str
        Record-level warnings (e.g. a record far shorter than the window).
    se_nT : ndarray, shape (k, 3), optional
        1-sigma standard error of each offset, residual correlation accounted for
        (:func:`magcal.offsets.windows.batch_error_and_dof`, with the day correlation
        pooled over the record when it spans enough days); columns ``Hp_se..`` of
        OFFSETS.csv (CONTRACTS §7.1), NaN where not computed.
    dof : ndarray, shape (k, 3), optional
        Degrees of freedom of ``se_nT`` (:func:`magcal.offsets.windows.batch_error_and_dof`:
        the standard error is estimated from a few correlated days, so an interval takes
        Student's t on them, :meth:`interval95`); columns ``Hp_dof..``, NaN where not
        computed.
    level_changes : tuple of LevelChange
        Sudden level changes of the offset found in the record
        (:func:`magcal.offsets.levels.detect_level_changes`), in time order; ``offsets
        apply`` flags the samples whose interpolation spans one.
    level_test : dict
        How they were looked for (``tested``, ``threshold``, ...; empty when unknown).
    segment : ndarray of int, shape (k,), optional
        Segment of each row when the windows were split at the level changes (0 before
        the first, 1 after it, ...; column ``segment``); None for the unsplit product,
        which ``offsets apply`` interpolates as one piece.
    """

    center: np.ndarray
    start: np.ndarray
    end: np.ndarray
    offset_nT: np.ndarray
    std_nT: np.ndarray
    mad_nT: np.ndarray
    n_used: np.ndarray
    n_available: np.ndarray
    fraction_used: np.ndarray
    reason: tuple = ()
    parameters: dict = dc_field(default_factory=dict)
    provenance: dict = dc_field(default_factory=dict)
    days_covered: np.ndarray | None = None
    lt_hours_covered: np.ndarray | None = None
    warnings: tuple = ()
    se_nT: np.ndarray | None = None
    dof: np.ndarray | None = None
    level_changes: tuple = ()
    level_test: dict = dc_field(default_factory=dict)
    segment: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.center.size)

    @property
    def valid(self) -> np.ndarray:
        """True for windows with a finite offset in all three components."""
        return np.all(np.isfinite(self.offset_nT), axis=1)

    def interval95(self) -> np.ndarray:
        """Half-width (nT) of each offset's 95 % interval, (k, 3): ``t(0.975, dof) se``.

        Without degrees of freedom (an OFFSETS.csv written before they were) the normal
        1.96 is used, which holds the truth less often than 95 % when the model miss is
        correlated over days (:func:`magcal.offsets.windows.batch_error_and_dof`). NaN
        where there is no standard error.

        Examples
        --------
        >>> c = np.array(["2019-11-15"], dtype="datetime64[ns]")
        >>> tab = OffsetTable(center=c, start=c, end=c, offset_nT=np.zeros((1, 3)),
        ...                   std_nT=np.ones((1, 3)), mad_nT=np.ones((1, 3)),
        ...                   n_used=np.array([9]), n_available=np.array([9]),
        ...                   fraction_used=np.ones(1), se_nT=np.array([[0.5, 0.5, np.nan]]),
        ...                   dof=np.array([[4.0, np.nan, np.nan]]))
        >>> tab.interval95().round(3)
        array([[1.388, 0.98 ,   nan]])
        """
        from magcal.stats import student_interval

        n = len(self)
        se = np.full((n, 3), np.nan) if self.se_nT is None else np.asarray(self.se_nT, float)
        dof = np.full((n, 3), np.nan) if self.dof is None else np.asarray(self.dof, float)
        return student_interval(0.0, se, np.where(np.isfinite(dof), dof, np.inf))[1]

    def to_frame(self) -> pd.DataFrame:
        """The product as a DataFrame with the CSV columns (times as datetime64)."""
        cols = {"center": self.center, "start": self.start, "end": self.end}
        for j, c in enumerate(COMPONENTS):
            cols[c] = self.offset_nT[:, j]
        for j, c in enumerate(COMPONENTS):
            cols[f"{c}_std"] = self.std_nT[:, j]
        cols["n_used"] = self.n_used
        cols["fraction_used"] = self.fraction_used
        for j, c in enumerate(COMPONENTS):
            cols[f"{c}_mad"] = self.mad_nT[:, j]
        cols["n_available"] = self.n_available
        cols["reason"] = list(self.reason) if len(self.reason) else [""] * len(self)
        for name in ("days_covered", "lt_hours_covered"):
            values = getattr(self, name)
            values = np.full(len(self), -1) if values is None else np.asarray(values)
            column = pd.array(values, dtype="Int64")
            column[values < 0] = pd.NA
            cols[name] = column
        se = np.full((len(self), 3), np.nan) if self.se_nT is None else self.se_nT
        for j, c in enumerate(COMPONENTS):
            cols[f"{c}_se"] = se[:, j]
        dof = np.full((len(self), 3), np.nan) if self.dof is None else self.dof
        for j, c in enumerate(COMPONENTS):
            cols[f"{c}_dof"] = dof[:, j]
        if self.segment is not None:
            cols["segment"] = np.asarray(self.segment, dtype=np.int64)
        return pd.DataFrame(cols)

    def to_json(self) -> dict:
        """JSON product: the windows as records, parameters and provenance."""
        frame = self.to_frame()
        for c in ("center", "start", "end"):
            frame[c] = np.datetime_as_string(frame[c].to_numpy(dtype="datetime64[s]"))
        frame = frame.astype(object).where(frame.notna(), None)
        return product_dict({"windows": frame.to_dict(orient="records"),
                             "warnings": list(self.warnings),
                             "parameters": self.parameters, "provenance": self.provenance,
                             **self.levels_json()})

    def levels_json(self) -> dict:
        """``level_changes`` (one record each, :meth:`LevelChange.to_dict`) and
        ``level_change_test`` for the JSON products."""
        return {"level_changes": [c.to_dict() for c in self.level_changes],
                "level_change_test": to_jsonable(self.level_test)}


def write_offsets_csv(path, table: OffsetTable, float_format: str = "%.4f") -> Path:
    """Write ``OFFSETS.csv`` (and ``<path>.provenance.json``) atomically."""
    frame = table.to_frame()
    for c in ("center", "start", "end"):
        frame[c] = np.datetime_as_string(frame[c].to_numpy(dtype="datetime64[s]"), unit="s")
    side = Path(str(path) + ".provenance.json")
    with atomic_path(path) as tmp:
        frame.to_csv(tmp, index=False, float_format=float_format, na_rep="NaN")
        with atomic_path(side) as tmp_side:
            payload = {"parameters": table.parameters, "warnings": list(table.warnings),
                       "provenance": table.provenance, **table.levels_json()}
            tmp_side.write_text(json.dumps(product_dict(to_jsonable(payload)), indent=2) + "\n")
    return Path(path)


def missing_as_nan(values) -> tuple[np.ndarray, np.ndarray]:
    """``values`` with fill values (:func:`magcal.io.csv.replace_fill_values`: the -1e31
    family, -9999) and non-finite numbers as NaN, and where they were.

    Examples
    --------
    >>> missing_as_nan([1.5, -1e31, np.inf, -9999.0, np.nan])
    (array([1.5, nan, nan, nan, nan]), array([False,  True,  True,  True, False]))
    """
    from magcal.io.csv import replace_fill_values

    out, _ = replace_fill_values(np.asarray(values, dtype=float))
    out[~np.isfinite(out)] = np.nan
    return out, np.isnan(out) & ~np.isnan(np.asarray(values, dtype=float))


def missing_offset_reasons(offsets_nT, reason) -> tuple:
    """``reason`` with a note on each window whose offset ``(k, 3)`` holds a fill value or
    a non-finite number: such a window is missing (NaN), never applied.

    Examples
    --------
    >>> missing_offset_reasons(np.array([[1.0, 2, 3], [-1e31, 2, 3]]), ("", ""))
    ('', 'offset Hp is a fill value or not finite (-1e+31): window treated as missing')
    """
    offsets = np.asarray(offsets_nT, dtype=float)
    flagged = missing_as_nan(offsets.ravel())[1].reshape(offsets.shape)
    out = list(reason)
    for k in np.flatnonzero(flagged.any(axis=1)):
        j = int(np.flatnonzero(flagged[k])[0])
        note = (f"offset {COMPONENTS[j]} is a fill value or not finite "
                f"({offsets[k, j]:g}): window treated as missing")
        old = str(out[k]) if str(out[k]) not in ("nan", "None") else ""
        out[k] = f"{note}; {old}" if old else note
    return tuple(out)


def read_offsets_csv(path) -> OffsetTable:
    """Read an ``OFFSETS.csv`` (contract columns required, extras optional).

    Raises
    ------
    InputError
        Missing file or column, unparsable time or number (naming the line), or
        centres not strictly increasing. Fill values (-1e31 family, -9999) and
        non-finite numbers are not errors: they read as NaN (a missing window).
    """
    from magcal.io.csv import parse_times, read_text_table

    p = Path(path)
    raw, _ = read_text_table(p)
    missing = [c for c in CONTRACT_COLUMNS if c not in raw.columns]
    if missing:
        raise InputError(f"missing column(s) {', '.join(missing)} (expected "
                         f"{','.join(CONTRACT_COLUMNS)})", file=p, column=missing[0])
    times = {}
    for c in ("center", "start", "end"):
        idx = parse_times(raw[c], file=p, column=c)
        times[c] = idx.tz_convert("UTC").tz_localize(None).to_numpy().astype("datetime64[ns]")
    if times["center"].size > 1 and np.any(np.diff(times["center"].astype(np.int64)) <= 0):
        bad = int(np.flatnonzero(np.diff(times["center"].astype(np.int64)) <= 0)[0]) + 1
        raise InputError("window centres not strictly increasing", file=p, row=bad + 2,
                         column="center")

    def num(col, default=np.nan, keep_missing=False):
        if col not in raw.columns:
            return np.full(len(raw), default, dtype=float)
        values = raw[col].str.strip().replace({"": "nan", "null": "nan", "NULL": "nan"})
        out = pd.to_numeric(values, errors="coerce").to_numpy(dtype=float)
        bad = np.isnan(out) & ~values.str.lower().isin(["nan"]).to_numpy()
        if bad.any():
            row = int(np.flatnonzero(bad)[0])
            raise InputError(f"not a number: {raw[col].iloc[row]!r}", file=p, row=row + 2,
                             column=col)
        return out if keep_missing else missing_as_nan(out)[0]

    # fill values and non-finite offsets are missing windows (NaN, skipped by apply),
    # with the reason saying so; the as-given values name them
    given = np.stack([num(c, keep_missing=True) for c in COMPONENTS], axis=1)
    offset = missing_as_nan(given)[0]
    std = np.stack([num(f"{c}_std") for c in COMPONENTS], axis=1)
    mad = np.stack([num(f"{c}_mad") for c in COMPONENTS], axis=1)
    n_used = np.nan_to_num(num("n_used"), nan=0).astype(np.int64)
    n_av = np.nan_to_num(num("n_available", -1), nan=-1).astype(np.int64)
    reason = tuple(raw["reason"]) if "reason" in raw.columns else ("",) * len(raw)
    reason = missing_offset_reasons(given, reason)
    cover = {c: np.nan_to_num(num(c, -1), nan=-1).astype(np.int64)
             for c in ("days_covered", "lt_hours_covered")}
    changes, test = _level_changes_beside(p, reason)
    segment = None
    if "segment" in raw.columns:
        seg = num("segment", keep_missing=True)
        whole = np.isfinite(seg) & (seg >= 0) & (seg == np.round(seg))
        if not whole.all():
            row = int(np.flatnonzero(~whole)[0])
            raise InputError(f"segment must be a whole number >= 0, got "
                             f"{raw['segment'].iloc[row]!r}", file=p, row=row + 2,
                             column="segment")
        segment = seg.astype(np.int64)
        if segment.size > 1 and np.any(np.diff(segment) < 0):
            row = int(np.flatnonzero(np.diff(segment) < 0)[0]) + 1
            raise InputError("segments must not decrease with the window centres", file=p,
                             row=row + 2, column="segment")
    return OffsetTable(center=times["center"], start=times["start"], end=times["end"],
                       offset_nT=offset, std_nT=std, mad_nT=mad, n_used=n_used,
                       n_available=n_av, fraction_used=num("fraction_used"), reason=reason,
                       parameters={"source": os.fspath(p)},
                       se_nT=np.stack([num(f"{c}_se") for c in COMPONENTS], axis=1),
                       dof=np.stack([num(f"{c}_dof") for c in COMPONENTS], axis=1),
                       level_changes=changes, level_test=test, segment=segment, **cover)


def _level_changes_beside(path: Path, reason) -> tuple:
    """The level changes in ``<path>.provenance.json`` when it lists them, else those the
    windows' ``reason`` cautions name; and the test's record ({} when unknown)."""
    from magcal.offsets.levels import LevelChange, changes_from_reasons

    side = Path(str(path) + ".provenance.json")
    try:
        payload = json.loads(side.read_text()) if side.is_file() else {}
    except (OSError, ValueError):
        payload = {}
    if isinstance(payload, dict) and isinstance(payload.get("level_changes"), list):
        try:
            changes = tuple(LevelChange.from_dict(d) for d in payload["level_changes"])
            return changes, dict(payload.get("level_change_test") or {})
        except (KeyError, TypeError, ValueError):
            pass
    return changes_from_reasons(reason), {}
