"""Automatic PiCoG plans (``magcal picog fit --auto``).

Choices, each recorded with its reason in the returned report:

1. **Reference stage** (§4.1): for every non-target sensor ``r`` a first-order fit of
   the target with ``r`` gives ``alpha_r``; the noise it would inject is
   ``|alpha_r| sigma_r`` (Eq. 22, ``sigma`` from second differences). A reference is used
   when the fit removes more disturbance variance from the target than the noise it adds
   (the paper's argument for AMR1 over AMR2: disturbance ratio against noise ratio);
   among the references that pay, those injecting less noise than the target's own are
   preferred. The boom partner is the lowest-noise other sensor; it is cleaned against
   the same reference and never used as one. The reference order's high-pass is half
   the pair's (the reference disturber's edges, not its plateaus, fix alpha).
2. **Timescales and windows** (§4.2): the spectrum and autocorrelation of the principal
   component of the pair difference are reported; the window of each order is the
   candidate (from a geometric grid, at most a quarter of the data) that most reduces
   the objective.
3. **Stopping**: orders are added while one reduces the objective by at least
   ``min_gain`` (the paper's AMR second order added noise: it would fail this test).
   On records of at least :data:`JOINT_MIN_RECORD_S` the chosen windows are then
   fitted jointly with the step and pulse events of the difference (one full 3x3 per
   sensor, :mod:`magcal.ac.joint`): rank-one orders chained one after another leave
   the last direction of a disturber cluster (co-located disturbers) to orders that
   the objective, dominated by the ambient field, no longer accepts.
4. **Non-orthogonal fallback**: the regression gradiometer with all sensors is tried
   too; it replaces the PiCoG pair stage when it reduces the objective further.

Every order uses ambient-free directions (``direction="coherent"``) after removing
running means of ``fit_highpass_s`` (see :mod:`magcal.ac.filters`). The objective is
the variance of the cleaned target after removing running means of ``highpass_s`` (the
ambient field is common to every candidate, so its slow variation is removed and the
rest of it cancels in the comparison).

Filter lengths and windows scale with the record (:func:`record_scales`).

Speed: orders are fitted incrementally. Each candidate window costs one scan of the
current pair (windows sliding by about 1 % of their length) and one objective; the
chain is never re-run per trial. The pair stage is run once more jointly and once
more in sequence to compare them (a simulated day at 1 s takes 11-28 s in all).
"""

from __future__ import annotations

import numpy as np

from magcal.ac.chain import (
    Order,
    Plan,
    Stage,
    _wcombine,
    apply_weights,
    fit_order,
    run_chain,
    sample_period_s,
)
from magcal.ac.core import correction_matrix
from magcal.ac.filters import running_mean
from magcal.errors import InputError
from magcal.stats import normal_mad

CANDIDATE_WINDOWS_S = (30.0, 100.0, 300.0, 700.0, 2000.0, 6000.0, 16000.0)
#: fewer samples cannot support a choice of filters, windows and orders (nor the band
#: check of the product, :func:`magcal.ac.bandcheck.record_bands_hz`)
MIN_AUTO_SAMPLES = 256
#: records at least this long get the joint pair fit (:func:`_pair_stage`): its event
#: half-widths (120 s) and chance-level lags (up to 1500 s) are geostationary timescales
#: that need hours of data to hold several events and many lags
JOINT_MIN_RECORD_S = 21600.0
#: the joint pair fit is kept unless it leaves this much more variance than the orders
#: fitted one after another (measured: a 2-sensor day whose pair also carries a 34 nT
#: disturber, +3.4 % and 342x -> 97x against the truth; 3-sensor days -0.2 to +0.5 %
#: with the joint fit better against the truth)
JOINT_TOLERANCE = 0.01


def noise_sigma(b: np.ndarray) -> float:
    """Robust white-noise rms (nT, summed over components) from second differences."""
    b = np.asarray(b, dtype=float)
    d2 = np.diff(b, n=2, axis=0)
    d2 = d2[np.all(np.isfinite(d2), axis=1)]
    if d2.shape[0] < 10:
        return float("nan")
    mad = normal_mad(d2, axis=0)
    return float(np.sqrt(np.sum((mad / np.sqrt(6.0)) ** 2)))


