"""The scalar residual of ELFIN counts against |IGRF|: the linear floor and what is left.

The scalar residual ``|B| - |B_IGRF|`` does not depend on attitude or spin phase, so it
isolates the instrument. This module measures, per science zone:

* the *linear floor*: the best 9-parameter scalar calibration ``B = A (b - O)`` (``A``
  upper triangular: 3 gains and 3 non-orthogonality angles; 3 offsets) fitted to
  ``|B_IGRF|`` (:func:`linear_scalar_fit`);
* the spin harmonics left in that residual, measured against the angle ``psi`` of the
  field in the sensor's spin plane (:func:`spin_plane_angle`, :func:`harmonic_amplitudes`);
* a residual model (:func:`fit_spin_harmonics`): a harmonic of ``psi`` whose coefficient
  is constant over the zone (a non-linearity fixed in the sensor, on the real data at
  4x spin) plus harmonics whose coefficients drift slowly (on the real data 1x and 2x:
  the spin-plane offsets and the spin-plane gain ratio/non-orthogonality drift within
  a pass).

The drifting terms are a description of the scalar residual, not a calibration: a
scalar-only fit of drifting offsets and gains is degenerate on these passes (the field
lies almost in the spin plane, and offset drifts of 1e7 counts reach 1 nT), so turning
them into calibration parameters needs the vector (attitude) constraint.

Data: ELFIN SOC (PI V. Angelopoulos, UCLA), "Open Data for Scientific Use".
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from magcal.errors import InputError
from magcal.lstsq import lstsq
from magcal.missions.elfin.phase import repair_timestamps, split_zones

_TRIU = np.triu_indices(3)


def fast_part(t_s, values, degree: int = 5) -> np.ndarray:
    """``values`` minus its least-squares polynomial of ``degree`` in time.

    The "fast part" of a residual: what a slowly varying reference error or drift
    cannot produce within one pass.

    Examples
    --------
    >>> t = np.linspace(0, 300, 3001)
    >>> float(np.abs(fast_part(t, 3 + 0.1 * t ** 2)).max()) < 1e-6
    True
    """
    t = np.asarray(t_s, dtype=float)
    x = 2.0 * (t - t[0]) / max(t[-1] - t[0], 1e-12) - 1.0
    v = np.asarray(values, dtype=float)
    return v - np.polynomial.polynomial.polyval(
        x, np.polynomial.polynomial.polyfit(x, v, degree))


def rms(values) -> float:
    """Root mean square of the finite values."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    return float(np.sqrt(np.mean(v ** 2))) if v.size else float("nan")


@dataclass(frozen=True)
class ScalarFit:
    """A 9-parameter scalar calibration ``B = A (b - O)`` of one zone.

    Attributes
    ----------
    matrix : ndarray (3, 3)
        Upper-triangular ``A`` in nT/count (the rotation of the triad is not seen by a
        scalar fit, so ``A`` is the triangular factor of the calibration matrix).
    offsets_counts : ndarray (3,)
        ``O``.
    residual_nT : ndarray (n,)
        ``|A (b - O)| - |B_ref|``.
    """

    matrix: np.ndarray
    offsets_counts: np.ndarray
    residual_nT: np.ndarray

    def calibrate(self, counts) -> np.ndarray:
        """Calibrated field (nT) in the triangular frame of ``matrix``."""
        return (np.asarray(counts, dtype=float) - self.offsets_counts) @ self.matrix.T


