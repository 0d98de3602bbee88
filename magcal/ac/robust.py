"""Outliers that pass quality control, left out of the PiCoG fit.

The variance analysis works on second moments, so a few samples far from the rest (a
spike of one sensor, a run where one sensor is stuck) can turn the maximum-variance
direction and ``alpha`` towards themselves. What tells such a sample from a
disturbance is the other sensor: a spacecraft disturber is seen by both sensors at the
same time (in a fixed ratio, which is what PiCoG fits), a glitch by one only.

:func:`sensor_outliers` flags, per sensor,

- **spikes**: samples whose residual to a running median (``median_n`` samples) is
  above ``threshold`` robust standard deviations (1.4826 MAD of that residual over the
  record) and above ``AC_FACTOR`` standard deviations of the sensor's AC variation in
  some component, while no other sensor is more than ``SEEN_THRESHOLD`` robust std
  off its running median at that sample or next to it (a disturber attenuated at the
  other sensor still shows there);
- **stuck runs**: ``stuck_n`` or more consecutive samples with all three components
  exactly repeated, while some other sensor varies; skipped for a sensor whose values
  repeat in more than ``max_stuck_fraction`` of its steps (coarse quantisation).

Flagged samples become NaN for the fit (:func:`screen`, in :class:`magcal.ac.PiCoG`);
the correction is still applied to every sample.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import median_filter

from magcal.ac.filters import running_mean
from magcal.ac.metrics import fill_nan
from magcal.stats import MAD_TO_SIGMA

#: robust standard deviations above which a sample is a spike candidate
THRESHOLD = 8.0
#: ... and this many standard deviations of the sensor's AC variation (running mean over
#: a 48th of the record removed): small glitches cannot turn the fit
AC_FACTOR = 0.0
#: another sensor "sees" a spike when it is this many robust std off its running median
SEEN_THRESHOLD = 5.5
#: running-median length (samples)
MEDIAN_N = 7
#: consecutive repeated samples that make a stuck run
STUCK_N = 4
#: a sensor repeating values this often is quantised, not stuck
MAX_STUCK_FRACTION = 0.01


def spike_candidates(b: np.ndarray, *, threshold: float = THRESHOLD,
                     median_n: int = MEDIAN_N, ac_factor: float = AC_FACTOR) -> np.ndarray:
    """Samples more than ``threshold`` robust std from the running median (any component).

    Examples
    --------
    >>> x = np.random.default_rng(0).normal(0, 0.1, (200, 3))
    >>> x[50, 1] += 5.0
    >>> np.flatnonzero(spike_candidates(x)).tolist()
    [50]
    """
    b = np.asarray(b, dtype=float)
    ok = np.all(np.isfinite(b), axis=1)
    if ok.sum() < 3 * median_n:
        return np.zeros(b.shape[0], dtype=bool)
    filled = fill_nan(b)
    resid = filled - median_filter(filled, size=(median_n, 1), mode="nearest")
    mad = np.median(np.abs(resid[ok]), axis=0) * MAD_TO_SIGMA
    # a noiseless component (mad 0) cannot say what is outlying in it
    scale = np.where(mad > 0, mad, np.inf)
    cand = ok & np.any(np.abs(resid) > threshold * scale, axis=1)
    if not cand.any() or ac_factor <= 0:
        return cand
    # only what stands out of the sensor's own variation (disturbers included) can turn
    # the variance analysis: the rest of the heavy tail stays in
    ac = filled - running_mean(filled, max(10 * median_n, b.shape[0] // 48))
    spread = np.std(ac[ok & ~cand], axis=0)
    return cand & np.any(np.abs(resid) > ac_factor * spread, axis=1)


def stuck_runs(b: np.ndarray, *, stuck_n: int = STUCK_N,
               max_fraction: float = MAX_STUCK_FRACTION) -> np.ndarray:
    """Samples in runs of ``stuck_n`` or more identical consecutive vectors.

    Examples
    --------
    >>> x = np.random.default_rng(0).normal(0, 0.1, (1000, 3))
    >>> x[10:16] = x[10]
    >>> np.flatnonzero(stuck_runs(x)).tolist()
    [10, 11, 12, 13, 14, 15]
    """
    b = np.asarray(b, dtype=float)
    n = b.shape[0]
    same = np.all(np.diff(b, axis=0) == 0, axis=1)
    out = np.zeros(n, dtype=bool)
    if n < 2 or same.mean() > max_fraction or not same.any():
        return out
    # runs of True in `same` of length >= stuck_n - 1 (stuck_n equal samples)
    padded = np.concatenate([[False], same, [False]])
    edges = np.flatnonzero(np.diff(padded.astype(np.int8)))
    for start, stop in zip(edges[::2], edges[1::2]):
        if stop - start >= stuck_n - 1:
            out[start:stop + 1] = True
    return out


def _grow(mask: np.ndarray, k: int = 1) -> np.ndarray:
    out = mask.copy()
    for s in range(1, k + 1):
        out[s:] |= mask[:-s]
        out[:-s] |= mask[s:]
    return out


def sensor_outliers(data: dict) -> dict:
    """Per sensor, the samples that are glitches of that sensor alone (module docstring):
    a spike candidate while no other sensor is outlying at or next to it, or a stuck run
    while some other sensor varies.

    Examples
    --------
    A disturbance spike seen by both sensors is kept; a glitch of one sensor is not:

    >>> rng = np.random.default_rng(0)
    >>> a = rng.normal(0, 0.1, (500, 3)); b = rng.normal(0, 0.1, (500, 3))
    >>> a[100] += 5.0; b[100] += 2.0          # a disturber, in both
    >>> a[300, 0] += 50.0                      # a glitch of a
    >>> bad = sensor_outliers({"a": a, "b": b})
    >>> np.flatnonzero(bad["a"]).tolist(), int(bad["b"].sum())
    ([300], 0)
    """
    spikes = {s: spike_candidates(b) for s, b in data.items()}
    stuck = {s: stuck_runs(b) for s, b in data.items()}
    near = {s: _grow(spike_candidates(b, threshold=SEEN_THRESHOLD, ac_factor=0.0))
            for s, b in data.items()}
    out = {}
    for s in data:
        others = [o for o in data if o != s]
        if not others:
            out[s] = np.zeros_like(spikes[s])
            continue
        near_other = np.logical_or.reduce([near[o] for o in others])
        all_stuck = np.logical_and.reduce([stuck[o] for o in others])
        out[s] = (spikes[s] & ~near_other) | (stuck[s] & ~all_stuck)
    return out


def glitch_rows(data: dict) -> np.ndarray:
    """Rows where some sensor has a glitch of its own (:func:`sensor_outliers`): left
    out of the fit, and of the delivered product's band filter and check, where one
    glitch would otherwise be spread over the record (:func:`magcal.ac.bands.deliver`)."""
    return _any_sensor(sensor_outliers(data), len(next(iter(data.values()), ())))


def _any_sensor(bad: dict, n: int) -> np.ndarray:
    """Rows flagged in any sensor's mask of ``bad`` (none when it is empty)."""
    return np.logical_or.reduce(list(bad.values())) if bad else np.zeros(n, dtype=bool)


