"""Time-stamp irregularities that the paired repair leaves: find them in the counts.

:func:`~magcal.missions.elfin.phase.repair_timestamps` undoes *paired* jumps (a block
stamped late, with a jump out and one back). ELFIN-A also has an *unpaired* jump
(2022-01-12, zone 4, 14:16:50.85: +12.5 ms) whose block has no visible start: the seven
samples before it are stamped 12.5 ms early, which rotates them by 1.6 deg of spin, a
1240 nT vector error. Such a block cannot be found in the time stamps; it is seen in the
counts, which a spinning sensor makes nearly sinusoidal:

* :func:`spin_model_residuals` fits each spin (with its neighbours) by harmonics of a
  uniform spin phase whose coefficients change linearly in time (a trimmed fit, so a few
  bad samples do not pull it), and returns every sample's residual and the model's time
  derivative. On the ELFIN zones the median residual is about 500 counts (5 nT); a
  sample stamped wrong by ``dt`` is off by ``|dc/dt| dt``, about 1e7 counts/s.
* :func:`check_timing` turns a residual into the implied stamp error
  ``dt = r . c' / |c'|^2``. Samples next to an unpaired jump whose ``dt`` equals the
  jump (within ``match_s``) are moved by it: repaired. Whatever is still far from the
  model (``flag_factor`` times the median residual; a sample straddling the jump, a
  spike, a mis-stamp with no jump) is returned as bad, for the calibration to mark
  ``used = 0`` and count.

Pure NumPy; times in float seconds, counts in any unit.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from magcal.lstsq import lstsq, lstsq_stack
from magcal.missions.elfin.phase import phase_from_counts


def _design(tau, w, harmonics):
    """Harmonics of ``w tau`` with coefficients linear in ``tau`` (constant quadratic);
    ``tau`` of any shape, the columns last."""
    cols, dcols = [np.ones_like(tau)], [np.zeros_like(tau)]
    for k in range(1, harmonics + 1):
        c, s = np.cos(k * w * tau), np.sin(k * w * tau)
        cols += [c, s]
        dcols += [-k * w * s, k * w * c]
    a0, d0 = np.stack(cols, axis=-1), np.stack(dcols, axis=-1)
    t = tau[..., None]
    a = np.concatenate([a0, a0 * t, t ** 2], axis=-1)
    d = np.concatenate([d0, d0 * t + a0, 2 * t], axis=-1)
    return a, d


def spin_model_residuals(t_s, counts, *, mask=None, harmonics: int = 4,
                         window_spins: float = 3.0, trim: float = 0.8,
                         rate_rad_s: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Residual of each sample from a local spin model of the counts, and its slope.

    Each spin (cores of one spin period) is fitted together with its neighbours
    (``window_spins`` periods) by ``sum_k (a_k + b_k tau) cos(k w tau) + (c_k + d_k tau)
    sin(k w tau) + e tau^2`` per axis, ``k = 0..harmonics``, ``w`` the spin rate. A window
    whose plain fit leaves a sample above 10x the median residual of the plain fits is
    refitted on its ``trim`` best samples (three concentration steps), then on the samples
    within 6x its median: a few bad samples do not pull the model.

    Parameters
    ----------
    t_s : array_like (n,)
        Times, seconds (increasing).
    counts : array_like (n, 3)
        Sensor readings.
    mask : array_like of bool, optional
        Samples fitted and screened (default all; e.g. leave out a turn-on transient).
    harmonics : int
        Highest spin harmonic in the model (4 covers the ELFIN non-linearity).
    window_spins : float
        Window length in spin periods.
    trim : float
        Share of a window kept in the concentration steps.
    rate_rad_s : float, optional
        Spin rate; default the mean rate of
        :func:`~magcal.missions.elfin.phase.phase_from_counts` over the screened samples.

    Returns
    -------
    residual : ndarray (n, 3)
        Counts minus the model (NaN outside ``mask``).
    slope : ndarray (n, 3)
        Time derivative of the model at each sample (counts per s).

    Examples
    --------
    >>> t = np.arange(0.0, 30.0, 0.1)
    >>> c = np.column_stack([np.cos(2.2 * t), np.sin(2.2 * t), 0.1 * np.cos(2.2 * t)]) * 1e6
    >>> r, d = spin_model_residuals(t, c)
    >>> bool(np.nanmax(np.abs(r)) < 100.0)            # 1e-4 of the amplitude
    True
    >>> round(float(np.nanmedian(np.abs(d[:, 0]))), -5)  # 2.2e6 |sin|, median 0.71
    1600000.0
    """
    t = np.asarray(t_s, dtype=float)
    c = np.asarray(counts, dtype=float)
    ok = np.ones(t.size, bool) if mask is None else np.asarray(mask, bool).copy()
    ok &= np.all(np.isfinite(c), axis=1)
    res = np.full(c.shape, np.nan)
    der = np.full(c.shape, np.nan)
    if ok.sum() < 4 * harmonics + 8:
        return res, der
    if rate_rad_s is None:                       # the mean rate: free of the ellipse's wobble
        phase = phase_from_counts(t[ok], c[ok])[0]
        rate_rad_s = (phase[-1] - phase[0]) / (t[ok][-1] - t[ok][0])
    w = abs(rate_rad_s)
    period = 2.0 * np.pi / w
    idx = np.flatnonzero(ok)
    tt = t[idx]
    centres = np.arange(tt[0], tt[-1] + period, period)
    lo, hi = (np.searchsorted(tt, centres + h * window_spins * period / 2, side="left")
              for h in (-1, 1))
    clo, chi = (np.searchsorted(tt, centres + h * period / 2, side="left") for h in (-1, 1))
    take = (chi > clo) & (hi - lo >= 4 * harmonics + 8)
    if not take.any():
        return res, der
    centres, lo, hi, clo, chi = (v[take] for v in (centres, lo, hi, clo, chi))
    # every window's plain fit at once: rows padded with zeros to the longest window
    # (a zero row changes no least-squares answer), normal equations per window
    rows = lo[:, None] + np.arange(int(np.max(hi - lo)))
    valid = rows < hi[:, None]
    rows = idx[np.minimum(rows, idx.size - 1)]
    a, d = _design(np.where(valid, t[rows] - centres[:, None], 0.0), w, harmonics)
    a *= valid[..., None]
    cw = c[rows] * valid[..., None]
    coef = lstsq_stack(a, cw)
    size = np.linalg.norm(cw - a @ coef, axis=2)
    scale = np.median(size[valid])
    for j in np.flatnonzero(np.max(np.where(valid, size, 0.0), axis=1) > 10.0 * scale):
        m = int(hi[j] - lo[j])
        aj, cj, s = a[j, :m], cw[j, :m], size[j, :m]
        keep = np.ones(m, bool)
        for it in range(12):
            new = s <= np.quantile(s, trim) if it < 3 else s < 6.0 * np.median(s[keep])
            if it >= 3 and np.array_equal(new, keep):
                break
            keep = new
            coef[j] = lstsq(aj[keep], cj[keep])
            s = np.linalg.norm(cj - aj @ coef[j], axis=1)
    fit_res, slope = cw - a @ coef, d @ coef
    for j in range(centres.size):
        core = slice(clo[j] - lo[j], chi[j] - lo[j])
        res[idx[clo[j]:chi[j]]] = fit_res[j, core]
        der[idx[clo[j]:chi[j]]] = slope[j, core]
    return res, der


