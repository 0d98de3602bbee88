"""Steps, spikes and high-frequency noise found in a sensor difference.

In the difference of two sensors the ambient field cancels and only the spacecraft's
disturbances remain, so events are detected there. Two families of detectors live
here, for two uses:

- the remnant measures of Constantinescu et al. (2020, Table 2), which need few, sure
  events: :func:`detect_steps` (running medians before and after a sample, peaks
  checked against the spread of their own windows), :func:`detect_spikes`,
  :func:`hf_intervals` (quiet etalon and disturbed interval) and :func:`remnants`;
- the event selections of the joint pair fit (:mod:`magcal.ac.joint`), which need the
  largest ramps and every other step or spike near them: the running-mean step signal
  and running-median spike signal (:func:`step_and_spike_signals`),
  :func:`event_intervals`, :func:`event_masks` and :func:`cleaned_events`.

Thresholds are robust: a number of normal-equivalent MADs above the median
(:func:`robust_threshold`).
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage, signal
from scipy.stats import median_abs_deviation

from magcal.ac.chain import sample_period_s
from magcal.ac.filters import running_mean
from magcal.ac.metrics import fill_nan
from magcal.errors import InputError
from magcal.stats import MAD_TO_SIGMA

#: Robust threshold (in MAD-sigmas above the median) for step and spike detection.
DETECT_SIGMA = 8.0
#: Factor from a MAD to a normal sigma, as ``median_abs_deviation(scale="normal")``
#: uses it (for running MADs computed with a median filter).
NORMAL_MAD = MAD_TO_SIGMA


def robust_threshold(v: np.ndarray, n_sigma: float, floor: float = -np.inf) -> float:
    """``median + n_sigma`` robust sigmas of ``v`` (at least ``floor``).

    Examples
    --------
    >>> v = np.r_[np.zeros(50), np.ones(50)]
    >>> round(robust_threshold(v, 2.0), 4)        # median 0.5, MAD 0.5
    1.9826
    """
    v = np.asarray(v, dtype=float)
    return max(float(np.median(v) + n_sigma * median_abs_deviation(v, scale="normal")),
               floor)


def detect_steps(d: np.ndarray, t_s: np.ndarray, *, span_s: float = 90.0, gap_s: float = 15.0,
                 n_sigma: float = 4.0, min_significance: float = 4.0,
                 min_nT: float = 0.0) -> np.ndarray:
    """Times of steps (ramps) in a sensor difference.

    The step signal is ``|m(t + h) - m(t - h)|`` with ``m`` the running median over
    ``span_s`` and ``h = gap_s + span_s / 2`` (the Table-2 ramp size at every sample);
    its peaks above ``median + n_sigma`` robust sigmas (and ``min_nT``) whose height is
    at least ``min_significance`` times the robust spread (MAD sigma, norm over
    components) of the samples in the noisier of the two ``span_s`` windows are the steps.
    The second test rejects the peaks that band-limited noise puts in the step signal (on the
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
    dt = sample_period_s(t_s)
    n = max(3, int(round(span_s / dt)) | 1)
    h = int(round(gap_s / dt)) + n // 2
    x = fill_nan(d)
    m = ndimage.median_filter(x, size=(n, 1), mode="nearest")
    s = np.zeros(len(t_s))
    s[h:-h] = np.linalg.norm(m[2 * h:] - m[:-2 * h], axis=1)
    thr = robust_threshold(s[h:-h], n_sigma, min_nT)
    peaks, _ = signal.find_peaks(s, height=thr, distance=h)
    # band-limited noise makes the step signal heavy-tailed: keep a candidate only when
    # the jump is ``min_significance`` times the spread of the samples in its two windows
    half_n = n // 2
    keep = []
    for p in peaks:
        if p - h - half_n < 0 or p + h + half_n >= len(s):
            continue
        # m[c] is the median of the window: its MAD about it, as a normal sigma
        spread = max(float(np.linalg.norm(median_abs_deviation(
            x[c - half_n:c + half_n + 1], axis=0, scale="normal"))) for c in (p - h, p + h))
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
    half height (GK-2A spikes: 6 s), at least ``span_s + gap_s`` from the next one and
    ``exclude_within_s`` from any time in ``exclude_s`` (the steps).

    Examples
    --------
    >>> t = np.arange(1000.0)
    >>> rng = np.random.default_rng(0)
    >>> d = rng.normal(0, 0.1, (1000, 3)); d[400, 0] += 5.0
    >>> detect_spikes(d, t).tolist()
    [400.0]
    """
    t_s = np.asarray(t_s, dtype=float)
    dt = sample_period_s(t_s)
    n = int(round(2 * (span_s + gap_s) / dt)) | 1
    x = fill_nan(d)
    res = x - ndimage.median_filter(x, size=(n, 1), mode="nearest")
    r = np.linalg.norm(res, axis=1)
    # local scale: noise bursts raise the threshold where they are
    local = np.linalg.norm(NORMAL_MAD * ndimage.median_filter(np.abs(res), size=(n, 1),
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
    dt = sample_period_s(t_s)
    block_n = max(3, int(round(block_s / dt)))
    per = max(1, int(round(window_s / block_s)))
    p2p = _block_p2p(fill_nan(d), block_n).sum(axis=1)
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
    >>> steps = out["steps"]
    >>> round(steps["raw"]["mean_abs_nT"][2], 1), round(steps["clean"]["mean_abs_nT"][2], 2)
    (2.0, 0.2)
    >>> spikes = out["spikes"]
    >>> round(spikes["raw"]["mean_abs_nT"][0], 1), round(spikes["clean"]["mean_abs_nT"][0], 1)
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


def step_and_spike_signals(d: np.ndarray, dt: float, span_s: float):
    """(span in samples, step signal, spike signal) of a difference ``d`` (NaN as 0):
    the step signal is ``|mean after - mean before|`` over ``span_s`` (running means),
    the spike signal ``|d - running median over 21 samples|``."""
    n = max(3, int(round(span_s / dt)))
    x = np.where(np.isfinite(d), d, 0.0)
    m = running_mean(x, n)
    s = np.zeros(len(x))
    s[n:-n] = np.linalg.norm(m[2 * n:] - m[:-2 * n], axis=1)
    sp = np.linalg.norm(x - ndimage.median_filter(x, size=(21, 1), mode="nearest"), axis=1)
    return n, s, sp


def largest_steps(s: np.ndarray, half_n: int, size_fraction: float) -> list[int]:
    """Centres (indices) of the peaks of a step signal ``s`` of at least
    ``size_fraction`` of the largest, at least ``2 half_n`` apart."""
    big = []
    work = s.copy()
    top = float(s.max())
    while True:
        p = int(np.argmax(work))
        if work[p] < size_fraction * top:
            break
        # the step signal of a ramp has a flat top: its centre is between the
        # half-height crossings, not at the (noise-placed) maximum
        lo, hi = p, p
        while lo > 0 and s[lo - 1] > 0.5 * s[p]:
            lo -= 1
        while hi < len(s) - 1 and s[hi + 1] > 0.5 * s[p]:
            hi += 1
        big.append((lo + hi) // 2)
        work[max(0, p - 2 * half_n):p + 2 * half_n + 1] = 0.0
    return sorted(big)


def event_intervals(d: np.ndarray, t_s: np.ndarray, *, half_s: float = 120.0,
                    span_s: float = 60.0, size_fraction: float = 0.3,
                    n_sigma: float = 6.0) -> list[tuple[float, float]]:
    """Intervals of ``+-half_s`` around the largest steps of the difference ``d``
    (at least ``size_fraction`` of the largest), dropping those that hold another step
    or spike (any other peak of the step or spike signal above ``n_sigma`` robust
    sigmas).

    Examples
    --------
    >>> t = np.arange(4000.0); rng = np.random.default_rng(1)
    >>> d = rng.normal(0, 0.05, (4000, 3)); d[1000:3000, 2] += 20.0
    >>> d[3060, 0] += 3.0                    # a spike near the second ramp
    >>> [tuple(round(v) for v in iv) for iv in event_intervals(d, t)]
    [(880, 1119)]
    """
    t_s = np.asarray(t_s, float)
    dt = sample_period_s(t_s)
    n, s, sp = step_and_spike_signals(d, dt, span_s)
    if not np.any(s > 0):
        return []
    half_n = int(round(half_s / dt))
    thr_s, thr_sp = robust_threshold(s[n:-n], n_sigma), robust_threshold(sp, n_sigma)
    out = []
    for p in largest_steps(s, half_n, size_fraction):
        lo, hi = max(0, p - half_n), min(len(s), p + half_n)
        # the ramp itself fills the step signal for +-2n samples; a running median
        # follows a ramp, so the spike signal sees it only near its corners
        others_s = np.r_[s[lo:max(lo, p - 2 * n)], s[min(hi, p + 2 * n):hi]]
        others_sp = np.r_[sp[lo:max(lo, p - n)], sp[min(hi, p + n):hi]]
        if np.any(others_s > thr_s) or np.any(others_sp > thr_sp):
            continue
        out.append((float(t_s[lo]), float(t_s[hi - 1])))
    return out


def event_windows(d, t_s, half_s, guard_s, span_s, size_fraction, n_sigma):
    """(centre index, keep mask, other-event mask) per large step of ``d``."""
    t_s = np.asarray(t_s, float)
    dt = sample_period_s(t_s)
    n, s, sp = step_and_spike_signals(d, dt, span_s)
    if not np.any(s > 0):
        return []
    half_n, g = int(round(half_s / dt)), max(1, int(round(guard_s / dt)))
    thr_s, thr_sp = robust_threshold(s[n:-n], n_sigma), robust_threshold(sp, n_sigma)
    bad_s = ndimage.binary_dilation(s > thr_s, np.ones(2 * n + 1, bool))
    lab_s, lab_sp = ndimage.label(bad_s)[0], ndimage.label(sp > thr_sp)[0]
    dil = np.ones(2 * g + 1, bool)
    out = []
    for p in largest_steps(s, half_n, size_fraction):
        # the ramp's own detections are the event, not another one: its step signal
        # (+-2n samples) and the spike signal at its corners (within n/2 of its centre)
        own_s = np.unique(lab_s[p])
        own_sp = np.unique(lab_sp[max(0, p - n // 2):p + n // 2 + 1])
        spikes = (lab_sp > 0) & ~np.isin(lab_sp, own_sp)
        # a spike also lifts the step signal: only step detections without a spike in
        # them are steps (masked over the step detector's span)
        spiky = np.unique(lab_s[spikes])
        other = ((bad_s & ~np.isin(lab_s, own_s) & ~np.isin(lab_s, spiky))
                 | ndimage.binary_dilation(spikes, dil))
        keep = np.zeros(len(s), bool)
        keep[max(0, p - half_n):p + half_n + 1] = True
        out.append((p, keep & ~other, other))
    return out


def event_masks(d: np.ndarray, t_s: np.ndarray, *, half_s: float = 120.0,
                guard_s: float = 15.0, span_s: float = 60.0, size_fraction: float = 0.3,
                n_sigma: float = 6.0) -> list[np.ndarray]:
    """Row masks of ``+-half_s`` around the largest steps of the difference ``d`` (at
    least ``size_fraction`` of the largest) with the samples within ``guard_s`` of any
    other spike (and of any other step, over the step detector's span) taken out,
    instead of dropping the whole interval as :func:`event_intervals` does.

    Examples
    --------
    >>> t = np.arange(4000.0); rng = np.random.default_rng(1)
    >>> d = rng.normal(0, 0.05, (4000, 3)); d[1000:3000, 2] += 20.0
    >>> d[3060, 0] += 3.0                    # a spike near the second ramp
    >>> [(int(m.sum()), bool(m[3060])) for m in event_masks(d, t)]
    [(241, False), (210, False)]
    """
    return [m for _, m, _ in event_windows(d, t_s, half_s, guard_s, span_s,
                                            size_fraction, n_sigma)]


def cleaned_events(dc: np.ndarray, dt_s: float, guard_s: float, n_sigma: float = 6.0):
    """(spike mask with guard, indices of step peaks) of a cleaned difference."""
    x = np.where(np.isfinite(dc), dc, 0.0)
    sp = np.linalg.norm(x - ndimage.median_filter(x, size=(21, 1), mode="nearest"), axis=1)
    g = max(1, int(round(guard_s / dt_s)))
    spikes = ndimage.binary_dilation(sp > robust_threshold(sp, n_sigma),
                                     np.ones(2 * g + 1, bool))
    n = max(2, int(round(10.0 / dt_s)))
    m = running_mean(x, n)
    s = np.zeros(len(x))
    s[n:-n] = np.linalg.norm(m[2 * n:] - m[:-2 * n], axis=1)
    s[spikes] = 0.0
    thr = robust_threshold(s[n:-n], n_sigma)
    # a step makes a peak of the step signal; the slope of a pulse only a plateau
    local = ndimage.median_filter(s, size=12 * n + 1, mode="nearest")
    peaks = np.flatnonzero((s > thr) & (s > 3.0 * local)
                           & (s >= ndimage.maximum_filter1d(s, 4 * n + 1)))
    return spikes, peaks
