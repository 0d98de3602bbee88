"""Apply offsets: linear interpolation between window centres, end values held.

A product split at level changes (an ``OffsetTable`` with ``segment``, OFFSETS.csv with
the ``segment`` column: ``OffsetEstimator(split_at_level_changes=True)``) is applied
segment by segment (:func:`interpolate_segmented`): each sample takes the offsets of its
own segment only, interpolated between that segment's centres and held out to the
segment's ends (the level changes), never a line across a change.
"""

from __future__ import annotations

import numpy as np

from magcal.errors import InputError

#: ``offset_flag`` values of corrected data.
FLAG_INTERPOLATED = 0
FLAG_HELD_BEFORE = 1
FLAG_HELD_AFTER = 2
FLAG_NO_OFFSET = 3
#: Interpolated between two valid window centres with a window without a valid offset
#: between them: the line spans twice the step or more, and any drift of the offset
#: that the skipped window would have seen is not in it.
FLAG_BRIDGED = 4
FLAG_MEANING = {FLAG_INTERPOLATED: "interpolated between window centres",
                FLAG_HELD_BEFORE: "before the first window centre: first offset held",
                FLAG_HELD_AFTER: "after the last window centre: last offset held",
                FLAG_NO_OFFSET: "no valid offset: data left NaN",
                FLAG_BRIDGED: "interpolated across a window without a valid offset"}


def interpolate_offsets(times, centers, offsets_nT):
    """Offsets at ``times``: linear between valid window centres, end values held.

    Parameters
    ----------
    times : array_like of datetime64, shape (n,)
    centers : array_like of datetime64, shape (k,)
        Window centres, increasing.
    offsets_nT : array_like, shape (k, m)
        Offsets per window; windows with any NaN component are skipped.

    Returns
    -------
    offsets : ndarray, shape (n, m)
    flag : ndarray of int8, shape (n,)
        :data:`FLAG_MEANING` codes.

    Examples
    --------
    >>> import numpy as np
    >>> c = np.array(["2019-11-08", "2019-11-15"], dtype="datetime64[ns]")
    >>> t = np.array(["2019-11-01", "2019-11-11T12", "2019-11-20"], dtype="datetime64[ns]")
    >>> off, flag = interpolate_offsets(t, c, [[10.0], [17.0]])
    >>> off[:, 0], flag
    (array([10. , 13.5, 17. ]), array([1, 0, 2], dtype=int8))

    A window without an offset between two valid ones: the samples between those two
    centres are bridged (4), not plainly interpolated.

    >>> c3 = np.array(["2019-11-08", "2019-11-15", "2019-11-22"], dtype="datetime64[ns]")
    >>> t3 = np.array(["2019-11-09", "2019-11-20", "2019-11-23"], dtype="datetime64[ns]")
    >>> interpolate_offsets(t3, c3, [[10.0], [np.nan], [24.0]])[1]
    array([4, 4, 2], dtype=int8)
    """
    t = np.asarray(times).astype("datetime64[ns]").astype(np.int64).astype(float)
    c = np.asarray(centers).astype("datetime64[ns]").astype(np.int64).astype(float)
    off = np.asarray(offsets_nT, dtype=float)
    off = off[:, None] if off.ndim == 1 else off
    if off.shape[0] != c.size:
        raise InputError(f"{off.shape[0]} offsets for {c.size} window centres")
    ok = np.all(np.isfinite(off), axis=1)
    skipped_c = c[~ok]
    c, off = c[ok], off[ok]
    if c.size > 1 and np.any(np.diff(c) <= 0):
        raise InputError("window centres must be strictly increasing")
    out = np.full((t.size, off.shape[1]), np.nan)
    flag = np.full(t.size, FLAG_NO_OFFSET, dtype=np.int8)
    if c.size == 0:
        return out, flag
    for j in range(off.shape[1]):
        out[:, j] = np.interp(t, c, off[:, j])
    flag[:] = FLAG_INTERPOLATED
    if skipped_c.size and c.size > 1:
        # each sample's bracketing pair of valid centres, and whether a skipped centre
        # lies strictly between them
        k = np.clip(np.searchsorted(c, t, side="right") - 1, 0, c.size - 2)
        between = (np.searchsorted(skipped_c, c[k + 1], side="left")
                   - np.searchsorted(skipped_c, c[k], side="right"))
        # a sample at a valid centre takes that window's own offset
        flag[(between > 0) & (t > c[k]) & (t < c[k + 1])] = FLAG_BRIDGED
    flag[t < c[0]] = FLAG_HELD_BEFORE
    flag[t > c[-1]] = FLAG_HELD_AFTER
    return out, flag