def _ellipsoid_start(counts, magnitude):
    """Algebraic start: ``|B|^2`` as a quadratic form in the counts (linear least squares)."""
    mean = counts.mean(axis=0)
    scale = float(np.abs(counts - mean).max()) or 1.0
    x = (counts - mean) / scale
    design = np.column_stack([x[:, 0] ** 2, x[:, 1] ** 2, x[:, 2] ** 2, 2 * x[:, 0] * x[:, 1],
                              2 * x[:, 0] * x[:, 2], 2 * x[:, 1] * x[:, 2], 2 * x,
                              np.ones(len(x))])
    w = lstsq(design, magnitude ** 2)
    quad = np.array([[w[0], w[3], w[4]], [w[3], w[1], w[5]], [w[4], w[5], w[2]]])
    centre = -np.linalg.solve(quad, w[6:9])
    val, vec = np.linalg.eigh(quad)
    # a pass that barely samples one direction can give a non-positive eigenvalue:
    # start that direction at half the middle gain^2 (the three sensors have similar gains)
    val = np.clip(val, 0.5 * np.median(val), None)
    upper = np.linalg.cholesky((vec * val) @ vec.T).T
    return upper / scale, mean + centre * scale


def linear_scalar_fit(counts, magnitude_nT, *, start=None, max_nfev: int = 1000) -> ScalarFit:
    """Best 9-parameter scalar calibration of counts against a reference magnitude.

    Parameters
    ----------
    counts : array_like (n, 3)
        Raw readings.
    magnitude_nT : array_like (n,)
        Reference field magnitude at the samples (e.g. ``|IGRF|``).
    start : tuple (matrix, offsets_counts), optional
        Starting point; default an algebraic ellipsoid fit.
    max_nfev : int
        Cap on the trust-region iterations. When the field barely leaves a plane (ELFIN:
        the spin-axis component is a few percent of |B|) the fit crawls along a narrow
        valley: two of the 12 ELFIN zones need several hundred iterations (10 s).

    Returns
    -------
    ScalarFit

    Examples
    --------
    >>> rng = np.random.default_rng(1)
    >>> u = rng.normal(size=(500, 3)); u /= np.linalg.norm(u, axis=1)[:, None]
    >>> b = 40000 * u
    >>> a = np.array([[0.010, 0.0002, -0.0001], [0, 0.011, 0.0003], [0, 0, 0.009]])
    >>> counts = np.linalg.solve(a, b.T).T + [1e5, -2e5, 3e4]
    >>> fit = linear_scalar_fit(counts, np.full(500, 40000.0))
    >>> bool(np.allclose(fit.matrix, a, rtol=1e-6)), rms(fit.residual_nT) < 1e-6
    (True, True)
    """
    from scipy.optimize import least_squares

    c = np.asarray(counts, dtype=float)
    f = np.asarray(magnitude_nT, dtype=float)
    if c.ndim != 2 or c.shape[1] != 3 or f.shape != (c.shape[0],):
        raise InputError("need counts (n, 3) and a magnitude (n,)")
    if c.shape[0] < 20 or not (np.all(np.isfinite(c)) and np.all(np.isfinite(f))):
        raise InputError("need at least 20 finite samples for a 9-parameter scalar fit")
    a0, o0 = _ellipsoid_start(c, f) if start is None else start
    a0 = np.asarray(a0, dtype=float) * np.sign(np.diag(a0))[:, None]
    p0 = np.r_[a0[_TRIU], o0]

    def unpack(p):
        a = np.zeros((3, 3))
        a[_TRIU] = p[:6]
        x = c - p[6:]
        y = x @ a.T
        return a, x, y, np.linalg.norm(y, axis=1)

    def resid(p):
        return unpack(p)[3] - f

    def jac(p):
        a, x, y, n = unpack(p)
        u = y / n[:, None]
        return np.column_stack([u[:, _TRIU[0]] * x[:, _TRIU[1]], -u @ a])

    sol = least_squares(resid, p0, jac=jac,
                        x_scale="jac",
                        method="trf", max_nfev=max_nfev)
    a = np.zeros((3, 3))
    a[_TRIU] = sol.x[:6]
    return ScalarFit(matrix=a, offsets_counts=sol.x[6:], residual_nT=sol.fun)


