"""AC cleaning quality without truth: remnants per disturbance class and parameter stability.

Constantinescu et al. (2020) judge a cleaning by (Table 2) the remnants of each disturbance
class in the corrected data and (Table 1) the stability of the fitted parameters over
repeated fits. A user has no truth, so here the events are found in the data themselves:
in the difference of two sensors (inboard minus outboard) the ambient field cancels and
only the spacecraft's disturbances remain.

- steps (and the ramps of longer disturbances): the difference of running medians over
  ``span_s`` before and after a sample, peaks above a robust threshold;
- spikes: short peaks of the difference above its running median;
- high-frequency noise: the 10 min window of least mean peak-to-peak amplitude of the
  difference is the quiet etalon, the event-free window of largest amplitude the
  disturbed interval.

At those times :func:`magcal.ac.metrics.ramp_sizes`, :func:`~magcal.ac.metrics.spike_heights`
and :func:`~magcal.ac.metrics.hf_peak_to_peak` measure the raw target and the cleaned data.

Stability: the same plan is refitted on each UTC day separately (interval orders keep
their time of day, as for a disturbance that recurs daily); the std of the directions
and alphas per step (:func:`magcal.ac.metrics.parameter_stability`) and ``Bmaxdev``, the
largest change of the corrected field between two refits' upload matrices applied to
the same data, are reported.

:func:`write_ac_quality` writes ``ac/AC_QUALITY.json`` from a products ``ac`` folder;
the uncertainty report reads it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
from scipy import ndimage, signal

from magcal.errors import InputError

DAY_S = 86400.0
#: Robust threshold (in MAD-sigmas above the median) for step and spike detection.
DETECT_SIGMA = 8.0


# ----------------------------------------------------------------------------- helpers
def _filled(x: np.ndarray) -> np.ndarray:
    """Linear interpolation over NaN per column (median filters need finite input)."""
    x = np.array(x, dtype=float, copy=True).reshape(len(x), -1)
    idx = np.arange(x.shape[0])
    for k in range(x.shape[1]):
        ok = np.isfinite(x[:, k])
        if not ok.any():
            raise InputError("a component of the sensor difference has no valid sample")
        if not ok.all():
            x[~ok, k] = np.interp(idx[~ok], idx[ok], x[ok, k])
    return x


def _robust_threshold(s: np.ndarray, n_sigma: float, floor: float) -> float:
    med = float(np.median(s))
    mad = float(np.median(np.abs(s - med))) * 1.4826
    return max(med + n_sigma * mad, floor)


def _dt(t_s: np.ndarray) -> float:
    return float(np.median(np.diff(np.asarray(t_s, dtype=float))))


# --------------------------------------------------------------------------- detection
def detect_steps(d: np.ndarray, t_s: np.ndarray, *, span_s: float = 90.0, gap_s: float = 15.0,
                 n_sigma: float = 4.0, min_significance: float = 4.0,
                 min_nT: float = 0.0) -> np.ndarray:
    """Times of steps (ramps) in a sensor difference.

    The step signal is ``|m(t + h) - m(t - h)|`` with ``m`` the running median over
    ``span_s`` and ``h = gap_s + span_s / 2`` (the Table-2 ramp size at every sample);
    its peaks above ``median + n_sigma`` robust sigmas (and ``min_nT``) whose height is
    at least ``min_significance`` times the robust spread (MAD sigma, norm over
    components) of the samples in the noisier of the two ``span_s`` windows are the steps. The second
    test rejects the peaks that band-limited noise puts in the step signal (on the
    GK-2A-like demo day the true steps have 4.5-38, noise peaks below 3.6).

    Parameters
    ----------
    d : ndarray (n, 3)
        Sensor difference (e.g. inboard minus outboard), NaN allowed.
    t_s : ndarray (n,)
        Uniform sample times (s).

    Returns
    -------
    ndarray
        Event times (s, same base as ``t_s``).

    Examples
    --------
    >>> t = np.arange(2000.0)
    >>> rng = np.random.default_rng(0)
    >>> d = rng.normal(0, 0.1, (2000, 3)); d[1000:, 1] += 3.0
    >>> detect_steps(d, t).tolist()   # between samples 999 and 1000
    [999.5]
    """
    t_s = np.asarray(t_s, dtype=float)
    dt = _dt(t_s)
    n = max(3, int(round(span_s / dt)) | 1)
    h = int(round(gap_s / dt)) + n // 2
    x = _filled(d)
    m = ndimage.median_filter(x, size=(n, 1), mode="nearest")
    s = np.zeros(len(t_s))
    s[h:-h] = np.linalg.norm(m[2 * h:] - m[:-2 * h], axis=1)
    thr = _robust_threshold(s[h:-h], n_sigma, min_nT)
    peaks, _ = signal.find_peaks(s, height=thr, distance=h)
    # band-limited noise makes the step signal heavy-tailed: keep a candidate only when
    # the jump is ``min_significance`` times the spread of the samples in its two windows
    half_n = n // 2
    keep = []
    for p in peaks:
        if p - h - half_n < 0 or p + h + half_n >= len(s):
            continue
        spread = max(float(np.linalg.norm(1.4826 * np.median(
            np.abs(x[c - half_n:c + half_n + 1] - m[c]), axis=0))) for c in (p - h, p + h))
        if s[p] >= min_significance * spread:
            keep.append(p)
    peaks = np.array(keep, dtype=int)
    # medians keep edges sharp, so a step gives a plateau ~2h wide: its centre (between
    # the half-height crossings) is the step time, robust to noise on the plateau
    centres = []
    for p in peaks:
        half = 0.5 * s[p]
        lo = p
        while lo > 0 and s[lo - 1] > half:
            lo -= 1
        hi = p
        while hi < len(s) - 1 and s[hi + 1] > half:
            hi += 1
        c = 0.5 * (t_s[lo] + t_s[hi])
        if not centres or c - centres[-1] > h * dt:
            centres.append(c)
    return np.array(centres)


def detect_spikes(d: np.ndarray, t_s: np.ndarray, *, span_s: float = 20.0, gap_s: float = 5.0,
                  max_width_s: float = 10.0, n_sigma: float = DETECT_SIGMA,
                  min_nT: float = 0.0, exclude_s=(), exclude_within_s: float = 60.0
                  ) -> np.ndarray:
    """Times of spikes in a sensor difference.

    A spike is a peak of ``|d - running median over 2 (span_s + gap_s)|`` above
    ``n_sigma`` local robust sigmas (running MAD over the same span, its
    largest value within that span; and ``min_nT``), narrower than ``max_width_s`` at
    half height (GK-2A spikes: 6 s), at least ``span_s + gap_s`` from the next one and ``exclude_within_s``
    from any time in ``exclude_s`` (the steps).

    Examples
    --------
    >>> t = np.arange(1000.0)
    >>> rng = np.random.default_rng(0)
    >>> d = rng.normal(0, 0.1, (1000, 3)); d[400, 0] += 5.0
    >>> detect_spikes(d, t).tolist()
    [400.0]
    """
    t_s = np.asarray(t_s, dtype=float)
    dt = _dt(t_s)
    n = int(round(2 * (span_s + gap_s) / dt)) | 1
    x = _filled(d)
    res = x - ndimage.median_filter(x, size=(n, 1), mode="nearest")
    r = np.linalg.norm(res, axis=1)
    # local scale: noise bursts raise the threshold where they are
    local = np.linalg.norm(1.4826 * ndimage.median_filter(np.abs(res), size=(n, 1),
                                                          mode="nearest"), axis=1)
    local = ndimage.maximum_filter1d(local, n, mode="nearest")  # burst edges too
    thr = np.maximum(n_sigma * local, min_nT)
    thr[:n // 2] = thr[-(n // 2):] = np.inf                      # filter edge effects
    peaks, _ = signal.find_peaks(r, height=thr, distance=max(1, int(round((span_s + gap_s)
                                                                         / dt))),
                                 width=(None, max(1.0, max_width_s / dt)), rel_height=0.5)
    times = t_s[peaks]
    ex = np.atleast_1d(np.asarray(exclude_s, dtype=float))
    if ex.size and times.size:
        near = np.min(np.abs(times[:, None] - ex[None, :]), axis=1) < exclude_within_s
        times = times[~near]
    return times


def _block_p2p(x: np.ndarray, block_n: int) -> np.ndarray:
    """Peak-to-peak per block after removing each block's linear trend, (n_blocks, 3)."""
    m = (x.shape[0] // block_n) * block_n
    blocks = x[:m].reshape(m // block_n, block_n, x.shape[1])
    tt = np.arange(block_n, dtype=float) - (block_n - 1) / 2.0
    slope = np.einsum("k,nkc->nc", tt, blocks) / np.sum(tt ** 2)
    res = blocks - blocks.mean(axis=1, keepdims=True) - slope[:, None, :] * tt[None, :, None]
    return res.max(axis=1) - res.min(axis=1)


def hf_intervals(d: np.ndarray, t_s: np.ndarray, *, window_s: float = 600.0,
                 block_s: float = 60.0, exclude_s=(), exclude_within_s: float = 120.0):
    """Quiet etalon and disturbed interval for the high-frequency class.

    The difference is cut into ``block_s`` blocks (linear trend removed); among the
    ``window_s`` windows of whole blocks free of excluded events (steps, spikes), the
    one of least mean peak-to-peak amplitude (summed over components) is the quiet
    etalon and the one of largest amplitude the disturbed interval.

    Returns
    -------
    quiet, disturbed : tuple (start, end) in s
    contrast : float
        Mean peak-to-peak of the disturbed over the quiet window (1: no HF class).

    Examples
    --------
    >>> t = np.arange(7200.0)
    >>> rng = np.random.default_rng(0)
    >>> d = rng.normal(0, 0.1, (7200, 3)); d[3600:4800] += rng.normal(0, 1.0, (1200, 3))
    >>> q, w, c = hf_intervals(d, t)
    >>> 3600 <= w[0] and w[1] <= 4800, c > 5
    (True, True)
    """
    t_s = np.asarray(t_s, dtype=float)
    dt = _dt(t_s)
    block_n = max(3, int(round(block_s / dt)))
    per = max(1, int(round(window_s / block_s)))
    p2p = _block_p2p(_filled(d), block_n).sum(axis=1)
    starts = t_s[0] + dt * block_n * np.arange(len(p2p))
    bad = np.zeros(len(p2p), bool)
    for e in np.atleast_1d(np.asarray(exclude_s, dtype=float)):
        bad |= (starts < e + exclude_within_s) & (starts + block_n * dt > e - exclude_within_s)
    if len(p2p) < per:
        raise InputError(f"the data are shorter than one {window_s:g} s window")
    mean = np.convolve(p2p, np.ones(per) / per, mode="valid")
    ok = np.convolve(bad.astype(float), np.ones(per), mode="valid") == 0
    if not ok.any():
        raise InputError(f"no {window_s:g} s window free of steps and spikes")
    cand = np.flatnonzero(ok)
    q, w = cand[np.argmin(mean[cand])], cand[np.argmax(mean[cand])]
    span = block_n * dt * per
    return ((float(starts[q]), float(starts[q] + span)),
            (float(starts[w]), float(starts[w] + span)), float(mean[w] / mean[q]))


# ---------------------------------------------------------------------------- remnants
def _summ(v: np.ndarray) -> dict:
    """Mean |component| and mean module of event vectors (n, 3)."""
    if v.size == 0:
        return {"mean_abs_nT": [float("nan")] * 3, "mean_module_nT": float("nan")}
    return {"mean_abs_nT": np.mean(np.abs(v), axis=0).tolist(),
            "mean_module_nT": float(np.mean(np.linalg.norm(v, axis=1)))}


def remnants(raw: np.ndarray, clean: np.ndarray, diff: np.ndarray, t_s: np.ndarray, *,
             n_sigma: float = DETECT_SIGMA, min_step_nT: float = 0.0,
             min_spike_nT: float = 0.0) -> dict:
    """Disturbance magnitudes in the raw target and remnants in the cleaned data (Table 2).

    Parameters
    ----------
    raw, clean : ndarray (n, 3)
        Raw target sensor and cleaned data on the same samples.
    diff : ndarray (n, 3)
        Difference of two sensors (e.g. inboard minus outboard), where events are found.
    t_s : ndarray (n,)
        Uniform sample times (s).

    Returns
    -------
    dict with ``steps``, ``spikes`` (``times_s``, ``n``, ``raw`` and ``clean`` summaries:
    ``mean_abs_nT`` per component, ``mean_module_nT``) and ``hf`` (``quiet_s``,
    ``disturbed_s``, ``contrast``, ``raw_nT`` and ``clean_nT`` per component).

    Examples
    --------
    >>> t = np.arange(4000.0)
    >>> rng = np.random.default_rng(1)
    >>> dist = np.zeros((4000, 3)); dist[2000:, 2] = 2.0; dist[1000, 0] = 4.0
    >>> amb = rng.normal(0, 0.02, (4000, 3))
    >>> out = remnants(amb + dist, amb + 0.1 * dist, 3 * dist + amb, t)
    >>> round(out["steps"]["raw"]["mean_abs_nT"][2], 1), round(out["steps"]["clean"]["mean_abs_nT"][2], 2)
    (2.0, 0.2)
    >>> round(out["spikes"]["raw"]["mean_abs_nT"][0], 1), round(out["spikes"]["clean"]["mean_abs_nT"][0], 1)
    (4.0, 0.4)
    """
    from magcal.ac.metrics import hf_peak_to_peak, ramp_sizes, spike_heights

    t_s = np.asarray(t_s, dtype=float)
    raw, clean, diff = (np.asarray(a, dtype=float) for a in (raw, clean, diff))
    steps = detect_steps(diff, t_s, min_nT=min_step_nT)
    spikes = detect_spikes(diff, t_s, n_sigma=n_sigma, min_nT=min_spike_nT, exclude_s=steps)
    out = {}
    for name, times, fn in (("steps", steps, ramp_sizes), ("spikes", spikes, spike_heights)):
        r, c = fn(raw, t_s, times), fn(clean, t_s, times)
        out[name] = {"n": int(r.shape[0]), "times_s": times.tolist(),
                     "raw": _summ(r), "clean": _summ(c)}
    try:
        quiet, dist, contrast = hf_intervals(diff, t_s, exclude_s=np.r_[steps, spikes])
        out["hf"] = {"quiet_s": list(quiet), "disturbed_s": list(dist), "contrast": contrast,
                     "raw_nT": hf_peak_to_peak(raw, t_s, quiet, dist).tolist(),
                     "clean_nT": hf_peak_to_peak(clean, t_s, quiet, dist).tolist()}
    except InputError as exc:
        out["hf"] = {"skipped": str(exc)}
    return out


# ------------------------------------------------------------------ parameter stability
def plan_from_params(plan_doc: dict, shift_s: float = 0.0):
    """:class:`~magcal.ac.chain.Plan` from the ``plan`` key of PARAMS.json.

    ``shift_s`` moves interval orders (e.g. by whole days for a daily refit); see
    :func:`magcal.ac.plan.plan_from_json`.

    Examples
    --------
    >>> doc = {"target": "o", "stages": [{"kind": "reference", "sensors": ["o"],
    ...        "reference": "a", "orders": [{"window_s": None, "interval": [0.0, 10.0]}]}]}
    >>> plan_from_params(doc, 86400.0).stages[0].orders[0].interval
    (86400.0, 86410.0)
    """
    from magcal.ac.plan import plan_from_json

    return plan_from_json(plan_doc, shift_s=shift_s)


def _shift_for_day(plan_doc: dict, day_start_s: float) -> float:
    """Shift that moves the plan's first interval to the same time of day on that day."""
    for st in plan_doc["stages"]:
        for o in st["orders"]:
            if o.get("interval"):
                start = float(o["interval"][0])
                return day_start_s - np.floor(start / DAY_S) * DAY_S
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
    from magcal.timeconv import epoch_seconds

    t = epoch_seconds(frame.index)
    day = np.floor(t / DAY_S)
    dt = _dt(t)
    out = []
    for d in np.unique(day):
        sel = day == d
        if sel.sum() * dt < min_fraction * DAY_S:
            continue
        plan = plan_from_params(plan_doc, _shift_for_day(plan_doc, d * DAY_S))
        model = PiCoG(plan, alpha_method=alpha_method).fit(frame.loc[sel])
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
    from magcal.ac.chain import apply_weights
    from magcal.ac.estimator import sensor_array
    from magcal.ac.metrics import parameter_stability

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


# ------------------------------------------------------------------------------ product
def difference_pair(params: dict) -> tuple[str, str]:
    """Sensors whose difference shows the disturbances: (other, target).

    The partner of the target in the first pair stage, else the first other sensor of
    a regression or reference stage (fluxgate partners first).

    Examples
    --------
    >>> difference_pair({"target": "fgmo", "plan": {"stages": [{"kind": "regression",
    ...     "sensors": ["fgmo"], "references": ["amr1", "fgmi"], "orders": []}]}})
    ('fgmi', 'fgmo')
    """
    target = params["target"]
    stages = (params.get("plan") or {}).get("stages", [])
    for st in stages:
        if st["kind"] == "pair" and target in st["sensors"]:
            return next(s for s in st["sensors"] if s != target), target
    others = []
    for st in stages:
        for s in [*st.get("sensors", []), *st.get("references", []),
                  *([st["reference"]] if st.get("reference") else [])]:
            if s != target and s not in others:
                others.append(s)
    if not others:
        raise InputError("the plan names no sensor besides the target")
    # a sensor of the same kind (same name without digits/last letter) first
    stem = target.rstrip("0123456789")[:-1]
    others.sort(key=lambda s: not s.startswith(stem))
    return others[0], target


def ac_quality(raw: pd.DataFrame, cleaned: dict, params: dict, *, refit: bool = True,
               n_sigma: float = DETECT_SIGMA) -> dict:
    """Remnants and (optionally) daily-refit stability of every cleaning plan.

    Parameters
    ----------
    raw : DataFrame
        Multi-sensor input (``<sensor>_x/_y/_z``, UTC DatetimeIndex).
    cleaned : dict name -> DataFrame with ``x, y, z``
    params : dict name -> PARAMS.json document (with ``target``, ``M``, ``plan``)
    refit : bool
        Refit each plan per day (costs about one fit of the whole record per plan).

    Returns
    -------
    dict name -> ``{"pair", "remnants", "stability"}`` (stability missing or
    ``{"skipped": reason}`` when not computed).
    """
    from magcal.ac.estimator import sensor_array
    from magcal.timeconv import epoch_seconds

    out = {}
    for name, prm in params.items():
        other, target = difference_pair(prm)
        clean = cleaned[name]
        common = raw.index.intersection(clean.index)
        r = raw.loc[common]
        t = epoch_seconds(common)
        entry = {"pair": [other, target], "target": target}
        entry["remnants"] = remnants(sensor_array(r, target),
                                     clean.loc[common, ["x", "y", "z"]].to_numpy(float),
                                     sensor_array(r, other) - sensor_array(r, target), t,
                                     n_sigma=n_sigma)
        if refit and prm.get("plan"):
            try:
                fits = daily_refits(raw, prm["plan"], alpha_method=prm.get("alpha_method",
                                                                           "decorrelate"))
                entry["stability"] = stability(raw, fits, prm.get("M"))
            except InputError as exc:
                entry["stability"] = {"skipped": str(exc)}
        out[name] = entry
    return out


def write_ac_quality(ac_dir, raw_path, *, refit: bool = True, out_name: str = "AC_QUALITY.json"
                     ) -> Path:
    """Write ``<ac_dir>/AC_QUALITY.json`` from ``PARAMS_*.json`` and ``CLEAN_*.csv.gz``.

    Parameters
    ----------
    ac_dir : path-like
        Folder with ``PARAMS_<name>.json`` and ``CLEAN_<name>.csv.gz`` (``magcal demo``'s
        ``ac/``).
    raw_path : path-like
        The multi-sensor input the parameters were fitted on.
    refit : bool
        Include the daily-refit stability (about one whole-record fit per plan).

    Returns
    -------
    Path of the product (``plans``: :func:`ac_quality` output, plus ``provenance``).
    """
    from magcal.io.csv import read_csv_frame
    from magcal.io.jsonio import read_json, write_json
    from magcal.provenance import make_provenance

    ac_dir, raw_path = Path(ac_dir), Path(raw_path)
    params, cleaned, inputs = {}, {}, [raw_path]
    for pf in sorted(ac_dir.glob("PARAMS_*.json")):
        name = pf.stem.removeprefix("PARAMS_")
        cp = ac_dir / f"CLEAN_{name}.csv.gz"
        if not cp.is_file():
            continue
        params[name] = read_json(pf, required=("target", "M"))
        cleaned[name] = read_csv_frame(cp)
        inputs += [pf, cp]
    if not params:
        raise InputError("no PARAMS_*.json with a CLEAN_*.csv.gz next to it", file=ac_dir)
    raw = read_csv_frame(raw_path)
    payload = {"plans": ac_quality(raw, cleaned, params, refit=refit),
               "definitions": {
                   "events": "found in the difference of the 'pair' sensors (ambient cancels)",
                   "steps": "median over 90 s after minus before, 15 s either side skipped",
                   "spikes": "peak minus median over 20 s intervals 5 s before and after",
                   "hf": "mean peak-to-peak over 60 s blocks, disturbed minus quiet etalon",
                   "stability": "plan refitted per UTC day; std over days; bmaxdev: largest "
                                "|change| of the corrected field between two days' matrices "
                                "applied to the whole input"},
               "provenance": make_provenance("ac quality", {"refit": refit},
                                             inputs=inputs)}
    out = ac_dir / out_name
    write_json(out, payload)
    return out
