"""Automatic PiCoG plans (``magcal picog fit --auto``).

Choices, each recorded with its reason in the returned report:

1. **Reference stage** (§4.1): for every non-target sensor ``r`` a first-order fit of
   the target with ``r`` gives ``alpha_r``; the noise it would inject is
   ``|alpha_r| sigma_r`` (Eq. 22, ``sigma`` from second differences). A reference is used
   when the fit removes more disturbance variance from the target than the noise it adds
   (the paper's argument for AMR1 over AMR2: disturbance ratio against noise ratio). The
   boom partner is the lowest-noise remaining sensor; it is cleaned against the same
   reference.
2. **Timescales and windows** (§4.2): the spectrum and autocorrelation of the principal
   component of the pair difference are reported; the window of each order is the
   candidate (from a geometric grid, at most a quarter of the data) that most reduces
   the objective.
3. **Stopping**: orders are added while one reduces the objective by at least
   ``min_gain`` (the paper's AMR second order added noise: it would fail this test).
4. **Non-orthogonal fallback**: the regression gradiometer with all sensors is tried
   too; it replaces the PiCoG pair stage when it reduces the objective further.

Every order uses ambient-free directions (``direction="coherent"``) after removing
running means of ``fit_highpass_s`` (see :mod:`magcal.ac.filters`). The objective is
the variance of the cleaned target after removing running means of ``highpass_s`` (the
ambient field is common to every candidate, so its slow variation is removed and the
rest of it cancels in the comparison).

Speed: orders are fitted incrementally. Each candidate window costs one scan of the
current pair (windows sliding by about 1 % of their length) and one objective; the
chain is never re-run per trial, so a simulated day takes a few seconds.
"""

from __future__ import annotations

import numpy as np

from magcal.ac.chain import (Order, Plan, Stage, _wcombine, apply_weights, fit_order, run_chain,
                             sample_period_s)
from magcal.ac.core import correction_matrix
from magcal.ac.nonorthogonal import _running_mean
from magcal.errors import InputError

CANDIDATE_WINDOWS_S = (30.0, 100.0, 300.0, 700.0, 2000.0, 6000.0, 16000.0)


def noise_sigma(b: np.ndarray) -> float:
    """Robust white-noise rms (nT, summed over components) from second differences."""
    b = np.asarray(b, dtype=float)
    d2 = np.diff(b, n=2, axis=0)
    d2 = d2[np.all(np.isfinite(d2), axis=1)]
    if d2.shape[0] < 10:
        return float("nan")
    mad = np.median(np.abs(d2 - np.median(d2, axis=0)), axis=0) / 0.6745
    return float(np.sqrt(np.sum((mad / np.sqrt(6.0)) ** 2)))


def objective(b: np.ndarray, highpass_n: int) -> float:
    """Variance of ``b`` after removing running means over ``highpass_n`` samples."""
    b = np.asarray(b, dtype=float)
    ok = np.all(np.isfinite(b), axis=1)
    x = b[ok]
    x = x - _running_mean(x, highpass_n)
    return float(np.sum(np.var(x, axis=0)))


def timescales(d: np.ndarray, dt_s: float) -> dict:
    """Characteristic timescales of a difference series (principal component).

    Returns the period of the spectral peak (periodogram, periods 2 s to a quarter of
    the data) and the lag where the autocorrelation first drops below 1/e.
    """
    from scipy import signal

    ok = np.all(np.isfinite(d), axis=1)
    x = np.asarray(d, dtype=float)[ok]
    x = x - x.mean(axis=0)
    w, v = np.linalg.eigh(x.T @ x)
    p = x @ v[:, 2]
    f, pxx = signal.periodogram(p, fs=1.0 / dt_s)
    period = np.where(f > 0, 1.0 / np.where(f > 0, f, 1.0), np.inf)
    sel = (period >= 2 * dt_s) & (period <= p.size * dt_s / 4)
    peak = float(period[sel][np.argmax(pxx[sel] * f[sel])]) if sel.any() else float("nan")
    n = min(p.size, 1 << 16)
    seg = p[:n] - p[:n].mean()
    ac = np.fft.irfft(np.abs(np.fft.rfft(seg, 2 * n)) ** 2)[:n]
    ac = ac / ac[0] if ac[0] > 0 else ac
    below = np.flatnonzero(ac < np.exp(-1))
    decorr = float(below[0] * dt_s) if below.size else float("nan")
    return {"spectral_peak_period_s": peak, "autocorrelation_1e_s": decorr}