def spin_plane_angle(b, t_s=None) -> tuple[np.ndarray, np.ndarray]:
    """Spin axis and the angle of the field in the spin plane, in the frame of ``b``.

    The spin axis is the direction of least variance of the sample-to-sample changes
    (the spin moves the field in the spin plane only); the angle is measured from an
    arbitrary but fixed axis of that plane, in the sensor's frame (so a harmonic of it
    that keeps its coefficient is fixed in the sensor, not in space).

    Parameters
    ----------
    b : array_like (n, 3)
        Field or counts in any fixed linear frame of the sensor.
    t_s : array_like (n,), optional
        Times; steps longer than 3x the median step (gaps) are left out.

    Returns
    -------
    axis : ndarray (3,)
        Unit spin axis (sign arbitrary).
    psi : ndarray (n,)
        Angle in radians, wrapped.
    """
    v = np.asarray(b, dtype=float)
    d = np.diff(v, axis=0)
    if t_s is not None:
        dt = np.diff(np.asarray(t_s, dtype=float))
        d = d[dt < 3 * np.median(dt)]
    _, vec = np.linalg.eigh(np.cov(d.T))
    axis = vec[:, 0]
    e1 = np.cross(axis, np.eye(3)[int(np.argmin(np.abs(axis)))])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    return axis, np.arctan2(v @ e2, v @ e1)


def _harmonics(psi, ks) -> np.ndarray:
    if not len(ks):
        return np.empty((len(psi), 0))
    return np.column_stack([g(k * psi) for k in ks for g in (np.cos, np.sin)])


def _unit_time(t):
    t = np.asarray(t, dtype=float)
    return 2.0 * (t - t[0]) / max(t[-1] - t[0], 1e-12) - 1.0


def harmonic_amplitudes(t_s, residual, psi, harmonics=(1, 2, 3, 4), *,
                        poly_degree: int = 5) -> dict:
    """Amplitudes (nT) of constant-coefficient harmonics of ``psi`` in a residual.

    Fitted jointly with a time polynomial of ``poly_degree`` (the slow part).

    Returns
    -------
    dict
        ``{k: amplitude}``.
    """
    x = _unit_time(t_s)
    design = np.column_stack([np.vander(x, poly_degree + 1), _harmonics(psi, harmonics)])
    w = lstsq(design, np.asarray(residual, dtype=float))
    h = w[poly_degree + 1:]
    return {int(k): float(np.hypot(h[2 * i], h[2 * i + 1])) for i, k in enumerate(harmonics)}


@dataclass(frozen=True)
class HarmonicFit:
    """Model of a scalar residual by spin harmonics (see :func:`fit_spin_harmonics`).

    Attributes
    ----------
    fixed_amplitudes_nT : dict
        ``{k: (amplitude, phase_rad)}`` of the constant-coefficient harmonics.
    fixed_std_nT : dict
        ``{k: standard error of the amplitude}`` (white-residual least squares; the
        residual is not white, so read it as a lower bound).
    drift_rms_nT : dict
        ``{k: rms}`` of each drifting harmonic's contribution.
    residual_nT : ndarray
        What the model leaves (its slow part removed by the polynomial).
    coefficients : dict
        ``{k: complex ndarray (n,)}``: the harmonic ``k`` contributes
        ``Re(c_k(t) e^{i k psi})`` at each sample (constant for the fixed harmonics).
    """

    fixed_amplitudes_nT: dict
    drift_rms_nT: dict
    residual_nT: np.ndarray
    coefficients: dict = field(default_factory=dict)
    fixed_std_nT: dict = field(default_factory=dict)