def quality_bits(flag, across_change=None, near_change=None) -> np.ndarray:
    """The ``quality`` bits (:mod:`magcal.qc.flags`) that ``offset_flag`` values set:
    16 (``offset_held_or_extrapolated``) for a held or missing offset (1, 2, 3), 64
    (``offset_bridged_over_missing_window``) for one bridged across a window without an
    offset (4), none for a plain interpolation (0); 128
    (``offset_interpolated_across_level_change``) where ``across_change`` (bool, from
    :func:`across_level_change`) is True; and 256 (``offset_near_level_change``) where
    ``near_change`` (bool, from :func:`near_level_change`) is True.

    Examples
    --------
    >>> quality_bits([0, 1, 2, 3, 4]).tolist()
    [0, 16, 16, 16, 64]
    >>> quality_bits([0, 0, 4], across_change=[False, True, True]).tolist()
    [0, 128, 192]
    >>> quality_bits([0, 2], near_change=[True, True]).tolist()
    [256, 272]
    """
    from magcal.qc.flags import (OFFSET_ACROSS_LEVEL_CHANGE, OFFSET_BRIDGED, OFFSET_HELD,
                                 OFFSET_NEAR_LEVEL_CHANGE)

    flag = np.asarray(flag)
    held = np.isin(flag, (FLAG_HELD_BEFORE, FLAG_HELD_AFTER, FLAG_NO_OFFSET))
    out = (np.where(held, OFFSET_HELD, 0)
           | np.where(flag == FLAG_BRIDGED, OFFSET_BRIDGED, 0)).astype(np.uint16)
    if across_change is not None:
        out |= np.where(np.asarray(across_change, dtype=bool), OFFSET_ACROSS_LEVEL_CHANGE,
                        0).astype(np.uint16)
    if near_change is not None:
        out |= np.where(np.asarray(near_change, dtype=bool), OFFSET_NEAR_LEVEL_CHANGE,
                        0).astype(np.uint16)
    return out


def segment_bounds(table):
    """The segments of a product split at level changes and where each begins.

    A segment begins at the earliest ``start`` of its rows: the pieces after a change
    start at the change (:func:`magcal.offsets.windows.split_windows`), so this is the
    change's time, read from OFFSETS.csv alone (no sidecar needed).

    Returns
    -------
    labels : ndarray of int
        The segments, increasing.
    bounds : ndarray of int64 (ns)
        Begin of each segment after the first (``labels.size - 1`` values): a sample at
        ``t`` lies in segment ``labels[searchsorted(bounds, t, side="right")]``.
    None when ``table`` has no ``segment``.

    Examples
    --------
    >>> from types import SimpleNamespace
    >>> s = np.array(["2019-11-01", "2019-11-08", "2019-12-12", "2019-12-12"],
    ...              dtype="datetime64[ns]")
    >>> labels, bounds = segment_bounds(SimpleNamespace(start=s, segment=np.array([0, 0, 1, 1])))
    >>> labels.tolist(), str(bounds.astype("datetime64[ns]")[0].astype("datetime64[D]"))
    ([0, 1], '2019-12-12')
    """
    seg = getattr(table, "segment", None)
    if seg is None:
        return None
    seg = np.asarray(seg, dtype=np.int64)
    start = np.asarray(table.start).astype("datetime64[ns]").astype(np.int64)
    labels = np.unique(seg)
    bounds = np.array([start[seg == lab].min() for lab in labels[1:]], dtype=np.int64)
    return labels, bounds