@dataclass(frozen=True)
class TimingCheck:
    """Result of :func:`check_timing` for one zone.

    Attributes
    ----------
    t_s : ndarray (n,)
        Times after the repair of blocks next to unpaired jumps.
    bad : ndarray of bool (n,)
        Samples still far from the spin model: to be left out (``used = 0``).
    events : list of dict
        ``{"kind": "unpaired_repaired", "index", "end_index", "jump_s", "n_samples"}`` per
        repaired block and ``{"kind": "flagged", "index", "end_index", "n_samples",
        "max_residual_ratio", "implied_shift_s"}`` per run of bad samples.
    median_residual : float
        Median |residual| of the spin model (counts): the scale of ``flag_factor``.
    """

    t_s: np.ndarray
    bad: np.ndarray
    events: list = field(default_factory=list)
    median_residual: float = float("nan")

    @property
    def n_flagged(self) -> int:
        """Number of samples to leave out."""
        return int(self.bad.sum())

    @property
    def n_repaired(self) -> int:
        """Number of samples moved in time."""
        return int(sum(e["n_samples"] for e in self.events if e["kind"] == "unpaired_repaired"))


def true_runs(flags) -> list[tuple[int, int]]:
    """``[start, stop)`` of the runs of True.

    >>> true_runs([0, 1, 1, 0, 1])
    [(1, 3), (4, 5)]
    """
    f = np.r_[False, np.asarray(flags, bool), False].astype(int)
    edges = np.flatnonzero(np.diff(f))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist()))


