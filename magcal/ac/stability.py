"""Stability of a PiCoG plan over repeated fits (Constantinescu et al. 2020, Table 1).

The same plan is refitted on each UTC day separately (interval orders keep their time
of day, as for a disturbance that recurs daily); the spread of the directions and
alphas per step (:func:`magcal.ac.metrics.parameter_stability`) and ``Bmaxdev``, the
largest change of the corrected field between two refits' upload matrices applied to
the same data, say how far a user can trust one fit.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from magcal.ac.chain import apply_weights, sample_period_s
from magcal.ac.metrics import parameter_stability
from magcal.ac.plan import plan_from_json
from magcal.errors import InputError
from magcal.timeconv import epoch_seconds

DAY_S = 86400.0


def shift_for_day(plan_doc: dict, day_start_s: float) -> float:
    """Shift that moves the plan's first interval to the same time of day on that day.

    Examples
    --------
    >>> doc = {"stages": [{"orders": [{"interval": [3600.0, 7200.0]}]}]}
    >>> shift_for_day(doc, 2 * 86400.0)
    172800.0
    """
    for st in plan_doc["stages"]:
        for o in st["orders"]:
            if o.get("interval"):
                start = float(o["interval"][0])
                return float(day_start_s - np.floor(start / DAY_S) * DAY_S)
    return 0.0


def daily_refits(frame: pd.DataFrame, plan_doc: dict, *, alpha_method: str = "decorrelate",
                 min_fraction: float = 0.5) -> list[dict]:
    """Refit a plan on each UTC day of ``frame`` separately.

    Days with less than ``min_fraction`` of a day of samples are left out. Interval
    orders are moved to the same time of day on each day.

    Returns
    -------
    list of dict ``{"day", "steps" (PARAMS style), "M"}``
    """
    from magcal.ac.estimator import PiCoG

    t = epoch_seconds(frame.index)
    day = np.floor(t / DAY_S)
    dt = sample_period_s(t)
    out = []
    for d in np.unique(day):
        sel = day == d
        if sel.sum() * dt < min_fraction * DAY_S:
            continue
        plan = plan_from_json(plan_doc, shift_s=shift_for_day(plan_doc, d * DAY_S))
        model = PiCoG(plan, alpha_method=alpha_method, check_bands=False).fit(frame.loc[sel])
        out.append({"day": str(pd.Timestamp(d * DAY_S, unit="s").date()),
                    "steps": [s.to_dict() for s in model.steps_],
                    "M": {k: np.asarray(v) for k, v in model.M_.items()}})
    return out


def stability(frame: pd.DataFrame, refits: list[dict], nominal_M: dict | None = None) -> dict:
    """Table-1-style stability of daily refits.

    Parameters
    ----------
    frame : DataFrame
        The multi-sensor input (``<sensor>_x/_y/_z``); every refit's matrices are applied
        to all of it.
    refits : output of :func:`daily_refits`
    nominal_M : dict, optional
        Upload matrices of the fit on the whole record (PARAMS ``M``).

    Returns
    -------
    dict with ``days``, ``steps`` (per step: ``stage, order, i, j, kind``,
    ``std_direction_i_deg``, ``std_direction_ij_deg``, ``std_alpha``, ``mean_alpha``;
    regression and joint steps: ``std_matrix_max``, the largest std of a matrix element),
    ``bmaxdev_nT`` (largest |change| of the corrected field between two refits),
    ``bmaxdev_ac_nT`` (the same with each corrected series' mean removed) and
    ``max_change_vs_nominal_nT`` per refit.
    """
    from magcal.ac.estimator import sensor_array

    if len(refits) < 2:
        raise InputError("parameter stability needs at least two daily refits")
    steps_list = [r["steps"] for r in refits]
    rows = []
    for k, first in enumerate(steps_list[0]):
        base = {key: first[key] for key in ("stage", "order", "i", "j", "kind")}
        if first.get("kind") in ("regression", "joint"):  # full 3x3, no direction/alpha
            a = np.array([s[k]["A"] for s in steps_list], dtype=float)
            base["std_matrix_max"] = float(np.max(a.std(axis=0, ddof=1)))
        else:
            base.update(parameter_stability([[s[k]] for s in steps_list])[0])
        rows.append(base)
    sensors = sorted(set().union(*(r["M"] for r in refits), nominal_M or {}))
    data = {s: sensor_array(frame, s) for s in sensors}
    corrected = [apply_weights(data, r["M"]) for r in refits]
    bmax = bmax_ac = 0.0
    for a in range(len(corrected)):
        for b in range(a + 1, len(corrected)):
            diff = corrected[a] - corrected[b]
            bmax = max(bmax, float(np.nanmax(np.abs(diff))))
            bmax_ac = max(bmax_ac, float(np.nanmax(np.abs(diff - np.nanmean(diff, axis=0)))))
    out = {"days": [r["day"] for r in refits], "steps": rows, "bmaxdev_nT": bmax,
           "bmaxdev_ac_nT": bmax_ac}
    if nominal_M:
        nom = apply_weights(data, {k: np.asarray(v, float) for k, v in nominal_M.items()})
        out["max_change_vs_nominal_nT"] = [float(np.nanmax(np.abs(c - nom))) for c in corrected]
    return out