def interpolate_segmented(times, table, values=None):
    """Offsets at ``times`` from a product split at level changes: each sample takes its
    own segment's windows only (:func:`interpolate_offsets` on them: linear between the
    segment's valid centres, its end values held out to the segment's ends, i.e. to the
    level change, flags 1 and 2).

    A sample whose segment has no valid window takes the unsplit interpolation over
    every valid window (its offset then comes across a change, as in the unsplit
    product; ``across`` says so, for quality bit 128).

    Parameters
    ----------
    times : array_like of datetime64, shape (n,)
    table : OffsetTable
        With ``segment`` (:func:`segment_bounds`).
    values : array_like, shape (k, m), optional
        What to interpolate (default ``table.offset_nT``; rows with any NaN are skipped).

    Returns
    -------
    offsets : ndarray, shape (n, m)
    flag : ndarray of int8, shape (n,)
    across : ndarray of bool, shape (n,)

    Examples
    --------
    Two windows each side of a change on 2019-12-12: before it the first segment's
    value is held to the change, after it the second's; no line joins them.

    >>> from types import SimpleNamespace
    >>> c = np.array(["2019-11-20", "2019-11-27", "2019-12-20", "2019-12-27"],
    ...              dtype="datetime64[ns]")
    >>> s = np.array(["2019-11-06", "2019-11-13", "2019-12-12", "2019-12-13"],
    ...              dtype="datetime64[ns]")
    >>> tab = SimpleNamespace(center=c, start=s, offset_nT=np.array([[1.0], [1.0], [4.0],
    ...                       [4.0]]), segment=np.array([0, 0, 1, 1]))
    >>> t = np.array(["2019-12-01", "2019-12-11T23", "2019-12-12T01"], dtype="datetime64[ns]")
    >>> off, flag, across = interpolate_segmented(t, tab)
    >>> off[:, 0], flag, across
    (array([1., 1., 4.]), array([2, 2, 1], dtype=int8), array([False, False, False]))
    """
    t = np.asarray(times).astype("datetime64[ns]")
    labels, bounds = segment_bounds(table)
    seg = np.asarray(table.segment, dtype=np.int64)
    vals = np.asarray(table.offset_nT if values is None else values, dtype=float)
    vals = vals[:, None] if vals.ndim == 1 else vals
    if vals.shape[0] != seg.size:
        raise InputError(f"{vals.shape[0]} rows of values for {seg.size} segment labels")
    centre = np.asarray(table.center).astype("datetime64[ns]")
    ok = np.all(np.isfinite(vals), axis=1)
    which = np.searchsorted(bounds, t.astype(np.int64), side="right")
    out = np.full((t.size, vals.shape[1]), np.nan)
    flag = np.full(t.size, FLAG_NO_OFFSET, dtype=np.int8)
    across = np.zeros(t.size, dtype=bool)
    for k, lab in enumerate(labels):
        rows, at = seg == lab, which == k
        if not at.any():
            continue
        if ok[rows].any():
            out[at], flag[at] = interpolate_offsets(t[at], centre[rows], vals[rows])
        elif ok.any():
            out[at], flag[at] = interpolate_offsets(t[at], centre, vals)
            across[at] = True
    return out, flag, across


def near_level_change(times, table) -> np.ndarray:
    """True for samples inside the 95 % time interval ``[time_lo, time_hi)`` of a level
    change of a product split at the changes (``table.segment``): the windows were cut
    at the change's most likely day, and within the interval which side's offset applies
    is uncertain (quality bit 256, ``offset_near_level_change``). Never True for an
    unsplit product (``segment`` None), whose samples around a change carry bit 128.

    Examples
    --------
    >>> from types import SimpleNamespace
    >>> ch = SimpleNamespace(time_lo=np.datetime64("2019-12-11", "ns"),
    ...                      time_hi=np.datetime64("2019-12-13", "ns"))
    >>> t = np.array(["2019-12-10T23", "2019-12-11", "2019-12-12T23", "2019-12-13"],
    ...              dtype="datetime64[ns]")
    >>> near_level_change(t, SimpleNamespace(segment=np.zeros(2), level_changes=(ch,)))
    array([False,  True,  True, False])
    >>> bool(near_level_change(t, SimpleNamespace(segment=None, level_changes=(ch,))).any())
    False
    """
    t = np.asarray(times).astype("datetime64[ns]").astype(np.int64)
    out = np.zeros(t.size, dtype=bool)
    if getattr(table, "segment", None) is None:
        return out
    for ch in tuple(getattr(table, "level_changes", ()) or ()):
        lo = np.datetime64(ch.time_lo, "ns").astype(np.int64)
        hi = np.datetime64(ch.time_hi, "ns").astype(np.int64)
        out |= (t >= lo) & (t < hi)
    return out


