"""Measure a model gap: where the residual (measured - model) concentrates.

:func:`profile_gap` summarises a residual per component by local time, by time (trend,
largest step), by frequency (periodogram peaks), by covariate (correlation) and by
field direction (fraction explained by a scale error or a small rotation). The numbers
feed the human-readable account and the ``gap_initial``/``gap_final`` sections of the
discovery report.
"""

from __future__ import annotations

import numpy as np

from magcal.discover.effects import DAY_S, EffectInputs
from magcal.discover.scan import periodogram, scan_step
from magcal.stats import finite_rms


def rms(residual) -> float:
    """Root mean square over all finite entries (nT); see :func:`magcal.stats.finite_rms`.

    Examples
    --------
    >>> rms(np.array([[3.0, 4.0], [np.nan, 0.0]]))
    2.886751345948129
    """
    return finite_rms(residual)


def local_time_profile(lt_h, residual, bin_h: float = 1.0):
    """Mean residual per local-time bin.

    Returns
    -------
    centres_h : ndarray (k,)
    means : ndarray (k, m)
        NaN where a bin is empty.
    """
    lt = np.asarray(lt_h, dtype=float)
    r = np.asarray(residual, dtype=float)
    nb = int(round(24.0 / bin_h))
    idx = np.clip((lt / bin_h).astype(int), 0, nb - 1)
    ok = np.isfinite(r)
    sums = np.zeros((nb, r.shape[1]))
    counts = np.zeros((nb, r.shape[1]))
    for c in range(r.shape[1]):
        sums[:, c] = np.bincount(idx[ok[:, c]], weights=r[ok[:, c], c], minlength=nb)
        counts[:, c] = np.bincount(idx[ok[:, c]], minlength=nb)
    with np.errstate(invalid="ignore", divide="ignore"):
        means = sums / counts
    return (np.arange(nb) + 0.5) * bin_h, means


def _corr(a, b) -> float:
    ok = np.isfinite(a) & np.isfinite(b)
    n = int(ok.sum())
    if n < 3:
        return float("nan")
    if n < a.size:
        a, b = a[ok], b[ok]
    a = a - a.mean()
    b = b - b.mean()
    den = np.sqrt(np.dot(a, a) * np.dot(b, b))
    return float(np.dot(a, b) / den) if den > 0 else float("nan")


def _explained(col, r) -> float:
    """Fraction of the variance of ``r`` explained by a regression on ``col`` (+ constant)."""
    c = _corr(col, r)
    return float(c * c) if np.isfinite(c) else float("nan")


def profile_gap(inputs: EffectInputs, residual, n_peaks: int = 3,
                spectrum: bool = True) -> dict:
    """Where a residual concentrates (JSON-ready).

    Parameters
    ----------
    inputs : EffectInputs
        Times, model field, covariates and local time of the samples.
    residual : ndarray, shape (n, m)
        Measured minus model (minus effects so far), NaN where missing.
    n_peaks : int
        Number of periodogram peaks to list.
    spectrum : bool
        Include the periodogram peaks (the most expensive part).

    Returns
    -------
    dict
        ``rms_nT`` (all components), ``by_component`` (per component: ``rms_nT``,
        ``mean_nT``, ``trend_nT_per_day``, ``lt_peak_to_peak_nT``, ``lt_peak_h``,
        ``lt_trough_h``, ``corr`` with each covariate, ``scale_explained``), plus
        ``largest_step`` (time and size per component), ``periodogram_peaks``
        (period and amplitude), ``rotation_explained`` and, with local time,
        ``local_time_profile`` (hourly means).

    Examples
    --------
    >>> t = np.arange(0, 4 * 86400, 600.0)
    >>> inp = EffectInputs(t, np.full((t.size, 1), 100.0), ("Hp",),
    ...                    local_time_h=np.mod(t / 3600, 24))
    >>> r = 4 * np.cos(2 * np.pi * (inp.local_time_h - 12) / 24)[:, None]
    >>> p = profile_gap(inp, r)["by_component"]["Hp"]
    >>> round(p["lt_peak_to_peak_nT"], 1), p["lt_peak_h"]
    (7.9, 12.5)
    """
    r = np.asarray(residual, dtype=float)
    t = inputs.times_s
    out: dict = {"rms_nT": rms(r), "by_component": {}}
    comps = inputs.components
    tc = (t - t.mean()) / DAY_S
    if inputs.local_time_h is not None:
        centres, means = local_time_profile(inputs.local_time_h, r)
        out["local_time_profile"] = {"lt_h": centres,
                                     **{c: means[:, i] for i, c in enumerate(comps)}}
    for i, comp in enumerate(comps):
        x = r[:, i]
        ok = np.isfinite(x)
        entry = {"rms_nT": rms(x), "mean_nT": float(np.mean(x[ok])) if ok.any() else np.nan}
        if ok.sum() > 2:
            entry["trend_nT_per_day"] = float(np.polyfit(tc[ok], x[ok], 1)[0])
        if inputs.local_time_h is not None:
            prof = means[:, i]
            if np.isfinite(prof).any():
                entry["lt_peak_to_peak_nT"] = float(np.nanmax(prof) - np.nanmin(prof))
                entry["lt_peak_h"] = float(centres[np.nanargmax(prof)])
                entry["lt_trough_h"] = float(centres[np.nanargmin(prof)])
        entry["corr"] = {name: _corr(np.asarray(v, dtype=float), x)
                         for name, v in inputs.covariates.items() if name != "phase"}
        entry["scale_explained"] = _explained(inputs.model[:, i], x)
        out["by_component"][comp] = entry
    t_step, size, _ = scan_step(t, r)
    if t_step is not None:
        import pandas as pd

        out["largest_step"] = {"time": pd.Timestamp(t_step, unit="s", tz="UTC").isoformat(),
                               "size_nT": {c: float(s) for c, s in zip(comps, size)}}
    if spectrum and t.size > 16:
        freq, amp = periodogram(t, r, oversample=1)
        total = (amp ** 2).sum(axis=1)
        keep = freq >= 3.0 / max(t[-1] - t[0], 1.0)
        order = np.argsort(np.where(keep, total, -1))[::-1][:n_peaks]
        out["periodogram_peaks"] = [
            {"period_h": float(1 / freq[k] / 3600.0),
             "amplitude_nT": {c: float(amp[k, i]) for i, c in enumerate(comps)}}
            for k in order if keep[k]]
    if inputs.m == 3:
        cols = np.stack([np.cross(np.eye(3)[j], inputs.model) for j in range(3)])
        ok = np.isfinite(r).all(axis=1)
        if ok.sum() > 3:
            X = cols[:, ok, :].reshape(3, -1).T
            yv = (r[ok] - r[ok].mean(axis=0)).reshape(-1)
            Xc = X - X.mean(axis=0)
            beta, *_ = np.linalg.lstsq(Xc, yv, rcond=None)
            fit = Xc @ beta
            out["rotation_explained"] = float((fit @ fit) / (yv @ yv)) if yv @ yv > 0 else 0.0
            out["rotation_deg"] = {c: float(np.rad2deg(b)) for c, b in zip(comps, beta)}
    return out