def fit_spin_harmonics(t_s, residual, psi, *, fixed=(4,), drifting=(1, 2),
                       drift_degree: int = 3, poly_degree: int = 5,
                       fixed_scale=None) -> HarmonicFit:
    """Fit constant and slowly drifting spin harmonics to a scalar residual.

    Model: ``r = P(T) + sum_fixed Re(c_k e^{i k psi}) + sum_drifting Re(c_k(T) e^{i k
    psi})`` with ``T`` in [-1, 1] over the zone, ``P`` a polynomial of ``poly_degree``
    and ``c_k(T)`` complex polynomials of ``drift_degree``. Linear least squares.
    ``fixed_scale`` (n,), if given, multiplies the fixed harmonics: a non-linearity
    whose size follows the field (a cubic: ``(|B_perp| / median)^3``); the amplitudes
    reported are then those at ``fixed_scale == 1``.

    Returns
    -------
    HarmonicFit
    """
    x = _unit_time(t_s)
    r = np.asarray(residual, dtype=float)
    scale = np.ones(len(x)) if fixed_scale is None else np.asarray(fixed_scale, dtype=float)
    blocks = [np.vander(x, poly_degree + 1), _harmonics(psi, fixed) * scale[:, None]]
    powers = x[:, None, None] ** np.arange(drift_degree + 1)
    drift_cols = [_harmonics(psi, [k])[:, :, None] * powers for k in drifting]
    blocks += [d.reshape(len(x), -1) for d in drift_cols]
    design = np.column_stack(blocks)
    w = lstsq(design, r)
    n0 = poly_degree + 1
    var = np.sum((r - design @ w) ** 2) / max(len(r) - design.shape[1], 1)
    tones = slice(n0, n0 + 2 * len(fixed))
    cov_fixed = var * np.linalg.pinv(design.T @ design)[tones, tones]
    fixed_amp, coefs, fixed_std = {}, {}, {}
    for i, k in enumerate(fixed):
        a, b = w[n0 + 2 * i], w[n0 + 2 * i + 1]
        fixed_amp[int(k)] = (float(np.hypot(a, b)), float(np.arctan2(b, a)))
        fixed_std[int(k)] = float(np.sqrt(0.5 * (cov_fixed[2 * i, 2 * i]
                                                + cov_fixed[2 * i + 1, 2 * i + 1])))
        coefs[int(k)] = (a - 1j * b) * scale
    pos = n0 + 2 * len(fixed)
    drift_rms = {}
    for k, d in zip(drifting, drift_cols):
        m = d.shape[1] * d.shape[2]
        drift_rms[int(k)] = rms(d.reshape(len(x), -1) @ w[pos:pos + m])
        wk = w[pos:pos + m].reshape(2, -1)          # rows: cos, sin; columns: powers of T
        tpow = x[:, None] ** np.arange(drift_degree + 1)
        coefs[int(k)] = coefs.get(int(k), 0) + tpow @ wk[0] - 1j * (tpow @ wk[1])
        pos += m
    return HarmonicFit(fixed_amplitudes_nT=fixed_amp, drift_rms_nT=drift_rms,
                       residual_nT=r - design @ w, coefficients=coefs,
                       fixed_std_nT=fixed_std)


@dataclass(frozen=True)
class ScalarZone:
    """Inputs of one science zone for scalar work.

    Attributes
    ----------
    number : int
        0-based zone number.
    start : str
        ISO UTC of the first sample.
    t_s : ndarray
        Repaired sample times, seconds from the file's first sample (after ``skip_s``).
    counts : ndarray (n, 3)
        Raw readings.
    igrf_nT : ndarray (n,)
        ``|IGRF|`` at the spacecraft.
    sun_fraction : float
        Fraction of the zone's state records in sunlight.
    """

    number: int
    start: str
    t_s: np.ndarray
    counts: np.ndarray
    igrf_nT: np.ndarray
    sun_fraction: float