def across_level_change(times, table) -> np.ndarray:
    """True for samples whose interpolated offset spans a level change of the offset
    (``table.level_changes``, :mod:`magcal.offsets.levels`).

    That is a sample between the two valid window centres that bracket a change (the
    line joins the two levels and spreads the change over the step or more), or one
    whose offset takes a weight from a valid window straddling a change (its median
    mixes both levels), held ends included. Samples with no valid offset are never
    flagged here (``offset_flag`` 3 says so). For a product split at the changes
    (``table.segment``) only samples whose own segment has no valid window, and so take
    their offset from across a change (:func:`interpolate_segmented`).

    Parameters
    ----------
    times : array_like of datetime64, shape (n,)
    table : OffsetTable
        With ``level_changes`` (a table without them flags nothing).

    Returns
    -------
    ndarray of bool, shape (n,)

    Examples
    --------
    Weekly centres, windows 28 days long, a change on 2019-12-12: the valid windows
    centred 11-29 .. 12-20 straddle it, so the offsets between 11-22 and 12-27 are
    interpolated from one of them.

    >>> import numpy as np
    >>> from types import SimpleNamespace
    >>> c = np.arange("2019-11-15", "2020-01-10", 7, dtype="datetime64[D]").astype("datetime64[ns]")
    >>> ch = SimpleNamespace(time=np.datetime64("2019-12-12", "ns"))
    >>> tab = SimpleNamespace(center=c, start=c - np.timedelta64(14, "D"),
    ...                       end=c + np.timedelta64(14, "D"), offset_nT=np.zeros((c.size, 3)),
    ...                       level_changes=(ch,))
    >>> t = np.array(["2019-11-22", "2019-11-23", "2019-12-26", "2019-12-28"],
    ...              dtype="datetime64[ns]")
    >>> across_level_change(t, tab)
    array([False,  True,  True, False])
    """
    from magcal.offsets.levels import straddling_windows

    if getattr(table, "segment", None) is not None:
        return interpolate_segmented(times, table)[2]
    t = np.asarray(times).astype("datetime64[ns]").astype(np.int64)
    out = np.zeros(t.size, dtype=bool)
    changes = tuple(getattr(table, "level_changes", ()) or ())
    ok = np.all(np.isfinite(np.asarray(table.offset_nT, dtype=float)), axis=1)
    if not changes or not ok.any():
        return out
    c = np.asarray(table.center).astype("datetime64[ns]").astype(np.int64)[ok]
    s = np.asarray(table.start).astype("datetime64[ns]").astype(np.int64)[ok]
    e = np.asarray(table.end).astype("datetime64[ns]").astype(np.int64)[ok]
    at = np.array([np.datetime64(ch.time, "ns").astype(np.int64) for ch in changes])
    straddles = np.array([bool(inside) for inside in straddling_windows(s, e, changes)])
    if c.size == 1:
        return out | bool(straddles[0])
    # each sample's bracketing pair of valid centres (the end pair beyond the ends)
    k = np.clip(np.searchsorted(c, t, side="right") - 1, 0, c.size - 2)
    lo, hi = c[k], c[k + 1]
    inside = (t > lo) & (t < hi)
    spans = np.zeros(t.size, dtype=bool)
    for a in at:
        spans |= inside & (lo < a) & (a < hi)
    # weights: left window where t < hi (or held before the first centre), right window
    # where t > lo (or held after the last)
    uses_left = (t < hi) & straddles[k]
    uses_right = (t > lo) & straddles[k + 1]
    return spans | uses_left | uses_right


def apply_offsets(times, data_hpen, table):
    """Subtract interpolated offsets from Hpen data (segment by segment for a product
    split at level changes, :func:`interpolate_segmented`).

    Parameters
    ----------
    times : array_like of datetime64, shape (n,)
    data_hpen : array_like, shape (n, 3)
    table : OffsetTable

    Returns
    -------
    corrected : ndarray, shape (n, 3)
    offsets : ndarray, shape (n, 3)
    flag : ndarray of int8, shape (n,)
    """
    data = np.asarray(data_hpen, dtype=float)
    if getattr(table, "segment", None) is not None:
        off, flag, _ = interpolate_segmented(times, table)
    else:
        off, flag = interpolate_offsets(times, table.center, table.offset_nT)
    if data.shape != off.shape:
        raise InputError(f"data shape {data.shape} does not match {off.shape}")
    return data - off, off, flag


