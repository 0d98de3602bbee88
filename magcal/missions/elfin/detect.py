"""Disturbed intervals of an ELFIN day located from the counts alone (opt-in).

Every time-varying step of the calibration is fitted against IGRF and takes part of a
natural field that IGRF lacks; left out of every fit (``fit_exclude`` of
:func:`~magcal.missions.elfin.pipeline.calibrate_elfin_day`), a disturbed interval comes
back whole. This module tries to find such intervals without an outside source:

1. the day is calibrated with a *stiff* variant of the settings (the gain drift tied
   to the reference-free 2x-spin harmonic, ``gain_drift_2x``, so that a field along B
   is not turned into a gain cubic);
2. per zone and per component of the residual against the model (despun ``x, y``, the
   spin axis ``z`` and ``|B|``), averaged over one spin, a robust cubic in time is
   taken as the instrument's slow part (Tukey biweights, :func:`robust_baseline`): what
   the drift steps can make over a pass;
3. what departs from it by more than ``threshold`` robust sigmas (and ``min_nT``) is
   flagged, grown while it stays above ``extend`` sigmas, padded by ``pad_s``
   (:func:`flag_excursions`);
4. the day is calibrated again without the flagged samples and step 2-3 repeated on
   that residual (``passes``), the flags accumulating.

The result is a boolean row mask for ``fit_exclude``. What it cannot do is tell a
slow natural field from the instrument's slow drift (anything the 90 s baseline spline
makes is the instrument's to it), and it flags real natural fields on a "clean" day
too (on 2022-01-12 zone 7 holds a 150 nT east-west excursion of about 40 s), which is
what it is for.

Measured on 2022-01-12, zones 1, 4, 7, 10 (``workflows/elfin_preservation.py
--settings detect_disturbed=true``; defaults of :class:`DetectSettings`): the 200 nT
40 s pulses across B are found (kept 99.5 % east-west, 86 % along-track, against 65 %
and 26 % without detection) but the clean and injected days flag different intervals
(distortion 35 % and 21 %); a 100 nT pulse along B of 90 s FWHM is not found (a
cubic-like bump of |B| on the 25-60 nT the 2x-tied drift leaves; kept 6 %), a current
sheet to the zone's end is found only at its rise (kept 3 %). On the clean day it
flags 9, 0, 18 and 10 % of the zones' samples, mostly at the zone ends where natural
excursions of 50-150 nT are seen, and the clean residual grows from 7.2 / 5.2 / 16.3
to 9.8 / 7.0 / 24.9 nT (scalar / fast / vector zone medians; 6.4 / 5.1 / 13.4 on the
unflagged samples): a flagged zone end is extrapolated. Looser settings (threshold 5,
extend 2.5, 15 nT, two passes) flag 20-36 % of the clean zones for a scalar residual
of 28 nT.

Data: ELFIN SOC (PI V. Angelopoulos, UCLA), "Open Data for Scientific Use".
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import pandas as pd

from magcal.missions.elfin.timing import true_runs

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
    tukey_c : float
        Tukey biweight tuning constant of the baseline, in robust sigmas.
    passes : int
        Detection passes (the second works on a calibration fitted without the first
        pass's flags, where a signal the fits absorbed comes back). Default 1: a second
        pass found nothing more of the injected signals on the real day and grew zone
        10's clean flags from 10 to 32 %.
    max_share : float
        Largest share of a zone's used samples that may be flagged: above it the
        zone's flags are dropped (a zone that is mostly disturbed cannot be calibrated
        against the model on what is left; the zone is then fitted as without
        detection).
    """

    threshold: float = 8.0
    extend: float = 4.0
    min_nT: float = 30.0
    min_s: float = 5.0
    pad_s: float = 5.0
    smooth_s: float = 3.0
    baseline_degree: int = 3
    baseline_knot_s: float = 90.0
    tukey_c: float = 4.685
    passes: int = 1
    max_share: float = 0.6


