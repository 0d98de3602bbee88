"""Level steps of the spin-axis field across intervals left out of the ELFIN fits.

A current sheet crossed inside a disturbed interval leaves the natural field at a new
level after it, mostly east-west and so within a few degrees of ELFIN's spin axis.
The calibration's spin-axis offset is set only against the model, so without help
its slow terms take the new level as an offset drift or a tilt and the product loses
the sheet (2022-01-12: 3 % of a 300 nT sheet kept). An instrument offset does not jump
within a pass; a natural field may. So where the delivered product's spin-axis
residual jumps across a left-out interval by most of its excursion inside it
(:func:`level_steps_wanted`), that interval is marked (:func:`level_step_rows`) and the
day is calibrated again with a free step of the spin-axis level after it
(:func:`step_columns`), fitted with the slow terms and left in the field
(``ElfinSettings.level_steps``).

How well a kept level is known is measured, not assumed (:func:`level_trials`,
``ElfinSettings.level_trials``): the step trades with the zone's slow spin-axis terms,
so its error is that of a sheet of its size put into other zones and measured again.

The decision is taken once, on the product without steps (residual about 15 nT), not
inside each fit (but where a zone wants several steps: a sheet bends that product, and
a real disturbance before it may then look like a level change too, so the strongest
step is kept first and the others judged on the day calibrated with it;
``max_steps`` of :func:`level_step_rows`): the linear fit's own residual (about
100 nT before the gain drift and the phase refit) jumps by tens of nT across quiet
gaps and gave steps to the bridge trials' gaps (bridge errors up to 86 nT on the real
day).

Data: ELFIN SOC (PI V. Angelopoulos, UCLA), "Open Data for Scientific Use".
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from magcal.missions.elfin.timing import true_runs

#: Smallest jump of the spin-axis residual across a left-out interval (nT) that gets
#: a level step: the detector's own smallest disturbance.
LEVEL_STEP_MIN_NT = 30.0
#: ... and its smallest share of the largest excursion within the interval: a field
#: that comes back (a pulse) jumps by a small share of its peak, a sheet by all of it.
LEVEL_STEP_MIN_SHARE = 0.5


def left_out_runs(t_s, fit, *, min_s: float = 5.0) -> list[tuple[int, int]]:
    """Row slices ``(a, b)`` of the runs of samples that ``fit`` leaves out between its
    first and last fitted sample and that last ``min_s`` or more.

    Examples
    --------
    >>> t = np.arange(0.0, 100.0, 1.0)
    >>> left_out_runs(t, (t < 40) | (t > 60))
    [(40, 61)]
    """
    t = np.asarray(t_s, dtype=float)
    fit = np.asarray(fit, bool)
    inner = ~fit & (t > t[fit][0]) & (t < t[fit][-1])
    return [(a, b) for a, b in true_runs(inner) if t[b - 1] - t[a] >= min_s]


def level_change(t_s, values, fit, start_s: float, end_s: float,
                 window_s: float = 30.0) -> float:
    """Median of ``values`` over the fitted samples in the ``window_s`` after ``end_s``
    minus that in the ``window_s`` before ``start_s`` (NaN if a side has none): the
    level change across an interval, or at a time when ``start_s == end_s``.

    Examples
    --------
    >>> t = np.arange(0.0, 100.0, 1.0)
    >>> float(level_change(t, np.where(t > 50, 300.0, 0.0), np.ones(100, bool), 40, 60))
    300.0
    """
    t = np.asarray(t_s, dtype=float)
    v = np.asarray(values, dtype=float)
    fit = np.asarray(fit, bool)
    before = fit & (t < start_s) & (t >= start_s - window_s)
    after = fit & (t > end_s) & (t <= end_s + window_s)
    if not (before.any() and after.any()):
        return float("nan")
    return float(np.median(v[after]) - np.median(v[before]))


def step_columns(marked) -> np.ndarray:
    """Columns (n, m): 1 after each run of ``marked`` rows, 0 before and inside.

    Fitted alongside a zone's slow terms and not removed from the field, a column lets
    the natural field's level differ across the run (a current sheet crossed there),
    where the slow terms would otherwise take the new level as a tilt or an offset
    drift. The rows inside the run are left out of the fits anyway.

    Examples
    --------
    >>> cols = step_columns([0, 1, 1, 0, 0, 1, 0])
    >>> cols.T.tolist()
    [[0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 1.0], [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]]
    """
    marked = np.asarray(marked, bool)
    idx = np.arange(marked.size)
    cols = [(idx >= b).astype(float) for _, b in true_runs(marked)]
    return np.column_stack(cols) if cols else np.empty((marked.size, 0))


#: ... and the factor by which it must divide the sum of squares of the trend fit
#: (2022-01-12, product without steps: injected 300 nT sheets 6.2-10.2; a real
#: disturbance that the detector flags only in part, with 40-130 nT of natural field
#: on the fitted side, 1.4 and 1.9 (zones 8 and 2); every other gap 1.00-1.50).
LEVEL_STEP_MIN_GAIN = 3.0
#: ... and the smallest share of it in the level change next to the interval (30 s
#: either side; 2022-01-12 with 300 nT sheets injected at 0.35, 0.5 and 0.65 of every
#: zone: 0.42-1.4; a disturbance flagged in part, with the trend bent to fit a short
#: side: 0.14-0.36).
LEVEL_STEP_MIN_LOCAL = 0.4
#: Degree of the polynomial in time fitted with the steps: the slow terms that took
#: part of a sheet in the product without steps (offset drift, tilt) leave a trend of
#: about this degree on both sides of it.
LEVEL_TREND_DEGREE = 3


def level_steps_wanted(t_s, axis_residual, fit, *, degree: int = LEVEL_TREND_DEGREE,
                       smooth_s: float = 3.0, window_s: float = 30.0,
                       min_s: float = 5.0, max_steps: int | None = None) -> np.ndarray:
    """Which intervals of :func:`left_out_runs` get a level step.

    The spin-axis residual on the fitted samples is fitted with a polynomial in time
    and steps after the intervals, chosen one at a time (the one that lowers the sum
    of squares most first). A step is kept if it divides the sum of squares by at
    least :data:`LEVEL_STEP_MIN_GAIN`, is at least :data:`LEVEL_STEP_MIN_NT`, at least
    :data:`LEVEL_STEP_MIN_SHARE` of the largest excursion inside its interval from the
    level before it, and the level change seen next to the interval (medians over the
    fitted samples within ``window_s`` either side) is of its sign and at least
    :data:`LEVEL_STEP_MIN_LOCAL` of it (all spin-averaged over ``smooth_s``): a field
    that comes back (a pulse) has a large excursion and no step, a current sheet a step
    as large as its excursion, and a disturbance that goes on beyond the interval
    (detected only in part) leaves natural field on the fitted side that a step
    explains only in part, or only with the trend bent on a short side. Fitting the
    trend with the steps keeps a sheet's trace in the product without steps (the slow
    terms tilted to take part of it) from posing as steps at the quiet gaps before it.
    ``max_steps`` stops the choice after that many.

    Returns
    -------
    ndarray of bool (m,)
        One per run of :func:`left_out_runs`; :func:`judge_level_steps` gives the
        tests' values too.

    Examples
    --------
    >>> t = np.arange(0.0, 300.0, 0.1)
    >>> sheet = 300.0 / (1.0 + np.exp(-(t - 150.0) / 4.0)) - 1.0 * t
    >>> pulse = 200.0 * np.exp(-0.5 * ((t - 150.0) / 17.0) ** 2)
    >>> fit = ((t < 120) | (t > 180)) & ~((t > 50) & (t < 70))
    >>> level_steps_wanted(t, sheet, fit).tolist(), level_steps_wanted(t, pulse, fit).tolist()
    ([False, True], [False, False])
    """
    table = judge_level_steps(t_s, axis_residual, fit, degree=degree, smooth_s=smooth_s,
                              window_s=window_s, min_s=min_s, max_steps=max_steps)
    return table["kept"].to_numpy(bool)


#: Columns of :func:`judge_level_steps`.
JUDGED_COLUMNS = ["start_s", "end_s", "step_nT", "share", "local_nT", "gain", "kept", "why"]
#: What ``level_steps.judged`` of ``ELFIN_CAL.json`` holds (:func:`judge_level_steps`).
JUDGED_NOTE = (
    "every left-out interval judged for a step on the spin-axis residual (spin-averaged) "
    "of the product without steps, kept or not: step_nT fitted with a cubic trend and "
    f"the kept steps; kept if it divides the sum of squares by {LEVEL_STEP_MIN_GAIN:g} or "
    f"more (gain), is {LEVEL_STEP_MIN_NT:g} nT or more, {LEVEL_STEP_MIN_SHARE:g} of the "
    "largest excursion inside or more (share) and the level change beside it (local_nT, "
    f"30 s either side) is {LEVEL_STEP_MIN_LOCAL:g} of it or more; why: the tests it fails")


def judge_level_steps(t_s, axis_residual, fit, *, degree: int = LEVEL_TREND_DEGREE,
                      smooth_s: float = 3.0, window_s: float = 30.0, min_s: float = 5.0,
                      max_steps: int | None = None) -> pd.DataFrame:
    """:func:`level_steps_wanted`'s choice with the values of its tests, per interval.

    For a kept step the values are those of the final fit with the steps kept (its
    ``gain``: the sum of squares without it over that with it); for one not kept,
    those of the kept steps with it added (``gain``: the kept steps' sum of squares
    over that with it). ``why`` names the tests an interval fails ("" if kept):
    so that a current sheet the product took as an offset drift shows as an interval
    judged and not kept, with how far it was from a step.

    Returns
    -------
    DataFrame
        One row per run of :func:`left_out_runs`: ``start_s``, ``end_s`` (times of its
        first and last sample), ``step_nT``, ``share`` (the step over the largest
        excursion inside the interval), ``local_nT`` (the level change next to it),
        ``gain``, ``kept`` and ``why``.

    Examples
    --------
    >>> t = np.arange(0.0, 300.0, 0.1)
    >>> pulse = 200.0 * np.exp(-0.5 * ((t - 150.0) / 17.0) ** 2)
    >>> fit = (t < 120) | (t > 180)
    >>> row = judge_level_steps(t, pulse, fit).iloc[0]
    >>> bool(row["kept"]), row["why"].split("; ")[:2]
    (False, ['gain under 3', 'under 30 nT'])
    """
    t = np.asarray(t_s, dtype=float)
    r = np.asarray(axis_residual, dtype=float)
    fit = np.asarray(fit, bool) & np.isfinite(r)
    runs = left_out_runs(t, fit, min_s=min_s)
    table = pd.DataFrame({"start_s": [t[a] for a, _ in runs],
                          "end_s": [t[b - 1] for _, b in runs],
                          "step_nT": np.nan, "share": np.nan, "local_nT": np.nan,
                          "gain": np.nan, "kept": False, "why": ""}, columns=JUDGED_COLUMNS)
    if not runs or fit.sum() <= degree + 1 + len(runs):
        table["why"] = "too few fitted samples"
        return table
    width = max(1, int(round(smooth_s / max(float(np.median(np.diff(t))), 1e-9))))
    r_s = np.convolve(np.nan_to_num(r), np.ones(width) / width, mode="same")
    T = 2.0 * (t - t[fit][0]) / (t[fit][-1] - t[fit][0]) - 1.0
    trend = np.column_stack([T ** d for d in range(degree + 1)])
    steps = np.column_stack([(t > t[b - 1]).astype(float) for _, b in runs])

    def solve(chosen):
        x = np.column_stack([trend, steps[:, chosen]])
        coef = np.linalg.lstsq(x[fit], r_s[fit], rcond=None)[0]
        return coef, float(np.sum((r_s - x @ coef)[fit] ** 2))

    def tests(j, chosen, coef) -> tuple:
        """Step j's size, share, local change and the size tests it fails, in the fit
        of the steps ``chosen`` (sorted, holding j)."""
        a, b = runs[j]
        size = coef[degree + 1 + chosen.index(j)]
        before = trend[a] @ coef[:degree + 1] + sum(
            c for i, c in zip(chosen, coef[degree + 1:]) if runs[i][1] <= a)
        peak = np.max(np.abs(r_s[a:b] - before))
        local = level_change(t, r_s, fit, t[a], t[b - 1], window_s)
        fails = []
        if abs(size) < LEVEL_STEP_MIN_NT:
            fails.append(f"under {LEVEL_STEP_MIN_NT:g} nT")
        if abs(size) < LEVEL_STEP_MIN_SHARE * peak:
            fails.append(f"under {LEVEL_STEP_MIN_SHARE:g} of the excursion inside")
        if not np.isfinite(local):
            fails.append("no fitted samples beside it")
        elif not local * size >= LEVEL_STEP_MIN_LOCAL * size ** 2:
            fails.append(f"level change beside it under {LEVEL_STEP_MIN_LOCAL:g} of it")
        return size, abs(size) / peak if peak > 0 else np.inf, local, fails

    chosen = []
    rss = solve(chosen)[1]
    while len(chosen) < min(len(runs), len(runs) if max_steps is None else max_steps):
        tried = []
        for j in range(len(runs)):
            if j in chosen:
                continue
            trial = sorted(chosen + [j])
            coef, new = solve(trial)
            if new * LEVEL_STEP_MIN_GAIN <= rss and not any(
                    tests(i, trial, coef)[3] for i in trial):
                tried.append((new, trial))
        if not tried:
            break
        rss, chosen = min(tried)
    coef_kept = solve(chosen)[0]
    for j in range(len(runs)):
        if j in chosen:
            rest = [i for i in chosen if i != j]
            size, share, local, fails = tests(j, chosen, coef_kept)
            gain = solve(rest)[1] / max(rss, 1e-300)
        else:
            trial = sorted(chosen + [j])
            coef, new = solve(trial)
            size, share, local, fails = tests(j, trial, coef)
            gain = rss / max(new, 1e-300)
            if gain < LEVEL_STEP_MIN_GAIN:
                fails = [f"gain under {LEVEL_STEP_MIN_GAIN:g}"] + fails
            if not fails:
                fails = ["not chosen (max_steps, or a kept step fails with it)"]
        table.loc[j, ["step_nT", "share", "local_nT", "gain"]] = [size, share, local, gain]
        table.loc[j, "kept"] = j in chosen
        table.loc[j, "why"] = "; ".join(fails) if j not in chosen else ""
    return table


def level_change_candidates(t_s, axis_residual, fit, *, window_s: float = 15.0,
                            grid_s: float = 1.0, edge_s: float = 20.0,
                            pad_s: float = 10.0) -> np.ndarray:
    """Fitted samples where the spin-axis residual changes level within ``window_s``.

    A current sheet's rise that the detector of disturbed intervals missed (its plateau
    is not a localized excursion, and the sheet bends the stiff calibration it looks
    at) is still an abrupt change of the product's spin-axis residual. On a grid of
    ``grid_s`` from ``edge_s`` after the first fitted sample to ``edge_s`` before the
    last, the :func:`level_change` over ``window_s`` either side; around each local
    extreme of at least :data:`LEVEL_STEP_MIN_NT`, the span where the change stays
    above half the extreme, widened by ``pad_s``, is a candidate if the ``2 window_s``
    either side are within the fitted span (a short end side makes any trend a step:
    2022-01-12 zone 1, an east-west pulse fitted without detection gave one 19 s
    before the end) and none of their samples is left out of the fits (2022-01-12
    zones 7 and 8: the falling edge of a disturbance whose top is left out is a level
    change only against the trend). :func:`level_steps_wanted` then judges them with
    the left-out intervals: a field that comes back (a pulse, a disturbance) fails its
    tests.

    Returns
    -------
    ndarray of bool (n,)
        True on the candidate samples.

    Examples
    --------
    >>> t = np.arange(0.0, 370.0, 0.2)
    >>> r = 300.0 / (1.0 + np.exp(-(t - 180.0) / 4.5))
    >>> c = level_change_candidates(t, r, np.ones(t.size, bool))
    >>> round(float(t[c][0])), round(float(t[c][-1]))
    (160, 200)
    """
    t = np.asarray(t_s, dtype=float)
    r = np.asarray(axis_residual, dtype=float)
    fit = np.asarray(fit, bool) & np.isfinite(r)
    out = np.zeros(t.size, bool)
    if fit.sum() < 10:
        return out
    tf = t[fit]
    grid = np.arange(tf[0] + edge_s, tf[-1] - edge_s + grid_s / 2, grid_s)
    if grid.size < 3:
        return out
    change = np.array([level_change(t, r, fit, g, g, window_s) for g in grid])
    size = np.abs(np.nan_to_num(change))
    reach = max(1, int(round(window_s / grid_s)))
    for i in np.flatnonzero(size >= LEVEL_STEP_MIN_NT):
        near = size[max(0, i - reach):i + reach + 1]
        if size[i] < near.max():
            continue                                    # not the local extreme
        half = size >= 0.5 * size[i]
        j0 = i
        while j0 > 0 and half[j0 - 1]:
            j0 -= 1
        j1 = i
        while j1 < grid.size - 1 and half[j1 + 1]:
            j1 += 1
        span = (t >= grid[j0] - pad_s) & (t <= grid[j1] + pad_s)
        near = (t >= grid[j0] - pad_s - 2 * window_s) & (t <= grid[j1] + pad_s + 2 * window_s)
        inside = (grid[j0] - pad_s - 2 * window_s >= tf[0]
                  and grid[j1] + pad_s + 2 * window_s <= tf[-1])
        if inside and not (near & ~span & ~fit).any():
            out |= span      # quiet fitted samples on both sides, no other gap next to it
    return out


def level_step_rows(field: pd.DataFrame, *, candidates: bool = True,
                    max_steps: int | None = None) -> np.ndarray:
    """Rows of the left-out intervals across which the spin-axis level may change.

    Parameters
    ----------
    field : DataFrame
        A calibrated day without level steps (``ElfinCalibration.field``: ``zone``,
        ``used``, ``fit``, ``bz_despun``, ``igrf_z_despun``, UTC index).
    candidates : bool
        Also judge the abrupt level changes of the fitted samples
        (:func:`level_change_candidates`) as if left out; a kept one is left out of
        the fits of the day calibrated again with its step.
    max_steps : int, optional
        Keep at most this many steps per zone, the strongest first
        (:func:`level_steps_wanted`).

    Returns
    -------
    ndarray of bool (n,)
        True on the rows of each interval of :func:`left_out_runs` (per zone, with the
        candidates merged in) that :func:`level_steps_wanted` keeps, judged on the
        spin-axis residual ``bz_despun - igrf_z_despun``; the ``level_step`` column of
        a day calibrated with them (``level_step_rows`` of
        :func:`~magcal.missions.elfin.pipeline.calibrate_elfin_day`).
    """
    return level_step_decision(field, candidates=candidates, max_steps=max_steps)[0]


def level_step_decision(field: pd.DataFrame, *, candidates: bool = True,
                        max_steps: int | None = None) -> tuple[np.ndarray, pd.DataFrame]:
    """:func:`level_step_rows` and every interval it judged, kept or not, with its
    tests (:func:`judge_level_steps`): ``zone``, ``start`` (UTC of the zone's first
    row) and the :data:`JUDGED_COLUMNS` (times in s from it)."""
    rows = np.zeros(len(field), bool)
    tabs = []
    for k, sel, runs, table in _zone_judgements(field, candidates, max_steps):
        for (a, b), keep in zip(runs, table["kept"]):
            rows[sel[a:b]] = keep
        if len(table):
            tabs.append(table.assign(zone=int(k), start=field.index[sel[0]]))
    cols = ["zone", "start", *JUDGED_COLUMNS]
    return rows, (pd.concat(tabs, ignore_index=True)[cols] if tabs
                  else pd.DataFrame(columns=cols))


def _zone_judgements(field: pd.DataFrame, candidates: bool, max_steps):
    """Per zone of ``field`` with fitted samples: its number, its rows, the runs of
    :func:`left_out_runs` (with the candidates merged in) and their
    :func:`judge_level_steps` table."""
    zone = field["zone"].to_numpy()
    fit_all = (field["used"].to_numpy() == 1) & (field["fit"].to_numpy() == 1)
    resid = (field["bz_despun"] - field["igrf_z_despun"]).to_numpy(float)
    ts = field.index.as_unit("ns").asi8 / 1e9
    for k in dict.fromkeys(zone):
        sel = np.flatnonzero(zone == k)
        t, fit = ts[sel] - ts[sel][0], fit_all[sel]
        if fit.sum() < 2:
            continue
        if candidates:
            fit = fit & ~level_change_candidates(t, resid[sel], fit)
        yield k, sel, left_out_runs(t, fit), judge_level_steps(t, resid[sel], fit,
                                                               max_steps=max_steps)


#: Seconds after a trial sheet's start from which its kept level is read (its 10-90 %
#: rise takes 20 s).
TRIAL_SETTLE_S = 30.0


def kept_level(field: pd.DataFrame, clean: pd.DataFrame, u, t_s, t0: float) -> float:
    """Level of a current sheet starting at ``t0`` that a calibrated zone kept: the
    median, over its fitted samples from :data:`TRIAL_SETTLE_S` after ``t0``, of
    ``field - clean`` (GEI) along the sheet's unit vectors ``u`` (n, 3), nT (NaN
    without such samples).

    Examples
    --------
    >>> t = np.arange(0.0, 200.0, 1.0)
    >>> idx = pd.date_range("2022-01-12", periods=t.size, freq="1s")
    >>> clean = pd.DataFrame({"bx_gei": 0.0, "by_gei": 0.0, "bz_gei": 0.0, "used": 1,
    ...                       "fit": 1}, index=idx)
    >>> field = clean.assign(bz_gei=np.where(t > 100, 280.0, 0.0))
    >>> kept_level(field, clean, np.tile([0.0, 0.0, 1.0], (t.size, 1)), t, 100.0)
    280.0
    """
    gei = ["bx_gei", "by_gei", "bz_gei"]
    change = np.sum((field[gei].to_numpy(float) - clean[gei].to_numpy(float))
                    * np.asarray(u, float), axis=1)
    read = (np.asarray(t_s, float) >= t0 + TRIAL_SETTLE_S) \
        & (field["used"].to_numpy() == 1) & (field["fit"].to_numpy() == 1)
    return float(np.median(change[read])) if read.any() else float("nan")


def trial_sheet(zone_field: pd.DataFrame, state: pd.DataFrame, step_nT: float, t_s,
                t0: float) -> tuple[np.ndarray, np.ndarray]:
    """An east-west current sheet that changes a zone's spin-axis level as a kept step
    of ``step_nT`` does (the trial of :func:`level_trials`).

    The sheet (:func:`~magcal.missions.elfin.injection.signal_shape` ``"sheet_ew"``,
    half risen at ``t0``, s on the zone's clock ``t_s``) is ``|step_nT|`` high along
    the orbit normal, signed so that its spin-axis component has the step's sign: the
    calibration does not treat the two signs alike (2022-01-12 zone 7 at mid-zone keeps
    126 % of a 300 nT sheet and loses the opposite one), so a trial of the other sign
    would state another sheet's error.

    Parameters
    ----------
    zone_field : DataFrame
        One zone of a calibrated field (UTC index, ``igrf_{x,y,z}_gei``,
        ``spin_axis_gei_{x,y,z}``).
    state : DataFrame
        The ELFIN state (:func:`~magcal.missions.elfin.files.read_elfin_state`).
    step_nT : float
        The kept step (spin-axis level change, nT); NaN gives no sheet.

    Returns
    -------
    signal : ndarray (n, 3)
        The sheet in GEI, nT.
    u : ndarray (n, 3)
        Unit vectors along which it is ``|step_nT|`` after its rise
        (:func:`kept_level` reads the trial along them).
    """
    from magcal.missions.elfin.injection import SIGNALS, directions, signal_shape

    size = abs(step_nT) if np.isfinite(step_nT) else 0.0
    b = zone_field[["igrf_x_gei", "igrf_y_gei", "igrf_z_gei"]].to_numpy(float)
    u = directions(zone_field.index, state, b)["ew"]
    axis = zone_field[[f"spin_axis_gei_{c}" for c in "xyz"]].to_numpy(float)
    sign = np.sign(step_nT) if size else 1.0
    u = u * sign * np.sign(np.median(np.sum(u * axis, axis=1)))
    return (size / SIGNALS["sheet_ew"][0]) * signal_shape("sheet_ew", t_s, t0)[:, None] * u, u


def level_trials(fgs: pd.DataFrame, state: pd.DataFrame, settings, day,
                 n_trials: int, *, fit_exclude=None) -> pd.DataFrame:
    """How well the day determines each kept level step: a current sheet of its size put
    into the counts of other zones at the same place and measured again.

    For each kept step of ``day`` (:meth:`ElfinDay.level_step_intervals`), an east-west
    current sheet of the step's size (20 s rise, to the zone's end;
    :func:`~magcal.missions.elfin.injection.signal_shape`) is added to the counts of up
    to ``n_trials`` other zones without a step of their own (the nearest in time first),
    half risen at the same fraction of the zone's used span and changing the spin-axis
    level with the step's sign, through the day's linear calibration
    (:func:`~magcal.missions.elfin.injection.inject_counts`). The day is calibrated
    again with ``settings`` and the sheets (the trial zones together: a zone calibrated
    alone lacks the day's spin-axis prior and lost 300 nT sheets that the day keeps),
    and the level each trial zone kept read against ``day`` (:func:`kept_level`). The
    RMS of the kept levels' errors is the step's stated error: it holds how the zone's
    slow terms trade with a free step, which no fit statistic of the day's own zone
    shows (on 2022-01-12 a kept sheet's level was off by 7-125 nT while the bridge
    trials said 6-82 nT). ``fit_exclude`` (rows of
    ``fgs``) is what ``day`` was given, so that the trial zones differ from it by the
    sheets alone.

    Returns
    -------
    DataFrame
        Per kept step: the columns of :meth:`ElfinDay.level_step_intervals`,
        ``trial_levels_nT`` (list: the level each trial zone kept of ``|step_nT|``) and
        ``step_error_nT`` (NaN without trials: no zone without a step, or the day with
        the trial sheets could not be calibrated as delivered).
    """
    from magcal.missions.elfin.injection import trial_day, trial_places

    kept = day.level_step_intervals()
    cols = ["zone", "start", "end", "step_nT", "trial_levels_nT", "step_error_nT"]
    if not kept or n_trials <= 0:
        return pd.DataFrame(kept, columns=cols[:4]).reindex(columns=cols)
    f = day.linear.field
    delivered = day.calibration.field
    busy = {p["zone"] for p in kept}
    out = []
    for p in kept:
        size = abs(p["step_nT"]) if np.isfinite(p["step_nT"]) else 0.0
        signals, places = {}, []
        for k, sel, t, t0 in trial_places(f, p["zone"], [p["start"], p["end"]], busy,
                                          n_trials):
            signals[k], u = trial_sheet(f.iloc[sel], state, p["step_nT"], t, t0)
            places.append((sel, u, t, t0))
        levels = []
        if signals:
            one = trial_day(fgs, state, settings, day, signals, fit_exclude=fit_exclude)
            trial = None if one is None else one.calibration.field
            if trial is not None and len(trial) == len(delivered):
                levels = [kept_level(trial.iloc[sel], delivered.iloc[sel], u, t, t0)
                          for sel, u, t, t0 in places]
        lv = np.asarray(levels, float)
        lv = lv[np.isfinite(lv)]
        out.append({**p, "trial_levels_nT": lv.tolist(),
                    "step_error_nT": float(np.sqrt(np.mean((lv - size) ** 2)))
                    if lv.size else float("nan")})
    return pd.DataFrame(out, columns=cols)