def _pair_update(cur, w, i, j, A_ij, e_ij):
    """Apply one coherent pair order (partner from Eq. 21) to states and weights."""
    A_ji = -A_ij - np.outer(e_ij, e_ij)
    d = cur[i] - cur[j]
    cur = dict(cur)
    w = dict(w)
    cur[i], cur[j] = cur[i] + d @ A_ij.T, cur[j] - d @ A_ji.T
    w[i], w[j] = _wcombine(w[i], w[j], A_ij), _wcombine(w[j], w[i], A_ji)
    return cur, w


def auto_plan(data: dict, t_s: np.ndarray, target: str, *, alpha_method: str = "decorrelate",
              highpass_s: float = 3600.0, min_gain: float = 0.05, max_orders: int = 3,
              candidate_windows_s=CANDIDATE_WINDOWS_S, fit_highpass_s: float | None = 1800.0,
              direction: str = "coherent") -> tuple[Plan, dict]:
    """Choose references, pair, windows and orders; return the plan and the reasons.

    Parameters
    ----------
    data : dict sensor -> (n, 3) on a uniform grid
    t_s : ndarray (n,)
    target : str
    highpass_s : float
        Running-mean length removed before computing the objective.
    min_gain : float
        Minimum relative reduction of the objective for an order (or stage) to be kept.
    fit_highpass_s : float or None
        ``highpass_s`` of every fitted order (running means removed before the fit).
    direction : {"coherent", "variance"}
        Direction method of every order (see :class:`magcal.ac.chain.Order`).

    Returns
    -------
    plan : Plan
    report : dict (JSON-ready)
    """
    if target not in data:
        raise InputError(f"target sensor {target!r} is missing from the input",
                         column=f"{target}_x")
    others = [s for s in data if s != target]
    if not others:
        raise InputError("--auto needs at least one sensor besides the target")
    dt = sample_period_s(t_s)
    n = len(t_s)
    hp = max(3, int(round(highpass_s / dt)))
    sigma = {s: noise_sigma(data[s]) for s in data}
    report: dict = {"noise_sigma_nT": sigma, "highpass_s": highpass_s,
                    "fit_highpass_s": fit_highpass_s, "direction": direction, "choices": []}
    base = objective(data[target], hp)
    report["objective_raw_nT2"] = base

    # 1. reference stage
    ref_order = Order(direction=direction, highpass_s=fit_highpass_s)
    ref_rows = []
    ref_fits = {}
    for r in others:
        try:
            alpha, e_i, e_ij, _ = fit_order(data[target], data[r], t_s, ref_order, dt_s=dt,
                                            alpha_method=alpha_method)
        except InputError as exc:
            ref_rows.append({"reference": r, "usable": False, "why": str(exc)})
            continue
        A = correction_matrix(alpha, e_i, e_ij)
        ref_fits[r] = A
        cleaned = data[target] + (data[target] - data[r]) @ A.T
        obj = objective(cleaned, hp)
        ref_rows.append({"reference": r, "usable": True, "alpha": float(alpha),
                         "injected_noise_nT": abs(alpha) * sigma[r],
                         "objective_nT2": obj, "gain": 1 - obj / base})
    report["reference_candidates"] = ref_rows
    partner_pool = sorted(others, key=lambda s: sigma[s])
    stages = []
    current = base
    usable = [row for row in ref_rows if row["usable"]]
    best_ref = max(usable, key=lambda row: row["gain"]) if usable else None
    partner = partner_pool[0]
    cur = {s: np.asarray(data[s], dtype=float) for s in (target, partner)}
    w = {s: {s: np.eye(3)} for s in (target, partner)}
    if best_ref is not None and best_ref["gain"] >= min_gain and best_ref["reference"] != partner:
        ref = best_ref["reference"]
        if best_ref["injected_noise_nT"] > sigma[target]:
            report["choices"].append(
                f"reference stage with {ref}: removes {best_ref['gain']:.0%} of the target "
                f"variance but injects {best_ref['injected_noise_nT']:.3g} nT noise")
        else:
            report["choices"].append(
                f"reference stage with {ref}: removes {best_ref['gain']:.0%} of the target "
                f"variance and injects only |alpha| sigma = {best_ref['injected_noise_nT']:.3g}"
                f" nT of its noise (target noise {sigma[target]:.3g} nT)")
        stages.append(Stage("reference", (target, partner), reference=ref, orders=(ref_order,)))
        b_ref = np.asarray(data[ref], dtype=float)
        alpha, e_i, e_ij, _ = fit_order(cur[partner], b_ref, t_s, ref_order, dt_s=dt,
                                        alpha_method=alpha_method)
        A_p = correction_matrix(alpha, e_i, e_ij)
        for s_, A in ((target, ref_fits[ref]), (partner, A_p)):
            cur[s_] = cur[s_] + (cur[s_] - b_ref) @ A.T
            w[s_] = _wcombine(w[s_], {ref: np.eye(3)}, A)
        current = objective(cur[target], hp)
    else:
        report["choices"].append("no reference stage: no other sensor removes at least "
                                 f"{min_gain:.0%} of the target variance as a first-order "
                                 "reference, or the best one is the boom partner")
    report["partner"] = partner
    report["choices"].append(f"pair partner {partner}: lowest noise "
                             f"({sigma[partner]:.3g} nT) of the other sensors")

    # 2. timescales and windows, fitted incrementally on the current pair
    report["timescales"] = timescales(cur[target] - cur[partner], dt)
    windows = [x for x in candidate_windows_s if int(round(x / dt)) <= n // 4
               and int(round(x / dt)) >= 10]
    orders: list[Order] = []
    order_rows = []
    obj_before = current
    for k in range(max_orders):
        trials = []
        for win in windows + [None]:
            order = Order(window_s=win, direction=direction, highpass_s=fit_highpass_s)
            step = 1 if win is None else max(1, int(round(win / dt)) // 100)
            try:
                alpha, e_i, e_ij, _ = fit_order(cur[target], cur[partner], t_s, order, dt_s=dt,
                                                alpha_method=alpha_method, scan_step=step)
            except InputError:
                continue
            A = correction_matrix(alpha, e_i, e_ij)
            trial = cur[target] + (cur[target] - cur[partner]) @ A.T
            trials.append((objective(trial, hp), win, A, e_ij))
        if not trials:
            break
        obj, win, A, e_ij = min(trials, key=lambda x: x[0])
        gain = 1 - obj / obj_before
        order_rows.append({"order": k + 1, "best_window_s": win, "objective_nT2": obj,
                           "gain": gain, "tried": [{"window_s": tw, "objective_nT2": to}
                                                   for to, tw, _, _ in trials]})
        if gain < min_gain:
            report["choices"].append(f"stop after {k} pair order(s): the best order {k + 1} "
                                     f"(window {win}) reduces the objective by only {gain:.1%}")
            break
        orders.append(Order(window_s=win, direction=direction, highpass_s=fit_highpass_s))
        report["choices"].append(f"pair order {k + 1}: window {win} s reduces the objective "
                                 f"by {gain:.0%} (best of {len(trials)} candidates)")
        if direction == "coherent":
            cur, w = _pair_update(cur, w, target, partner, A, np.asarray(e_ij, float))
        else:
            res = run_chain(data, t_s, Plan(target, tuple(stages) + (Stage(
                "pair", (target, partner), orders=tuple(orders)),)), alpha_method=alpha_method)
            cur = {target: res.corrected, partner: apply_weights(data, res.weights[partner])}
        obj_before = obj
    report["pair_orders"] = order_rows
    picog_stages = tuple(stages) + ((Stage("pair", (target, partner), orders=tuple(orders)),)
                                    if orders else ())
    picog_obj = obj_before

    # 4. regression gradiometer with all sensors
    reg_plan = Plan(target, (Stage("regression", (target,), references=tuple(others),
                                   orders=(Order(detrend_s=highpass_s),)),))
    try:
        reg_obj = objective(run_chain(data, t_s, reg_plan).corrected, hp)
    except InputError as exc:
        reg_obj = float("inf")
        report["regression_error"] = str(exc)
    report["objective_picog_nT2"] = picog_obj
    report["objective_regression_nT2"] = reg_obj
    if reg_obj < picog_obj * (1 - min_gain) or not picog_stages:
        plan = reg_plan
        report["choices"].append(
            f"regression gradiometer with {', '.join(others)}: objective {reg_obj:.4g} nT^2 "
            f"vs {picog_obj:.4g} for the PiCoG chain (non-orthogonal or more disturbers "
            "than one pair can separate)")
        report["method"] = "regression"
    else:
        plan = Plan(target, picog_stages)
        report["choices"].append(f"PiCoG chain kept: objective {picog_obj:.4g} nT^2 vs "
                                 f"{reg_obj:.4g} for the regression gradiometer")
        report["method"] = "picog"
    return plan, report