def _screen(t, c, mask, kw):
    res, der = spin_model_residuals(t, c, mask=mask, **kw)
    size = np.linalg.norm(res, axis=1)
    scale = float(np.nanmedian(size))
    shift = np.sum(res * der, axis=1) / np.maximum(np.sum(der ** 2, axis=1), 1e-300)
    return size, scale, shift


def check_timing(t_s, counts, anomalies=(), *, mask=None, flag_factor: float = 30.0,
                 match_s: float = 0.002, max_block: int = 100, **kw) -> TimingCheck:
    """Repair blocks next to unpaired time-stamp jumps from the counts; flag the rest.

    Parameters
    ----------
    t_s : array_like (n,)
        Times after :func:`~magcal.missions.elfin.phase.repair_timestamps`, seconds.
    counts : array_like (n, 3)
        Raw sensor readings.
    anomalies : sequence of dict
        The jumps :func:`~magcal.missions.elfin.phase.repair_timestamps` reported; the
        ``"unpaired"`` ones are examined (``index``: first sample after the jump,
        ``jump_s``: the excess step).
    mask : array_like of bool, optional
        Samples screened (default all; leave out a turn-on transient).
    flag_factor : float
        A sample whose residual from the spin model exceeds this many times the median
        residual is bad (30: on ELFIN-A about 150 nT, or a mis-stamp of 1.5 ms; the
        clean zones of 2022-01-12 reach 21 at most).
    match_s : float
        A sample next to an unpaired jump ``J`` is repaired when its implied stamp error
        is within this of ``J`` (stamped early, before the jump) or of ``-J`` (late,
        after it).
    max_block : int
        Longest block searched on each side of a jump.
    **kw
        Passed to :func:`spin_model_residuals`.

    Returns
    -------
    TimingCheck

    Examples
    --------
    >>> t = np.arange(0.0, 60.0, 0.1)
    >>> c = np.column_stack([np.cos(2.2 * t), np.sin(2.2 * t), 0.1 + 0 * t]) * 1e6
    >>> stamps = t.copy()
    >>> stamps[300:307] -= 0.0125                    # seven samples stamped early ...
    >>> out = check_timing(stamps, c, [{"kind": "unpaired", "index": 307, "jump_s": 0.0125}])
    >>> bool(np.allclose(out.t_s, t)), out.n_repaired, out.n_flagged   # ... then a jump
    (True, 7, 0)
    """
    t = np.asarray(t_s, dtype=float).copy()
    c = np.asarray(counts, dtype=float)
    screened = np.ones(t.size, bool) if mask is None else np.asarray(mask, bool)
    size, scale, shift = _screen(t, c, screened, kw)
    events = []
    for a in anomalies:
        if a.get("kind") != "unpaired":
            continue
        j, jump = int(a["index"]), float(a["jump_s"])
        far = size > flag_factor * scale
        for sign, rng in ((1.0, range(j - 1, max(j - 1 - max_block, -1), -1)),
                          (-1.0, range(j, min(j + max_block, t.size)))):
            block = []
            for i in rng:
                if not (far[i] and abs(shift[i] - sign * jump) < match_s):
                    break
                block.append(i)
            if block:
                lo, hi = min(block), max(block) + 1
                moved = t[lo:hi] + sign * jump
                if (lo > 0 and moved[0] <= t[lo - 1]) or (hi < t.size and moved[-1] >= t[hi]):
                    continue                   # would pass a neighbour: left to the flags
                t[lo:hi] = moved
                events.append({"kind": "unpaired_repaired", "index": lo, "end_index": hi,
                               "jump_s": jump, "n_samples": hi - lo})
    if events:
        size, scale, shift = _screen(t, c, screened, kw)
    bad = np.nan_to_num(size, nan=0.0) > flag_factor * scale
    for lo, hi in true_runs(bad):
        events.append({"kind": "flagged", "index": lo, "end_index": hi, "n_samples": hi - lo,
                       "max_residual_ratio": float(size[lo:hi].max() / scale),
                       "implied_shift_s": float(np.median(shift[lo:hi]))})
    return TimingCheck(t_s=t, bad=bad, events=events, median_residual=scale)
