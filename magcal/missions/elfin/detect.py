"""Disturbed intervals of an ELFIN day located from the counts alone (delivered).

Every time-varying step of the calibration is fitted against IGRF and takes part of a
natural field that IGRF lacks; left out of every fit (``fit_exclude`` of
:func:`~magcal.missions.elfin.pipeline.calibrate_elfin_day`), a disturbed interval comes
back whole. This module finds such intervals without an outside source
(:func:`locate_disturbed`); :func:`magcal.missions.elfin.disturbed.calibrate_detected`
calibrates the day without them (what ``ElfinSettings.detect_disturbed`` runs):

1. the day is calibrated with a *stiff* variant of the settings (the gain drift tied
   to the reference-free 2x-spin harmonic, ``gain_drift_2x``, so that a field along B
   is not turned into a gain cubic);
2. per zone and per component of the residual against the model (despun ``x, y``, the
   spin axis ``z`` and ``|B|``), averaged over one spin, two robust baselines in time
   are taken as the instrument's slow part: a spline with 90 s knots and a cubic
   (Tukey biweights from a least-absolute-deviation start, :func:`robust_baseline`);
   where that calibration keeps a level step of the spin-axis field (a current sheet,
   :mod:`magcal.missions.elfin.levels`) and a step lowers the robust sigma by
   :data:`LEVEL_BASELINE_GAIN`, the spin-axis baselines have it; where a few
   excursions together bend the vector components' spline so far that its robust
   sigma is the excursions' and not the noise's, they are left out of its fit
   (:func:`peeled_baseline`), and what that baseline flags beyond the plain one's
   flags is added;
3. what departs from either by more than ``threshold`` robust sigmas (and ``min_nT``)
   is flagged, grown while it stays above ``extend`` sigmas, padded by ``pad_s``, unless
   it comes within ``edge_s`` of a zone end, where the calibration would be
   extrapolated over it (:func:`flag_excursions`); ``|B|`` and the vector components
   are flagged apart;
4. the day is calibrated with the ``|B|`` flags out of every fit and the vector flags
   out of the slow vector fits (a field across B leaves ``|B|`` alone to first order;
   the vector step's body-fixed harmonics, spin tones in the despun frame, are fitted
   on every sample), and with no flags; a flagged run where leaving it out changed the
   product more in spin tones (calibration errors the fits could not bridge) than in
   its slow field (a natural field kept) is put back and the day calibrated again
   (:func:`magcal.missions.elfin.disturbed.bridge_check`).

What it cannot do is tell a slow natural field from the instrument's slow drift
(anything the baselines make is the instrument's to it): a 100 nT pulse along B of
90 s FWHM spans half a zone and 71 % of its energy is a cubic in time, the gain drift's
own shape, and a current sheet lasting to the zone's end is, past its rise, a level
that the zone's spin-axis offset and tilt take. It flags real natural fields on a
"clean" day too (on 2022-01-12 east-west excursions of 100-200 nT over 40-90 s in zones
5-8), which is what it is for.

Measured on 2022-01-12, zones 1, 4, 7, 10 (``workflows/elfin_preservation.py``;
defaults of :class:`DetectSettings`): the 200 nT 40 s pulses across B are kept (107 %
of the energy east-west, 97 % along-track, distortion 13 and 15 %; 65 % and 26 %
without detection); a pulse along B keeps 8 % and a current sheet 3 %. The clean
residual is unchanged but for the kept natural fields (7.20 / 5.14 / 15.09 nT scalar /
fast / vector, zone medians; 7.20 / 5.16 / 14.83 without detection); the clean zones are
17, 0, 18 and 0 % flagged.
The whole day: 103 % and 91 % of the pulses kept (distortion 11 and 13 %), 0-36 % of
each zone left out of the slow fits, no run put back by the bridge check, 6.8 / 5.2 /
16.1 nT (14.9 without detection: the natural fields kept). A detector that flagged
exactly the injected signal and nothing else would leave a distortion of 15-16 %:
leaving 70 s out of the slow fits moves the calibration elsewhere by that much
(``workflows/elfin_preservation.py --mask-injected-only 0.05``).

Data: ELFIN SOC (PI V. Angelopoulos, UCLA), "Open Data for Scientific Use".
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import pandas as pd

from magcal.lstsq import lstsq
from magcal.missions.elfin.levels import step_columns
from magcal.missions.elfin.timing import true_runs
from magcal.stats import normal_mad

#: Component names of :func:`zone_residuals` (despun frame; ``z`` the spin axis).
COMPONENTS = ("x", "y", "z", "scalar")


@dataclass(frozen=True)
class DetectSettings:
    """Parameters of the disturbed-interval detector.

    Attributes
    ----------
    threshold : float
        Robust sigmas (1.4826 MAD of the departure from the baseline, per zone and
        component) above which a spin-averaged sample starts a flagged interval.
    extend : float
        Robust sigmas above which a flagged interval grows on either side.
    min_nT : float
        Smallest departure (nT) that flags, whatever the robust sigma (a quiet zone's
        sigma of 2 nT would otherwise flag every wiggle).
    min_s : float
        Shortest interval (s) above ``threshold`` kept (spikes and the time-stamp
        repairs are shorter).
    pad_s : float
        Seconds added on each side of a flagged interval.
    smooth_s : float
        Running mean (s) applied to the residual first (about one spin).
    baseline_degree : int
        Degree of the robust baseline in time over the zone.
    baseline_knot_s : float
        If positive, the baseline is a cubic B-spline with knots this many seconds
        apart instead (it follows the zone edges; it also follows a field slower than
        about the knot spacing).
    also_polynomial : bool
        With ``baseline_knot_s``, also flag the departures from the robust polynomial
        of ``baseline_degree``: the spline follows part of a 40 s pulse (on 2022-01-12
        an east-west one in zone 7 went unflagged), the cubic cannot, while the spline
        catches what the cubic leaves at the zone edges (an along-track pulse in zone 4).
        The flags of both are joined.
    tukey_c : float
        Tukey biweight tuning constant of the baseline, in robust sigmas.
    passes : int
        Detection passes (the second works on a calibration fitted without the first
        pass's flags, where a signal the fits absorbed comes back). Default 1: a second
        pass found nothing more of the injected signals on the real day and grew zone
        10's clean flags from 10 to 32 %.
    edge_s : float
        A flagged interval that comes closer than this to the zone's first or last used
        sample is not flagged: the calibration would be extrapolated over it instead of
        bridged, and on 2022-01-12 that made spin-tone errors of 200-400 nT at the ends
        of 5 of the 12 zones (whole-day vector residual 16.4 -> 39 nT). A natural field
        at a zone end stays absorbed, as without detection.
    max_share : float
        Largest share of a zone's used samples that may be flagged: above it the
        zone's flags are dropped (a zone that is mostly disturbed cannot be calibrated
        against the model on what is left; the zone is then fitted as without
        detection).
    peel_gain : float
        Factor by which leaving the largest excursions out of a baseline's fit must
        lower its robust sigma for them to stay out (:func:`peeled_baseline`; 0
        switches peeling off). Only the vector components' 90 s spline baselines are
        peeled, only excursions away from the zone ends that leave ``|B|`` alone (a
        field across B), and only where the sigma, not ``min_nT``, sets the flagging
        level (``threshold * sigma > min_nT``). The flags about a peeled baseline add
        intervals to the plain ones (``min_island_s``) and, in the spin plane, widen
        them (:func:`_zone_flags`).
    max_peels : int
        Most excursions left out of one baseline's fit that way.
    min_island_s : float
        An interval flagged only about a peeled baseline is added if it leaves at least
        this many seconds to the plain flags: a short fitted island between two
        left-out intervals is read as the quiet level by the level steps (2022-01-12,
        zone 8 with a -200 nT along-track pulse at 0.35: the first 35 s of the real
        disturbance added, a 10 s island, a false step of -85 nT over the rest of the
        zone, distortion 17 -> 146 %).
    peel_polynomial : bool
        Also peel the cubic baseline (off: on 2022-01-12 it made the cubic's misfit of
        the clean zones' slow structure into flags, zones 2, 3, 6 and 7 going from 7,
        0, 22 and 18 % flagged to 31, 32, 42 and 35 %).
    """

    threshold: float = 8.0
    extend: float = 4.0
    min_nT: float = 30.0
    min_s: float = 5.0
    pad_s: float = 5.0
    smooth_s: float = 3.0
    baseline_degree: int = 3
    baseline_knot_s: float = 90.0
    also_polynomial: bool = True
    tukey_c: float = 4.685
    passes: int = 1
    edge_s: float = 20.0
    max_share: float = 0.6
    peel_gain: float = 2.0
    max_peels: int = 3
    peel_polynomial: bool = False
    min_island_s: float = 30.0


def robust_baseline(t_s, values, use, *, degree: int = 3, c: float = 4.685,
                    n_iter: int = 20, knot_s: float = 0.0,
                    l1_iter: int = 30, steps=None) -> tuple[np.ndarray, float]:
    """Polynomial in time fitted by Tukey-biweighted least squares, and its robust sigma.

    The biweights start from a least-absolute-deviation fit (``l1_iter`` reweighting
    passes), not from ordinary least squares: a 200 nT pulse of 40 s in a 6 min zone
    pulls the least-squares cubic so far that its departures no longer stand out and
    the biweights never reject it (zone 7 of 2022-01-12), where the L1 cubic passes
    under it.

    Parameters
    ----------
    t_s, values : array_like (n,)
        Times (s) and the series.
    use : array_like of bool (n,)
        Samples fitted.
    degree : int
        Polynomial degree (time scaled to -1..1 over ``use``).
    c : float
        Tukey constant in robust sigmas (1.4826 MAD of the departure).
    n_iter : int
        Reweighting passes.
    knot_s : float
        If positive, a cubic B-spline with knots every ``knot_s`` seconds instead of
        the polynomial.
    l1_iter : int
        Reweighting passes of the least-absolute-deviation start (0: start from
        ordinary least squares).
    steps : array_like (n, m), optional
        Further columns of the baseline (the level steps of
        :func:`~magcal.missions.elfin.levels.step_columns`): a level change that a
        polynomial or a 90 s spline cannot follow would otherwise raise the robust
        sigma and hide the disturbances next to it.

    Returns
    -------
    baseline : ndarray (n,)
    sigma : float
        1.4826 times the median absolute departure on ``use``.

    Examples
    --------
    >>> t = np.arange(0.0, 360.0, 0.1)
    >>> rng = np.random.default_rng(24)
    >>> y = 0.001 * (t - 180) ** 2 + rng.normal(0, 2, t.size)
    >>> y[(t > 150) & (t < 190)] += 200.0
    >>> base, sigma = robust_baseline(t, y, t >= 0)
    >>> bool(np.abs(base - 0.001 * (t - 180) ** 2).max() < 1.5), round(sigma)
    (True, 2)
    """
    t = np.asarray(t_s, float)
    v = np.asarray(values, float)
    use = np.asarray(use, bool)
    if knot_s > 0:
        from scipy.interpolate import BSpline

        from magcal.missions.elfin.phase import spline_knots

        knots = spline_knots(t[use], knot_s)
        a = BSpline.design_matrix(np.clip(t, knots[0], knots[-1]), knots, 3).toarray()
    else:
        x = 2.0 * (t - t[use][0]) / max(t[use][-1] - t[use][0], 1e-12) - 1.0
        a = np.column_stack([x ** d for d in range(degree + 1)])
    if steps is not None and np.size(steps):
        a = np.column_stack([a, np.asarray(steps, float).reshape(t.size, -1)])
    au, vu = a[use], v[use]

    def solve(w):
        sw = np.sqrt(w)
        coef = lstsq(au * sw[:, None], vu * sw)
        return coef, vu - au @ coef

    coef, r = solve(np.ones(vu.size))
    for _ in range(max(0, l1_iter)):
        # iteratively reweighted least squares towards the least absolute deviations
        floor = 1e-3 * float(np.std(r)) + 1e-9
        coef, r = solve(1.0 / np.maximum(np.abs(r), floor))
    w = np.ones(vu.size)
    sigma = 0.0
    for _ in range(max(1, n_iter)):
        sigma = float(normal_mad(r))
        u = r / max(c * sigma, 1e-12)
        w_new = np.where(np.abs(u) < 1.0, (1.0 - u ** 2) ** 2, 0.0)
        if np.allclose(w_new, w):
            break
        w = w_new
        coef, r = solve(w)
    sigma = float(normal_mad(r))
    return a @ coef, sigma


def peeled_baseline(t_s, values, use, *, gain: float = 2.0, max_peels: int = 3,
                    floor_sigma: float = 0.0, share: float = 0.25, pad_s: float = 5.0,
                    edge_s: float = 0.0, magnitude=None, along_share: float = 0.5,
                    first=None, **kw) -> tuple[np.ndarray, float, np.ndarray]:
    """:func:`robust_baseline` fitted again without the excursions that inflate its sigma.

    Every robust start fails when the disturbed samples are many and gathered in time:
    on 2022-01-12, zone 6 with a 200 nT east-west pulse of 40 s beside the zone's own
    disturbance (about 100 s of 370 s), the least-absolute-deviation cubic and spline
    bend up under both (locally they are the majority), the biweights start from a
    robust sigma of 38 nT instead of 1.7 and reject nothing, and nothing is flagged,
    neither the pulse nor the disturbance the clean zone had flagged. Here the largest
    departure from the baseline (with the samples around it above ``share`` of its
    peak, padded by ``pad_s``) is left out and the baseline fitted again, up to
    ``max_peels`` times, each from the last fit; the fit with the lowest robust sigma
    is kept if that sigma is ``gain``-fold below the first (zone 6: 38 -> 3.4 nT about
    the 90 s spline, the pulse then the disturbance left out), else nothing is left
    out. One excursion at a time need not halve the sigma (the other still bends the
    spline). A quiet zone's sigma is set by its noise, which leaving out its largest
    wiggles hardly changes.

    Parameters
    ----------
    t_s, values, use : array_like (n,)
        As :func:`robust_baseline`.
    gain : float
        Factor by which the sigma must drop for an excursion to stay out (0: no
        peeling).
    max_peels : int
        Most excursions left out.
    floor_sigma : float
        Peel only while the sigma exceeds this (below it, another bound sets the
        flagging level and the sigma does not matter).
    share : float
        Samples next to the largest departure whose departure exceeds this share of it
        are left out with it.
    pad_s : float
        Seconds left out on either side of those.
    edge_s : float
        An excursion that comes (padded) closer than this to the first or last sample
        of ``use`` stays in: the baseline would be extrapolated over it, and a level
        that lasts to the zone's end (a current sheet's plateau) is not an excursion.
    magnitude : array_like (n,), optional
        The ``|B|`` residual on the same samples, for a vector component: an excursion
        whose ``|B|`` departs (from the median over ``pad_s`` beyond each side) by
        ``along_share`` of its own peak or more is a field along B and stays in. Such a
        field is what the ``|B|`` flags and the pulse step along B are for; left out of
        the slow vector fits as well, 90 s pulses along B on 2022-01-12 came back with
        18 % distortion instead of 4 % (36 placements).
    along_share : float
        See ``magnitude``.
    first : tuple, optional
        ``robust_baseline(t_s, values, use, **kw)`` if the caller has it already.
    **kw
        Passed to :func:`robust_baseline`.

    Returns
    -------
    baseline : ndarray (n,)
    sigma : float
        Robust sigma on the samples fitted.
    peeled : ndarray of bool (n,)
        Samples left out of the final fit.

    Examples
    --------
    A pulse and a disturbance on 2 nT of noise, about 40 % of the record:

    >>> t = np.arange(0.0, 370.0, 0.5)
    >>> rng = np.random.default_rng(6)
    >>> y = rng.normal(0, 2, t.size)
    >>> y += 170 * np.exp(-0.5 * ((t - 125) / 20) ** 2)
    >>> y += 150 * np.exp(-0.5 * ((t - 285) / 20) ** 2)
    >>> round(robust_baseline(t, y, t >= 0, knot_s=0.0)[1])
    40
    >>> base, sigma, peeled = peeled_baseline(t, y, t >= 0, knot_s=0.0)
    >>> round(sigma), bool(np.abs(base).max() < 4)
    (4, True)
    """
    t = np.asarray(t_s, float)
    v = np.asarray(values, float)
    use = np.asarray(use, bool)
    base, sigma = robust_baseline(t, v, use, **kw) if first is None else first
    best = (base, sigma, np.zeros(t.size, bool))
    if gain <= 0 or sigma <= floor_sigma:
        return best
    first_s, last_s = t[use][0], t[use][-1]
    trial, fit, skip, peels = best[2], (base, sigma), np.zeros(t.size, bool), 0
    for _ in range(2 * max_peels):
        dev = np.abs(v - fit[0])
        k = int(np.argmax(np.where(use & ~trial & ~skip, dev, -1.0)))
        lo, hi = _grown_span(t, k, k + 1, dev > share * dev[k], pad_s)
        window = (t >= lo) & (t <= hi)
        if lo - first_s < edge_s or last_s - hi < edge_s:
            # the largest departure reaches a zone end: the baseline would be
            # extrapolated over the gap, and a level lasting to the zone's end (a
            # current sheet's plateau) is not an excursion that others hide behind
            break
        if magnitude is not None and _along_b(t, magnitude, use, lo, hi, pad_s) \
                >= along_share * dev[k]:
            skip |= window                # a field along B: left to the |B| flags
            continue
        trial = trial | window
        if (use & ~trial).sum() < 0.5 * use.sum():
            break
        fit = robust_baseline(t, v, use & ~trial, **kw)
        if fit[1] < best[1]:
            best = (*fit, trial)
        peels += 1
        if peels == max_peels:
            break
    return best if best[1] * gain <= sigma else (base, sigma, np.zeros(t.size, bool))


def _grown_span(t, a, b, grow, pad_s) -> tuple[float, float]:
    """Times ``(lo, hi)`` of the rows ``a:b`` grown while ``grow`` holds next to them,
    padded by ``pad_s`` seconds."""
    while a > 0 and grow[a - 1]:
        a -= 1
    while b < t.size and grow[b]:
        b += 1
    return t[a] - pad_s, t[b - 1] + pad_s


def _along_b(t, magnitude, use, lo, hi, pad_s) -> float:
    """Largest departure of ``magnitude`` on ``[lo, hi]`` from its median over the
    ``pad_s`` seconds (at least 5 s) beyond either end (used samples only)."""
    m = np.asarray(magnitude, float)
    w = max(pad_s, 5.0)
    inside = use & (t >= lo) & (t <= hi)
    flanks = use & (((t >= lo - w) & (t < lo)) | ((t > hi) & (t <= hi + w)))
    if not inside.any() or not flanks.any():
        return 0.0
    return float(np.abs(m[inside] - np.median(m[flanks])).max())


def flag_excursions(t_s, z, dev_nT, use, settings: DetectSettings | None = None
                    ) -> np.ndarray:
    """Samples of one zone inside a localized excursion of a standardised residual.

    Parameters
    ----------
    t_s : array_like (n,)
        Times, s.
    z : array_like (n, m)
        Departures from the baseline in robust sigmas, one column a component.
    dev_nT : array_like (n, m)
        The same departures in nT (for ``min_nT``).
    use : array_like of bool (n,)
        Samples that may start a flag (the used ones).
    settings : DetectSettings, optional

    Returns
    -------
    ndarray of bool (n,)
        Flagged samples: a run above ``threshold`` (and ``min_nT``) lasting at least
        ``min_s``, grown while any component stays above ``extend``, padded by ``pad_s``.

    Examples
    --------
    >>> t = np.arange(0.0, 300.0, 0.1)
    >>> z = np.zeros((t.size, 1)); z[(t > 100) & (t < 120), 0] = 8.0
    >>> z[(t > 95) & (t <= 100), 0] = 3.0
    >>> s = DetectSettings(threshold=5.0, extend=2.5, pad_s=1.0)
    >>> f = flag_excursions(t, z, 10 * z, t >= 0, s)
    >>> round(float(t[f][0]), 1), round(float(t[f][-1]), 1)
    (94.1, 120.9)
    """
    s = settings or DetectSettings()
    t = np.asarray(t_s, float)
    za = np.abs(np.asarray(z, float))
    dev = np.abs(np.asarray(dev_nT, float))
    use = np.asarray(use, bool)
    hot = use & np.any((za > s.threshold) & (dev > s.min_nT), axis=1)
    warm = use & np.any(za > s.extend, axis=1)
    out = np.zeros(t.size, bool)
    if not use.any():
        return out
    first, last = t[use][0], t[use][-1]
    for a, b in true_runs(hot):
        if t[b - 1] - t[a] < s.min_s:
            continue
        lo, hi = _grown_span(t, a, b, warm, s.pad_s)
        if lo - first < s.edge_s or last - hi < s.edge_s:
            continue                      # the calibration would be extrapolated over it
        out |= (t >= lo) & (t <= hi)
    return out


def zone_residuals(zone_field: pd.DataFrame, smooth_s: float = 3.0) -> np.ndarray:
    """Calibrated minus IGRF of one zone (despun ``x, y, z`` and ``|B|``), spin-averaged.

    Returns
    -------
    ndarray (n, 4)
        Columns as :data:`COMPONENTS`, nT; a running mean over the used samples within
        ``smooth_s`` seconds.
    """
    from scipy.ndimage import uniform_filter1d

    b = zone_field[["bx_despun", "by_despun", "bz_despun"]].to_numpy(float)
    ref = zone_field[["igrf_x_despun", "igrf_y_despun", "igrf_z_despun"]].to_numpy(float)
    r = np.column_stack([b - ref, np.linalg.norm(b, axis=1) - np.linalg.norm(ref, axis=1)])
    use = (zone_field["used"].to_numpy() == 1).astype(float)
    r = np.where(use[:, None] > 0, r, 0.0)
    t = (zone_field.index.asi8 - zone_field.index.asi8[0]) / 1e9
    dt = float(np.median(np.diff(t))) if t.size > 1 else 1.0
    width = max(1, round(smooth_s / max(dt, 1e-9)))
    # mean over the used samples in the window only (the zone's unused first seconds
    # carry a start transient of hundreds of nT)
    num = uniform_filter1d(r * use[:, None], width, axis=0, mode="constant")
    den = uniform_filter1d(use, width, mode="constant")
    return num / np.maximum(den, 1e-12)[:, None]


def detect_in_field(field: pd.DataFrame, settings: DetectSettings | None = None
                    ) -> tuple[np.ndarray, pd.DataFrame]:
    """Flag localized excursions of the residual of a calibrated field, zone by zone.

    The vector components (despun ``x, y, z``) and ``|B|`` are flagged apart: a field
    across B shows in the first and leaves ``|B|`` alone to first order, so the fits to
    ``|B|`` need not lose those samples (:func:`~magcal.missions.elfin.drift.fit_samples`).

    Parameters
    ----------
    field : DataFrame
        ``ElfinCalibration.field`` (``zone``, ``used``, despun field and IGRF).
    settings : DetectSettings, optional

    Returns
    -------
    flags : ndarray of bool (len(field), 2)
        Column 0: flagged from the vector components; column 1: from ``|B|``.
    table : DataFrame
        Per zone: ``zone``, ``flagged_share`` (of the used samples, either column),
        ``scalar_flagged_share`` (column 1), ``sigma_<c>_nT`` (robust sigma per
        component about the first baseline), ``dropped`` (flags dropped by
        ``max_share``).
    """
    s = settings or DetectSettings()
    zone = field["zone"].to_numpy()
    flags = np.zeros((len(field), 2), bool)
    rows = []
    for k in dict.fromkeys(zone):
        sel = np.flatnonzero(zone == k)
        z = field.iloc[sel]
        use = z["used"].to_numpy() == 1
        t = (z.index.asi8 - z.index.asi8[0]) / 1e9
        r = zone_residuals(z, s.smooth_s)
        level = z["level_step"].to_numpy() == 1 if "level_step" in z.columns \
            else np.zeros(len(z), bool)
        f, sigmas = _zone_flags(t, r, use, level, s)
        share = float(f[use].any(axis=1).mean()) if use.any() else 0.0
        dropped = share > s.max_share
        if not dropped:
            flags[sel] = f
        rows.append({"zone": int(k), "flagged_share": 0.0 if dropped else share,
                     "scalar_flagged_share": 0.0 if dropped or not use.any()
                     else float(f[use, 1].mean()),
                     "dropped": dropped, **sigmas})
    return flags, pd.DataFrame(rows)


#: Factor by which a kept level step must lower the robust sigma of the spin-axis
#: residual about a baseline to become part of that baseline (2022-01-12: an injected
#: 300 nT sheet 6.2 -> 2.3 nT about the 90 s spline, 41 -> 3.2 nT about the cubic;
#: the clean day's one stepped zone, a 33 nT step at a disturbance's end, 1.64 -> 1.63
#: and 2.7 -> 2.4).
LEVEL_BASELINE_GAIN = 1.5


def _zone_flags(t, r, use, level, s: DetectSettings) -> tuple[np.ndarray, dict]:
    """Flags (n, 2) of one zone's spin-averaged residual ``r`` (:func:`zone_residuals`)
    and the robust sigma per component about the first baseline.

    ``level`` marks the rows of the zone's kept level changes (``level_step``). Where
    the data demand it (:data:`LEVEL_BASELINE_GAIN`), a step after each is part of the
    spin-axis baseline: a current sheet's plateau is not a localized excursion, and
    about a baseline that cannot follow it the robust sigma doubles and a real
    disturbance beside it falls under the threshold (2022-01-12 zone 7: 4.4 -> 7.7 nT,
    and a third of the clean day's flags lost). The level rows are then flagged and do
    not start or grow other flags: bridged by the slow terms, they depart from any
    baseline by the bridge's error too.

    Where a baseline is peeled (:func:`peeled_baseline`), the flags about it add the
    intervals the plain baselines did not flag at all; an interval both flag keeps the
    plain extent along the spin axis. About a peeled baseline the lower sigma also grows
    a flag over the slow part of the stiff calibration's own response: a current sheet
    (east-west, near the spin axis) that calibration half absorbed comes back as its
    rise and a slow recovery, and with the recovery left out of the fits too the level
    steps no longer see the sheet's level change (2022-01-12 zone 2, a 300 nT sheet at
    0.35: flagged 127-175 s, 74 % kept; flagged 117-251 s, 7 %). In the spin plane the
    peeled extent is taken: the plain flags of an along-track pulse end where the
    sigma the pulse inflated says, inside its flanks.
    """
    steps = step_columns(level) if level.any() else None
    knots = (s.baseline_knot_s, 0.0) if s.also_polynomial and s.baseline_knot_s > 0 \
        else (s.baseline_knot_s,)
    sigmas, plain, peeled, stepped = {}, [], [], False
    any_peeled, spin_plane_peeled = False, False
    for knot_s in knots:
        dev = np.zeros((2,) + r.shape)            # about the plain and the peeled baseline
        score = np.zeros((2,) + r.shape)
        for j, name in enumerate(COMPONENTS):
            kw = {"degree": s.baseline_degree, "c": s.tukey_c, "knot_s": knot_s}
            peel = {"gain": s.peel_gain if (knot_s > 0 or s.peel_polynomial) and j < 3
                    else 0.0,
                    "max_peels": s.max_peels, "floor_sigma": s.min_nT / s.threshold,
                    "pad_s": s.pad_s, "edge_s": s.edge_s}
            fit_use, fit_steps = use, None
            first = robust_baseline(t, r[:, j], use, **kw)
            if name == "z" and steps is not None:
                # whether the data demand the step is judged without peeling: a level
                # lasting to the zone's end is not an excursion to leave out
                stepped_fit = robust_baseline(t, r[:, j], use & ~level, steps=steps, **kw)
                if stepped_fit[1] * LEVEL_BASELINE_GAIN <= first[1]:
                    fit_use, fit_steps, stepped = use & ~level, steps, True
                    first = stepped_fit
            base, sigma, out = peeled_baseline(t, r[:, j], fit_use, steps=fit_steps,
                                               magnitude=r[:, 3] if j < 3 else None,
                                               first=first, **kw, **peel)
            any_peeled |= bool(out.any())
            spin_plane_peeled |= j < 2 and bool(out.any())
            for i, (b, sg) in enumerate((first, (base, sigma))):
                dev[i, :, j] = r[:, j] - b
                score[i, :, j] = dev[i, :, j] / max(sg, 1e-9)
            sigmas.setdefault(f"sigma_{name}_nT", sigma)
        plain.append((dev[0], score[0]))
        peeled.append((dev[1], score[1]))
    free = use & ~level if stepped else use

    def flags(scores, vector=slice(0, 3)):
        f = np.zeros((len(t), 2), bool)
        for dev, score in scores:
            f |= np.column_stack([flag_excursions(t, score[:, vector], dev[:, vector], free, s),
                                  flag_excursions(t, score[:, 3:], dev[:, 3:], free, s)])
        return f

    f = flags(plain)
    if any_peeled:
        f = f | _new_runs(t, flags(peeled), f, s.min_island_s)
        if spin_plane_peeled:
            f[:, 0] |= flags(peeled, slice(0, 2))[:, 0]
    if stepped:
        f[:, 0] |= level & use
    return f, sigmas


def _new_runs(t, extra, found, island_s: float = 0.0) -> np.ndarray:
    """The runs of ``extra`` (per column) that neither overlap a run of ``found`` nor
    come within ``island_s`` seconds of one."""
    out = np.zeros_like(extra)
    for c in range(extra.shape[1]):
        for a, b in true_runs(extra[:, c]):
            near = (t >= t[a] - island_s) & (t <= t[b - 1] + island_s)
            if not found[near, c].any():
                out[a:b, c] = True
    return out


def zone_shares(mask, used, zone, zones) -> list[float]:
    """Share of each zone's used samples that ``mask`` holds, for the zone numbers
    ``zones`` (``used``, ``zone`` and ``mask`` row by row)."""
    return [float(mask[used & (zone == k)].mean()) for k in zones]


@dataclass(frozen=True)
class Disturbed:
    """Rows of an ELFIN day flagged by :func:`locate_disturbed`.

    Attributes
    ----------
    vector : ndarray of bool (n,)
        Flagged from the vector components (or known beforehand): left out of the
        slow vector fits (linear, the vector step's tilt, phase refit).
    scalar : ndarray of bool (n,)
        Flagged from ``|B|`` (or known beforehand): left out of every fit.
    table : DataFrame
        :func:`detect_in_field`'s table for each pass (column ``pass``, from 1), with
        ``flagged_share`` the share of each zone's used samples flagged after that pass.
    """

    vector: np.ndarray
    scalar: np.ndarray
    table: pd.DataFrame

    @property
    def any(self) -> np.ndarray:
        """Rows flagged either way (the vector fits' ``fit_exclude``)."""
        return self.vector | self.scalar


def detect_disturbed(fgs: pd.DataFrame, state: pd.DataFrame, settings=None, *,
                     detect: DetectSettings | None = None, fit_exclude=None,
                     hold_phase=None) -> tuple[np.ndarray, pd.DataFrame]:
    """Rows of an ELFIN day inside disturbed intervals, flagged either way.

    :func:`locate_disturbed` with its two masks joined: ``(found.any, found.table)``.
    """
    found = locate_disturbed(fgs, state, settings, detect=detect, fit_exclude=fit_exclude,
                             hold_phase=hold_phase)
    return found.any, found.table


def locate_disturbed(fgs: pd.DataFrame, state: pd.DataFrame, settings=None, *,
                     detect: DetectSettings | None = None, fit_exclude=None,
                     hold_phase=None, linear=None, zone_numbers=None) -> Disturbed:
    """Rows of an ELFIN day inside disturbed intervals found from the counts alone.

    Parameters
    ----------
    fgs, state : DataFrame
        The day (:mod:`magcal.missions.elfin.files`).
    settings : ElfinSettings, optional
        The pipeline's settings; the detection calibrates with ``gain_drift_2x = True``
        and no detection of its own.
    detect : DetectSettings, optional
    fit_exclude : array_like of bool, optional
        Rows already known to be disturbed (kept flagged and left out from the start).
    hold_phase : array_like, optional
        Passed to the calibration (the injection tests' machinery check).
    linear : ElfinCalibration, optional
        The linear calibration of these rows with ``fit_exclude`` (first pass only;
        see :func:`~magcal.missions.elfin.pipeline.calibrate_elfin_day`).
    zone_numbers : sequence of int, optional
        The zone numbers of these rows (passed to the calibration).

    Returns
    -------
    Disturbed
        ``vector`` and ``scalar`` masks (both include ``fit_exclude``) and the table
        (``flagged_share``: all passes so far and ``fit_exclude``).
    """
    from magcal.missions.elfin.pipeline import ElfinSettings, calibrate_elfin_day

    d = detect or DetectSettings()
    stiff = replace(settings or ElfinSettings(), gain_drift_2x=True, gain_drift_robust_c=0.0,
                    detect_disturbed=False, joint=False, scan=False, bridge_trials=0,
                    pulses_b=False, level_trials=0)
    known = np.zeros(len(fgs), bool) if fit_exclude is None else np.asarray(fit_exclude, bool)
    flags = np.column_stack([known, known])
    tables = []
    for _ in range(max(1, d.passes)):
        either = flags.any(axis=1)
        day = calibrate_elfin_day(fgs, state, stiff, hold_phase=hold_phase,
                                  fit_exclude=either if either.any() else None,
                                  diagnostics=False, linear=linear if not tables else None,
                                  zone_numbers=zone_numbers)
        f = day.calibration.field
        new, table = detect_in_field(f, d)
        settled = not (new & ~flags).any()
        flags = flags | new
        used = f["used"].to_numpy() == 1
        zone = f["zone"].to_numpy()
        table["flagged_share"] = zone_shares(flags.any(axis=1), used, zone, table["zone"])
        table["scalar_flagged_share"] = zone_shares(flags[:, 1], used, zone, table["zone"])
        tables.append(table.assign(**{"pass": len(tables) + 1}))
        if settled:
            break
    return Disturbed(vector=flags[:, 0], scalar=flags[:, 1],
                     table=pd.concat(tables, ignore_index=True))
