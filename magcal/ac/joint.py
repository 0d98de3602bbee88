"""Joint pair fit: one constant 3x3 correction per sensor from several selections.

A PiCoG pair stage fits one rank-one order per selection and chains them, each order
undoing part of the previous ones. The joint fit instead collects, for every selection
``s`` of the same pair, the cross-covariance of the cleaned sensor with the difference
``C_id,s`` and the difference covariance ``C_dd,s``, and solves for one full matrix

    ``K = -(sum_s w_s C_id,s) (sum_s w_s C_dd,s)^-1``

so that ``B_i + K (B_i - B_j)`` is decorrelated from the difference over all
selections. The weights are reweighted minimax-style towards the selection whose
coherent power (``tr(r C_dd^+ r^T)``, ``r = C_id + K C_dd``) is reduced least; a
selection not above its own chance level (the difference lagged) is dropped
(``min_snr``), since the reweighting would chase it.

Selections (:func:`selections`): the windows of a ``window_s`` scan, a ``band_hz``
band-pass, an ``interval``, and the events around the largest steps of the difference
(found by :mod:`magcal.ac.events`). Why events are matched filters
(``events = "pulse"``): an edge pulse is seen at few events a day and the ambient
field, present in the cleaned sensor, correlates with it by chance. A disturbance is a
fixed moment times a time profile (Constantinescu et al. 2020, §2), and its profile is
seen in the difference free of the ambient, so both sensors are projected on the
event's pulse shape (:func:`pulse_selection`), with other spikes and steps masked and,
where it helps, the ambient interpolated across the event from its flanks
(:func:`flank_ambient`); the events of a pair are pooled with inverse-chance weights
(:func:`pool_pulses`). Steps of the cleaned difference outside the events are matched
filters in the same way (:func:`step_selection`, pooled per disturber by
:func:`step_group`). ``events = "interval"`` uses whole intervals free of other events
instead (:func:`event_intervals`). Measured gains are in CHANGELOG.md and the
benchmarks.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from magcal.ac.events import cleaned_events, event_intervals, event_windows
from magcal.ac.filters import bandpass, highpass, highpass_samples
from magcal.ac.scan import scan_first_order, summarize_scan
from magcal.errors import InputError

#: how event selections are formed (see :func:`selections`)
EVENT_MODES = ("pulse", "interval")
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
    #: chance levels of the coherent power (for ``b_i``, for ``b_j``) when known
    #: otherwise (pulse selections); None: from lagging or none
    chance: tuple | None = None


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


#: periods (s) tried for the ambient wave in :func:`flank_ambient` (Pc4-Pc5 range)
AMBIENT_PERIODS_S = tuple(float(p) for p in range(120, 901, 20))


def flank_ambient(x: np.ndarray, t_s: np.ndarray, centre_s: float, *,
                  core_s: float = 100.0, flank_s: float = 600.0, degree: int = 3,
                  periods_s=AMBIENT_PERIODS_S, exclude: np.ndarray | None = None,
                  steps_s=()) -> np.ndarray:
    """Ambient field across an event core interpolated from its flanks.

    Fits a polynomial of ``degree`` plus the best single sinusoid (period from
    ``periods_s``, or none) and steps at ``centre_s + steps_s`` to ``x`` on
    ``core_s < |t - centre_s| <= flank_s`` (rows in ``exclude`` left out) by least squares
    and evaluates it on ``|t - centre_s| <= flank_s`` (NaN elsewhere). Subtracted from
    both sensors of a pair it leaves their difference unchanged and removes most of a
    ULF wave from the event core, which would otherwise correlate with the event's pulse
    by chance.

    Examples
    --------
    >>> t = np.arange(3000.0); w = np.sin(2 * np.pi * t / 300.0)[:, None] * [1.0, 0.5, 0.0]
    >>> pulse = np.maximum(0, 1 - np.abs(t - 1500) / 90)[:, None] * [0.0, 0.0, 2.0]
    >>> a = flank_ambient(w + pulse, t, 1500.0)
    >>> bool(np.nanmax(np.abs(a - w)) < 1e-6)
    True
    """
    x = np.asarray(x, float)
    t_s = np.asarray(t_s, float)
    # t_s increases (the chain's time base): work on the flanks' slice only (a day has
    # tens of events, each interpolated at dozens of chance lags)
    lo = int(np.searchsorted(t_s, centre_s - flank_s, side="left"))
    hi = int(np.searchsorted(t_s, centre_s + flank_s, side="right"))
    span = slice(lo, hi)
    ts, xs = t_s[span] - centre_s, x[span]
    rows = (np.abs(ts) > core_s) & np.all(np.isfinite(xs), axis=1)
    if exclude is not None:
        rows &= ~np.asarray(exclude, bool)[span]
    u = ts / flank_s
    poly = [u ** k for k in range(degree + 1)] + [
        np.clip(ts - st, -1.0, 1.0) for st in steps_s]
    best = None
    for period in (None, *periods_s):
        cols = poly if period is None else poly + [
            np.sin(2 * np.pi * u * flank_s / period), np.cos(2 * np.pi * u * flank_s / period)]
        basis = np.column_stack(cols)
        if rows.sum() <= basis.shape[1]:
            continue
        coef, *_ = np.linalg.lstsq(basis[rows], xs[rows], rcond=None)
        rss = float(np.sum((xs[rows] - basis[rows] @ coef) ** 2))
        if best is None or rss < best[0]:
            best = (rss, basis @ coef)
    out = np.full(x.shape, np.nan)
    if best is not None:
        out[span] = best[1]
    return out


def flank_ambient_error(x: np.ndarray, t_s: np.ndarray, centre_s: float, *,
                        core_s: float = 100.0, flank_s: float = 600.0,
                        shifts_s=(-350.0, 350.0), exclude: np.ndarray | None = None
                        ) -> tuple[float, float]:
    """Cross-check of :func:`flank_ambient` at pseudo-cores ``centre_s + shifts_s``:
    (rms of ``x`` minus the interpolated ambient there, rms of ``x`` about its mean
    there), both mean-removed per core and summed over components. Interpolating pays
    off when the first is clearly below the second (a coherent ambient wave).
    """
    x = np.asarray(x, float)
    t_s = np.asarray(t_s, float)
    e_mod, e_raw = [], []
    for sh in shifts_s:
        c = centre_s + sh
        core = (np.abs(t_s - c) <= core_s) & np.all(np.isfinite(x), axis=1)
        if exclude is not None:
            core &= ~np.asarray(exclude, bool)
        if core.sum() < 3:
            continue
        r = (x - flank_ambient(x, t_s, c, core_s=core_s, flank_s=flank_s,
                               exclude=exclude))[core]
        if not np.all(np.isfinite(r)):
            continue
        e_mod.append(np.sqrt(r.var(axis=0).sum()))
        e_raw.append(np.sqrt(x[core].var(axis=0).sum()))
    if not e_mod:
        return float("nan"), float("nan")
    return float(np.mean(e_mod)), float(np.mean(e_raw))


#: template shifts (s) for the chance level of a pulse selection
PULSE_LAGS_S = tuple(float(v) for v in np.r_[-np.arange(1800, 299, -100),
                                             np.arange(300, 1801, 100)])


def _pulse_template(dd: np.ndarray, tt: np.ndarray, steps_s=()) -> np.ndarray:
    """Main temporal component of the difference ``dd`` (rows of one event) with its
    mean, the ramp (a step at ``tt = 0``) and other steps (at ``steps_s``) regressed
    out."""
    nuis = np.column_stack([np.ones(len(tt)), np.clip(tt / 15.0, -1.0, 1.0)]
                           + [np.clip((tt - s) / 1.0, -1.0, 1.0) for s in steps_s])
    r = dd - nuis @ np.linalg.lstsq(nuis, dd, rcond=None)[0]
    _, _, vt = np.linalg.svd(r, full_matrices=False)
    return r @ vt[0]


def _pulse_coef(z, cm, t_s, centre_s, offsets_s, u, ambient, exclude, steps_s=()):
    """Projection coefficients (3,) of ``z`` on the template ``u`` placed at
    ``centre_s + offsets_s`` (None where that window leaves the data or meets another
    event); the ambient interpolated from the flanks of ``cm`` removed first if asked."""
    rows = np.searchsorted(t_s, centre_s + offsets_s)
    if rows[0] <= 0 or rows[-1] >= len(t_s) - 1:
        return None
    if exclude is not None and np.any(exclude[rows]):
        return None
    v = z[rows]
    if ambient:
        v = v - flank_ambient(cm, t_s, centre_s, exclude=exclude, steps_s=steps_s)[rows]
    if not np.all(np.isfinite(v)):
        return None
    return u @ (v - v.mean(axis=0)) / (u @ u)


def pulse_selection(name: str, x: np.ndarray, y: np.ndarray, t_s: np.ndarray,
                    centre_s: float, mask: np.ndarray, other: np.ndarray | None = None, *,
                    ambient: bool = False, lags_s=PULSE_LAGS_S, steps_s=()) -> Selection:
    """A rank-one selection of one event (a matched filter): both sensors projected on
    the event's pulse shape in their difference (:func:`_pulse_template`, free of the
    ambient field), after removing the ambient interpolated from the flanks of their
    mean (:func:`flank_ambient`) if ``ambient``. Its chance levels (one per sensor)
    are the same projection with the template moved by ``lags_s`` (windows that meet
    another event, ``other``, skipped).

    Examples
    --------
    >>> rng = np.random.default_rng(2); t = np.arange(6000.0)
    >>> pulse = np.maximum(0, 1 - np.abs(t - 3000) / 90)[:, None]
    >>> amb = rng.normal(0, 0.05, (6000, 3))
    >>> x = amb + pulse * [0.0, 0.0, 2.0]; y = amb + pulse * [0.0, 0.0, 5.0]
    >>> sel = pulse_selection("e", x, y, t, 3000.0, np.abs(t - 3000) <= 120)
    >>> fit = fit_joint([sel], 1.0)
    >>> round(float(fit.K[2, 2]), 2), bool(fit.snr["e pulse"] > 100)
    (0.67, True)
    """
    t_s = np.asarray(t_s, float)
    rows = np.flatnonzero(mask)
    if not np.all(np.isfinite((x - y)[rows])):
        # samples left out of the fit (glitches, QC flags) are NaN: no template there
        raise InputError(f"event {name}: the pulse window holds NaN")
    off = t_s[rows] - centre_s
    u = _pulse_template((x - y)[rows], off, steps_s)
    cm = 0.5 * (x + y)
    cx = _pulse_coef(x, cm, t_s, centre_s, off, u, ambient, None, steps_s)
    cy = _pulse_coef(y, cm, t_s, centre_s, off, u, ambient, None, steps_s)
    if cx is None or cy is None:
        raise InputError(f"event {name}: the pulse window leaves the data or holds NaN")
    scale = (u @ u) / len(rows)
    # the event itself (pulse and ramp) must not enter the shifted windows or their
    # flank fits
    lag_exclude = np.abs(t_s - centre_s) <= np.max(np.abs(off)) + 30.0
    if other is not None:
        lag_exclude |= other
    chance = []
    for z in (x, y):
        vals = [c @ c * scale for c in (_pulse_coef(z, cm, t_s, centre_s + lag, off, u,
                                                    ambient, lag_exclude) for lag in lags_s)
                if c is not None]
        chance.append(float(np.mean(vals)) if vals else float("nan"))
    bx, by = np.zeros_like(x), np.zeros_like(y)
    bx[rows], by[rows] = np.outer(u, cx), np.outer(u, cy)
    return Selection(name + " pulse", bx, by, mask, lag_null=False, chance=tuple(chance))


def pulse_snr(sel: Selection) -> float:
    """Coherent power of a pulse selection over its chance level, both sensors together
    (NaN when no chance level could be formed)."""
    rows = sel.mask
    p0 = float(np.sum(sel.b_i[rows].var(axis=0)) + np.sum(sel.b_j[rows].var(axis=0)))
    ch = sel.chance[0] + sel.chance[1]
    return p0 / ch if ch > 0 else float("nan")


def pool_pulses(pulses: list[Selection]) -> Selection:
    """One rank-one selection from the pulse selections of one pair (the same disturber
    at every event): the per-event signatures (cleaned sensor and partner per unit of
    difference) are averaged with weights ``|d|^2 / chance``, so a pulse hidden in
    ambient waves counts little, and the events do not compete in the minimax. Each
    event keeps its own pulse shape and size.

    Examples
    --------
    >>> t = np.arange(8000.0); rng = np.random.default_rng(0)
    >>> h = lambda c: np.maximum(0, 1 - np.abs(t - c) / 90)[:, None]
    >>> x = rng.normal(0, 0.05, (8000, 3)) + (h(3000) + h(5700)) * [0.0, 0.0, 2.0]
    >>> y = x + (h(3000) + h(5700)) * [0.0, 0.0, 3.0]
    >>> sels = [pulse_selection(str(c), x, y, t, c, np.abs(t - c) <= 120)
    ...         for c in (3000.0, 5700.0)]
    >>> fit = fit_joint([pool_pulses(sels)], 1.0)
    >>> round(float(fit.K[2, 2]), 2)
    0.67
    """
    parts = []
    ref = None
    for s in pulses:
        rows = np.flatnonzero(s.mask)
        u, sv, vt = np.linalg.svd(np.hstack([s.b_i[rows], s.b_j[rows]]), full_matrices=False)
        shape, cx, cy = u[:, 0] * sv[0], vt[0, :3], vt[0, 3:]
        cd = cx - cy
        if ref is None:
            ref = cd
        if cd @ ref < 0:
            shape, cx, cy, cd = -shape, -cx, -cy, -cd
        size = float(np.linalg.norm(cd))
        w = size ** 2 * float(shape @ shape) * 2.0 / (s.chance[0] + s.chance[1])
        parts.append((rows, shape * size, cx / size, cy / size, w))
    tot = sum(p[4] for p in parts)
    ax = sum(p[4] * p[2] for p in parts) / tot
    ay = sum(p[4] * p[3] for p in parts) / tot
    bx, by = np.zeros_like(pulses[0].b_i), np.zeros_like(pulses[0].b_j)
    mask = np.zeros(len(bx), bool)
    for rows, shape, *_ in parts:
        bx[rows], by[rows] = np.outer(shape, ax), np.outer(shape, ay)
        mask[rows] = True
    # chance level of the pooled coherent power: the events' chance levels, weighted
    # as their signatures are
    n = mask.sum()
    chance = tuple(sum(p[4] / tot * s.chance[k] * p[0].size for p, s in zip(parts, pulses))
                   * len(parts) / n for k in (0, 1))
    return Selection("pulses " + "; ".join(s.name for s in pulses), bx, by, mask,
                     lag_null=False, chance=chance)


def step_selection(name: str, x: np.ndarray, y: np.ndarray, t_s: np.ndarray,
                   centre_s: float, keep: np.ndarray, *, half_s: float = 120.0,
                   lags_s=PULSE_LAGS_S, avoid: np.ndarray | None = None) -> Selection:
    """A rank-one selection of one step of the difference (a matched filter): within
    ``+-half_s`` of ``centre_s`` (rows in ``keep``) a quadratic is regressed out of
    both sensors, the step's shape is the main temporal component of what is left of
    their difference, and both sensors are projected on it. A step is seen in a few
    samples of a day; over longer selections its slow level correlates with the
    ambient field by chance. Chance levels as in :func:`pulse_selection` (template
    moved by ``lags_s``, windows meeting ``avoid`` skipped).

    Examples
    --------
    >>> rng = np.random.default_rng(3); t = np.arange(8000.0)
    >>> st = np.clip((t - 4000) / 20, -0.5, 0.5)[:, None]
    >>> amb = rng.normal(0, 0.05, (8000, 3))
    >>> x = amb + st * [0.0, 2.0, 0.0]; y = amb + st * [0.0, 5.0, 0.0]
    >>> sel = step_selection("s", x, y, t, 4000.0, np.ones(8000, bool))
    >>> fit = fit_joint([sel], 1.0)
    >>> bool(abs(fit.K[1, 1] - 2 / 3) < 0.02), bool(fit.snr["s step"] > 100)
    (True, True)
    """
    t_s = np.asarray(t_s, float)
    off_all = t_s - centre_s
    rows = np.flatnonzero((np.abs(off_all) <= half_s) & keep)
    if rows.size < 10 or rows[0] == 0 or rows[-1] >= len(t_s) - 1:
        raise InputError(f"step {name}: the window leaves the data")
    tt = off_all[rows] / half_s
    nuis = np.column_stack([np.ones(len(tt)), tt, tt ** 2])
    proj = nuis @ np.linalg.pinv(nuis)

    def resid(v):
        return v - proj @ v

    d = resid((x - y)[rows])
    if not np.all(np.isfinite(d)):
        raise InputError(f"step {name}: the window holds NaN")
    _, _, vt = np.linalg.svd(d, full_matrices=False)
    u = d @ vt[0]
    uu = float(u @ u)
    cx, cy = u @ resid(x[rows]) / uu, u @ resid(y[rows]) / uu
    scale = uu / len(rows)
    off = t_s[rows] - centre_s
    bad = np.abs(off_all) <= half_s + 30.0
    if avoid is not None:
        bad |= avoid
    chance = [[], []]
    for lag in lags_s:
        r = np.searchsorted(t_s, centre_s + lag + off)
        if r[0] <= 0 or r[-1] >= len(t_s) - 1 or np.any(bad[r]):
            continue
        for k, z in enumerate((x, y)):
            v = resid(z[r])
            if np.all(np.isfinite(v)):
                c = u @ v / uu
                chance[k].append(c @ c * scale)
    ch = tuple(float(np.mean(c)) if c else float("nan") for c in chance)
    bx, by = np.zeros_like(x), np.zeros_like(y)
    bx[rows], by[rows] = np.outer(u, cx), np.outer(u, cy)
    mask = np.zeros(len(t_s), bool)
    mask[rows] = True
    return Selection(name + " step", bx, by, mask, lag_null=False, chance=ch)


def step_group(steps: list[Selection], min_snr: float = 2.5,
               min_cos: float = 0.9) -> list[Selection]:
    """The steps of one disturber: those standing ``min_snr`` above their chance level
    whose difference signature is parallel (``|cos| >= min_cos``) to that of the
    clearest step (a disturber is a fixed moment times a profile)."""
    good = [s for s in steps if np.isfinite(pulse_snr(s)) and pulse_snr(s) >= min_snr]
    if not good:
        return []

    def dsig(s):
        rows = s.mask
        v = np.linalg.svd(s.b_i[rows] - s.b_j[rows], full_matrices=False)[2][0]
        return v

    ref = dsig(max(good, key=pulse_snr))
    return [s for s in good if abs(float(dsig(s) @ ref)) >= min_cos]


def selections(b_i: np.ndarray, b_j: np.ndarray, t_s: np.ndarray, orders, dt_s: float, *,
               event_half_s: float | None = 120.0,
               event_difference: np.ndarray | None = None,
               events: str = "pulse", event_guard_s: float = 15.0,
               step_events: bool = True) -> list[Selection]:
    """Selections of the pair from the stage's orders (see the module docstring).

    Every order's ``highpass_s`` is applied before its selection; event intervals use
    the first order's. Events are detected in ``event_difference`` (default
    ``b_i - b_j``; the chain passes the raw difference of the pair, where the
    midnight ramps stand out before earlier stages have removed most of them).
    ``events = "interval"``: one selection per ``+-event_half_s`` interval that holds no
    other step or spike (:func:`event_intervals`). ``events = "pulse"``: every event
    with the samples within ``event_guard_s`` of other spikes and steps left out
    (:func:`event_masks`), the ambient removed where a wave interpolates across it
    (:func:`flank_ambient_error`), projected on its pulse shape
    (:func:`pulse_selection`), and all events pooled into one selection
    (:func:`pool_pulses`).
    """
    if events not in EVENT_MODES:
        raise InputError(f"events must be one of {EVENT_MODES}, got {events!r}")
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
    if not event_half_s:
        return out
    hp = highpass_samples(orders[0].highpass_s, dt_s)
    x, y = (highpass(b_i, hp), highpass(b_j, hp)) if hp else (b_i, b_j)
    ev = (b_i - b_j) if event_difference is None else event_difference
    if events == "interval":
        for lo, hi in event_intervals(ev, t_s, half_s=event_half_s):
            out.append(Selection(f"event {lo:.0f}-{hi:.0f} s", x, y,
                                 (t_s >= lo) & (t_s <= hi)))
        return out
    # spikes and steps next to the ramp hide in its detection signals of the raw
    # difference; in the cleaned difference the ramp is (mostly) gone
    spikes_c, steps_c = cleaned_events(x - y, dt_s, event_guard_s)
    pulses = []
    wins = event_windows(ev, t_s, event_half_s, event_guard_s, 60.0, 0.3, 6.0)
    for p, m, other in wins:
        m = m & ~spikes_c
        idx = np.flatnonzero(m)
        name = f"event {t_s[idx[0]]:.0f}-{t_s[idx[-1]]:.0f} s"
        st = [t_s[k] - t_s[p] for k in steps_c
              if idx[0] <= k <= idx[-1] and abs(t_s[k] - t_s[p]) > 20.0]
        try:
            cand = [pulse_selection(name + (" (ambient removed)" if amb else ""),
                                    x, y, t_s, t_s[p], m, other, ambient=amb, steps_s=st)
                    for amb in (False, True)]
        except InputError:
            continue        # an event at the edge of the data: no pulse selection
        # keep the variant whose pulse stands out more above its own chance level
        cand = [c for c in cand if np.isfinite(pulse_snr(c))]
        if cand:
            pulses.append(max(cand, key=pulse_snr))
    if pulses:
        out.append(pool_pulses(pulses))
    if step_events:
        avoid = spikes_c.copy()
        for p, _, _ in wins:
            avoid |= np.abs(t_s - t_s[p]) <= event_half_s
        cand = []
        for k in steps_c:
            if avoid[k]:
                continue
            try:
                cand.append(step_selection(f"{t_s[k]:.0f} s", x, y, t_s, t_s[k], ~spikes_c,
                                           avoid=avoid))
            except InputError:
                continue
        group = step_group(cand)
        if len(group) >= 2:
            pooled = pool_pulses(group)
            out.append(Selection("steps " + pooled.name[len("pulses "):], pooled.b_i,
                                 pooled.b_j, pooled.mask, False, pooled.chance))
    return out


def fit_joint(sels: list[Selection], dt_s: float, *, min_snr: float = 5.0,
              pulse_min_snr: float = 2.5, n_iter: int = 30, power: float = 0.5) -> JointFit:
    """Joint minimax fit of ``K`` over the selections (module docstring).

    Selections with a known chance level (pulse selections) are kept from
    ``pulse_min_snr``, the others from ``min_snr``.

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
    threshold = {}
    for s in sels:
        c = _moments(s.b_i, s.b_i - s.b_j, s.mask)
        if c is None:
            continue
        p0 = coherent_power(*c)
        mom[s.name] = c
        threshold[s.name] = min_snr if s.chance is None else pulse_min_snr
        if s.chance is not None:
            snr[s.name] = p0 / s.chance[0] if s.chance[0] > 0 else float("inf")
        else:
            ch = chance_level(s.b_i, s.b_j, s.mask, dt_s) if s.lag_null else 0.0
            snr[s.name] = p0 / ch if ch > 0 else float("inf")
    keys = [k for k in mom if snr[k] >= threshold[k]]
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
    return [Selection(s.name, s.b_j, s.b_i, s.mask, s.lag_null,
                      None if s.chance is None else s.chance[::-1]) for s in sels]
