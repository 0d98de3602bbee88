"""ELFIN fluxgate counts calibrated end to end against IGRF (spinning CubeSat in LEO).

Model, per science zone, in the notation of Kivelson et al. (1992), ``B = C (b - O)``
with ``b`` the raw counts, extended by slow drifts that the real data need:

* body frame: ``Bx = a1 . b + o1(T)``, ``By = a2 . b + o2(T)`` (constant gains and
  coupling ``a1, a2`` in nT/count), ``Bz = a3(T) . b + o3(T)``: the spin-axis row may
  turn slowly (the spin axis moves in the body frame by about a degree per pass), and
  the offsets ``o(T)`` drift; ``T`` runs from -1 to 1 over the zone and the drifts are
  polynomials of degree ``axis_degree`` and ``offset_degree`` (0 gives the plain
  12-parameter model);
* despun frame (rows of :func:`~magcal.missions.elfin.phase.despun_basis`, ``Z`` = spin
  axis from the attitude file): ``B_despun = despin(B_body, p)`` (CONTRACTS §4 sense),
  with the spin phase ``p`` = a quadratic in time plus a cubic spline with knots every
  ``phase_knot_s``;
* the target is IGRF at the spacecraft position, rotated into the despun frame.

Given the phase, the model is linear in the calibration parameters (ordinary least
squares, per component); given the calibration, the phase correction is the spline fit
of the angle between the calibrated and the IGRF spin-plane field. The two steps
alternate. The first phase comes from the counts alone
(:func:`~magcal.missions.elfin.phase.phase_from_counts`); its sense is chosen by the fit.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
import pandas as pd

from magcal.errors import InputError
from magcal.io.jsonio import product_dict
from magcal.lstsq import lstsq
from magcal.missions.elfin.clipping import clipped_samples
from magcal.missions.elfin.files import ns_index
from magcal.missions.elfin.levels import step_columns
from magcal.missions.elfin.phase import (
    TWO_PI,
    despun_basis,
    phase_from_counts,
    repair_timestamps,
    spline_knots,
    split_zones,
    wrap,
)
from magcal.missions.elfin.timing import check_timing
from magcal.spin.despin import despin, spin

CREDIT = "ELFIN SOC (PI V. Angelopoulos, UCLA); data: Open Data for Scientific Use"
_SCALE = 1.0e6  # counts are O(1e6): work with (counts - mean) / 1e6


@dataclass(frozen=True)
class ZoneCalibration:
    """Calibration of one science zone against IGRF.

    Attributes
    ----------
    start, end : str
        ISO UTC of the first and last sample.
    n_samples, n_used : int
        Samples in the zone, and used in the fit (after ``skip_s``).
    coupling : ndarray (3, 3)
        ``C`` at mid-zone, nT per count (rows: body X, Y, Z = spin axis).
    gains_nT_per_count : ndarray (3,)
        Column norms of ``C``: field per count of each sensor.
    offsets_counts : ndarray (3,)
        ``O`` at mid-zone with ``B = C (b - O)``.
    offsets_nT : ndarray (3,)
        ``-C O`` at mid-zone (body frame).
    offset_drift_nT : ndarray (3,)
        Change of the body-frame offsets from zone start to end.
    spin_axis_turn_deg : float
        Angle by which the spin-axis row turns between zone start and end.
    spin_period_s : float
        Mean spin period (from the total phase over the zone).
    spin_period_change_s : float
        End minus start period of the quadratic phase.
    phase_wander_rad : float
        RMS of the spline phase correction about a straight line.
    phase_jumps_rad : list of float
        Phase step across each internal data gap (> 1 s), from one spin each side.
    rms_vector_nT : ndarray (3,)
        RMS of calibrated minus IGRF per despun component (X, Y, Z).
    rms_scalar_nT : float
        RMS of ``|B| - |B_IGRF|``.
    rms_vector_constant_nT, rms_scalar_constant_nT :
        The same with the plain 12-parameter model (no drifts, quadratic phase only).
    spin_sense : int
        +1 if the phase increases (spin about +Z of the attitude file), -1 otherwise.
    det_coupling_sign : int
        Sign of ``det C`` (+1: right-handed sensor triad mapped onto a right-handed frame).
    attitude_correction_deg : ndarray (2,)
        Tilt of the spin axis from the attitude file's towards despun X and Y; zero
        unless ``fit_attitude`` (on the ELFIN data that fit is degenerate: several
        degrees, both spin senses equally good, so it is off by default).
    rms_by_sense_nT : list of float
        Overall vector RMS with the phase sense +1 and -1 (the smaller one among those
        of the required ``handedness`` is kept, see :func:`fit_zone`).
    timestamp_anomalies : list of dict
        From :func:`~magcal.missions.elfin.phase.repair_timestamps` and
        :func:`~magcal.missions.elfin.timing.check_timing` (repaired and flagged blocks).
    n_timing_repaired, n_timing_flagged : int
        Samples moved next to an unpaired time-stamp jump, and samples left out
        (``used = 0``) because the counts do not fit the spin where they are stamped.
    n_clipped : int
        Samples left out (``used = 0``) because an axis reads its clipped extreme
        (:func:`~magcal.missions.elfin.clipping.clipped_samples`: saturation).
    n_level_steps : int
        Intervals left out of the fit across which the spin-axis field's level was let
        change (``level_step_rows`` of :func:`fit_zone`;
        :func:`~magcal.missions.elfin.levels.level_step_rows`).
    det_sign_by_sense : list of int
        Sign of ``det C`` of the solution with the phase sense +1 and -1 (the two are
        mirror images; their signs differ).
    """

    start: str
    end: str
    n_samples: int
    n_used: int
    coupling: np.ndarray
    gains_nT_per_count: np.ndarray
    offsets_counts: np.ndarray
    offsets_nT: np.ndarray
    offset_drift_nT: np.ndarray
    spin_axis_turn_deg: float
    spin_period_s: float
    spin_period_change_s: float
    phase_wander_rad: float
    phase_jumps_rad: list
    rms_vector_nT: np.ndarray
    rms_scalar_nT: float
    rms_vector_constant_nT: np.ndarray
    rms_scalar_constant_nT: float
    spin_sense: int
    det_coupling_sign: int
    attitude_correction_deg: np.ndarray
    rms_by_sense_nT: list
    timestamp_anomalies: list = field(default_factory=list)
    det_sign_by_sense: list = field(default_factory=list)
    n_timing_repaired: int = 0
    n_timing_flagged: int = 0
    n_clipped: int = 0
    n_level_steps: int = 0

    def as_dict(self) -> dict:
        """Plain dictionary (JSON-ready after :func:`magcal.io.jsonio.to_jsonable`)."""
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


@dataclass(frozen=True)
class _ZoneFit:
    """Internal: fitted model of one zone on all its samples."""

    b_despun: np.ndarray
    phase: np.ndarray
    used: np.ndarray
    summary: ZoneCalibration
    fit: np.ndarray | None = None


def _powers(T, degree: int, first: int = 0) -> np.ndarray:
    return np.column_stack([T ** d for d in range(first, degree + 1)]) if degree >= first \
        else np.empty((T.size, 0))


def _iterate(t, x, T, target, base, used, *, offset_degree, axis_degree, knots, n_iter,
             fit_attitude=False, hold=False, phase_degree=2, axis_prior=None,
             axis_prior_weight=0.0, steps=None):
    """Alternate calibration (linear) and phase steps; return weights, body field, phase.

    Spin-plane rows: ``[counts, 1, T, .., T^offset_degree]``. Spin-axis row:
    ``[counts, 1]`` plus the calibrated spin-plane components times ``T^d``
    (``d = 1..axis_degree``): a slow tilt of the spin axis in the body frame. The
    spin-axis offset does not drift in the model: with the small range of the
    spin-axis field in one pass a drifting ``o3`` would trade off against the
    spin-axis gain. The phase correction is a cubic spline (``knots``) or, without
    knots, such that the whole phase is a polynomial of ``phase_degree`` (2: the
    base's quadratic plus a quadratic). ``hold``: the phase stays ``base`` (no phase step).
    ``axis_prior``: a spin-axis row (nT per count) that the row's count coefficients are
    drawn towards, with ``axis_prior_weight`` times their squared difference in nT per
    10^6 counts added to the sum of squares (nT^2). ``steps`` (n, m): level steps of the
    spin-axis field fitted in its row and left in the field
    (:func:`~magcal.missions.elfin.levels.step_columns`).
    """
    from scipy.interpolate import make_lsq_spline

    xy = np.column_stack([x, _powers(T, offset_degree)])
    xy_used = xy[used]                     # the spin-plane rows' design: the same each step
    corr = np.zeros_like(t)
    knot_vector = None if knots is None else spline_knots(t[used], knots, origin=t[0],
                                                          trim_end=False)
    tu = t[used] - t[used][0]
    steps = np.empty((t.size, 0)) if steps is None else np.asarray(steps, float)
    n_cal = 4 + 2 * axis_degree            # the row's columns that calibrate the counts

    def calibrate(phase):
        tgt = spin(target, phase)
        wx, wy = lstsq(xy_used, tgt[used, :2]).T
        bx, by = xy @ wx, xy @ wy
        tilt = _powers(T, axis_degree, first=1)
        att = -target[:, :2] if fit_attitude else np.zeros((T.size, 2))
        z = np.column_stack([x, np.ones_like(T), bx[:, None] * tilt, by[:, None] * tilt,
                             steps, att])
        a_z, y_z = z[used], tgt[used, 2]
        if axis_prior is not None and axis_prior_weight > 0:
            ridge = np.zeros((3, z.shape[1]))
            ridge[:, :3] = np.sqrt(axis_prior_weight) * np.eye(3)
            a_z = np.vstack([a_z, ridge])
            y_z = np.r_[y_z, np.sqrt(axis_prior_weight) * np.asarray(axis_prior) * _SCALE]
        wz = lstsq(a_z, y_z)
        if not fit_attitude:
            wz[-2:] = 0.0
        # the level steps and the attitude correction (the last two) are not part of the
        # calibration: the field keeps them
        return (wx, wy, wz), np.column_stack([bx, by, z[:, :n_cal] @ wz[:n_cal]]), tgt

    for _ in range(0 if hold else max(1, n_iter)):
        _, b_body, tgt = calibrate(base + corr)
        dphi = wrap(np.arctan2(tgt[:, 1], tgt[:, 0]) - np.arctan2(b_body[:, 1], b_body[:, 0]))
        if knot_vector is not None:
            spl = make_lsq_spline(t[used], dphi[used], knot_vector, k=3)
            corr = corr + spl(np.clip(t, t[used][0], t[used][-1]))
        else:
            # the whole phase (base + correction) a polynomial of phase_degree
            total = base + corr + dphi
            corr = np.polyval(np.polyfit(tu, total[used], phase_degree), t - t[used][0]) - base
    phase = base + corr
    w, b_body, _ = calibrate(phase)
    eps = w[2][-2:]
    cal = despin(b_body, phase)                  # in the attitude-corrected despun frame
    cal_file = cal + np.column_stack([eps[0] * cal[:, 2], eps[1] * cal[:, 2],
                                      -eps[0] * cal[:, 0] - eps[1] * cal[:, 1]])
    return w, b_body, phase, corr, cal_file


def _phase_jumps(t, resid_angle, used, period_s, min_gap_s=1.0) -> list:
    jumps = []
    for g in np.flatnonzero(np.diff(t) > min_gap_s):
        idx = np.arange(t.size)
        before = used & (idx <= g) & (t > t[g] - period_s)
        after = used & (idx > g) & (t < t[g + 1] + period_s)
        if before.sum() >= 5 and after.sum() >= 5:
            jumps.append(float(np.median(resid_angle[after]) - np.median(resid_angle[before])))
    return jumps


def fit_zone(t_s, counts, b_despun_nT, *, skip_s: float = 2.0, offset_degree: int = 2,
             axis_degree: int = 2, phase_knot_s: float | None = 30.0, n_iter: int = 8,
             fit_attitude: bool = False, times_iso=("", ""), timestamp_anomalies=(),
             exclude=None, phase=None, fit_exclude=None, phase_degree: int = 2,
             handedness: int = 1, axis_prior=None, axis_prior_weight: float = 0.0,
             level_step_rows=None) -> _ZoneFit:
    """Calibrate one zone of raw counts against a reference field in the despun frame.

    Parameters
    ----------
    t_s : array_like (n,)
        Sample times, seconds (repaired, increasing).
    counts : array_like (n, 3)
        Raw sensor readings.
    b_despun_nT : array_like (n, 3)
        Reference field (IGRF) in the despun frame (Z = spin axis) at the samples.
    skip_s : float
        Seconds at the start of the zone left out of the fit (instrument turn-on
        transient: about 1 s of up to 2000 nT error in the ELFIN data).
    offset_degree, axis_degree : int
        Polynomial degrees of the offset drift and of the spin-axis row (0, 0: plain
        12-parameter model).
    phase_knot_s : float or None
        Knot spacing of the spline phase correction; None for a polynomial phase only.
    phase_degree : int
        Without knots, the degree of the whole spin phase in time (2: a spin rate that
        changes linearly; 1: a constant spin rate, so that a spin-plane natural field
        cannot turn the phase within the pass).
    n_iter : int
        Alternations of the calibration and phase steps.
    fit_attitude : bool
        Also fit a constant tilt of the attitude file's spin axis (two angles).
    exclude : array_like of bool, optional
        Samples never used (e.g. flagged by
        :func:`~magcal.missions.elfin.timing.check_timing`); they stay in the output.
    phase : array_like (n,), optional
        Hold the spin phase at this solution (rad) and fit only the linear calibration:
        the injection tests' reference run (:mod:`magcal.missions.elfin.injection`),
        where a phase fitted against the model cannot absorb an injected field.
    fit_exclude : array_like of bool, optional
        Samples left out of the fit but kept in the output (``used`` stays 1): e.g.
        intervals with a natural field the model lacks, so that the fit cannot absorb it.
    handedness : {1, -1, 0}
        Sign that the coupling's determinant must have: 1, a right-handed sensor triad
        (default); 0, whichever spin sense fits better. The two senses of the counts'
        phase give mirror solutions (the coupling reflected in the spin plane, the phase
        reversed) that fit a model field turning slowly in the spin plane almost
        equally well (2022-01-12: within 0.2-19 nT of each other, the mirror better in 8
        of 12 zones with a quadratic phase); the mirror flips the sign of every field
        across B in the spin plane, a natural one included, so the instrument's
        handedness decides, not the fit.
    axis_prior : array_like (3,), optional
        A spin-axis row of the coupling (nT per count) to draw this zone's towards,
        with ``axis_prior_weight`` (nT^2 per (nT per 10^6 counts)^2; 0: none). The row's
        gain along the spin axis is set only by how much the spin-axis field changes
        over the pass; where that is small the tilt terms and the offset can rebuild
        it, and a natural field along the spin axis is taken as a gain change
        (:func:`calibrate_elfin`, ``axis_prior_weight``).
    level_step_rows : array_like of bool, optional
        Rows of intervals (left out of the fit) across which the spin-axis field's
        level may change: a step after each run, fitted in the spin-axis row and left
        in the field (:func:`~magcal.missions.elfin.levels.step_columns`;
        ``ElfinSettings.level_steps``).
    Returns
    -------
    _ZoneFit
        ``b_despun`` (calibrated, all samples), ``phase``, ``used`` mask and the
        :class:`ZoneCalibration` summary.
    """
    t = np.asarray(t_s, dtype=float)
    c = np.asarray(counts, dtype=float)
    ref = np.asarray(b_despun_nT, dtype=float)
    used = (t >= t[0] + skip_s) & np.all(np.isfinite(c), axis=1) & np.all(np.isfinite(ref), axis=1)
    if exclude is not None:
        used &= ~np.asarray(exclude, bool)
    out_used = used.copy()
    if fit_exclude is not None:
        used &= ~np.asarray(fit_exclude, bool)
    if used.sum() < MIN_USABLE:
        n_bad = 0 if exclude is None else int(np.sum(exclude))
        raise InputError(f"zone {times_iso[0]}: only {int(used.sum())} usable samples of "
                         f"{t.size} ({n_bad} flagged: timing or clipped counts; "
                         f"{int(np.sum(~np.all(np.isfinite(c), axis=1)))} fill)")
    c_mean = c[used].mean(axis=0)
    x = (c - c_mean) / _SCALE
    span = t[used][-1] - t[used][0]
    T = 2.0 * (t - t[used][0]) / span - 1.0
    # the rough phase comes from the counts alone (no model), so it is taken on every
    # usable sample, the fit-excluded ones too: unwrapping across a minute left out of
    # the fit can slip whole turns, and a natural field turns it by at most B_nat / |B|
    raw_phase, _ = phase_from_counts(t[out_used], c[out_used])
    raw = np.interp(t, t[out_used], raw_phase)
    knots = None if phase_knot_s is None else float(phase_knot_s)

    held = phase is not None

    def fit_senses(steps):
        best, tried, dets = None, [], []
        for sense in ((1.0,) if held else (1.0, -1.0)):
            if held:
                base = np.asarray(phase, dtype=float)
                coef = np.polyfit(t[used] - t[0], base[used], 2)
            else:
                coef = np.polyfit(t[used] - t[0], sense * raw[used], 2)
                base = np.polyval(coef, t - t[0])
            out = _iterate(t, x, T, ref, base, used, offset_degree=offset_degree,
                           axis_degree=axis_degree, knots=knots, n_iter=n_iter,
                           fit_attitude=fit_attitude, hold=held, phase_degree=phase_degree,
                           axis_prior=axis_prior, axis_prior_weight=axis_prior_weight,
                           steps=steps)
            fitted = out[4]
            rms = float(np.sqrt(np.mean((fitted - ref)[used] ** 2)))
            tried.append(rms)
            wx, wy, wz = out[0]
            dets.append(int(np.sign(np.linalg.det(np.array([wx[:3], wy[:3], wz[:3]])))))
            allowed = held or handedness == 0 or dets[-1] == handedness
            if allowed and (best is None or rms < best[0]):
                best = (rms, sense, coef, base, out, fitted)
        if best is None:
            raise InputError(f"zone {times_iso[0]}: no spin sense gives a coupling of "
                             f"determinant sign {handedness:+d} (signs {dets})")
        return best, tried, dets

    steps = None if level_step_rows is None else step_columns(level_step_rows)
    n_steps = 0 if steps is None else steps.shape[1]
    best, tried, dets = fit_senses(steps if n_steps else None)
    _, sense, coef, base, (w, b_body, phase, corr, _), fitted = best
    const = _iterate(t, x, T, ref, base, used, offset_degree=0, axis_degree=0, knots=None,
                     n_iter=n_iter, fit_attitude=False)
    const_fit = const[4]

    # physical parameters at mid-zone (T = 0) and their drift
    def body_params(Tv):
        wx, wy, wz = w
        po = np.array([Tv ** d for d in range(offset_degree + 1)])
        tilt = np.array([Tv ** d for d in range(1, axis_degree + 1)])
        a_xy = np.array([wx[:3], wy[:3]]) / _SCALE
        o_xy = np.array([wx[3:] @ po, wy[3:] @ po])
        u, v = wz[4:4 + axis_degree] @ tilt, wz[4 + axis_degree:4 + 2 * axis_degree] @ tilt
        a3 = wz[:3] / _SCALE + u * a_xy[0] + v * a_xy[1]
        o3 = wz[3] + u * o_xy[0] + v * o_xy[1]
        amat = np.vstack([a_xy, a3])
        return amat, np.r_[o_xy, o3] - amat @ c_mean     # B = amat @ counts + o_nT

    a_mid, o_mid = body_params(0.0)
    a_beg, o_beg = body_params(-1.0)
    a_end, o_end = body_params(1.0)
    axis_beg = np.linalg.solve(a_mid.T, a_beg[2])
    axis_end = np.linalg.solve(a_mid.T, a_end[2])
    turn = np.degrees(np.arccos(np.clip(axis_beg @ axis_end / np.linalg.norm(axis_beg)
                                        / np.linalg.norm(axis_end), -1.0, 1.0)))
    resid = (fitted - ref)[used]
    scal = (np.linalg.norm(fitted, axis=1) - np.linalg.norm(ref, axis=1))[used]
    cres = (const_fit - ref)[used]
    cscal = (np.linalg.norm(const_fit, axis=1) - np.linalg.norm(ref, axis=1))[used]
    duration = t[used][-1] - t[used][0]
    total = phase[used][-1] - phase[used][0]
    rate0 = np.polyval(np.polyder(coef), 0.0)
    rate1 = np.polyval(np.polyder(coef), t[-1] - t[0])
    tc = t[used] - t[used].mean()
    lin = np.polyfit(tc, corr[used], 1)
    wander = float(np.std(corr[used] - np.polyval(lin, tc)))
    period = float(TWO_PI * duration / abs(total))
    ang_resid = wrap(np.arctan2(spin(ref, phase)[:, 1], spin(ref, phase)[:, 0])
                     - np.arctan2(b_body[:, 1], b_body[:, 0]))
    summary = ZoneCalibration(
        start=times_iso[0], end=times_iso[1], n_samples=int(t.size), n_used=int(used.sum()),
        coupling=a_mid, gains_nT_per_count=np.linalg.norm(a_mid, axis=0),
        offsets_counts=-np.linalg.solve(a_mid, o_mid), offsets_nT=o_mid,
        offset_drift_nT=o_end - o_beg, spin_axis_turn_deg=float(turn),
        spin_period_s=period,
        spin_period_change_s=float(TWO_PI / abs(rate1) - TWO_PI / abs(rate0)),
        phase_wander_rad=wander,
        phase_jumps_rad=_phase_jumps(t, ang_resid, used, period),
        rms_vector_nT=np.sqrt(np.mean(resid ** 2, axis=0)),
        rms_scalar_nT=float(np.sqrt(np.mean(scal ** 2))),
        rms_vector_constant_nT=np.sqrt(np.mean(cres ** 2, axis=0)),
        rms_scalar_constant_nT=float(np.sqrt(np.mean(cscal ** 2))),
        spin_sense=int(np.sign(total)), det_coupling_sign=int(np.sign(np.linalg.det(a_mid))),
        attitude_correction_deg=np.degrees(w[2][-2:]), rms_by_sense_nT=tried,
        det_sign_by_sense=dets,
        timestamp_anomalies=list(timestamp_anomalies),
        n_timing_repaired=sum(a["n_samples"] for a in timestamp_anomalies
                              if a["kind"] == "unpaired_repaired"),
        n_timing_flagged=int(np.sum(exclude)) if exclude is not None else 0,
        n_level_steps=n_steps)
    return _ZoneFit(b_despun=fitted, phase=phase, used=out_used, summary=summary,
                    fit=used)


#: Standard deviation (nT) of the spin-axis field over a pass above which a zone's own
#: spin-axis row is trusted (:func:`axis_row_prior`; 2022-01-12: zones 0, 1, 2, 11).
AXIS_PRIOR_MIN_STD_NT = 500.0


def axis_row_prior(fits, axis_fields) -> dict:
    """The day's spin-axis row: the median over the zones whose spin-axis field changes.

    The spin axis is fixed in the body, so the coupling's spin-axis row (nT per count)
    is one for the day, but each zone sees its gain along the spin axis only through
    how much the spin-axis field changes over the pass (2022-01-12: 74-992 nT std; the
    rows spread over a factor 1.8 and zone 3's, at 74 nT, is a quarter of the others).

    Parameters
    ----------
    fits : sequence of _ZoneFit
        The zones fitted on their own.
    axis_fields : sequence of ndarray
        Each zone's reference spin-axis component (nT) on its samples.

    Returns
    -------
    dict
        ``row_nT_per_count`` (3,), ``from_zones`` (positions in ``fits`` whose
        spin-axis field's standard deviation on the used samples is at least
        :data:`AXIS_PRIOR_MIN_STD_NT`, or the one with the largest) and
        ``axis_field_std_nT`` per zone.
    """
    stds = [float(np.std(np.asarray(bz)[f.used])) for f, bz in zip(fits, axis_fields)]
    chosen = [i for i, v in enumerate(stds) if v >= AXIS_PRIOR_MIN_STD_NT] or \
        [int(np.argmax(stds))]
    rows = np.array([fits[i].summary.coupling[2] for i in chosen])
    return {"row_nT_per_count": np.median(rows, axis=0), "from_zones": chosen,
            "axis_field_std_nT": stds}


def igrf_gei(times, pos_gei_km) -> np.ndarray:
    """IGRF (IRBEM through spacepy) in GEI nT at GEI positions in km.

    Examples
    --------
    >>> t = np.array(["2022-01-12T15:46:00"], dtype="datetime64[ns]")
    >>> b = igrf_gei(t, [[-2431.1, 3822.9, 5059.7]])
    >>> 30000 < float(np.linalg.norm(b)) < 60000
    True
    """
    from magcal.frames.geo import EARTH_RADIUS_KM, convert_vectors
    from magcal.models.irbem import field_geo

    pos = np.atleast_2d(np.asarray(pos_gei_km, dtype=float))
    pos_geo = convert_vectors(pos, times, "GEI", "GEO") / EARTH_RADIUS_KM
    return convert_vectors(field_geo(times, pos_geo, model="IGRF"), times, "GEO", "GEI")


#: State columns :func:`with_igrf` adds: IGRF in GEI (nT) at the state record.
IGRF_COLUMNS = ["igrf_gei_x", "igrf_gei_y", "igrf_gei_z"]


def with_igrf(state: pd.DataFrame, fgs: pd.DataFrame, *, min_gap_s: float = 60.0,
              margin_s: float = 10.0) -> pd.DataFrame:
    """``state`` with IGRF in GEI (:data:`IGRF_COLUMNS`) on the records within
    ``margin_s`` of a science zone of ``fgs`` (NaN elsewhere).

    The reference depends on the orbit only, not on the counts or the fit settings, but
    a day's calibration fits the same zones 8 or more times (detection, level steps,
    bridge trials), and IRBEM's coordinate transforms made the reference 13 % of that
    time; :func:`calibrate_elfin` reads these columns where they are finite instead of
    evaluating the model again. A state frame that has them for these zones is
    returned as it is.

    Examples
    --------
    >>> idx = pd.date_range("2022-01-12T15:46:00", periods=3, freq="1s", tz="UTC")
    >>> state = pd.DataFrame({"pos_gei_x": -2431.1, "pos_gei_y": 3822.9,
    ...                       "pos_gei_z": 5059.7}, index=idx)
    >>> fgs = pd.DataFrame(index=idx[1:2])
    >>> out = with_igrf(state, fgs, margin_s=0.5)
    >>> np.isfinite(out["igrf_gei_x"]).tolist()
    [False, True, False]
    """
    t_fgs = fgs.index.as_unit("ns").asi8
    t_all = (t_fgs - t_fgs[0]) / 1e9
    ts = (state.index.as_unit("ns").asi8 - t_fgs[0]) / 1e9
    near = np.zeros(len(state), bool)
    for a, b in split_zones(t_all, min_gap_s):
        near |= (ts >= t_all[a] - margin_s) & (ts <= t_all[b - 1] + margin_s)
    if set(IGRF_COLUMNS) <= set(state.columns) and \
            np.isfinite(state[IGRF_COLUMNS].to_numpy()[near]).all():
        return state
    out = state.copy()
    ref = np.full((len(state), 3), np.nan)
    if near.any():
        pos = state[["pos_gei_x", "pos_gei_y", "pos_gei_z"]].to_numpy()[near]
        ref[near] = igrf_gei(state.index[near], pos)
    out[IGRF_COLUMNS] = ref
    return out


#: Fewest usable samples (after fill, timing and clipping flags) a zone is fitted with.
MIN_USABLE = 200


class ZonesNotCalibratedError(InputError):
    """Zones of the rows given could not be calibrated (``skipped``: each zone's
    :class:`SkippedZone`, with the reason and its rows among those calibrated).

    :func:`calibrate_elfin` raises it when no zone could be;
    :func:`~magcal.missions.elfin.pipeline.calibrate_elfin_day` when a zone the plain
    fit calibrates fails once the rows given to be left out of the fits are left out,
    which the detection of disturbed intervals catches to fit that zone without its
    flags (:func:`magcal.missions.elfin.disturbed.calibrate_detected`).
    """

    def __init__(self, message: str, *, skipped=()):
        super().__init__(message)
        self.skipped = list(skipped)


@dataclass(frozen=True)
class SkippedZone:
    """A science zone :func:`calibrate_elfin` could not calibrate, and why.

    Attributes
    ----------
    zone : int
        Zone number (0-based, as in ``field["zone"]``).
    start, end : str
        First and last sample (UTC, ISO).
    n_samples : int
        Its FGS rows (kept in the delivered series with ``used = 0``).
    reason : str
        The error the zone's fit raised.
    rows : tuple of int
        Its rows ``[first, last + 1)`` among the rows calibrated.
    times : DatetimeIndex
        The rows' times (not in :meth:`as_dict`).
    """

    zone: int
    start: str
    end: str
    n_samples: int
    reason: str
    rows: tuple = (0, 0)
    times: pd.DatetimeIndex = field(repr=False, default=None)

    def as_dict(self) -> dict:
        """Plain dictionary without the times."""
        return {k: getattr(self, k) for k in ("zone", "start", "end", "n_samples", "reason",
                                              "rows")}


@dataclass(frozen=True)
class ElfinCalibration:
    """Result of :func:`calibrate_elfin`: per-zone table and the calibrated series.

    ``field`` is a DataFrame (UTC index ``time``) with ``zone``, ``used`` (0/1),
    calibrated ``bx_gei, by_gei, bz_gei`` and ``bx_despun ... bz_despun``, the IGRF
    ``igrf_x_gei ...`` and ``igrf_x_despun ...``, the spin ``phase`` (rad) and the
    attitude file's spin axis ``spin_axis_gei_x ..`` (despun Z, defines the despun frame)
    and the raw counts ``b1, b2, b3`` (for fits that start again from the counts, e.g.
    :func:`magcal.missions.elfin.joint.calibrate_joint`).

    ``skipped`` holds the zones that could not be calibrated (:class:`SkippedZone`: too
    few usable samples, no attitude); their rows are not in ``field``, and
    :meth:`skipped_rows` gives them back with ``used = 0`` for the delivered series.
    """

    zones: tuple
    field: pd.DataFrame
    parameters: dict
    provenance: dict = field(default_factory=dict)
    skipped: tuple = ()

    @property
    def zone_numbers(self) -> list[int]:
        """The zone numbers of ``field`` in row order (``zone_numbers`` of
        :func:`calibrate_elfin`; not positions once zones are skipped)."""
        return list(dict.fromkeys(self.field["zone"].tolist()))

    def kept_rows(self, n_rows: int) -> np.ndarray:
        """Rows (of the ``n_rows`` calibrated) that are in ``field``: not in a skipped zone."""
        keep = np.ones(n_rows, bool)
        for z in self.skipped:
            keep[z.rows[0]:z.rows[1]] = False
        return keep

    def skipped_rows(self, columns) -> pd.DataFrame:
        """Rows of the skipped zones: ``zone`` set, ``used`` 0, every other column NaN."""
        if not self.skipped:
            return pd.DataFrame(columns=list(columns), dtype=float)
        idx = pd.DatetimeIndex(np.concatenate([z.times.asi8 for z in self.skipped]),
                               tz=self.skipped[0].times.tz, name="time")
        out = pd.DataFrame(np.nan, index=idx, columns=list(columns))
        out["zone"] = np.concatenate([np.full(len(z.times), z.zone) for z in self.skipped])
        out["used"] = 0.0
        return out

    def table(self) -> pd.DataFrame:
        """One row per zone: residuals, gains, offsets, spin period, phase jumps."""
        rows = []
        for z in self.zones:
            rows.append({
                "start": z.start, "n_used": z.n_used,
                "rms_scalar_nT": z.rms_scalar_nT,
                **{f"rms_{c}_nT": v for c, v in zip("XYZ", z.rms_vector_nT)},
                "rms_vector_nT": float(np.sqrt(np.mean(z.rms_vector_nT ** 2))),
                "rms_scalar_constant_nT": z.rms_scalar_constant_nT,
                "rms_vector_constant_nT": float(np.sqrt(np.mean(z.rms_vector_constant_nT ** 2))),
                **{f"gain{j + 1}_nT_per_count": g for j, g in enumerate(z.gains_nT_per_count)},
                **{f"O{j + 1}_counts": o for j, o in enumerate(z.offsets_counts)},
                **{f"o{c}_nT": o for c, o in zip("xyz", z.offsets_nT)},
                "spin_period_s": z.spin_period_s, "spin_axis_turn_deg": z.spin_axis_turn_deg,
                "phase_wander_rad": z.phase_wander_rad,
                "max_phase_jump_rad": max([abs(j) for j in z.phase_jumps_rad], default=0.0),
                "n_timestamp_jumps": sum(a["kind"] in ("paired", "unpaired")
                                         for a in z.timestamp_anomalies),
                "n_timing_repaired": z.n_timing_repaired,
                "n_timing_flagged": z.n_timing_flagged,
                "n_clipped": z.n_clipped,
                "n_level_steps": z.n_level_steps,
            })
        return pd.DataFrame(rows)

    def to_json(self) -> dict:
        """JSON payload: parameters, per-zone results, summary, credit, provenance."""
        tab = self.table()
        gains = tab[[f"gain{j}_nT_per_count" for j in (1, 2, 3)]].to_numpy()
        return product_dict({
            "credit": CREDIT,
            "model": "B_body = C(T) (b - O(T)); B_despun = despin(B_body, p); target IGRF "
                     "in the despun frame (Z = attitude spin axis)",
            "parameters": self.parameters,
            "zones": [z.as_dict() for z in self.zones],
            "skipped_zones": [z.as_dict() for z in self.skipped],
            "summary": {
                "n_zones": len(self.zones),
                "n_zones_skipped": len(self.skipped),
                "rms_vector_nT_median": float(tab["rms_vector_nT"].median()),
                "rms_scalar_nT_median": float(tab["rms_scalar_nT"].median()),
                "rms_vector_constant_nT_median": float(tab["rms_vector_constant_nT"].median()),
                "gain_mean_nT_per_count": gains.mean(axis=0),
                "gain_spread_percent": 100 * gains.std(axis=0) / gains.mean(axis=0),
                "spin_period_s": [float(tab["spin_period_s"].min()),
                                  float(tab["spin_period_s"].max())],
                "n_timing_repaired": int(tab["n_timing_repaired"].sum()),
                "n_timing_flagged": int(tab["n_timing_flagged"].sum()),
                "n_clipped": int(tab["n_clipped"].sum()),
            },
            "provenance": self.provenance,
        })


def calibrate_elfin(fgs: pd.DataFrame, state: pd.DataFrame, *, min_gap_s: float = 60.0,
                    time_shift_s: float = 0.0, repair_times: bool = True,
                    check_times: bool = True, check_clipping: bool = True,
                    zones=None, zone_numbers=None, provenance=None,
                    hold_phase=None, fit_exclude=None, axis_prior_weight: float = 0.0,
                    level_step_rows=None, **fit_kw) -> ElfinCalibration:
    """Calibrate ELFIN FGS counts zone by zone against IGRF at the spacecraft.

    Parameters
    ----------
    fgs : DataFrame
        From :func:`magcal.missions.elfin.files.read_elfin_fgs` (``b1, b2, b3`` counts, UTC index).
    state : DataFrame
        From :func:`magcal.missions.elfin.files.read_elfin_state` (GEI position km, spin axis).
    min_gap_s : float
        Gaps longer than this separate science zones.
    time_shift_s : float
        The reference is evaluated at ``t + time_shift_s`` (to scan for a timing
        offset between the counts and the orbit).
    repair_times : bool
        Undo paired time-stamp jumps (:func:`~magcal.missions.elfin.phase.repair_timestamps`).
    check_times : bool
        Then check the stamps against the spin in the counts
        (:func:`~magcal.missions.elfin.timing.check_timing`): repair blocks next to
        unpaired jumps, mark what still does not fit ``used = 0`` (counted in
        ``n_timing_flagged``).
    check_clipping : bool
        Mark the samples where an axis reads its clipped extreme ``used = 0``
        (:func:`~magcal.missions.elfin.clipping.clipped_samples`, counted in
        ``n_clipped``); they are also kept out of the timing check's spin model.
    zones : sequence of int, optional
        Only these zones (0-based positions among the zones of ``fgs``).
    zone_numbers : sequence of int, optional
        The number each zone of ``fgs`` carries in ``field["zone"]`` (default its
        position): rows of a day with zones taken out keep their numbers.
    hold_phase : array_like (len(fgs),), optional
        Spin phase (rad) per FGS row, held instead of fitted (``phase`` of
        :func:`fit_zone`); e.g. the ``phase`` column of an earlier calibration of the
        same rows.
    fit_exclude : array_like (len(fgs),) of bool, optional
        Rows left out of every fit but kept in the product (``fit_exclude`` of
        :func:`fit_zone`); the field's ``fit`` column (0/1) carries it to the later steps.
    level_step_rows : array_like (len(fgs),) of bool, optional
        Rows of left-out intervals across which the spin-axis level may change
        (``level_step_rows`` of :func:`fit_zone`); the field's ``level_step`` column
        (0/1) carries them to the vector step's tilt.
    axis_prior_weight : float
        If positive, the zones whose spin-axis field changes little over the pass are
        fitted again with their spin-axis row drawn towards the day's
        (:func:`axis_row_prior`; ``axis_prior`` of :func:`fit_zone`); recorded as
        ``parameters["axis_prior"]``. 0: every zone on its own (default).
    **fit_kw
        Passed to :func:`fit_zone`.

    Returns
    -------
    ElfinCalibration
        A zone that cannot be calibrated (fewer than 200 usable samples after fill,
        timing and clipping flags; no attitude; no right-handed solution) is left out
        of ``field`` and listed in ``skipped`` with the reason: one bad pass does not
        stop the day.

    Raises
    ------
    InputError
        No ``b1, b2, b3`` columns, a ``hold_phase`` of the wrong length, or no zone that
        can be calibrated.
    """
    from scipy.interpolate import CubicSpline

    if not {"b1", "b2", "b3"} <= set(fgs.columns):
        raise InputError("FGS frame needs columns b1, b2, b3")
    fgs, state = ns_index(fgs, "FGS frame"), ns_index(state, "state frame")
    if hold_phase is not None and len(hold_phase) != len(fgs):
        raise InputError(f"hold_phase has {len(hold_phase)} values for {len(fgs)} FGS rows")
    steps = np.zeros(len(fgs), bool) if level_step_rows is None \
        else np.asarray(level_step_rows, bool)
    if steps.shape != (len(fgs),):
        raise InputError(f"level_step_rows has {steps.size} values for {len(fgs)} FGS rows")
    t_all = (fgs.index.asi8 - fgs.index.asi8[0]) / 1e9
    t_ref = fgs.index[0]
    ts = (state.index.asi8 - fgs.index.asi8[0]) / 1e9
    pos = state[["pos_gei_x", "pos_gei_y", "pos_gei_z"]].to_numpy()
    axis = state[["spin_axis_gei_x", "spin_axis_gei_y", "spin_axis_gei_z"]].to_numpy()
    state_igrf = state[IGRF_COLUMNS].to_numpy() if set(IGRF_COLUMNS) <= set(state.columns) \
        else np.full((len(state), 3), np.nan)
    ranges = split_zones(t_all, min_gap_s)
    chosen = range(len(ranges)) if zones is None else zones
    if zone_numbers is not None and len(zone_numbers) != len(ranges):
        raise InputError(f"zone_numbers has {len(zone_numbers)} numbers for {len(ranges)} "
                         "zones")
    label = list(range(len(ranges))) if zone_numbers is None else list(zone_numbers)
    inputs, skipped = [], []

    def skip_zone(k, a, b, reason):
        return SkippedZone(zone=int(k), start=str(fgs.index[a].tz_convert(None)),
                           end=str(fgs.index[b - 1].tz_convert(None)), n_samples=b - a,
                           reason=reason, rows=(int(a), int(b)), times=fgs.index[a:b])
    all_counts = fgs[["b1", "b2", "b3"]].to_numpy()
    for k in chosen:
        a, b = ranges[k]
        t = t_all[a:b]
        counts = all_counts[a:b]
        anomalies, bad = [], None
        clipped = clipped_samples(counts) if check_clipping else np.zeros(b - a, bool)
        n_good = int(np.sum(np.all(np.isfinite(counts), axis=1) & ~clipped))
        if n_good < MIN_USABLE:
            skipped.append(skip_zone(label[k], a, b, f"zone {label[k]}: {n_good} samples "
                                     f"of {b - a} finite and not clipped (fewer than "
                                     f"{MIN_USABLE})"))
            continue
        if repair_times:
            t, anomalies = repair_timestamps(t)
        if check_times:
            check = check_timing(t, counts, anomalies,
                                 mask=(t >= t[0] + fit_kw.get("skip_s", 2.0)) & ~clipped)
            t, bad = check.t_s, check.bad & ~clipped
            anomalies = anomalies + check.events
        n_timing = 0 if bad is None else int(bad.sum())
        if clipped.any():
            bad = clipped if bad is None else bad | clipped
        sel = (ts >= t[0] - 5) & (ts <= t[-1] + 5) & np.all(np.isfinite(axis), axis=1)
        if sel.sum() < 10:
            skipped.append(skip_zone(label[k], a, b, "no orbit/attitude records for zone "
                                                       f"{label[k]} ({fgs.index[a]})"))
            continue
        b_gei_ref = state_igrf[sel] if np.isfinite(state_igrf[sel]).all() \
            else igrf_gei(state.index[sel], pos[sel])
        tq = t + time_shift_s
        ref_gei = CubicSpline(ts[sel], b_gei_ref)(tq)
        ax = np.column_stack([np.interp(tq, ts[sel], axis[sel, j]) for j in range(3)])
        basis = despun_basis(ax)
        inputs.append({"k": k, "a": a, "b": b, "t": t, "anomalies": anomalies, "bad": bad,
                       "n_timing": n_timing, "n_clipped": int(clipped.sum()),
                       "ref_gei": ref_gei, "ax": ax, "basis": basis,
                       "ref": np.einsum("nij,nj->ni", basis, ref_gei)})

    def fit_one(z, **kw):
        a, b = z["a"], z["b"]
        iso = (str(fgs.index[a].tz_convert(None)), str(fgs.index[b - 1].tz_convert(None)))
        held = None if hold_phase is None else np.asarray(hold_phase, float)[a:b]
        skip = None if fit_exclude is None else np.asarray(fit_exclude, bool)[a:b]
        fit = fit_zone(z["t"], all_counts[a:b], z["ref"], times_iso=iso,
                       timestamp_anomalies=z["anomalies"], exclude=z["bad"], phase=held,
                       fit_exclude=skip, level_step_rows=steps[a:b], **fit_kw, **kw)
        # fit_zone counts every excluded sample as timing-flagged; split the two causes
        return replace(fit, summary=replace(fit.summary, n_timing_flagged=z["n_timing"],
                                            n_clipped=z["n_clipped"]))

    fits, fitted = [], []
    for z in inputs:
        try:
            fits.append(fit_one(z))
            fitted.append(z)
        except InputError as err:          # this zone only: the day goes on without it
            skipped.append(skip_zone(label[z["k"]], z["a"], z["b"], str(err)))
    inputs = fitted
    if not inputs:
        raise ZonesNotCalibratedError("no science zone could be calibrated: " + "; ".join(
            z.reason for z in skipped), skipped=skipped)
    skipped.sort(key=lambda z: z.zone)
    prior = None
    if axis_prior_weight > 0:
        prior = axis_row_prior(fits, [z["ref"][:, 2] for z in inputs])
        fits = [fit_one(z, axis_prior=prior["row_nT_per_count"],
                        axis_prior_weight=axis_prior_weight)
                if i not in prior["from_zones"] else f
                for i, (z, f) in enumerate(zip(inputs, fits))]
    results, frames = [], []
    for z, fit in zip(inputs, fits):
        k, a, b, t, ax = z["k"], z["a"], z["b"], z["t"], z["ax"]
        results.append(fit.summary)
        cal_gei = np.einsum("nji,nj->ni", z["basis"], fit.b_despun)
        idx = t_ref + pd.to_timedelta(np.round(t * 1e9).astype("int64"), unit="ns")
        data = {"zone": np.full(t.size, label[k]), "used": fit.used.astype(int),
                "fit": fit.fit.astype(int), "level_step": steps[a:b].astype(int)}
        for name, arr in (("{}_gei", cal_gei), ("{}_despun", fit.b_despun)):
            for j, c in enumerate("xyz"):
                data["b" + name.format(c)] = arr[:, j]
        for name, arr in (("igrf_{}_gei", z["ref_gei"]), ("igrf_{}_despun", z["ref"])):
            for j, c in enumerate("xyz"):
                data[name.format(c)] = arr[:, j]
        data["phase"] = fit.phase
        for j in range(3):
            data[f"b{j + 1}"] = fgs[f"b{j + 1}"].to_numpy()[a:b]
        for j, c in enumerate("xyz"):
            data[f"spin_axis_gei_{c}"] = ax[:, j]
        frames.append(pd.DataFrame(data, index=pd.DatetimeIndex(idx, name="time")))
    params = {"min_gap_s": min_gap_s, "time_shift_s": time_shift_s,
              "repair_times": repair_times, "check_times": check_times, **dict(fit_kw)}
    if prior is not None:
        params["axis_prior"] = {**prior, "weight": axis_prior_weight,
                                "zones": [label[inputs[i]["k"]] for i in prior["from_zones"]]}
    return ElfinCalibration(zones=tuple(results), field=pd.concat(frames),
                            parameters=params, provenance=provenance or {},
                            skipped=tuple(skipped))