def scalar_zones(fgs: pd.DataFrame, state: pd.DataFrame, *, min_gap_s: float = 60.0,
                 skip_s: float = 2.0, repair_times: bool = True) -> list[ScalarZone]:
    """Split ELFIN counts into science zones with ``|IGRF|`` at each sample.

    Parameters
    ----------
    fgs, state : DataFrame
        From :mod:`magcal.missions.elfin.files`.
    min_gap_s : float
        Gaps longer than this separate zones.
    skip_s : float
        Seconds left out at each zone's start (turn-on transient).
    repair_times : bool
        Undo paired time-stamp jumps first.
    """
    from scipy.interpolate import CubicSpline

    from magcal.missions.elfin.linear import igrf_gei

    if not {"b1", "b2", "b3"} <= set(fgs.columns):
        raise InputError("FGS frame needs columns b1, b2, b3")
    t_all = (fgs.index.asi8 - fgs.index.asi8[0]) / 1e9
    ts = (state.index.asi8 - fgs.index.asi8[0]) / 1e9
    pos = state[["pos_gei_x", "pos_gei_y", "pos_gei_z"]].to_numpy()
    good_pos = np.all(np.isfinite(pos), axis=1)
    counts_all = fgs[["b1", "b2", "b3"]].to_numpy()
    sun = state["sun"].to_numpy() if "sun" in state else np.full(len(state), np.nan)
    out = []
    for k, (a, b) in enumerate(split_zones(t_all, min_gap_s)):
        t = t_all[a:b]
        if repair_times:
            t, _ = repair_timestamps(t)
        sel = (ts >= t[0] - 5) & (ts <= t[-1] + 5) & good_pos
        if sel.sum() < 10:
            raise InputError(f"no orbit records for zone {k} ({fgs.index[a]})")
        mag = np.linalg.norm(CubicSpline(ts[sel], igrf_gei(state.index[sel], pos[sel]))(t), axis=1)
        c = counts_all[a:b]
        ok = (t >= t[0] + skip_s) & np.all(np.isfinite(c), axis=1)
        lit = sun[sel][np.isfinite(sun[sel])]
        out.append(ScalarZone(number=k, start=str(fgs.index[a].tz_convert(None)), t_s=t[ok],
                              counts=c[ok], igrf_nT=mag[ok],
                              sun_fraction=float(lit.mean()) if lit.size else float("nan")))
    return out


def scalar_floor_table(zones, *, drift_degree: int = 3, fixed=(4,), drifting=(1, 2),
                       poly_degree: int = 5) -> pd.DataFrame:
    """Per-zone scalar numbers: the linear floor, its spin harmonics, the harmonic model.

    Columns: ``zone, start, sun_fraction, n, mean_igrf_nT``, ``floor_rms_nT`` and ``floor_fast_nT``
    (the 9-parameter fit; fast = after a ``poly_degree`` polynomial), ``amp{k}_nT`` for
    k = 1..4 (constant harmonics of the sensor-frame angle in the floor residual),
    ``fixed{k}_nT`` for the model's constant harmonics, ``model_fast_nT`` (what
    :func:`fit_spin_harmonics` leaves).
    """
    rows = []
    for z in zones:
        fit = linear_scalar_fit(z.counts, z.igrf_nT)
        _, psi = spin_plane_angle(fit.calibrate(z.counts), z.t_s)
        r = fit.residual_nT
        amps = harmonic_amplitudes(z.t_s, r, psi, (1, 2, 3, 4), poly_degree=poly_degree)
        model = fit_spin_harmonics(z.t_s, r, psi, fixed=fixed, drifting=drifting,
                                   drift_degree=drift_degree, poly_degree=poly_degree)
        rows.append({"zone": z.number, "start": z.start, "sun_fraction": z.sun_fraction,
                     "n": int(z.t_s.size), "mean_igrf_nT": float(np.mean(z.igrf_nT)),
                     "floor_rms_nT": rms(r),
                     "floor_fast_nT": rms(fast_part(z.t_s, r, poly_degree)),
                     **{f"amp{k}_nT": v for k, v in amps.items()},
                     **{f"fixed{k}_nT": v[0] for k, v in model.fixed_amplitudes_nT.items()},
                     **{f"drift{k}_rms_nT": v for k, v in model.drift_rms_nT.items()},
                     "model_fast_nT": rms(model.residual_nT)})
    return pd.DataFrame(rows)