def target_suspect(b: np.ndarray) -> np.ndarray:
    """Rows where the target itself reads a spike, a saturated component or a stuck
    value by the quality-control tests (:mod:`magcal.qc.checks`): a raw target with
    them is no yardstick for the never-worse-than-raw check (a 10-minute saturated
    component hid a product 2.5x worse than raw on every other row)."""
    from magcal.qc.checks import saturation_mask, spike_mask, stuck_mask

    b = np.asarray(b, dtype=float)
    return spike_mask(b) | saturation_mask(b, min_run=STUCK_N) | stuck_mask(b)


def screen(data: dict) -> tuple[dict, dict]:
    """The sensors with every flagged row (:func:`sensor_outliers`) set to NaN in all of
    them, and a JSON-ready report (samples flagged per sensor, rows left out)."""
    bad = sensor_outliers(data)
    rows = _any_sensor(bad, len(next(iter(data.values()), ())))
    report = {"flagged": {s: int(m.sum()) for s, m in bad.items()},
              "rows_left_out": int(rows.sum()),
              "rule": f"spike: > {THRESHOLD:g} robust std from a {MEDIAN_N}-sample running "
                      f"median in one sensor only; stuck: >= {STUCK_N} identical samples "
                      "in one sensor only"}
    if not rows.any():
        return data, report
    out = {}
    for s, b in data.items():
        b = np.array(b, dtype=float, copy=True)
        b[rows] = np.nan
        out[s] = b
    return out, report
