"""Timing and spin-phase helpers for ELFIN-like spinning CubeSat data (pure NumPy).

* :func:`split_zones` - science zones as index ranges, cut at long gaps.
* :func:`repair_timestamps` - find and undo paired time-stamp jumps (a block of samples
  stamped a few ms late, as in ELFIN level-1 survey data).
* :func:`unwrap_predictive` - unwrap an angle across data gaps using a known rate.
* :func:`phase_from_counts` - a first spin phase from raw, uncalibrated counts.
* :func:`despun_basis` - a despun frame (rows X, Y, Z) from the spin-axis direction.
* :func:`spline_knots` - cubic-spline knots every so many seconds where there are data.

Times are float seconds from any epoch; angles in radians.
"""

from __future__ import annotations

import numpy as np

from magcal.errors import InputError

TWO_PI = 2.0 * np.pi


def wrap(angle):
    """Wrap angles into [-pi, pi).

    Examples
    --------
    >>> float(wrap(3 * np.pi / 2).round(6))
    -1.570796
    """
    return (np.asarray(angle, dtype=float) + np.pi) % TWO_PI - np.pi


def spline_knots(t_used, knot_s: float, *, origin: float | None = None,
                 trim_end: bool = True, min_samples: int = 20) -> np.ndarray:
    """Full knot vector of a cubic spline over the samples ``t_used`` (increasing).

    Interior knots every ``knot_s`` seconds from the first sample, none that would
    leave fewer than ``min_samples`` samples between it and its neighbours: a stretch
    left out of a fit (a gap, or a disturbance kept out of the fit) is bridged by one
    cubic piece instead of a basis function with no data under it (singular, or pulled
    to zero by a minimum-norm solution). Knots sit at ``origin + n knot_s`` (default:
    the first sample); ``trim_end``: no sliver of an interval (under half a spacing) at
    the end.

    Examples
    --------
    >>> t = np.r_[np.arange(0.0, 100.0, 0.5), np.arange(200.0, 300.0, 0.5)]
    >>> spline_knots(t, 30.0)[4:-4].tolist()          # none inside the gap 100-200 s
    [30.0, 60.0, 90.0, 210.0, 240.0, 270.0]
    """
    t = np.asarray(t_used, dtype=float)
    t0, t1 = t[0], t[-1]
    start = t0 if origin is None else float(origin)
    inner, last = [], t0
    for k in np.arange(start, t1, float(knot_s)):
        if k > t0 and np.count_nonzero((t > last) & (t <= k)) >= min_samples:
            inner.append(k)
            last = k
    while inner and ((trim_end and t1 - inner[-1] < 0.5 * knot_s)
                     or np.count_nonzero(t > inner[-1]) < min_samples):
        inner.pop()
    return np.r_[[t0] * 4, inner, [t1] * 4]


def split_zones(t_s, min_gap_s: float = 60.0) -> list[tuple[int, int]]:
    """Index ranges ``[start, stop)`` of runs separated by gaps longer than ``min_gap_s``.

    Examples
    --------
    >>> split_zones([0.0, 0.1, 0.2, 100.0, 100.1])
    [(0, 3), (3, 5)]
    """
    t = np.asarray(t_s, dtype=float)
    if t.size == 0:
        return []
    cuts = np.flatnonzero(np.diff(t) > min_gap_s) + 1
    edges = np.r_[0, cuts, t.size]
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])]


def repair_timestamps(t_s, *, tol_s: float = 0.002, max_gap_s: float = 1.0,
                      match_s: float = 0.002) -> tuple[np.ndarray, list[dict]]:
    """Undo paired time-stamp jumps in a nominally regular series.

    A step that differs from the median step by more than ``tol_s`` and is followed by
    an opposite step of the same size (within ``match_s``) marks a block of samples
    stamped late (or early) by that amount; those samples are shifted back. Steps
    longer than ``max_gap_s`` are data gaps and are left alone. Unpaired jumps are
    reported but not changed.

    Returns
    -------
    t_fixed : ndarray
    anomalies : list of dict
        ``{"kind": "paired"|"unpaired", "index", "end_index", "jump_s", "n_samples"}``.

    Examples
    --------
    >>> t = np.arange(10) * 0.1
    >>> t[3:6] += 0.009
    >>> fixed, found = repair_timestamps(t)
    >>> bool(np.allclose(fixed, np.arange(10) * 0.1)), found[0]["n_samples"]
    (True, 3)
    """
    t = np.asarray(t_s, dtype=float).copy()
    d = np.diff(t)
    small = d < max_gap_s
    if not np.any(small):
        return t, []
    step = float(np.median(d[small]))
    excess = d - step
    idx = np.flatnonzero(small & (np.abs(excess) > tol_s))
    out: list[dict] = []
    i = 0
    while i < idx.size:
        a = idx[i]
        if (i + 1 < idx.size and np.sign(excess[idx[i + 1]]) != np.sign(excess[a])
                and abs(abs(excess[idx[i + 1]]) - abs(excess[a])) < match_s):
            b = idx[i + 1]
            t[a + 1:b + 1] -= excess[a]
            out.append({"kind": "paired", "index": int(a + 1), "end_index": int(b + 1),
                        "jump_s": float(excess[a]), "n_samples": int(b - a)})
            i += 2
        else:
            out.append({"kind": "unpaired", "index": int(a + 1), "end_index": None,
                        "jump_s": float(excess[a]), "n_samples": 0})
            i += 1
    return t, out


