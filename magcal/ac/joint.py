"""Joint pair fit: one constant 3x3 correction per sensor from several selections.

A PiCoG pair stage fits one rank-one order per selection (window scan, band, interval)
and chains them; each order undoes part of the previous ones. The joint fit instead
collects, for every selection ``s`` of the same pair, the cross-covariance of the
cleaned sensor with the difference ``C_id,s`` and the difference covariance
``C_dd,s``, and solves for one full matrix

    ``K = -(sum_s w_s C_id,s) (sum_s w_s C_dd,s)^-1``

so that ``B_i + K (B_i - B_j)`` is decorrelated from the difference in the weighted
sum of the selections. The weights are reweighted minimax-style towards the selection
whose coherent power (the part of ``B_i`` explained by the difference,
``tr(r C_dd^+ r^T)`` with ``r = C_id + K C_dd``) is reduced least. A selection whose
cross-covariance is not above its own chance level (estimated from the data by lagging
the difference) cannot be cleaned to the target and would make the reweighting chase
it: it is dropped (``min_snr``).

Selections (from the stage's orders, see :func:`selections`): the windows a
``window_s`` scan selects, a ``band_hz`` band-pass over the whole record, an
``interval``; and intervals of ``event_half_s`` around the largest steps of the
difference (the midnight ramps with their edge pulses) that hold no other detected
step or spike.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from magcal.ac.core import pair_moments
from magcal.ac.filters import bandpass, highpass, highpass_samples, running_mean
from magcal.ac.scan import scan_first_order, summarize_scan
from magcal.errors import InputError

#: lags (s) of the difference used for the chance level of a cross-covariance
NULL_LAGS_S = (-1500.0, -1100.0, -700.0, -400.0, 400.0, 700.0, 1100.0, 1500.0)


@dataclass(frozen=True)
class Selection:
    """One selection of the pair: filtered series and the rows used."""

    name: str
    b_i: np.ndarray
    b_j: np.ndarray
    mask: np.ndarray
    lag_null: bool = True   #: chance level by lagging (not for a spectral line)


@dataclass(frozen=True)
class JointFit:
    """Outcome of :func:`fit_joint`."""

    K: np.ndarray               #: (3, 3): ``B_i + K (B_i - B_j)``
    names: tuple
    reduction: dict             #: selection -> estimated coherent-power reduction
    snr: dict                   #: selection -> coherent power / chance level
    weight: dict                #: selection -> final weight (0: dropped)

    def to_dict(self) -> dict:
        return {"names": [str(n) for n in self.names],
                "reduction": {str(k): float(v) for k, v in self.reduction.items()},
                "snr": {str(k): float(v) for k, v in self.snr.items()},
                "weight": {str(k): float(v) for k, v in self.weight.items()}}


def coherent_power(c_id: np.ndarray, c_dd: np.ndarray, K: np.ndarray | None = None) -> float:
    """Power of ``B_i + K d`` explained by the difference: ``tr(r C_dd^+ r^T)``.

    Examples
    --------
    >>> c_dd = np.eye(3); c_id = np.diag([2.0, 0.0, 0.0])
    >>> coherent_power(c_id, c_dd), coherent_power(c_id, c_dd, -c_id)
    (4.0, 0.0)
    """
    r = np.asarray(c_id, float) + (0.0 if K is None else np.asarray(K, float) @ c_dd)
    return float(np.trace(r @ np.linalg.pinv(c_dd) @ r.T))


def _moments(x: np.ndarray, d: np.ndarray, mask: np.ndarray):
    ok = mask & np.all(np.isfinite(x), axis=1) & np.all(np.isfinite(d), axis=1)
    n = int(ok.sum())
    if n < 3:
        return None
    xs = x[ok] - x[ok].mean(axis=0)
    ds = d[ok] - d[ok].mean(axis=0)
    return xs.T @ ds / n, ds.T @ ds / n


def chance_level(b_i: np.ndarray, b_j: np.ndarray, mask: np.ndarray, dt_s: float,
                 lags_s=NULL_LAGS_S) -> float:
    """Mean coherent power of ``b_i`` with the difference lagged by ``lags_s``: what a
    cross-covariance of that many samples shows by chance."""
    d = b_i - b_j
    vals = []
    for lag in lags_s:
        m = _moments(b_i, np.roll(d, int(round(lag / dt_s)), axis=0), mask)
        if m is not None:
            vals.append(coherent_power(*m))
    return float(np.mean(vals)) if vals else float("nan")


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
    dt = float(np.median(np.diff(t_s)))
    n = max(3, int(round(span_s / dt)))
    x = np.where(np.isfinite(d), d, 0.0)
    m = running_mean(x, n)
    s = np.zeros(len(t_s))
    s[n:-n] = np.linalg.norm(m[2 * n:] - m[:-2 * n], axis=1)
    sp = np.linalg.norm(x - ndimage.median_filter(x, size=(21, 1), mode="nearest"), axis=1)
    if not np.any(s > 0):
        return []
    half_n = int(round(half_s / dt))
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

    def robust(v):
        med = np.median(v)
        return med + n_sigma * 1.4826 * np.median(np.abs(v - med))

    thr_s, thr_sp = robust(s[n:-n]), robust(sp)
    out = []
    for p in sorted(big):
        lo, hi = max(0, p - half_n), min(len(s), p + half_n)
        # the ramp itself fills the step signal for +-2n samples; a running median
        # follows a ramp, so the spike signal sees it only near its corners
        others_s = np.r_[s[lo:max(lo, p - 2 * n)], s[min(hi, p + 2 * n):hi]]
        others_sp = np.r_[sp[lo:max(lo, p - n)], sp[min(hi, p + n):hi]]
        if np.any(others_s > thr_s) or np.any(others_sp > thr_sp):
            continue
        out.append((float(t_s[lo]), float(t_s[hi - 1])))
    return out


def selections(b_i: np.ndarray, b_j: np.ndarray, t_s: np.ndarray, orders, dt_s: float, *,
               event_half_s: float | None = 120.0,
               event_difference: np.ndarray | None = None) -> list[Selection]:
    """Selections of the pair from the stage's orders (see the module docstring).

    Every order's ``highpass_s`` is applied before its selection; event intervals use
    the first order's. Events are detected in ``event_difference`` (default
    ``b_i - b_j``; the chain passes the raw difference of the pair, where the
    midnight ramps stand out before earlier stages have removed most of them).
    """
    t_s = np.asarray(t_s, float)
    out = []
    for k, o in enumerate(orders, start=1):
        hp = highpass_samples(o.highpass_s, dt_s)
        x, y = (highpass(b_i, hp), highpass(b_j, hp)) if hp else (b_i, b_j)
        mask = np.ones(len(t_s), bool)
        if o.interval is not None:
            mask = (t_s >= o.interval[0]) & (t_s < o.interval[1])
        if o.band_hz is not None:
            out.append(Selection(f"band {o.band_hz[0]:g}-{o.band_hz[1]:g} Hz",
                                 bandpass(x, o.band_hz, dt_s), bandpass(y, o.band_hz, dt_s),
                                 mask, lag_null=False))
        elif o.window_s is not None:
            wn = int(round(o.window_s / dt_s))
            scan = scan_first_order(x, y, wn, direction=o.direction)
            summ = summarize_scan(scan, cone_deg=o.cone_deg)
            m = np.zeros(len(t_s), bool)
            for s0 in np.asarray(scan.start)[summ.selected]:
                m[s0:s0 + wn] = True
            out.append(Selection(f"window {o.window_s:g} s", x, y, m & mask))
        else:
            out.append(Selection(f"order {k}", x, y, mask))
    if event_half_s:
        hp = highpass_samples(orders[0].highpass_s, dt_s)
        x, y = (highpass(b_i, hp), highpass(b_j, hp)) if hp else (b_i, b_j)
        ev = (b_i - b_j) if event_difference is None else event_difference
        for lo, hi in event_intervals(ev, t_s, half_s=event_half_s):
            out.append(Selection(f"event {lo:.0f}-{hi:.0f} s", x, y,
                                 (t_s >= lo) & (t_s <= hi)))
    return out


def fit_joint(sels: list[Selection], dt_s: float, *, min_snr: float = 5.0,
              n_iter: int = 30, power: float = 0.5) -> JointFit:
    """Joint minimax fit of ``K`` over the selections (module docstring).

    Examples
    --------
    >>> rng = np.random.default_rng(0); t = np.arange(20000.0)
    >>> s = rng.normal(size=(20000, 2)); amb = rng.normal(size=(20000, 3))
    >>> u, v = np.array([0.0, 0.6, 0.8]), np.array([1.0, 0.0, 0.0])
    >>> bi = amb + 2 * s[:, :1] * u + s[:, 1:] * v
    >>> bj = amb + 0.5 * s[:, :1] * u + 0.25 * s[:, 1:] * v
    >>> m = np.ones(20000, bool)
    >>> fit = fit_joint([Selection("all", bi, bj, m)], 1.0)
    >>> r = bi + (bi - bj) @ fit.K.T - amb     # remnant: chance correlation with amb only
    >>> bool(np.max(np.abs(r)) < 0.1), bool(np.std(bi - amb) / np.std(r) > 50)
    (True, True)
    """
    mom, snr = {}, {}
    for s in sels:
        c = _moments(s.b_i, s.b_i - s.b_j, s.mask)
        if c is None:
            continue
        p0 = coherent_power(*c)
        mom[s.name] = c
        snr[s.name] = (p0 / chance_level(s.b_i, s.b_j, s.mask, dt_s) if s.lag_null
                       else float("inf"))
    keys = [k for k in mom if snr[k] >= min_snr]
    if not keys:
        raise InputError(f"no selection of the pair has a cross-covariance {min_snr:g} "
                         "times above its chance level")
    p0 = {k: coherent_power(*mom[k]) for k in keys}
    w = {k: 1.0 / p0[k] for k in keys}
    K = np.zeros((3, 3))
    red = {}
    for _ in range(n_iter):
        K = -(sum(w[k] * mom[k][0] for k in keys)
              @ np.linalg.pinv(sum(w[k] * mom[k][1] for k in keys)))
        red = {k: p0[k] / max(coherent_power(*mom[k], K), 1e-300) for k in keys}
        for k in keys:
            w[k] *= red[k] ** -power
        tot = sum(w.values())
        w = {k: v / tot for k, v in w.items()}
    return JointFit(K=K, names=tuple(mom), reduction=red, snr=snr,
                    weight={k: w.get(k, 0.0) for k in mom})


def swap(sels: list[Selection]) -> list[Selection]:
    """The same selections with the roles of the two sensors exchanged."""
    return [Selection(s.name, s.b_j, s.b_i, s.mask, s.lag_null) for s in sels]