def objective(b: np.ndarray, highpass_n: int) -> float:
    """Variance of ``b`` after removing running means over ``highpass_n`` samples."""
    b = np.asarray(b, dtype=float)
    ok = np.all(np.isfinite(b), axis=1)
    x = b[ok]
    x = x - running_mean(x, highpass_n)
    return float(np.sum(np.var(x, axis=0)))


def timescales(d: np.ndarray, dt_s: float) -> dict:
    """Characteristic timescales of a difference series (principal component).

    Returns the period of the spectral peak (periodogram, periods 2 s to a quarter of
    the data) and the lag where the autocorrelation first drops below 1/e.
    """
    from scipy import signal

    ok = np.all(np.isfinite(d), axis=1)
    x = np.asarray(d, dtype=float)[ok]
    if x.shape[0] < 4:  # the pair shares no samples: nothing to characterise
        return {"spectral_peak_period_s": float("nan"), "autocorrelation_1e_s": float("nan")}
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


def record_scales(n: int, dt_s: float, candidate_windows_s=CANDIDATE_WINDOWS_S) -> dict:
    """Filter lengths and candidate windows scaled to a record of ``n`` samples.

    The objective's running mean is a 24th of the record (at most 3600 s), the fit's
    high-pass half of that (at most 1800 s): on a day of data these are the lengths the
    paper's timescales call for, on a two-minute record they keep the ambient field's
    slow variation out of a fit that has only seconds of disturbance to go on. Windows
    are the fixed candidates that hold at least 10 samples and at most a quarter of the
    record; when fewer than three fit, a geometric grid (factor 3) down from a quarter
    of the record is used instead.

    Examples
    --------
    >>> s = record_scales(86400, 1.0)
    >>> s["highpass_s"], s["fit_highpass_s"], s["windows_s"][-1]
    (3600.0, 1800.0, 16000.0)
    >>> s = record_scales(15153, 1 / 128)
    >>> round(s["highpass_s"], 2), [round(w, 2) for w in s["windows_s"]]
    (4.93, [0.12, 0.37, 1.1, 3.29, 9.87, 29.6])
    """
    record_s = n * dt_s
    windows = [float(w) for w in candidate_windows_s
               if 10 <= int(round(w / dt_s)) <= n // 4]
    if len(windows) < 3:
        windows, w = [], record_s / 4
        while int(round(w / dt_s)) >= 10:
            windows.insert(0, float(w))
            w /= 3.0
    return {"record_s": record_s, "highpass_s": min(3600.0, record_s / 24),
            "fit_highpass_s": min(1800.0, record_s / 48), "windows_s": windows}


def _fmt_s(value) -> str:
    return "none" if value is None else f"{value:.4g} s"


def _fmt_window(win) -> str:
    return "the whole record" if win is None else f"window {win:.4g} s"


def _reference_stage(data, t_s, target, partner, others, ctx, report):
    """Step 1: the best first-order reference (if it pays), applied to target and
    partner. Returns (stages, cur, w, objective)."""
    dt, hp, sigma, base = ctx["dt"], ctx["hp"], ctx["sigma"], ctx["base"]
    ref_order = Order(direction=ctx["direction"], highpass_s=ctx["fit_highpass_s"] / 2)
    ref_rows, ref_fits = [], {}
    for r in others:
        try:
            alpha, e_i, e_ij, _ = fit_order(data[target], data[r], t_s, ref_order, dt_s=dt,
                                            alpha_method=ctx["alpha_method"])
        except InputError as exc:
            ref_rows.append({"reference": r, "usable": False, "why": str(exc)})
            continue
        A = correction_matrix(alpha, e_i, e_ij)
        ref_fits[r] = A
        obj = objective(data[target] + (data[target] - data[r]) @ A.T, hp)
        ref_rows.append({"reference": r, "usable": True, "alpha": float(alpha),
                         "injected_noise_nT": abs(alpha) * sigma[r],
                         "objective_nT2": obj, "gain": 1 - obj / base})
    report["reference_candidates"] = ref_rows
    cur = {s: np.asarray(data[s], dtype=float) for s in (target, partner)}
    w = {s: {s: np.eye(3)} for s in (target, partner)}
    # the boom partner is cleaned by the reference, never used as one; a reference that
    # injects more noise than the target carries is only taken when no quieter one pays
    paying = [row for row in ref_rows if row["usable"] and row["reference"] != partner
              and row["gain"] >= ctx["min_gain"]]
    quiet = [row for row in paying if row["injected_noise_nT"] <= sigma[target]]
    best = max(quiet or paying, key=lambda row: row["gain"]) if paying else None
    if best is None:
        report["choices"].append("no reference stage: no sensor besides the boom partner "
                                 f"removes at least {ctx['min_gain']:.0%} of the target "
                                 "variance as a first-order reference")
        return [], cur, w, base
    ref = best["reference"]
    noise = best["injected_noise_nT"]
    report["choices"].append(
        f"reference stage with {ref}: removes {best['gain']:.0%} of the target variance "
        + (f"but injects {noise:.3g} nT noise" if noise > sigma[target] else
           f"and injects only |alpha| sigma = {noise:.3g} nT of its noise (target noise "
           f"{sigma[target]:.3g} nT)"))
    b_ref = np.asarray(data[ref], dtype=float)
    alpha, e_i, e_ij, _ = fit_order(cur[partner], b_ref, t_s, ref_order, dt_s=dt,
                                    alpha_method=ctx["alpha_method"])
    for s_, A in ((target, ref_fits[ref]), (partner, correction_matrix(alpha, e_i, e_ij))):
        cur[s_] = cur[s_] + (cur[s_] - b_ref) @ A.T
        w[s_] = _wcombine(w[s_], {ref: np.eye(3)}, A)
    stages = [Stage("reference", (target, partner), reference=ref, orders=(ref_order,))]
    return stages, cur, w, objective(cur[target], hp)


def _best_order(cur, t_s, target, partner, windows, ctx):
    """Best window (or whole record) for the next pair order: (objective, window, A,
    e_ij, trials) or None."""
    trials = []
    for win in windows + [None]:
        order = Order(window_s=win, direction=ctx["direction"],
                      highpass_s=ctx["fit_highpass_s"])
        step = 1 if win is None else max(1, int(round(win / ctx["dt"])) // 100)
        try:
            alpha, e_i, e_ij, _ = fit_order(cur[target], cur[partner], t_s, order,
                                            dt_s=ctx["dt"], alpha_method=ctx["alpha_method"],
                                            scan_step=step)
        except InputError:
            continue
        A = correction_matrix(alpha, e_i, e_ij)
        trial = cur[target] + (cur[target] - cur[partner]) @ A.T
        trials.append((objective(trial, ctx["hp"]), win, A, e_ij))
    if not trials:
        return None
    obj, win, A, e_ij = min(trials, key=lambda x: x[0])
    return obj, win, A, e_ij, trials


def _pair_orders(data, t_s, stages, cur, w, target, partner, obj_before, ctx, report):
    """Step 2-3: pair orders added while each reduces the objective by ``min_gain``.
    Returns (orders, objective)."""
    direction, alpha_method = ctx["direction"], ctx["alpha_method"]
    orders: list[Order] = []
    order_rows = []
    for k in range(ctx["max_orders"]):
        best = _best_order(cur, t_s, target, partner, ctx["windows"], ctx)
        if best is None:
            break
        obj, win, A, e_ij, trials = best
        gain = 1 - obj / obj_before
        order_rows.append({"order": k + 1, "best_window_s": win, "objective_nT2": obj,
                           "gain": gain, "tried": [{"window_s": tw, "objective_nT2": to}
                                                   for to, tw, _, _ in trials]})
        if gain < ctx["min_gain"]:
            report["choices"].append(f"stop after {k} pair order(s): the best order {k + 1} "
                                     f"({_fmt_window(win)}) reduces the objective by only "
                                     f"{gain:.1%}")
            break
        orders.append(Order(window_s=win, direction=direction,
                            highpass_s=ctx["fit_highpass_s"]))
        report["choices"].append(f"pair order {k + 1}: {_fmt_window(win)} reduces the "
                                 f"objective by {gain:.0%} (best of {len(trials)} candidates)")
        if direction == "coherent":
            cur, w = _pair_update(cur, w, target, partner, A, np.asarray(e_ij, float))
        else:
            res = run_chain(data, t_s, Plan(target, tuple(stages) + (Stage(
                "pair", (target, partner), orders=tuple(orders)),)), alpha_method=alpha_method)
            cur = {target: res.corrected, partner: apply_weights(data, res.weights[partner])}
        obj_before = obj
    report["pair_orders"] = order_rows
    return orders, obj_before


def auto_plan(data: dict, t_s: np.ndarray, target: str, *, alpha_method: str = "decorrelate",
              highpass_s: float | None = None, min_gain: float = 0.05, max_orders: int = 3,
              candidate_windows_s=CANDIDATE_WINDOWS_S, fit_highpass_s="scaled",
              direction: str = "coherent", n_record: int | None = None
              ) -> tuple[Plan, dict]:
    """Choose references, pair, windows and orders; return the plan and the reasons.

    Parameters
    ----------
    data : dict sensor -> (n, 3) on a uniform grid
    t_s : ndarray (n,)
    target : str
    highpass_s : float, optional
        Running-mean length removed before computing the objective (also the
        regression's ``detrend_s``); default from :func:`record_scales`.
    min_gain : float
        Minimum relative reduction of the objective for an order (or stage) to be kept.
    candidate_windows_s : sequence of float
        Pair-order windows tried (scaled to the record by :func:`record_scales`).
    fit_highpass_s : float, None or "scaled"
        ``highpass_s`` of every fitted order (running means removed before the fit;
        None: no filtering; "scaled": from :func:`record_scales`).
    direction : {"coherent", "variance"}
        Direction method of every order (see :class:`magcal.ac.chain.Order`).
    n_record : int, optional
        Samples the record holds, which the filters are scaled to (default: the rows
        where ``data[target]`` has data). Given by :class:`magcal.ac.PiCoG` from the
        target before its glitches were left out: a few glitches do not shorten the
        record, a gap of a week does not lengthen it.

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
    # the record is the target's samples, not the grid's span: a two-hour record with a
    # week's gap is scaled as two hours (windows of days would hold no data)
    held = (int(np.all(np.isfinite(np.asarray(data[target], dtype=float)), axis=1).sum())
            if n_record is None else int(n_record))
    if held < MIN_AUTO_SAMPLES:
        raise InputError(f"the record has {held} samples with data; --auto needs at least "
                         f"{MIN_AUTO_SAMPLES} to choose filters and orders (give a plan)")
    dt = sample_period_s(t_s)
    scales = record_scales(held, dt, candidate_windows_s)
    highpass_s = scales["highpass_s"] if highpass_s is None else float(highpass_s)
    if isinstance(fit_highpass_s, str):
        fit_highpass_s = scales["fit_highpass_s"]
    hp = max(3, int(round(highpass_s / dt)))
    sigma = {s: noise_sigma(data[s]) for s in data}
    report: dict = {"noise_sigma_nT": sigma, "record_s": scales["record_s"],
                    "highpass_s": highpass_s, "fit_highpass_s": fit_highpass_s,
                    "candidate_windows_s": scales["windows_s"], "direction": direction,
                    "choices": [f"filters scaled to the {scales['record_s']:.4g} s record at "
                                f"{dt:.4g} s: objective high-pass {_fmt_s(highpass_s)}, fit "
                                f"high-pass {_fmt_s(fit_highpass_s)}, windows "
                                f"{[float(f'{v:.3g}') for v in scales['windows_s']]} s"]}
    base = objective(data[target], hp)
    report["objective_raw_nT2"] = base
    ctx = {"dt": dt, "hp": hp, "sigma": sigma, "base": base, "direction": direction,
           "fit_highpass_s": fit_highpass_s, "alpha_method": alpha_method,
           "min_gain": min_gain, "max_orders": max_orders, "windows": scales["windows_s"]}
    partner = sorted(others, key=lambda s: sigma[s])[0]
    stages, cur, w, current = _reference_stage(data, t_s, target, partner, others, ctx, report)
    report["partner"] = partner
    report["choices"].append(f"pair partner {partner}: lowest noise "
                             f"({sigma[partner]:.3g} nT) of the other sensors")
    report["timescales"] = timescales(cur[target] - cur[partner], dt)
    orders, picog_obj = _pair_orders(data, t_s, stages, cur, w, target, partner, current,
                                     ctx, report)
    pair, picog_obj = _pair_stage(data, t_s, stages, orders, target, partner, picog_obj,
                                  scales["record_s"], ctx, report)
    picog_stages = tuple(stages) + ((pair,) if pair is not None else ())
    return _choose_method(data, t_s, target, others, picog_stages, picog_obj, highpass_s,
                          ctx, report)


def _pair_stage(data, t_s, stages, orders, target, partner, seq_obj, record_s, ctx, report):
    """Step 3b: on records of at least :data:`JOINT_MIN_RECORD_S`, the pair's orders are
    fitted jointly (one full 3x3 per sensor over the orders' windows plus the step and
    pulse events of the difference, :mod:`magcal.ac.joint`) instead of one rank-one
    order after another, unless that raises the objective, computed with a quarter of
    its high-pass (less of the ambient's slow variation, which hides differences of a
    percent), by more than :data:`JOINT_TOLERANCE`. Returns (stage or None, objective).
    """
    if not orders:
        return None, seq_obj
    seq = Stage("pair", (target, partner), orders=tuple(orders))
    if record_s < JOINT_MIN_RECORD_S:
        return seq, seq_obj
    joint = Stage("pair", (target, partner), orders=tuple(orders), joint=True)
    short = max(3, ctx["hp"] // 4)
    try:
        res = {kind: run_chain(data, t_s, Plan(target, tuple(stages) + (st,)),
                               alpha_method=ctx["alpha_method"]).corrected
               for kind, st in (("seq", seq), ("joint", joint))}
    except (InputError, np.linalg.LinAlgError) as exc:
        report["choices"].append(f"pair orders one after another: the joint fit failed ({exc})")
        return seq, seq_obj
    obj = objective(res["joint"], ctx["hp"])
    o_seq, o_joint = objective(res["seq"], short), objective(res["joint"], short)
    report["objective_joint_nT2"] = obj
    report["objective_short_nT2"] = {"highpass_s": short * ctx["dt"], "one_after_another":
                                     o_seq, "joint": o_joint}
    if o_joint > o_seq * (1 + JOINT_TOLERANCE):
        report["choices"].append(
            f"pair orders one after another: fitted jointly they leave {o_joint / o_seq - 1:.1%} "
            f"more variance above {short * ctx['dt']:.4g} s")
        return seq, seq_obj
    report["choices"].append(
        f"pair orders fitted jointly (one 3x3 per sensor over their windows and the step "
        f"and pulse events of the difference): {o_joint:.4g} nT^2 above "
        f"{short * ctx['dt']:.4g} s vs {o_seq:.4g} one after another")
    return joint, obj


def _choose_method(data, t_s, target, others, picog_stages, picog_obj, highpass_s, ctx,
                   report):
    """Step 4: the regression gradiometer with all sensors replaces the PiCoG chain when
    it reduces the objective further."""
    reg_plan = Plan(target, (Stage("regression", (target,), references=tuple(others),
                                   orders=(Order(detrend_s=highpass_s),)),))
    try:
        reg_obj = objective(run_chain(data, t_s, reg_plan).corrected, ctx["hp"])
    except InputError as exc:
        reg_obj = float("inf")
        report["regression_error"] = str(exc)
    report["objective_picog_nT2"] = picog_obj
    report["objective_regression_nT2"] = reg_obj
    if reg_obj < picog_obj * (1 - ctx["min_gain"]) or not picog_stages:
        report["choices"].append(
            f"regression gradiometer with {', '.join(others)} (detrend {highpass_s:.4g} s): "
            f"objective {reg_obj:.4g} nT^2 vs {picog_obj:.4g} for the PiCoG chain "
            "(non-orthogonal or more disturbers than one pair can separate)")
        report["method"] = "regression"
        return reg_plan, report
    report["choices"].append(f"PiCoG chain kept: objective {picog_obj:.4g} nT^2 vs "
                             f"{reg_obj:.4g} for the regression gradiometer")
    report["method"] = "picog"
    return Plan(target, picog_stages), report
