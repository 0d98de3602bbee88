"""Score a chain's products against known truth (simulated input, or a reference run).

The truth file (``[truth] file``) is a CSV with ``time`` and any of
``offset_Hp,offset_He,offset_Hn`` (the DC offsets the offset product must follow) and
``clean_Hp,clean_He,clean_Hn`` (the target field a perfect AC cleaning returns). The
stage reports how closely the products follow them; it never feeds back into them.
"""

from __future__ import annotations

import numpy as np

from magcal.chain.config import ChainConfig
from magcal.chain.prepare import HPEN, CleanedData, naive_times
from magcal.chain.product import StageProduct
from magcal.errors import InputError
from magcal.stats import finite_rms

_DAY_NS = 86_400 * 10**9


def offsets_against_truth(table, t_truth: np.ndarray, true_offsets: np.ndarray) -> dict:
    """RMS and largest error of the interpolated offset product against the true offsets.

    Errors are given over all times the product covers and, separately, over times
    at least half a window away from any jump of the truth (a sliding-window median
    smooths a step over one window by construction). A product split at level changes
    (``table.segment``) is scored as ``offsets apply`` applies it, segment by segment.

    Examples
    --------
    >>> from magcal.offsets import OffsetEstimator
    >>> t = np.datetime64("2019-11-01", "ns") + np.arange(60 * 1440) * np.timedelta64(60, "s")
    >>> truth = np.column_stack([np.linspace(0, 1, t.size)] * 3)
    >>> est = OffsetEstimator().fit(t, truth, np.zeros_like(truth), kp=np.zeros(t.size))
    >>> r = offsets_against_truth(est.table_, t, truth)
    >>> r["rms_nT"] < 0.02
    True
    """
    from magcal.offsets import interpolate_offsets

    if getattr(table, "segment", None) is None:
        est, flag = interpolate_offsets(t_truth, table.center, table.offset_nT)
        inside = flag == 0
    else:
        # split at level changes: scored as applied (within segments, held out to each
        # change), over the span of the valid centres like the unsplit product
        from magcal.offsets.apply import interpolate_segmented

        est, flag, _ = interpolate_segmented(t_truth, table)
        c = np.asarray(table.center)[table.valid].astype("datetime64[ns]")
        t_ns = np.asarray(t_truth).astype("datetime64[ns]")
        inside = (np.isin(flag, (0, 1, 2)) & (t_ns >= c[0]) & (t_ns <= c[-1])
                  if c.size else np.zeros(flag.size, dtype=bool))
    err = est - true_offsets
    jumps = np.flatnonzero(np.abs(np.diff(true_offsets, axis=0)).max(axis=1) > 0.5)
    t_ns = t_truth.astype("datetime64[ns]").astype(np.int64)
    half = 0.5 * float(table.parameters.get("window_days", 28.0)) * _DAY_NS
    away = inside.copy()
    for j in jumps:
        away &= np.abs(t_ns - t_ns[j]) > half
    per = {c: finite_rms(err[inside, k]) for k, c in enumerate(HPEN)}
    return {"rms_nT": finite_rms(err[inside]), "rms_per_component_nT": per,
            "max_abs_nT": float(np.nanmax(np.abs(err[inside]))) if inside.any() else None,
            "rms_away_from_steps_nT": finite_rms(err[away]),
            "max_abs_away_from_steps_nT": float(np.nanmax(np.abs(err[away])))
            if away.any() else None,
            "n_steps_in_truth": int(len(jumps)),
            "true_change_nT": np.ptp(true_offsets, axis=0).tolist()}


def run_truth(cleaned: CleanedData, table, raw_target, config: ChainConfig):
    """Compare the AC-cleaned target and the offset product with the truth file."""
    from magcal.io.formats import read_any

    path = config.resolve(config["truth"]["file"])
    if path is None:
        raise InputError("no [truth] file", file=config.path)
    truth = read_any(path)
    t = naive_times(truth.index)
    summary, lines = {}, []
    off_cols = [f"offset_{c}" for c in HPEN]
    if all(c in truth for c in off_cols):
        res = offsets_against_truth(table, t, truth[off_cols].to_numpy(dtype=float))
        summary["offsets"] = res
        if res["max_abs_nT"] is None:
            res["reason"] = "no truth time inside the span of valid offset windows"
            lines.append(f"offset product vs injected drift and step: not scored ({res['reason']})")
        else:
            away = res["max_abs_away_from_steps_nT"]
            lines.append(
                f"offset product vs injected drift and step: rms {res['rms_nT']:.2f} nT, "
                f"max {res['max_abs_nT']:.2f} nT; away from the step "
                + (f"rms {res['rms_away_from_steps_nT']:.2f} nT, max {away:.2f} nT"
                   if away is not None else "no time (every time is within half a window)")
                + " (true change " + "/".join(f"{v:.1f}" for v in res["true_change_nT"])
                + " nT)")
    clean_cols = [f"clean_{c}" for c in HPEN]
    if all(c in truth for c in clean_cols):
        t_all = naive_times(cleaned.times)
        k = np.searchsorted(t_all, t)
        ok = (k < len(t_all)) & (t_all[np.minimum(k, len(t_all) - 1)] == t)
        if cleaned.quality is not None:  # scored on the samples QC keeps
            from magcal.qc import EXCLUDE

            good = (cleaned.quality & EXCLUDE) == 0
            ok &= good[np.minimum(k, len(t_all) - 1)]
        want = truth[clean_cols].to_numpy(dtype=float)[ok]
        got, raw = cleaned.hpen[k[ok]], raw_target[k[ok]]
        res_c = (got - want) - np.nanmean(got - want, axis=0)
        res_r = (raw - want) - np.nanmean(raw - want, axis=0)
        ratio = np.nanmean(res_r ** 2) / np.nanmean(res_c ** 2)
        summary["ac"] = {"rms_raw_nT": finite_rms(res_r), "rms_cleaned_nT": finite_rms(res_c),
                         "power_reduction": float(ratio), "n_compared": int(ok.sum())}
        lines.append(f"AC cleaning vs truth: disturbance rms {finite_rms(res_r):.3f} -> "
                     f"{finite_rms(res_c):.3f} nT ({ratio:.0f}x in power)")
    if not summary:
        raise InputError("the truth file has neither offset_Hp,.. nor clean_Hp,.. columns",
                         file=path)
    return summary, StageProduct(stage="truth", summary=summary, lines=tuple(lines))