def unwrap_predictive(t_s, angle_rad, rate_rad_s: float | None = None
                      ) -> tuple[np.ndarray, float]:
    """Unwrap an angle that turns at a nearly known rate, also across data gaps.

    Plain :func:`numpy.unwrap` is ambiguous across a gap of about one spin (ELFIN drops
    2.6 s packets at a 2.85 s spin). Here each step is taken as the predicted advance
    ``rate * dt`` plus the wrapped difference from it.

    Parameters
    ----------
    rate_rad_s : float, optional
        Rate; default the median wrapped step rate over steps shorter than 3x the
        median step.

    Returns
    -------
    unwrapped : ndarray
    rate_rad_s : float

    Examples
    --------
    >>> t = np.r_[np.arange(0, 5, 0.1), np.arange(7.6, 10, 0.1)]
    >>> u, w = unwrap_predictive(t, wrap(2.2 * t))
    >>> bool(np.allclose(u, 2.2 * t)), round(w, 6)
    (True, 2.2)
    """
    t = np.asarray(t_s, dtype=float)
    a = np.asarray(angle_rad, dtype=float)
    if t.size < 3:
        raise InputError("need at least 3 samples to unwrap a spin phase")
    dt = np.diff(t)
    d = wrap(np.diff(a))
    if rate_rad_s is None:
        ok = dt < 3 * np.median(dt)
        rate_rad_s = float(np.median(d[ok] / dt[ok]))
    steps = wrap(d - rate_rad_s * dt) + rate_rad_s * dt
    return np.r_[a[0], a[0] + np.cumsum(steps)], float(rate_rad_s)


def phase_from_counts(t_s, counts) -> tuple[np.ndarray, float]:
    """Rough spin phase from raw counts whose sensor axes are not aligned with the spin.

    The spin plane in count space is spanned by the two largest principal directions
    of the sample-to-sample changes (the spin dominates them); the angle of the counts
    in that plane, each axis scaled to unit spread, is unwrapped with
    :func:`unwrap_predictive`. Sense and zero of this phase are arbitrary; the
    calibration fixes both.

    Returns
    -------
    phase : ndarray
    rate_rad_s : float

    Examples
    --------
    >>> t = np.arange(0, 60, 0.1)
    >>> c = np.column_stack([3 * np.cos(2.2 * t), 5 * np.sin(2.2 * t), 0.01 * t])
    >>> p, w = phase_from_counts(t, c @ np.array([[1, .2, 0], [0, 1, .1], [.3, 0, 1]]))
    >>> round(abs(w), 2)
    2.2
    """
    t = np.asarray(t_s, dtype=float)
    c = np.asarray(counts, dtype=float)
    dc = np.diff(c, axis=0)[np.diff(t) < 3 * np.median(np.diff(t))]
    _, vec = np.linalg.eigh(np.cov(dc.T))
    plane = (c - c.mean(axis=0)) @ vec[:, 1:]
    plane /= plane.std(axis=0)
    return unwrap_predictive(t, np.arctan2(plane[:, 1], plane[:, 0]))


def despun_basis(spin_axis) -> np.ndarray:
    """Despun frame from spin-axis unit vectors: rows ``X, Y, Z`` in the input frame.

    ``Z`` is the spin axis, ``X`` the unit vector along ``e_z x Z`` (in the input frame,
    e.g. GEI: ``X`` lies in the equatorial plane), ``Y = Z x X``. The zero of the spin
    phase is therefore arbitrary but fixed in inertial space.

    Examples
    --------
    >>> despun_basis([[0.0, 1.0, 0.0]]).round(12)[0] + 0.0
    array([[-1.,  0.,  0.],
           [ 0.,  0.,  1.],
           [ 0.,  1.,  0.]])
    """
    s = np.atleast_2d(np.asarray(spin_axis, dtype=float))
    z = s / np.linalg.norm(s, axis=1, keepdims=True)
    x = np.cross([0.0, 0.0, 1.0], z)
    norm = np.linalg.norm(x, axis=1, keepdims=True)
    if np.any(norm < 1e-6):
        raise InputError("spin axis along the frame's z axis: despun X is undefined")
    x /= norm
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=1)
