"""Slow sensor offsets kept out of the correction: steps plus a smooth remainder.

The correction ``delta = sum_k M_k B_k + G - B_target`` is a combination of sensor
differences. Besides the disturbers it carries, through the matrices, whatever the
sensors do on their own: a boom sensor's temperature offset (a drift of about a nT
over the hours of the daily boom shadow), the ambient field seen through the sensors'
different misalignments. Those vary smoothly; a spacecraft disturber switched on or
off changes the difference in a ramp of seconds to a minute (the midnight disturbance,
toggling units, a unit's DC level while on), and faster disturbers (spikes, noise)
have no slow part to speak of.

:func:`slow_part` splits the record's slow variation of ``delta`` into steps at the
ramps it finds and a cubic spline with knots every :data:`KNOT_S` (the product averages
the fits with :data:`PRODUCT_KNOTS_S`), fitted together on
block means (spikes masked, the ramps themselves left out of the fit, so their shape
and exact time do not matter); the spline is the slow part that is *not* a step. The
ground product (:func:`magcal.ac.bands.deliver`) removes it from the correction: a
smooth variation of the difference without a ramp is taken for the sensors' own
offsets, not a disturber, and the target keeps its own offsets instead of receiving the
partner's. What the spline cannot follow (the 150-170 s offset oscillations, anything
faster than the knots) stays in the correction.

The fit of the matrices is biased by the same offsets (a target's own drift and
oscillations correlate with the difference that carries them): on records of at least
:data:`MIN_RECORD_S`, ``--auto`` leaves out of the fit the intervals where the smooth
part of the difference with the boom partner changes fast (:func:`offset_intervals`),
bridged by straight lines (:func:`bridge_intervals`).

Steps are found one at a time on the residual of the fit so far (largest first): the
jump between the medians of two windows of :data:`STEP_WINDOW_S` either side of a
:data:`STEP_GAP_S` gap, above a robust threshold over the record and at least
:data:`MIN_SIGNIFICANCE` times the spread inside the two windows. A step that is missed
is partly taken by the spline and so left in the product: the rule is only applied on
records of at least :data:`MIN_RECORD_S`, where the knots are short against the record
and the steps' plateaus long against the windows.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy import ndimage
from scipy.interpolate import BSpline

from magcal.stats import MAD_TO_SIGMA

#: records shorter than this keep the whole correction (a geostationary day's
#: timescales: the knots and step windows need hours of data around them)
MIN_RECORD_S = 21600.0
#: spline knot spacing: a boom sensor's shadow drift (time constants 20-30 min) is
#: followed, a ramp of a minute is not; the product averages the fits with three
#: spacings around it
KNOT_S = 1200.0
PRODUCT_KNOTS_S = (900.0, 1200.0, 1800.0)
#: block length of the means the fit works on, and the ramps left out of the fit
BLOCK_S = 10.0
RAMP_MASK_S = 40.0
#: step statistic: medians of two windows either side of a gap
STEP_WINDOW_S = 120.0
STEP_GAP_S = 20.0
#: step detection thresholds: robust sigmas of the statistic over the record, and the
#: jump against the spread inside its own windows (the offset oscillations and noise
#: bursts inflate that spread; a ramp stands clear of it)
STEP_SIGMA = 8.0
MIN_SIGNIFICANCE = 2.0
MAX_STEPS = 400
#: samples beyond this many robust sigmas of a running median over SPIKE_MEDIAN_S are
#: spikes (left out of the block means)
SPIKE_SIGMA = 6.0
SPIKE_MEDIAN_S = 60.0
#: :func:`offset_intervals`: the smooth part's rate of change flagged above the
#: record's median plus this many robust sigmas, widened by OFFSET_GUARD_S each side;
#: nothing is left out when more than OFFSET_MAX_FRACTION of the record would be
OFFSET_SIGMA = 10.0
#: ... and at least this many times the median rate (the ambient field seen through
#: the sensors' misalignments changes the difference slowly all day; a boom sensor's
#: temperature drift is an order of magnitude faster)
OFFSET_RATE_FACTOR = 20.0
OFFSET_GUARD_S = 900.0
OFFSET_MAX_FRACTION = 0.4


@dataclass(frozen=True)
class SlowPart:
    """Outcome of :func:`slow_part`."""

    smooth: np.ndarray        #: (n, 3) the spline part (mean removed), 0 when not applied
    steps_s: np.ndarray       #: times (s from the first sample) of the steps found
    applied: bool
    reason: str
    knots_s: tuple = ()       #: knot spacings averaged

    def to_dict(self) -> dict:
        rms = np.sqrt(np.mean(self.smooth ** 2, axis=0)) if self.smooth.size else np.zeros(3)
        return {"removed": self.applied, "reason": self.reason,
                "knot_s": KNOT_S, "knots_s": list(self.knots_s),
                "n_steps": int(len(self.steps_s)),
                "removed_rms_nT": [float(v) for v in rms]}


def spline_basis(t_s: np.ndarray, knot_s: float, t0: float, t1: float) -> np.ndarray:
    """Cubic B-spline design matrix on ``[t0, t1]`` with equally spaced knots at most
    ``knot_s`` apart (``(len(t_s), n_knots + 3)``).

    Examples
    --------
    >>> b = spline_basis(np.linspace(0, 100, 11), 50.0, 0.0, 100.0)
    >>> b.shape, bool(np.allclose(b.sum(axis=1), 1.0))
    ((11, 5), True)
    """
    return _sparse_basis(t_s, knot_s, t0, t1).toarray()


def _sparse_basis(t_s: np.ndarray, knot_s: float, t0: float, t1: float):
    """:func:`spline_basis` as a sparse CSR matrix (four non-zeros a row)."""
    n_int = max(1, int(np.ceil((t1 - t0) / knot_s)))
    knots = np.r_[[t0] * 3, np.linspace(t0, t1, n_int + 1), [t1] * 3]
    return BSpline.design_matrix(np.clip(t_s, t0, t1), knots, 3).tocsr()


def _block_means(x: np.ndarray, dt_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Spike-masked block means of ``x``: (means, block centre times, usable, block
    length in samples of ``x``). Faster than 1 s, samples are first averaged to about
    1 s (the running median would otherwise dominate a 10 Hz day)."""
    pre = max(1, int(1.0 / dt_s)) if dt_s < 1.0 else 1
    if pre > 1:
        m = x.shape[0] // pre
        with np.errstate(invalid="ignore"):
            x = np.nanmean(x[:m * pre].reshape(m, pre, 3), axis=1)
        means, t_b, good, b = _block_means(x, dt_s * pre)
        return means, t_b, good, b * pre
    ok = np.all(np.isfinite(x), axis=1)
    xf = np.where(ok[:, None], x, np.nanmedian(x[ok], axis=0) if ok.any() else 0.0)
    k = max(3, int(round(SPIKE_MEDIAN_S / dt_s)) | 1)
    res = xf - ndimage.median_filter(xf, size=(k, 1), mode="nearest")
    sig = MAD_TO_SIGMA * np.median(np.abs(res[ok]), axis=0) if ok.any() else np.ones(3)
    spike = np.any(np.abs(res) > SPIKE_SIGMA * np.maximum(sig, 1e-12), axis=1)
    spike = ndimage.binary_dilation(spike, iterations=max(1, int(round(5.0 / dt_s))))
    use = ok & ~spike
    b = max(1, int(round(BLOCK_S / dt_s)))
    nb = x.shape[0] // b
    u = use[:nb * b].reshape(nb, b)
    xs = np.where(u[..., None], xf[:nb * b].reshape(nb, b, 3), 0.0)
    cnt = u.sum(axis=1)
    means = xs.sum(axis=1) / np.maximum(cnt, 1)[:, None]
    t_b = (np.arange(nb) + 0.5) * b * dt_s
    return means, t_b, cnt >= max(1, b // 3), b


def running_nanmedian(r: np.ndarray, w: int) -> np.ndarray:
    """Median of the finite values of every ``w`` consecutive rows of ``r`` (n, m):
    row ``i`` of the result covers rows ``i .. i + w - 1`` (NaN where all are NaN).

    pandas' rolling median (a skip list, O(n log w)) gives the same numbers as
    ``numpy.nanmedian`` over every window, 15x faster on a day of 10 s blocks; an
    infinite value would spoil its running state, so such input takes numpy's way.

    Examples
    --------
    >>> r = np.array([[1.0], [np.nan], [3.0], [2.0], [np.nan], [np.nan]])
    >>> running_nanmedian(r, 2).ravel()
    array([1. , 3. , 2.5, 2. , nan])
    """
    if w > r.shape[0]:
        return np.empty((0, r.shape[1]))
    if np.isinf(r).any():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)   # all-NaN windows
            return np.nanmedian(np.lib.stride_tricks.sliding_window_view(r, w, axis=0),
                                axis=2)
    return pd.DataFrame(r).rolling(w, min_periods=1).median().to_numpy()[w - 1:]


