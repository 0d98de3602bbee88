"""How well the calibration bridges an interval left out of its fits: trial gaps.

Samples left out of the fits (a natural field located from the counts, or given in
``[spin] disturbed``) are calibrated by the fits of the rest of the zone: their product
keeps the natural field, plus whatever the calibration would have been different had
they been fitted. That second part cannot be seen where the natural field is; it can
be measured elsewhere in the same zone. Each trial leaves out, in every zone with
left-out samples, a *quiet* interval as long as the zone's longest left-out run, and
calibrates the day again with the same settings; the product's change over the trial
interval is the error such a bridge makes (:func:`bridge_trials`).

On 2022-01-12 (zones 1, 4, 7, 10, 70 s trials at five positions, no detection) the
change over the gap was 4-42 nT RMS (vector norm), and at the zone centre it came
within 30 % of the error a detector that flagged exactly an injected 40 s pulse left
(4-11 nT): the ``distortion`` of :mod:`magcal.missions.elfin.injection` is this error.
With detection and three trials per zone (the delivered settings), 40 s pulses across B
injected at 0.35, 0.5 and 0.65 of every zone of the day (67 cases left out) had an RMS
error over their left-out samples within the stated ``bridge_rms_nT`` in 81 % of the
cases and within twice it in all (largest ratio 1.98). With the pulses at drawn places
(0.3-0.7 of zones 1, 4, 7, 10; 20 seeds, with and without added instrument noise,
:mod:`magcal.missions.elfin.noise`) twice the stated error held in 97-100 %; it is a
typical size, not a bound: a pulse at 0.53-0.55 of zone 4, where a gap is bridged
worst, had 2.4-4.3 times the error the trials elsewhere in the zone measured.

Data: ELFIN SOC (PI V. Angelopoulos, UCLA), "Open Data for Scientific Use".
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from magcal.missions.elfin.timing import true_runs

#: Columns of the calibrated field compared (GEI, nT).
_COLS = ["bx_gei", "by_gei", "bz_gei"]


def trial_intervals(t_s, left_out, used, n_trials: int, *, edge_s: float = 20.0,
                    min_len_s: float = 20.0) -> tuple[list[tuple[float, float]], float]:
    """Quiet intervals of one zone, as long as its longest left-out run, for trials.

    Candidate centres step through the used span (every ``max(1 s, length / 20)``,
    taken from the middle outwards); a candidate is taken when it stays ``edge_s`` from
    the zone's ends and does not touch a left-out sample or an interval taken before.
    Where no interval that long fits, 3/4 and then 1/2 of it are tried (not below
    ``min_len_s``): a shorter gap is bridged better, so the error is then understated.

    Parameters
    ----------
    t_s : array_like (n,)
        Times of the zone's samples, s.
    left_out, used : array_like of bool (n,)
        Samples left out of the fits, and calibrated samples.
    n_trials : int
        Intervals wanted.
    edge_s, min_len_s : float
        Distance from the zone's first and last used samples; shortest trial length.

    Returns
    -------
    intervals : list of (start, end)
        In seconds (fewer than ``n_trials`` when the zone has no room).
    length_s : float
        The trial length used: the longest left-out run (at least ``min_len_s``), or
        the shortened one.

    Examples
    --------
    >>> t = np.arange(0.0, 360.0, 0.1)
    >>> out = (t > 150) & (t < 210)
    >>> iv, length = trial_intervals(t, out, t >= 0, 2)
    >>> round(length), [(round(a), round(b)) for a, b in iv]
    (60, [(89, 149), (211, 271)])
    """
    t = np.asarray(t_s, float)
    left_out = np.asarray(left_out, bool) & np.asarray(used, bool)
    used = np.asarray(used, bool)
    runs = [t[b - 1] - t[a] for a, b in true_runs(left_out)]
    longest = max([min_len_s] + runs)
    for length in (longest, 0.75 * longest, 0.5 * longest):
        length = max(length, min_len_s)
        taken = _place(t, left_out, used, n_trials, length, edge_s)
        if taken:
            return taken, length
    return [], longest


def _place(t, left_out, used, n_trials, length, edge_s) -> list[tuple[float, float]]:
    """Up to ``n_trials`` intervals of ``length`` (s) clear of ``left_out`` and the ends."""
    first, last = t[used][0] + edge_s, t[used][-1] - edge_s
    if last - first < length or n_trials < 1:
        return []
    step = max(1.0, length / 20.0)
    centres = np.arange(first + length / 2, last - length / 2 + 1e-9, step)
    order = np.argsort(np.abs(centres - (first + last) / 2), kind="stable")
    taken: list[tuple[float, float]] = []
    busy = t[left_out]
    for c in centres[order]:
        a, b = c - length / 2, c + length / 2
        if np.any((busy >= a) & (busy <= b)):
            continue
        if any(a <= y and x <= b for x, y in taken):
            continue
        taken.append((float(a), float(b)))
        if len(taken) == n_trials:
            break
    return taken


def bridge_trials(calibrate, field: pd.DataFrame, left_out, n_trials: int = 3, *,
                  edge_s: float = 20.0) -> pd.DataFrame:
    """Per zone with left-out samples: the product's change over quiet trial gaps.

    Parameters
    ----------
    calibrate : callable
        ``calibrate(extra)`` returns the calibrated field (same rows as ``field``) with
        the rows ``extra`` (bool, len(field)) left out of every fit as well.
    field : DataFrame
        The delivered calibrated field (``zone``, ``used``, GEI components).
    left_out : array_like of bool (len(field),)
        Rows the delivered calibration left out of its fits.
    n_trials : int
        Trial gaps per zone (trial ``j`` of every zone share one calibration).
    edge_s : float
        Trial gaps stay this far from the zone's ends (the calibration is bridged
        there, not extrapolated, as for the detected runs).

    Returns
    -------
    DataFrame
        One row per zone with left-out samples: ``zone``, ``length_s``, ``n_trials``,
        ``bridge_rms_nT`` (RMS over the trials' gap samples of the vector change,
        ``|delta B|``), ``outside_rms_nT`` (the same over the zone's other fitted
        samples: what leaving the gap out moved elsewhere), ``longest_s`` (the longest
        left-out run; ``length_s`` is shorter where the zone had no room for it),
        ``at_zone_end`` (a left-out run within ``edge_s`` of a zone end: the calibration
        is extrapolated there, not bridged, and the trials understate its error),
        ``trials`` (start and end of each gap, s from the zone's first sample, and its
        RMS).
    """
    left_out = np.asarray(left_out, bool)
    zone = field["zone"].to_numpy()
    used = field["used"].to_numpy() == 1
    plans = {}
    for k in dict.fromkeys(zone.tolist()):
        sel = np.flatnonzero(zone == k)
        if not (left_out[sel] & used[sel]).any():
            continue
        ns = field.index.as_unit("ns").asi8[sel]
        t = (ns - ns[0]) / 1e9
        iv, length = trial_intervals(t, left_out[sel], used[sel], n_trials, edge_s=edge_s)
        spans = true_runs(left_out[sel] & used[sel])
        tu = t[used[sel]]
        at_end = any(t[a] - tu[0] < edge_s or tu[-1] - t[b - 1] < edge_s for a, b in spans)
        plans[k] = (sel, t, iv, length, max(t[b - 1] - t[a] for a, b in spans), at_end)
    base = field[_COLS].to_numpy(float)
    sums = {k: {"gap": [], "out": [], "trials": []} for k in plans}
    for j in range(max((len(p[2]) for p in plans.values()), default=0)):
        extra = np.zeros(len(field), bool)
        for k, (sel, t, iv, *_) in plans.items():
            if j < len(iv):
                a, b = iv[j]
                extra[sel] = (t >= a) & (t <= b)
        new = calibrate(extra)[_COLS].to_numpy(float)
        change = np.linalg.norm(new - base, axis=1)
        for k, (sel, t, iv, *_) in plans.items():
            if j >= len(iv):
                continue
            gap = extra[sel] & used[sel]
            out = ~extra[sel] & ~left_out[sel] & used[sel]
            sums[k]["gap"].append(change[sel][gap])
            sums[k]["out"].append(change[sel][out])
            sums[k]["trials"].append({"start_s": iv[j][0], "end_s": iv[j][1],
                                      "rms_nT": float(np.sqrt(np.mean(change[sel][gap] ** 2)))})
    rows = []
    for k, (sel, t, iv, length, longest, at_end) in plans.items():
        gap = np.concatenate(sums[k]["gap"]) if sums[k]["gap"] else np.array([])
        out = np.concatenate(sums[k]["out"]) if sums[k]["out"] else np.array([])
        rows.append({"zone": int(k), "length_s": float(length),
                     "longest_s": float(longest), "at_zone_end": bool(at_end),
                     "n_trials": len(iv),
                     "bridge_rms_nT": float(np.sqrt(np.mean(gap ** 2))) if gap.size else np.nan,
                     "outside_rms_nT": float(np.sqrt(np.mean(out ** 2))) if out.size else np.nan,
                     "trials": sums[k]["trials"]})
    return pd.DataFrame(rows, columns=["zone", "length_s", "longest_s", "at_zone_end",
                                       "n_trials",
                                       "bridge_rms_nT", "outside_rms_nT", "trials"])


def bridge_column(field: pd.DataFrame, left_out, table: pd.DataFrame) -> np.ndarray:
    """Per row: the zone's ``bridge_rms_nT`` where the row was left out of the fits,
    NaN elsewhere (fitted rows, or a zone without room for a trial)."""
    out = np.full(len(field), np.nan)
    zone = field["zone"].to_numpy()
    rms = dict(zip(table["zone"], table["bridge_rms_nT"]))
    left = np.asarray(left_out, bool) & (field["used"].to_numpy() == 1)
    for k, v in rms.items():
        out[left & (zone == k)] = v
    return out
