"""Localized fields across B kept as a natural-field template instead of left out.

Leaving a disturbed interval out of the fits (:mod:`magcal.missions.elfin.disturbed`)
keeps a natural field there, but the fits then bridge the gap and the zone's
calibration itself changes (:mod:`magcal.missions.elfin.leave_out`): a pulse across B
comes back distorted by what the bridge moved. ``ElfinSettings.pulses_perp`` fits the
pulse instead, as part of the reference:

1. the day is calibrated as delivered (detection on), and on each detected interval
   that is not a level step a Gaussian of free centre, width and GEI vector amplitude
   on a linear baseline is fitted to the product's residual against IGRF
   (:func:`fit_gaussian`); it is a pulse across B when it explains most of the
   interval's residual, is 10-150 s wide (FWHM), rises and falls inside the zone, is
   30 nT or higher and lies mostly across B (:func:`find_perp_pulses`);
2. the day is calibrated again with those intervals' rows in the fits and the
   reference IGRF + ``a g(t)`` (``g`` the unit Gaussian), and the Gaussian's centre,
   width and amplitude ``a`` are fitted again on the product made with it (or, with
   ``refine=False``, ``a`` alone corrected by regressing the product's residual on
   ``[1, g]`` over the zone; backfitting, :func:`calibrate_perp`), until the change is
   small;
3. a zone whose backfit does not settle within the iterations keeps its intervals left
   out (the delivered product there), with the reason recorded.

The reference columns of the delivered field are IGRF alone: the template is the
natural field the product keeps, not part of the model.

Data: ELFIN SOC (PI V. Angelopoulos, UCLA), "Open Data for Scientific Use".
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pandas as pd

from magcal.missions.elfin.pipeline import _utc
from magcal.missions.elfin.pulses import gaussian

#: Seconds of the product either side of a detected interval in the Gaussian's fit.
MARGIN_S = 30.0
#: Least share of the interval's residual (about a linear baseline) the Gaussian explains.
MIN_SHARE = 0.8
#: FWHM range (s) of a pulse across B kept as a template.
FWHM_RANGE_S = (10.0, 150.0)
#: Least height (nT) of a kept pulse.
MIN_HEIGHT_NT = 30.0
#: Largest share of the height along B (cosine of the angle to B) of a pulse across B.
MAX_ALONG_B = 0.5
#: Backfit iterations at most, and the correction (nT, or share of the height if larger)
#: below which a zone's amplitudes have settled.
MAX_ITER = 8
TOL_NT, TOL_SHARE = 2.0, 0.01
#: Rows of a kept pulse's interval put back into the fits: within this many FWHM of its
#: centre (its field 0.2 % of the height there).
REACH_FWHM = 1.5
#: Rounding (s) of the times of a run's ends.
_ROUND_S = 1e-3
#: Columns of the residual in GEI.
_B = ["bx_gei", "by_gei", "bz_gei"]
_REF = ["igrf_x_gei", "igrf_y_gei", "igrf_z_gei"]
_REF_DESPUN = ["igrf_x_despun", "igrf_y_despun", "igrf_z_despun"]
#: Columns of the pulse table (:func:`find_perp_pulses`).
PULSE_COLUMNS = ["zone", "start", "start_s", "end_s", "centre_s", "fwhm_s", "amp_x_nT",
                 "amp_y_nT", "amp_z_nT", "height_nT", "along_b", "share", "accepted",
                 "why"]


def fit_gaussian(t_s, r, centre_s: float, fwhm_s: float, *, lo_s: float | None = None,
                 hi_s: float | None = None) -> dict:
    """A Gaussian of free centre and width with a vector amplitude on a linear baseline
    per component, least squares to ``r``.

    The centre and width are fitted by :func:`scipy.optimize.least_squares`, the
    amplitudes and baselines solved linearly for each (variable projection).

    Parameters
    ----------
    t_s : array_like (n,)
        Times (s).
    r : array_like (n, k)
        Residual (nT), ``k`` components.
    centre_s, fwhm_s : float
        Start values.
    lo_s, hi_s : float, optional
        Bounds of the centre (default: the span of ``t_s``).

    Returns
    -------
    dict
        ``centre_s``, ``fwhm_s``, ``amplitude`` (k,), ``baseline`` (2, k: value at the
        window's middle and slope per s), ``share``: the part of the sum of squares
        of ``r`` about the linear baseline alone that the Gaussian explains.

    Examples
    --------
    >>> t = np.arange(0.0, 200.0, 0.5)
    >>> r = np.outer(gaussian(t, 90.0, 40.0), [150.0, -80.0, 10.0]) + 0.1 * t[:, None]
    >>> p = fit_gaussian(t, r, 100.0, 60.0)
    >>> round(p["centre_s"], 3), round(p["fwhm_s"], 3), np.round(p["amplitude"], 3).tolist()
    (90.0, 40.0, [150.0, -80.0, 10.0])
    """
    from scipy.optimize import least_squares

    t = np.asarray(t_s, float)
    r = np.asarray(r, float).reshape(t.size, -1)
    mid = 0.5 * (t[0] + t[-1])
    base = np.column_stack([np.ones(t.size), t - mid])
    lo = t[0] if lo_s is None else lo_s
    hi = t[-1] if hi_s is None else hi_s

    def solve(p):
        g = gaussian(t, p[0], np.exp(p[1]))
        x = np.column_stack([base, g])
        coef = np.linalg.lstsq(x, r, rcond=None)[0]
        return coef, r - x @ coef

    p0 = [float(np.clip(centre_s, lo, hi)), float(np.log(np.clip(fwhm_s, 2.0, 500.0)))]
    out = least_squares(lambda p: solve(p)[1].ravel(), p0,
                        bounds=([lo, np.log(2.0)], [hi, np.log(500.0)]), x_scale=[5.0, 0.2])
    coef, res = solve(out.x)
    trend = r - base @ np.linalg.lstsq(base, r, rcond=None)[0]
    total = float(np.sum(trend ** 2))
    return {"centre_s": float(out.x[0]), "fwhm_s": float(np.exp(out.x[1])),
            "amplitude": coef[2], "baseline": coef[:2],
            "share": 1.0 - float(np.sum(res ** 2)) / total if total > 0 else 0.0}


def _zone_times(field: pd.DataFrame, zone) -> tuple[np.ndarray, np.ndarray]:
    """Rows of zone ``zone`` of ``field`` and their times (s from its first row)."""
    rows = np.flatnonzero(field["zone"].to_numpy() == zone)
    ts = field.index.as_unit("ns").asi8[rows]
    return rows, (ts - ts[0]) / 1e9


def find_perp_pulses(field: pd.DataFrame, runs: pd.DataFrame) -> pd.DataFrame:
    """Pulses across B on the detected intervals of a calibrated day.

    Parameters
    ----------
    field : DataFrame
        The delivered field of the day calibrated with its disturbed intervals left out
        (``zone``, ``used``, GEI field and reference, ``level_step`` if any, and the
        ``pulse_b_<j>`` shapes of kept pulses along B if any).
    runs : DataFrame
        The detected runs (``steps["disturbed_runs"]`` of
        :func:`~magcal.missions.elfin.disturbed.calibrate_detected`): ``zone``,
        ``start_s``, ``end_s`` (from the zone's first row) and ``kept``.

    Returns
    -------
    DataFrame
        One row per run left out (:data:`PULSE_COLUMNS`): the fitted Gaussian (times
        from the zone's first row, amplitude in GEI nT), ``along_b`` (share of the
        height along B), ``share`` (:func:`fit_gaussian`), ``accepted`` and ``why`` (the
        tests it fails; empty when accepted).
    """
    from magcal.missions.elfin.pulses import NATURAL_COLUMNS, shape_columns

    out = []
    if runs is None or not len(runs):
        return pd.DataFrame(columns=PULSE_COLUMNS)
    level = field["level_step"].to_numpy() == 1 if "level_step" in field.columns \
        else np.zeros(len(field), bool)
    along = shape_columns(field, NATURAL_COLUMNS)
    along = along.max(axis=1) >= 0.5 if along.shape[1] else np.zeros(len(field), bool)
    used_all = field["used"].to_numpy() == 1
    for run in runs.itertuples():
        if not bool(run.kept):
            continue
        rows, t = _zone_times(field, run.zone)
        used = used_all[rows]
        inside = (t >= run.start_s) & (t <= run.end_s)
        window = used & (t >= run.start_s - MARGIN_S) & (t <= run.end_s + MARGIN_S)
        rec = {"zone": int(run.zone), "start": field.index[rows[0]], "start_s": run.start_s,
               "end_s": run.end_s}
        why = []
        if level[rows][inside].any():
            why.append("a level step")
        if along[rows][inside].any():
            why.append("a pulse along B")
        if window.sum() < 20:
            why.append("too few samples")
        if why:
            out.append({**rec, "accepted": False, "why": "; ".join(why)})
            continue
        z = field.iloc[rows]
        r = z[_B].to_numpy(float) - z[_REF].to_numpy(float)
        p = fit_gaussian(t[window], r[window], 0.5 * (run.start_s + run.end_s),
                         0.5 * (run.end_s - run.start_s),
                         lo_s=run.start_s - MARGIN_S, hi_s=run.end_s + MARGIN_S)
        a = np.asarray(p["amplitude"], float)
        height = float(np.linalg.norm(a))
        k = int(np.argmin(np.abs(t - p["centre_s"])))
        b = z[_REF].to_numpy(float)[k]
        along_b = abs(float(a @ b)) / (height * np.linalg.norm(b)) if height > 0 else 1.0
        span = t[used]
        if p["share"] < MIN_SHARE:
            why.append(f"explains {p['share']:.0%} of the residual (< {MIN_SHARE:.0%})")
        if not FWHM_RANGE_S[0] <= p["fwhm_s"] <= FWHM_RANGE_S[1]:
            why.append(f"FWHM {p['fwhm_s']:.0f} s outside {FWHM_RANGE_S[0]:.0f}-"
                       f"{FWHM_RANGE_S[1]:.0f} s")
        if p["centre_s"] - p["fwhm_s"] < span[0] or p["centre_s"] + p["fwhm_s"] > span[-1]:
            why.append("does not rise and fall inside the zone")
        if height < MIN_HEIGHT_NT:
            why.append(f"under {MIN_HEIGHT_NT:.0f} nT")
        if along_b > MAX_ALONG_B:
            why.append(f"{along_b:.0%} of it along B")
        out.append({**rec, "centre_s": p["centre_s"], "fwhm_s": p["fwhm_s"],
                    "amp_x_nT": a[0], "amp_y_nT": a[1], "amp_z_nT": a[2],
                    "height_nT": height, "along_b": along_b, "share": p["share"],
                    "accepted": not why, "why": "; ".join(why)})
    return pd.DataFrame(out, columns=PULSE_COLUMNS)


def template_rows(times, pulses: pd.DataFrame) -> np.ndarray:
    """The sum of the pulses' fields (len(times), 3), GEI nT, at UTC ``times``.

    ``pulses`` rows carry the zone's first time ``start``, ``centre_s``, ``fwhm_s`` and
    ``amp_x_nT .. amp_z_nT``.
    """
    ts = pd.DatetimeIndex(times).as_unit("ns").asi8
    out = np.zeros((ts.size, 3))
    for p in pulses.itertuples():
        t0 = pd.Timestamp(p.start).as_unit("ns").value
        g = gaussian((ts - t0) / 1e9, p.centre_s, p.fwhm_s)
        out += g[:, None] * np.array([p.amp_x_nT, p.amp_y_nT, p.amp_z_nT])
    return out


def with_templates(state: pd.DataFrame, pulses: pd.DataFrame) -> pd.DataFrame:
    """``state`` (with its IGRF columns) with the pulses' fields added to the reference."""
    from magcal.missions.elfin.linear import IGRF_COLUMNS

    if not len(pulses):
        return state
    out = state.copy()
    out[IGRF_COLUMNS] = state[IGRF_COLUMNS].to_numpy(float) + template_rows(state.index,
                                                                               pulses)
    return out


def without_templates(field: pd.DataFrame, pulses: pd.DataFrame) -> pd.DataFrame:
    """A calibrated field whose reference columns held the pulses: IGRF alone again (GEI
    and despun)."""
    from magcal.missions.elfin.phase import despun_basis

    if not len(pulses):
        return field
    extra = template_rows(field.index, pulses)
    basis = despun_basis(field[[f"spin_axis_gei_{c}" for c in "xyz"]].to_numpy(float))
    return field.assign(**{
        **{c: field[c].to_numpy(float) - extra[:, j] for j, c in enumerate(_REF)},
        **{c: field[c].to_numpy(float) - v for c, v in
           zip(_REF_DESPUN, np.einsum("nij,nj->ni", basis, extra).T)}})


def amplitude_steps(field: pd.DataFrame, pulses: pd.DataFrame) -> np.ndarray:
    """Per pulse the correction (3,) of its amplitude: the product's residual against
    its reference (holding the pulses) regressed on ``[1, g_1 .. g_m]`` over the used
    rows of the pulse's zone (``g`` the unit shapes of that zone's pulses)."""
    out = np.zeros((len(pulses), 3))
    for k in dict.fromkeys(pulses["zone"]):
        mine = np.flatnonzero(pulses["zone"].to_numpy() == k)
        rows, t = _zone_times(field, k)
        used = field["used"].to_numpy()[rows] == 1
        z = field.iloc[rows]
        r = (z[_B].to_numpy(float) - z[_REF].to_numpy(float))[used]
        g = [gaussian(t[used], pulses["centre_s"].iloc[i], pulses["fwhm_s"].iloc[i])
             for i in mine]
        x = np.column_stack([np.ones(used.sum()), *g])
        coef = np.linalg.lstsq(x, r, rcond=None)[0]
        out[mine] = coef[1:]
    return out


def refitted(field: pd.DataFrame, pulses: pd.DataFrame) -> pd.DataFrame:
    """The pulses' Gaussians fitted again (:func:`fit_gaussian`, from their current
    centre and width) to a product calibrated with them in the reference: its residual
    against IGRF alone over each detected interval and :data:`MARGIN_S`, the zone's
    other pulses taken off."""
    out = pulses.copy()
    amp = ["amp_x_nT", "amp_y_nT", "amp_z_nT"]
    for i, p in enumerate(pulses.itertuples()):
        rows, t = _zone_times(field, p.zone)
        z = field.iloc[rows]
        used = z["used"].to_numpy() == 1
        window = used & (t >= p.start_s - MARGIN_S) & (t <= p.end_s + MARGIN_S)
        others = pulses[(pulses["zone"] == p.zone) & (np.arange(len(pulses)) != i)]
        r = z[_B].to_numpy(float) - z[_REF].to_numpy(float) \
            + template_rows(z.index, pulses.iloc[[i]]) - template_rows(z.index, others)
        q = fit_gaussian(t[window], r[window], p.centre_s, p.fwhm_s,
                         lo_s=p.start_s - MARGIN_S, hi_s=p.end_s + MARGIN_S)
        out.loc[out.index[i], ["centre_s", "fwhm_s", *amp]] = [q["centre_s"], q["fwhm_s"],
                                                              *q["amplitude"]]
    return out


def template_change(field: pd.DataFrame, old: pd.DataFrame, new: pd.DataFrame
                    ) -> np.ndarray:
    """Per pulse the largest change (nT) of its field over its zone's rows."""
    out = np.zeros(len(old))
    for i, p in enumerate(old.itertuples()):
        rows, _ = _zone_times(field, p.zone)
        idx = field.index[rows]
        d = template_rows(idx, new.iloc[[i]]) - template_rows(idx, old.iloc[[i]])
        out[i] = float(np.max(np.linalg.norm(d, axis=1)))
    return out


def _to_rows(values, keep, n, fill=0.0) -> np.ndarray:
    """Values on the calibrated rows (``keep`` of ``n``) spread to all ``n`` rows."""
    v = np.asarray(values)
    out = np.full((n,) + v.shape[1:], fill, dtype=v.dtype)
    out[keep] = v
    return out


def _interval_rows(field: pd.DataFrame, pulses: pd.DataFrame) -> np.ndarray:
    """Rows of ``field`` inside the detected intervals of ``pulses`` and within
    :data:`REACH_FWHM` of their centres (a run that also holds another disturbance
    keeps that one left out)."""
    out = np.zeros(len(field), bool)
    for p in pulses.itertuples():
        rows, t = _zone_times(field, p.zone)
        near = np.abs(t - p.centre_s) <= REACH_FWHM * p.fwhm_s
        # the run's ends are times of the same rows, read through another float path
        inside = (t >= p.start_s - _ROUND_S) & (t <= p.end_s + _ROUND_S)
        out[rows[inside & near]] = True
    return out


def calibrate_perp(fgs: pd.DataFrame, state: pd.DataFrame, settings, *, provenance=None,
                   hold_phase=None, fit_exclude=None, fit_exclude_scalar=None,
                   diagnostics: bool = True, linear=None, level_step_rows=None,
                   pulse_templates=None, drift_templates=None, refine: bool = True):
    """The day calibrated with its pulses across B fitted as templates of the reference.

    What ``ElfinSettings.pulses_perp`` runs (module docstring). ``state`` carries the
    IGRF columns (:func:`~magcal.missions.elfin.linear.with_igrf`); the other arguments
    are those of :func:`~magcal.missions.elfin.pipeline.calibrate_elfin_day`. Each
    backfit step fits the pulses' centre, width and amplitude again on the product made
    with them (:func:`refitted`; ``refine``) or only corrects the amplitudes by
    regression over the zone (:func:`amplitude_steps`, ``refine=False``).

    Returns
    -------
    ElfinDay
        With ``steps["pulses_perp"]``: per detected interval the Gaussian found
        (:func:`find_perp_pulses`) and, for those kept, ``iterations``,
        ``converged``, ``kept`` (True: fitted as a template and in the fits; False:
        left out as delivered) and ``why`` (the reason otherwise).
    """
    from magcal.missions.elfin.pipeline import _with_bridge, calibrate_elfin_day
    from magcal.missions.elfin.joint import score_field
    from magcal.missions.elfin.pulses import DRIFT_COLUMNS, NATURAL_COLUMNS, shape_columns

    s = settings
    first = calibrate_elfin_day(fgs, state, replace(s, pulses_perp=False, bridge_trials=0),
                                provenance=provenance, hold_phase=hold_phase,
                                fit_exclude=fit_exclude,
                                fit_exclude_scalar=fit_exclude_scalar,
                                diagnostics=diagnostics, linear=linear,
                                level_step_rows=level_step_rows,
                                pulse_templates=pulse_templates,
                                drift_templates=drift_templates)
    f = first.calibration.field
    found = find_perp_pulses(f, first.steps.get("disturbed_runs"))
    pulses = found[found["accepted"].astype(bool)].reset_index(drop=True)
    table = found.assign(iterations=0, converged=False, kept=False)

    def done(day, table, kept=None):
        if s.bridge_trials > 0:
            # the trials fit the kept pulses' rows too: with the pulses in the reference
            reference = state if kept is None else with_templates(state, kept)
            day = _with_bridge(fgs, reference, replace(s, pulses_perp=False), day,
                               hold_phase=hold_phase)
        return replace(day, settings=s, steps={**day.steps, "pulses_perp": table})

    if not len(pulses):
        return done(first, table)
    n = len(fgs)
    keep = first.calibration.kept_rows(n)
    used = f["used"].to_numpy() == 1
    left = used & (f["fit"].to_numpy() == 0)
    left_scalar = used & (f["fit_scalar"].to_numpy() == 0) if "fit_scalar" in f.columns \
        else left
    fixed = dict(level_step_rows=_to_rows(f["level_step"].to_numpy() == 1, keep, n, False)
                 if "level_step" in f.columns else np.zeros(n, bool),
                 pulse_templates=_to_rows(shape_columns(f, NATURAL_COLUMNS), keep, n),
                 drift_templates=_to_rows(shape_columns(f, DRIFT_COLUMNS), keep, n))
    plain = replace(s.without_trials(), pulses_perp=False, detect_disturbed=False)

    def calibrate(pulses, diag=False):
        back = _interval_rows(f, found[found["accepted"].astype(bool)
                                       & found["zone"].isin(pulses["zone"])])
        vector, scalar = left & ~back, left_scalar & ~back
        return calibrate_elfin_day(fgs, with_templates(state, pulses), plain,
                                   provenance=provenance, hold_phase=hold_phase,
                                   fit_exclude=_to_rows(vector | scalar, keep, n, False),
                                   fit_exclude_scalar=_to_rows(scalar, keep, n, False),
                                   diagnostics=diag, **fixed)

    zones = list(dict.fromkeys(pulses["zone"]))
    settled = {k: False for k in zones}
    iterations = {k: 0 for k in zones}
    damping = {k: 1.0 for k in zones}
    last_step = {k: np.inf for k in zones}
    amp = ["amp_x_nT", "amp_y_nT", "amp_z_nT"]
    for _ in range(MAX_ITER):
        day = calibrate(pulses)
        g = day.calibration.field
        if refine:
            target = refitted(g, pulses)
            size = template_change(g, pulses, target)
        else:
            step = amplitude_steps(g, pulses)
            size = np.linalg.norm(step, axis=1)
        height = np.linalg.norm(pulses[amp].to_numpy(float), axis=1)
        for k in zones:
            if settled[k]:
                continue
            mine = pulses["zone"].to_numpy() == k
            iterations[k] += 1
            largest = float(np.max(size[mine] / np.maximum(TOL_NT, TOL_SHARE * height[mine])))
            if largest <= 1.0:
                settled[k] = True
                continue
            if largest > 0.8 * last_step[k]:      # not shrinking: damp
                damping[k] *= 0.5
            last_step[k] = largest
            if refine:
                shape = ["centre_s", "fwhm_s", *amp]
                now = pulses.loc[mine, shape].to_numpy(float)
                pulses.loc[mine, shape] = now + damping[k] * (
                    target.loc[mine, shape].to_numpy(float) - now)
            else:
                pulses.loc[mine, amp] = pulses.loc[mine, amp].to_numpy(float) \
                    + damping[k] * step[mine]
        if all(settled.values()):
            break
    if not all(settled.values()):
        # those zones keep their intervals left out: the delivered product there
        pulses_all = pulses
        pulses = pulses[[settled[k] for k in pulses["zone"]]].reset_index(drop=True)
        day = calibrate(pulses, diagnostics) if len(pulses) else first
        unsettled = pulses_all[[not settled[k] for k in pulses_all["zone"]]]
    else:
        unsettled = pulses.iloc[:0]
        if diagnostics:
            day = calibrate(pulses, True)
    for p in pulses.itertuples():
        hit = (table["zone"] == p.zone) & (table["start_s"] == p.start_s)
        table.loc[hit, ["centre_s", "fwhm_s", *amp]] = [p.centre_s, p.fwhm_s, p.amp_x_nT,
                                                        p.amp_y_nT, p.amp_z_nT]
        table.loc[hit, "height_nT"] = float(np.linalg.norm([p.amp_x_nT, p.amp_y_nT,
                                                            p.amp_z_nT]))
        table.loc[hit, ["iterations", "converged", "kept"]] = [iterations[p.zone], True, True]
    for p in unsettled.itertuples():
        hit = (table["zone"] == p.zone) & (table["start_s"] == p.start_s)
        table.loc[hit, ["iterations", "converged", "kept"]] = [iterations[p.zone], False,
                                                               False]
        table.loc[hit, "why"] = (f"backfit did not settle in {MAX_ITER} iterations "
                                 "(left out as delivered)")
    if day is first:
        return done(first, table)
    # the delivered reference is IGRF alone, and so are the scores
    products = {k: replace(v, field=without_templates(v.field, pulses))
                for k, v in day.products.items()}
    delivered = next((products[k] for k, v in day.products.items()
                      if v is day.calibration),
                     replace(day.calibration,
                             field=without_templates(day.calibration.field, pulses)))
    scores = {k: score_field(v.field) for k, v in products.items()}
    if "joint" in day.scores:
        scores["joint"] = score_field(delivered.field) if day.delivered == "joint" \
            else day.scores["joint"]
    day = replace(day, calibration=delivered, linear=products["linear"], products=products,
                  scores=scores, steps={**first.steps, **day.steps})
    return done(day, table, pulses)


def perp_listing(day) -> list[dict]:
    """The pulses across B of ``day.steps["pulses_perp"]`` for the JSON: per detected
    interval fitted, ``zone``, ``centre`` (UTC, ISO), ``fwhm_s``, ``amplitude_gei_nT``,
    ``height_nT``, ``iterations``, ``converged``, ``kept`` and ``why``."""
    table = day.steps.get("pulses_perp")
    if table is None or not len(table):
        return []
    out = []
    for r in table.itertuples():
        rec = {"zone": int(r.zone), "start_s": float(r.start_s), "end_s": float(r.end_s),
               "kept": bool(r.kept), "converged": bool(r.converged),
               "iterations": int(r.iterations), "why": str(r.why)}
        if pd.notna(r.centre_s):
            rec.update(centre=_utc(pd.Timestamp(r.start), r.centre_s),
                       fwhm_s=float(r.fwhm_s), height_nT=float(r.height_nT),
                       amplitude_gei_nT=[float(r.amp_x_nT), float(r.amp_y_nT),
                                         float(r.amp_z_nT)],
                       share=float(r.share), along_b=float(r.along_b))
        out.append(rec)
    return out


#: Columns of :func:`perp_trials`.
TRIAL_COLUMNS = ["zone", "centre", "fwhm_s", "height_nT", "trial_errors_nT",
                 "trials_kept", "error_rms_nT"]


def kept_pulses(day) -> pd.DataFrame:
    """The pulses across B ``day`` keeps as templates (rows of ``steps["pulses_perp"]``
    with ``kept``)."""
    table = day.steps.get("pulses_perp")
    if table is None or not len(table):
        return pd.DataFrame(columns=PULSE_COLUMNS)
    return table[table["kept"].astype(bool)].reset_index(drop=True)


def perp_trials(fgs: pd.DataFrame, state: pd.DataFrame, settings, day, n_trials: int, *,
                fit_exclude=None) -> pd.DataFrame:
    """The error of each kept pulse across B: a pulse like it put into the counts of
    other zones at the same place and kept again.

    For each pulse ``day`` keeps as a template (:func:`kept_pulses`), a Gaussian of its
    FWHM and GEI amplitude is added to the counts of up to ``n_trials`` other zones
    without a kept pulse (the nearest first), at the same fraction of the zone's used
    span, through the day's linear calibration; the day is calibrated again with
    ``settings`` (the trial zones together, as the pulse and level trials are:
    :func:`magcal.missions.elfin.injection.trial_day`). A trial's error is the RMS over
    the rows within :data:`REACH_FWHM` FWHM of the place of ``|trial - day - pulse|``
    (GEI): what the product makes of a pulse of that size there, whether the trial zone
    kept it as a template or left it out. The RMS of the trials' errors is the stated
    error of the kept pulse's rows (``pulse_error_nT`` of the calibrated table).

    Returns
    -------
    DataFrame
        :data:`TRIAL_COLUMNS` per kept pulse: ``zone``, ``centre`` (UTC, ISO, no zone),
        ``fwhm_s``, ``height_nT``, ``trial_errors_nT`` (list), ``trials_kept`` (how
        many trial zones kept their pulse as a template) and ``error_rms_nT`` (NaN
        without trials: no zone without a pulse, or the day with the trial pulses could
        not be calibrated).
    """
    from magcal.missions.elfin.injection import trial_day, trial_places

    kept = kept_pulses(day)
    if not len(kept) or n_trials <= 0:
        return pd.DataFrame([_trial_row(p, [], 0) for p in kept.itertuples()],
                            columns=TRIAL_COLUMNS)
    f = day.calibration.field
    lin = day.linear.field
    busy = set(kept["zone"].tolist())
    out = []
    for p in kept.itertuples():
        amp = np.array([p.amp_x_nT, p.amp_y_nT, p.amp_z_nT])
        signals, places = {}, []
        for k, rows, t, c in trial_places(lin, p.zone, [_utc(pd.Timestamp(p.start),
                                                             p.centre_s)], busy, n_trials):
            signals[k] = gaussian(t, c, p.fwhm_s)[:, None] * amp
            places.append((k, rows, t, c))
        errors, n_kept = [], 0
        trial = trial_day(fgs, state, settings, day, signals, fit_exclude=fit_exclude) \
            if signals else None
        if trial is not None:
            g = trial.calibration.field
            again = kept_pulses(trial)
            for k, rows, t, c in places:
                near = np.abs(t - c) <= REACH_FWHM * p.fwhm_s
                sel = rows[near]
                ok = (f["used"].to_numpy()[sel] == 1) & (g["used"].to_numpy()[sel] == 1)
                diff = (g[_B].to_numpy(float)[sel] - f[_B].to_numpy(float)[sel]
                        - signals[k][near])[ok]
                if diff.size:
                    errors.append(float(np.sqrt(np.mean(np.sum(diff ** 2, axis=1)))))
                n_kept += int(np.any(again["zone"].to_numpy() == k))
        out.append(_trial_row(p, errors, n_kept))
    return pd.DataFrame(out, columns=TRIAL_COLUMNS)


def _trial_row(p, errors, n_kept) -> dict:
    e = np.asarray(errors, float)
    return {"zone": int(p.zone), "centre": _utc(pd.Timestamp(p.start), p.centre_s),
            "fwhm_s": float(p.fwhm_s),
            "height_nT": float(np.linalg.norm([p.amp_x_nT, p.amp_y_nT, p.amp_z_nT])),
            "trial_errors_nT": e.tolist(), "trials_kept": int(n_kept),
            "error_rms_nT": float(np.sqrt(np.mean(e ** 2))) if e.size else float("nan")}


def pulse_error_column(day) -> np.ndarray:
    """Per row of the delivered field: the stated error (nT) of the kept pulse across B
    whose rows (within :data:`REACH_FWHM` FWHM of its centre) it lies in
    (``steps["perp_trials"]``), NaN elsewhere or where not measured."""
    f = day.calibration.field
    out = np.full(len(f), np.nan)
    trials = day.steps.get("perp_trials")
    if trials is None or not len(trials):
        return out
    ns = f.index.as_unit("ns").asi8
    zone = f["zone"].to_numpy()
    for r in trials.itertuples():
        c = pd.Timestamp(r.centre, tz="UTC").value
        near = (zone == r.zone) & (np.abs(ns - c) / 1e9 <= REACH_FWHM * r.fwhm_s)
        out[near] = r.error_rms_nT
    return out