def robust_baseline(t_s, values, use, *, degree: int = 3, c: float = 4.685,
                    n_iter: int = 20, knot_s: float = 0.0) -> tuple[np.ndarray, float]:
    """Polynomial in time fitted by Tukey-biweighted least squares, and its robust sigma.

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
    w = np.ones(int(use.sum()))
    coef = np.zeros(a.shape[1])
    sigma = 0.0
    for _ in range(max(1, n_iter)):
        sw = np.sqrt(w)
        coef = np.linalg.lstsq(a[use] * sw[:, None], v[use] * sw, rcond=None)[0]
        r = v[use] - a[use] @ coef
        sigma = 1.4826 * float(np.median(np.abs(r - np.median(r))))
        u = r / max(c * sigma, 1e-12)
        w_new = np.where(np.abs(u) < 1.0, (1.0 - u ** 2) ** 2, 0.0)
        if np.allclose(w_new, w):
            break
        w = w_new
    return a @ coef, sigma


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
    for a, b in true_runs(hot):
        if t[b - 1] - t[a] < s.min_s:
            continue
        while a > 0 and warm[a - 1]:
            a -= 1
        while b < t.size and warm[b]:
            b += 1
        out |= (t >= t[a] - s.pad_s) & (t <= t[b - 1] + s.pad_s)
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

    Parameters
    ----------
    field : DataFrame
        ``ElfinCalibration.field`` (``zone``, ``used``, despun field and IGRF).
    settings : DetectSettings, optional

    Returns
    -------
    flags : ndarray of bool (len(field),)
    table : DataFrame
        Per zone: ``zone``, ``flagged_share`` (of the used samples), ``sigma_<c>_nT``
        (robust sigma per component), ``dropped`` (flags dropped by ``max_share``).
    """
    s = settings or DetectSettings()
    zone = field["zone"].to_numpy()
    flags = np.zeros(len(field), bool)
    rows = []
    for k in dict.fromkeys(zone):
        sel = np.flatnonzero(zone == k)
        z = field.iloc[sel]
        use = z["used"].to_numpy() == 1
        t = (z.index.asi8 - z.index.asi8[0]) / 1e9
        r = zone_residuals(z, s.smooth_s)
        dev = np.zeros_like(r)
        score = np.zeros_like(r)
        sigmas = {}
        for j, name in enumerate(COMPONENTS):
            base, sigma = robust_baseline(t, r[:, j], use, degree=s.baseline_degree,
                                          c=s.tukey_c, knot_s=s.baseline_knot_s)
            dev[:, j] = r[:, j] - base
            score[:, j] = dev[:, j] / max(sigma, 1e-9)
            sigmas[f"sigma_{name}_nT"] = sigma
        f = flag_excursions(t, score, dev, use, s)
        share = float(f[use].mean()) if use.any() else 0.0
        dropped = share > s.max_share
        if not dropped:
            flags[sel] = f
        rows.append({"zone": int(k), "flagged_share": 0.0 if dropped else share,
                     "dropped": dropped, **sigmas})
    return flags, pd.DataFrame(rows)


def detect_disturbed(fgs: pd.DataFrame, state: pd.DataFrame, settings=None, *,
                     detect: DetectSettings | None = None, fit_exclude=None,
                     hold_phase=None) -> tuple[np.ndarray, pd.DataFrame]:
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

    Returns
    -------
    flags : ndarray of bool (len(fgs),)
        The rows to leave out of every fit (``fit_exclude``), including ``fit_exclude``.
    table : DataFrame
        :func:`detect_in_field`'s table for each pass (column ``pass``, from 1), with
        ``flagged_share`` the share of each zone's used samples flagged after that
        pass (all passes so far and ``fit_exclude``).
    """
    from magcal.missions.elfin.pipeline import ElfinSettings, calibrate_elfin_day

    d = detect or DetectSettings()
    stiff = replace(settings or ElfinSettings(), gain_drift_2x=True, gain_drift_robust_c=0.0,
                    detect_disturbed=False, joint=False, scan=False)
    known = np.zeros(len(fgs), bool) if fit_exclude is None else np.asarray(fit_exclude, bool)
    flags = known.copy()
    tables = []
    for _ in range(max(1, d.passes)):
        day = calibrate_elfin_day(fgs, state, stiff, hold_phase=hold_phase,
                                  fit_exclude=flags if flags.any() else None,
                                  diagnostics=False)
        f = day.calibration.field
        new, table = detect_in_field(f, d)
        settled = not (new & ~flags).any()
        flags = flags | new
        used = f["used"].to_numpy() == 1
        table["flagged_share"] = [float(flags[used & (f["zone"].to_numpy() == k)].mean())
                                  for k in table["zone"]]
        tables.append(table.assign(**{"pass": len(tables) + 1}))
        if settled:
            break
    return flags, pd.concat(tables, ignore_index=True)