def _step_statistic(r: np.ndarray, w: int, g: int) -> tuple[np.ndarray, np.ndarray]:
    """(block indices, |median after - median before|) of block residuals ``r``."""
    nb = r.shape[0]
    idx = np.arange(g + w, nb - g - w)
    med = running_nanmedian(r, w)
    stat = np.linalg.norm(med[idx + g + 1] - med[idx - g - w], axis=1)
    return idx, np.where(np.isfinite(stat), stat, 0.0)


def _lstsq(S, T: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Least squares of ``y`` on the columns ``[S, T]`` (``S`` a sparse spline basis,
    ``T`` a few dense step columns) through the normal equations, with a tiny ridge
    for columns the rows do not constrain (a step between masked ramps).

    The spline block of the normal matrix is formed sparse (four non-zeros a row): the
    dense product of a day of 10 s blocks against ~300 columns cost 30 ms a call, and a
    day with many steps makes hundreds of calls.
    """
    ss = (S.T @ S).toarray()
    st = np.asarray(S.T @ T)
    A = np.block([[ss, st], [st.T, T.T @ T]])
    A[np.diag_indices_from(A)] += 1e-9 * max(float(np.trace(A)) / A.shape[0], 1e-300)
    return np.linalg.solve(A, np.vstack([np.asarray(S.T @ y), T.T @ y]))


def _spread(r: np.ndarray) -> float:
    return float(np.linalg.norm(MAD_TO_SIGMA * np.nanmedian(
        np.abs(r - np.nanmedian(r, axis=0)), axis=0)))


def slow_part(delta: np.ndarray, dt_s: float, *, force: bool = False,
              knots_s=PRODUCT_KNOTS_S) -> SlowPart:
    """The smooth (non-step) slow part of a correction ``delta`` (module docstring).

    Parameters
    ----------
    delta : ndarray (n, 3)
        Correction on a uniform grid, NaN for missing samples.
    dt_s : float
        Sample period.
    force : bool
        Fit even on records shorter than :data:`MIN_RECORD_S`.
    knots_s : sequence of float
        Knot spacings; the smooth part is the mean of the fits with each (where the
        knots fall against a drift's corner moves a single fit; the product averages
        :data:`PRODUCT_KNOTS_S`, :func:`offset_intervals` uses :data:`KNOT_S`).

    Examples
    --------
    Two steps and a smooth bump of 1 nT: the bump is the slow part, the steps are not.

    >>> t = np.arange(0.0, 43200.0, 2.0)
    >>> rng = np.random.default_rng(3)
    >>> bump = np.exp(-0.5 * ((t - 20000.0) / 1500.0) ** 2)[:, None] * [1.0, -0.5, 0.2]
    >>> steps = ((t > 9000) & (t < 30000))[:, None] * [2.5, 1.0, -1.5]
    >>> out = slow_part(bump + steps + rng.normal(0, 0.05, (t.size, 3)), 2.0)
    >>> out.applied, np.round(out.steps_s, -2)   # block centres, 20 s from the ramps
    (True, array([ 9000., 30000.]))
    >>> bool(np.abs(out.smooth - (bump - bump.mean(axis=0))).max() < 0.1)
    True
    """
    x = np.asarray(delta, dtype=float)
    n = x.shape[0]
    record_s = n * dt_s
    none = np.zeros_like(x)
    if not force and record_s < MIN_RECORD_S:
        return SlowPart(none, np.zeros(0), False, f"record of {record_s:.4g} s, under "
                        f"{MIN_RECORD_S:.4g} s: the whole correction is kept")
    means, t_b, good, b = _block_means(x, dt_s)
    block_s = b * dt_s
    w = max(2, int(round(STEP_WINDOW_S / block_s)))
    g = int(round(STEP_GAP_S / block_s))
    knots_s = tuple(float(k) for k in knots_s)
    if good.sum() < 4 * (w + g) or record_s < 4 * max(knots_s):
        return SlowPart(none, np.zeros(0), False, "too few samples to separate steps "
                        "from a smooth part: the whole correction is kept")
    # the spline between block centres is a straight line to well under a pT (knots
    # every 900 s or more, blocks of 10 s): interpolated to the samples
    t_full = np.arange(n) * dt_s
    t_knots = np.r_[0.0, t_b, record_s]
    smooth = np.zeros_like(x)
    found = []
    for knot_s in knots_s:
        coef, steps = _spline_and_steps(means, t_b, good, w, g, knot_s, record_s)
        on_blocks = spline_basis(t_knots, knot_s, 0.0, record_s) @ coef
        smooth += np.column_stack([np.interp(t_full, t_knots, on_blocks[:, c])
                                   for c in range(3)])
        found.append(steps)
    smooth /= len(knots_s)
    smooth -= smooth.mean(axis=0)
    steps = found[len(found) // 2]
    spacing = "/".join(f"{k:g}" for k in knots_s)
    return SlowPart(smooth, np.array(sorted(steps)), True,
                    f"smooth part (knots every {spacing} s, averaged; {len(steps)} step(s) "
                    "found) taken for the sensors' own slow offsets and kept out of the "
                    "correction", knots_s)


def _spline_and_steps(means, t_b, good, w, g, knot_s, record_s):
    """Spline coefficients (knots every ``knot_s``) and the step times found with them
    on the block means (module docstring)."""
    S = _sparse_basis(t_b, knot_s, 0.0, record_s)
    steps: list[float] = []
    blocked = np.zeros(means.shape[0], dtype=bool)
    thr = None
    coef = None
    for it in range(MAX_STEPS + 1):
        T = np.column_stack([t_b > ts for ts in steps]).astype(float) if steps \
            else np.empty((t_b.size, 0))
        rows = good.copy()
        for ts in steps:
            rows &= np.abs(t_b - ts) > RAMP_MASK_S
        coef = _lstsq(S[rows], T[rows], means[rows])
        r = np.where(good[:, None], means - (S @ coef[:S.shape[1]] + T @ coef[S.shape[1]:]),
                     np.nan)
        idx, stat = _step_statistic(r, w, g)
        if thr is None:
            med = float(np.median(stat))
            thr = med + STEP_SIGMA * MAD_TO_SIGMA * float(np.median(np.abs(stat - med)))
        stat[blocked[idx]] = 0.0
        added = False
        if it < MAX_STEPS:
            for o in np.argsort(stat)[::-1][:50]:
                if stat[o] < thr:
                    break
                j = int(idx[o])
                spread = max(_spread(r[j - g - w:j - g]), _spread(r[j + g + 1:j + g + 1 + w]))
                if stat[o] >= MIN_SIGNIFICANCE * spread:
                    steps.append(float(t_b[j]))
                    blocked[max(0, j - w):j + w + 1] = True
                    added = True
                    break
                blocked[j] = True
        if not added:
            break
    return coef[:S.shape[1]], steps


def offset_intervals(data: dict, target: str, dt_s: float) -> tuple[np.ndarray, dict]:
    """Samples where a sensor's own slow offset changes fast: left out of the fit.

    The smooth part of ``target - partner`` (:func:`slow_part`; the partner is the
    quietest other sensor, as ``--auto`` pairs it) is differentiated; samples where the
    rate (norm over components) exceeds the record's median by :data:`OFFSET_SIGMA`
    robust sigmas and :data:`OFFSET_RATE_FACTOR` times the median, widened by
    :data:`OFFSET_GUARD_S`, are flagged (a boom sensor cooling into the shadow and
    warming out of it, with the offset oscillations that come with the temperature
    change). Returns ``(mask (n,), report)``; the mask is all False on
    records shorter than :data:`MIN_RECORD_S` or when more than
    :data:`OFFSET_MAX_FRACTION` of the record would be flagged.

    Examples
    --------
    >>> t = np.arange(0.0, 43200.0, 2.0)
    >>> rng = np.random.default_rng(4)
    >>> amb = rng.normal(0, 0.05, (t.size, 3)).cumsum(axis=0)      # common to both
    >>> drift = (1 - np.exp(-np.clip(t - 25000.0, 0, None) / 1800.0))[:, None] * [1, -1, 0.5]
    >>> data = {"o": amb + rng.normal(0, 0.03, (t.size, 3)),
    ...         "i": amb + drift + rng.normal(0, 0.03, (t.size, 3))}
    >>> mask, rep = offset_intervals(data, "o", 2.0)
    >>> bool(mask[t == 26000.0][0]), bool(mask[t == 10000.0][0])
    (True, False)
    """
    x0 = np.asarray(data[target], dtype=float)
    n = x0.shape[0]
    mask = np.zeros(n, dtype=bool)
    report = {"left_out_rows": 0, "sensors": [], "intervals_s": []}
    # the record is the samples the target has, not the span: a gap of a week on the
    # grid would otherwise make a record of two hours long enough, and the fraction
    # flagged small enough, to leave every sample out
    held = np.all(np.isfinite(x0), axis=1)
    if held.sum() * dt_s < MIN_RECORD_S:
        report["reason"] = f"record under {MIN_RECORD_S:.4g} s of data: nothing left out"
        return mask, report
    from magcal.ac.auto import noise_sigma

    others = [s for s in data if s != target]
    sigma = {s: noise_sigma(data[s]) for s in others}
    # the boom partner (the quietest other sensor, as --auto pairs it): a noisier
    # reference hides small steps, which its spline then takes for fast changes
    for s in sorted(others, key=lambda s: (not np.isfinite(sigma[s]), sigma[s]))[:1]:
        diff = x0 - np.asarray(data[s], dtype=float)
        sp = slow_part(diff, dt_s, knots_s=(KNOT_S,))
        if not sp.applied:
            continue
        # the rate where both sensors have data (the spline is unconstrained in a gap)
        valid = np.all(np.isfinite(diff), axis=1)
        rate = np.linalg.norm(np.gradient(sp.smooth, axis=0), axis=1)[valid]
        med = float(np.median(rate))
        thr = max(med + OFFSET_SIGMA * MAD_TO_SIGMA * float(np.median(np.abs(rate - med))),
                  OFFSET_RATE_FACTOR * med)
        hi = np.zeros(n, dtype=bool)
        hi[valid] = rate > thr
        if hi.any():
            hi = ndimage.binary_dilation(hi, iterations=max(1, int(round(OFFSET_GUARD_S / dt_s))))
            report["sensors"].append(s)
            mask |= hi
    flagged = float(mask[held].mean())
    if flagged > OFFSET_MAX_FRACTION:
        report["reason"] = (f"{flagged:.0%} of the record flagged, over "
                            f"{OFFSET_MAX_FRACTION:.0%}: nothing left out")
        return np.zeros(n, dtype=bool), report
    edges = np.flatnonzero(np.diff(np.r_[0, mask.astype(np.int8), 0]))
    report["intervals_s"] = [[float(a * dt_s), float(b * dt_s)]
                             for a, b in zip(edges[::2], edges[1::2])]
    report["left_out_rows"] = int((mask & held).sum())
    report["reason"] = ("intervals where the smooth part of a difference with the target "
                        "changes fast (a sensor's own offset drifting) left out of the fit")
    return mask, report


def bridge_intervals(x: np.ndarray, mask: np.ndarray, dt_s: float,
                     edge_s: float = 60.0) -> np.ndarray:
    """``x`` with every run of ``mask`` replaced by a straight line between the medians
    of ``edge_s`` on either side: the run's content leaves the fit while the record
    stays continuous (dropping the rows would join levels that differ by the run's
    steps and drift, a jump every running-mean filter then sees).

    Examples
    --------
    >>> x = np.r_[np.zeros(10), np.full(5, 9.0), np.ones(10)][:, None] * [1.0, 2.0, 3.0]
    >>> m = np.zeros(25, dtype=bool); m[10:15] = True
    >>> bridge_intervals(x, m, 1.0, edge_s=3.0)[9:16, 0].round(3).tolist()
    [0.0, 0.167, 0.333, 0.5, 0.667, 0.833, 1.0]
    """
    x = np.asarray(x, dtype=float)
    out = x.copy()
    edges = np.flatnonzero(np.diff(np.r_[0, np.asarray(mask, dtype=np.int8), 0]))
    k = max(1, int(round(edge_s / dt_s)))
    n = x.shape[0]
    for a, b in zip(edges[::2], edges[1::2]):
        before = x[max(0, a - k):a]
        after = x[b:min(n, b + k)]
        lo = np.nanmedian(before, axis=0) if before.size else None
        hi = np.nanmedian(after, axis=0) if after.size else None
        lo = hi if lo is None or not np.all(np.isfinite(lo)) else lo
        hi = lo if hi is None or not np.all(np.isfinite(hi)) else hi
        if lo is None or not np.all(np.isfinite(lo)):
            out[a:b] = np.nan
            continue
        frac = (np.arange(a, b) - a + 1.0) / (b - a + 1.0)
        out[a:b] = lo + frac[:, None] * (hi - lo)
    return out