def outside_valid_windows(times, table) -> np.ndarray:
    """True for samples that lie in no valid window ``[start, end)`` of ``table``.

    Their offset was held or interpolated from windows that never saw them (before the
    first or after the last valid window, or across windows without a trusted offset);
    ``offsets apply`` says how many there are.

    Examples
    --------
    >>> import numpy as np
    >>> from types import SimpleNamespace
    >>> day = np.timedelta64(1, "D")
    >>> s = np.array(["2019-11-01", "2019-11-08"], dtype="datetime64[ns]")
    >>> tab = SimpleNamespace(start=s, end=s + 28 * day,
    ...                       offset_nT=np.array([[1.0], [np.nan]]))
    >>> t = np.array(["2019-10-31", "2019-11-20", "2019-12-01"], dtype="datetime64[ns]")
    >>> outside_valid_windows(t, tab)
    array([ True, False,  True])
    """
    t = np.asarray(times).astype("datetime64[ns]").astype(np.int64)
    ok = np.all(np.isfinite(np.asarray(table.offset_nT, dtype=float)), axis=1)
    starts = np.asarray(table.start).astype("datetime64[ns]").astype(np.int64)[ok]
    ends = np.asarray(table.end).astype("datetime64[ns]").astype(np.int64)[ok]
    if starts.size == 0:
        return np.ones(t.size, dtype=bool)
    order = np.argsort(starts, kind="stable")
    starts, reach = starts[order], np.maximum.accumulate(ends[order])
    k = np.searchsorted(starts, t, side="right") - 1
    inside = (k >= 0) & (t < reach[np.maximum(k, 0)])
    return ~inside


def skipped_windows_note(table) -> str:
    """What ``offsets apply`` says about windows without a valid offset (NaN, fill value
    or non-finite in OFFSETS.csv): they are skipped, never applied; '' when there are none.

    Examples
    --------
    >>> import numpy as np
    >>> from types import SimpleNamespace
    >>> c = np.array(["2019-11-04T12", "2019-11-07T12"], dtype="datetime64[ns]")
    >>> tab = SimpleNamespace(center=c, offset_nT=np.array([[1.0], [np.nan]]))
    >>> for part in skipped_windows_note(tab).split(", skipped: "):
    ...     print(part)
    1 of 2 windows without a valid offset (NaN, fill value or non-finite)
    centre 2019-11-07T12:00:00
    """
    bad = ~np.all(np.isfinite(np.asarray(table.offset_nT, dtype=float)), axis=1)
    if not bad.any():
        return ""
    centres = [str(np.datetime64(c, "s")) for c in np.asarray(table.center)[bad]]
    shown = ", ".join(centres[:5]) + (f" and {len(centres) - 5} more" if len(centres) > 5
                                      else "")
    return (f"{int(bad.sum())} of {bad.size} windows without a valid offset (NaN, fill value "
            f"or non-finite), skipped: centre{'s' if len(centres) > 1 else ''} {shown}")


def offset_uncertainty(times, table) -> np.ndarray:
    """1-sigma uncertainty (nT) of the interpolated offset at each sample, (n, 3).

    The offset at a sample is a linear blend ``(1 - w) o_a + w o_b`` of two window
    offsets; overlapping windows share samples, so their errors are positively
    correlated and the blend's error is at most ``(1 - w) se_a + w se_b`` (full
    correlation), which is what is returned: an upper bound, never an understatement.
    Held ends take the end window's standard error (a drift beyond the last window is
    not included). NaN where no window has a standard error. A product split at level
    changes takes each sample's own segment (:func:`interpolate_segmented`).

    Parameters
    ----------
    times : array_like of datetime64, shape (n,)
    table : OffsetTable
        With ``se_nT`` (from :class:`~magcal.offsets.OffsetEstimator` or OFFSETS.csv).

    Examples
    --------
    >>> import numpy as np
    >>> from magcal.offsets.table import OffsetTable
    >>> c = np.array(["2019-11-08", "2019-11-15"], dtype="datetime64[ns]")
    >>> tab = OffsetTable(center=c, start=c, end=c, offset_nT=np.zeros((2, 3)),
    ...                   std_nT=np.ones((2, 3)), mad_nT=np.ones((2, 3)),
    ...                   n_used=np.array([9, 9]), n_available=np.array([9, 9]),
    ...                   fraction_used=np.ones(2), se_nT=np.array([[0.2] * 3, [0.4] * 3]))
    >>> t = np.array(["2019-11-01", "2019-11-11T12"], dtype="datetime64[ns]")
    >>> offset_uncertainty(t, tab)[:, 0].round(3)
    array([0.2, 0.3])
    """
    se = getattr(table, "se_nT", None)
    n = np.asarray(times).size
    if se is None:
        return np.full((n, 3), np.nan)
    se = np.where(np.all(np.isfinite(table.offset_nT), axis=1)[:, None], se, np.nan)
    ok = np.all(np.isfinite(se), axis=1)
    if not ok.any():
        return np.full((n, 3), np.nan)
    if getattr(table, "segment", None) is not None:
        return interpolate_segmented(times, table, values=se)[0]
    out, _ = interpolate_offsets(times, np.asarray(table.center)[ok], se[ok])
    return out
