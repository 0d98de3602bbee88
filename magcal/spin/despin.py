"""Despinning and spin phase (CONTRACTS §4).

Convention: the calibrated field in the rotating spacecraft frame ``(Bx, By, Bz)`` is
despun with the spin phase ``p`` as

    BX = Bx cos p - By sin p,   BY = Bx sin p + By cos p,   BZ = Bz,

and, without a phase column, ``p = 2 pi (t - t0) / S`` for spin period ``S``.
All functions work on arrays; times are float seconds from an arbitrary epoch. The
rotations themselves (:func:`despin`, :func:`spin`) live in :mod:`magcal.frames.spinning`
so that simulators use them without importing the spin estimators.
"""

from __future__ import annotations

import numpy as np

from magcal.errors import InputError
from magcal.frames.spinning import TWO_PI, despin, spin

__all__ = ["TWO_PI", "check_period_consistent", "despin", "phase_from_data",
           "phase_from_period", "spin"]


def phase_from_period(t_s, period_s: float, t0_s: float | None = None) -> np.ndarray:
    """Spin phase ``2 pi (t - t0) / S`` (``t0`` defaults to the first time).

    Examples
    --------
    >>> phase_from_period([0.0, 5.0, 10.0], 20.0).round(6)
    array([0.      , 1.570796, 3.141593])
    """
    t = np.asarray(t_s, dtype=float)
    if not np.isfinite(period_s) or period_s <= 0:
        raise InputError(f"spin period must be a positive number of seconds, got {period_s}")
    t0 = t[0] if t0_s is None else float(t0_s)
    return TWO_PI * (t - t0) / float(period_s)


def phase_from_data(t_s, b1, b2, *, degree: int = 2,
                    max_rms_rad: float = 0.5) -> tuple[np.ndarray, dict]:
    """Derive the spin phase from the rotation of the spin-plane sensor readings.

    The spin-plane field seen in the rotating frame turns at minus the spin rate, so
    ``p(t) = -unwrap(atan2(b2, b1))`` up to the (slowly varying) direction of the
    ambient field. A polynomial of ``degree`` in time is fitted to that angle so that
    ripple and waves do not enter the phase; the phase is referenced so that
    ``p = 0`` at the first sample of the fitted curve.

    Parameters
    ----------
    t_s : array_like, shape (n,)
        Times in seconds, increasing.
    b1, b2 : array_like, shape (n,)
        Spin-plane sensor readings (offsets and scale do not need to be known, but the
        rotating spin-plane field must dominate them).
    degree : int
        Degree of the phase polynomial (1 = constant period, 2 = linear drift).
    max_rms_rad : float
        Largest accepted scatter of the raw angle about the polynomial.

    Returns
    -------
    phase : ndarray, shape (n,)
    info : dict
        ``spin_period_s`` (mean), ``period_start_s``, ``period_end_s``,
        ``phase_rms_rad`` (scatter of the raw angle about the fit).

    Examples
    --------
    >>> import numpy as np
    >>> t = np.arange(0, 200, 0.25)
    >>> ang = -2 * np.pi * t / 20 + 1
    >>> p, info = phase_from_data(t, 30 * np.cos(ang), 30 * np.sin(ang))
    >>> round(info["spin_period_s"], 6)
    20.0
    """
    t = np.asarray(t_s, dtype=float)
    x = np.asarray(b1, dtype=float)
    y = np.asarray(b2, dtype=float)
    ok = np.isfinite(t) & np.isfinite(x) & np.isfinite(y)
    if ok.sum() < 3 * (degree + 1):
        raise InputError("too few valid samples to derive the spin phase from the data")
    # Remove the spin-plane mean (offsets) before taking the angle.
    x0 = x - np.nanmedian(x[ok])
    y0 = y - np.nanmedian(y[ok])
    ang = -np.unwrap(np.arctan2(y0[ok], x0[ok]))
    steps = np.diff(ang)
    if steps.size and np.median(steps) <= 0:
        raise InputError("the spin-plane field does not rotate in the positive sense: "
                         "cannot derive a spin phase (give a phase column or --spin-period)")
    tc = t[ok] - t[ok][0]
    scale = max(tc[-1], 1.0)
    coef = np.polynomial.polynomial.polyfit(tc / scale, ang, degree)
    fitted = np.polynomial.polynomial.polyval((t - t[ok][0]) / scale, coef)
    resid = ang - fitted[ok]
    rate0 = np.polynomial.polynomial.polyval(0.0, np.polynomial.polynomial.polyder(coef)) / scale
    rate1 = np.polynomial.polynomial.polyval(1.0, np.polynomial.polynomial.polyder(coef)) / scale
    phase = fitted - fitted[0]
    rms = float(np.sqrt(np.mean(resid ** 2)))
    if rms > max_rms_rad:
        raise InputError(
            f"cannot derive the spin phase from the data: the spin-plane field angle "
            f"scatters by {rms:.2f} rad about a smooth spin (more than {max_rms_rad} rad); "
            "give a phase column or --spin-period")
    info = {
        "spin_period_s": float(TWO_PI * tc[-1] / (fitted[ok][-1] - fitted[ok][0])),
        "period_start_s": float(TWO_PI / rate0),
        "period_end_s": float(TWO_PI / rate1),
        "phase_rms_rad": float(np.sqrt(np.mean(resid ** 2))),
    }
    return phase, info


def check_period_consistent(t_s, phase_data_rad, period_s: float,
                            max_slip_rad: float = 1.0) -> None:
    """Raise :class:`InputError` when a constant period does not follow the data.

    ``phase_data_rad`` is a phase derived from the data (see :func:`phase_from_data`).
    The constant-period phase may slip against it by at most ``max_slip_rad`` over the
    whole interval.
    """
    t = np.asarray(t_s, dtype=float)
    ref = phase_from_period(t, period_s)
    slip = (np.asarray(phase_data_rad) - phase_data_rad[0]) - ref
    worst = float(np.nanmax(np.abs(slip)))
    if worst > max_slip_rad:
        raise InputError(
            f"spin period {period_s:g} s does not fit the data: the phase slips by "
            f"{worst:.2f} rad over {t[-1] - t[0]:.0f} s (spin period not constant, or "
            "wrong); give a phase column, or omit --spin-period to derive the phase "
            "from the data", column="time")
