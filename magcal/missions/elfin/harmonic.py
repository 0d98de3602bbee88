"""Spin-harmonic correction of calibrated ELFIN vectors (beyond the linear floor).

The scalar residual of any linear ELFIN calibration holds (see
:mod:`magcal.missions.elfin.scalar`) a 4x-spin harmonic fixed in the sensor (a cubic
non-linearity of the spin-plane sensors: amplitude about 8e-4 of |B|, growing as
|B|^2.7 across zones) and 1x/2x harmonics whose coefficients drift within a pass
(spin-plane offsets and gain ratio/non-orthogonality changing over the ~6 min of a
science zone). Here the scalar model is turned into a vector correction in the
spinning body frame (``z`` = spin axis), with ``beta = Bx + i By = |beta| e^{i psi}``:

    the scalar term ``Re(c_k e^{i k psi})`` is removed by ``delta_k = -conj(c_k)
    e^{-i (k-1) psi} |B| / |beta|``,

so ``k = 1`` is a spin-plane offset, ``k = 2`` a symmetric traceless spin-plane matrix
(gain ratio, non-orthogonality) and ``k = 4`` a cubic distortion ``~ conj(beta)^3``.
The scalar residual cannot tell ``conj(beta)^3`` from ``beta^5 / |beta|^2`` (both give
4x); the cubic is the lower-order, physically usual choice. The spin-axis component and
the slow part of the residual are left alone (the slow part may be reference error).

Data: ELFIN SOC (PI V. Angelopoulos, UCLA), "Open Data for Scientific Use".
"""

from __future__ import annotations

import numpy as np

from magcal.lstsq import lstsq
from magcal.missions.elfin.scalar import fast_part, fit_spin_harmonics, rms
from magcal.spin.despin import despin, spin


def _over_perp(mag, beta):
    """``|B| / |B_perp|`` per sample; NaN where the counts were fill (no warning)."""
    perp = np.abs(beta)
    return np.divide(mag, perp, out=np.full(perp.shape, np.nan), where=perp > 0)


def harmonic_vector_correction(t_s, b_body, ref_magnitude_nT, *, fixed=(4,), drifting=(1, 2),
                               drift_degree: int = 3, poly_degree: int = 5,
                               fixed_power: float = 3.0, n_iter: int = 2,
                               fit_mask=None) -> tuple[np.ndarray, dict]:
    """Remove the spin-harmonic part of the scalar residual from body-frame vectors.

    Parameters
    ----------
    t_s : array_like (n,)
        Times, seconds.
    b_body : array_like (n, 3)
        Calibrated field in the spinning frame, ``z`` along the spin axis (nT).
    ref_magnitude_nT : array_like (n,)
        Reference magnitude (|IGRF|).
    fixed, drifting, drift_degree, poly_degree :
        Passed to :func:`~magcal.missions.elfin.scalar.fit_spin_harmonics`.
    fixed_power : float
        The fixed harmonics scale as ``|beta|^fixed_power`` (3: a cubic non-linearity;
        across the ELFIN zones the 4x amplitude grows as |B|^2.7).
    n_iter : int
        Refits (the correction is first order in the small terms; a second pass removes
        what the first leaves at second order).
    fit_mask : array_like of bool, optional
        Samples used in the fit (default all); the correction is applied to all.

    Returns
    -------
    corrected : ndarray (n, 3)
    info : dict
        ``fixed_amplitudes_nT`` (first pass, at the median |beta|), their standard errors
        ``fixed_std_nT``, ``fixed_at_45000nT`` (scaled to |beta| = 45000 nT with
        ``fixed_power``: comparable across zones), ``drift_rms_nT`` and the scalar RMS
        and fast-part RMS before and after (on the fitted samples).
    """
    t = np.asarray(t_s, dtype=float)
    b = np.array(b_body, dtype=float)
    ref = np.asarray(ref_magnitude_nT, dtype=float)
    use = np.ones(t.size, bool) if fit_mask is None else np.asarray(fit_mask, bool)
    r0 = np.linalg.norm(b, axis=1) - ref
    first = None
    for _ in range(max(1, n_iter)):
        beta = b[:, 0] + 1j * b[:, 1]
        psi = np.angle(beta)
        mag = np.linalg.norm(b, axis=1)
        r = mag - ref
        scale = (np.abs(beta) / np.median(np.abs(beta[use]))) ** fixed_power
        model = fit_spin_harmonics(t[use], r[use], psi[use], fixed=fixed, drifting=drifting,
                                   drift_degree=drift_degree, poly_degree=poly_degree,
                                   fixed_scale=scale[use])
        first = first or model
        delta = np.zeros(t.size, complex)
        for k, c in model.coefficients.items():
            ck = np.interp(t, t[use], c.real) + 1j * np.interp(t, t[use], c.imag)
            delta -= np.conj(ck) * np.exp(-1j * (k - 1) * psi) * _over_perp(mag, beta)
        b[:, 0] += delta.real
        b[:, 1] += delta.imag
    r1 = np.linalg.norm(b, axis=1) - ref
    b_in = np.asarray(b_body, dtype=float)
    ref_perp = float(np.median(np.hypot(b_in[:, 0], b_in[:, 1])[use]))
    info = {"fixed_amplitudes_nT": {k: v[0] for k, v in first.fixed_amplitudes_nT.items()},
            "fixed_std_nT": first.fixed_std_nT,
            "fixed_at_45000nT": {k: v[0] * (45000.0 / ref_perp) ** fixed_power
                                 for k, v in first.fixed_amplitudes_nT.items()},
            "drift_rms_nT": first.drift_rms_nT,
            "scalar_rms_before_nT": rms(r0[use]), "scalar_rms_after_nT": rms(r1[use]),
            "scalar_fast_before_nT": rms(fast_part(t[use], r0[use], poly_degree)),
            "scalar_fast_after_nT": rms(fast_part(t[use], r1[use], poly_degree))}
    return b, info


def correct_elfin_calibration(cal, **kw):
    """Apply :func:`harmonic_vector_correction` zone by zone to an ElfinCalibration.

    Parameters
    ----------
    cal : magcal.missions.elfin.ElfinCalibration
        From :func:`~magcal.missions.elfin.linear.calibrate_elfin`.
    **kw
        Passed to :func:`harmonic_vector_correction`.

    Returns
    -------
    corrected : ElfinCalibration
        Same columns; ``bx_despun ..`` and ``bx_gei ..`` corrected. (The per-zone
        summaries are those of the linear fit.)
    table : DataFrame
        Per zone: scalar and vector RMS against IGRF before and after, fast parts, the
        4x amplitude and the drifting 1x/2x RMS.
    """
    from magcal.missions.elfin.drift import map_zones

    def step(t, z, used):
        phase = z["phase"].to_numpy()
        desp = z[["bx_despun", "by_despun", "bz_despun"]].to_numpy()
        ref_d = z[["igrf_x_despun", "igrf_y_despun", "igrf_z_despun"]].to_numpy()
        body, info = harmonic_vector_correction(t, spin(desp, phase),
                                                np.linalg.norm(ref_d, axis=1),
                                                fit_mask=used, **kw)
        new_d = despin(body, phase)
        return new_d, {**info, "vector_rms_before_nT": rms((desp - ref_d)[used]),
                       "vector_rms_after_nT": rms((new_d - ref_d)[used])}

    return map_zones(cal, step, "spin_harmonic_correction", kw, scalar=True)


def drifting_harmonic_correction(t_s, b_body, ref_magnitude_nT, *, harmonics=(1, 2),
                                 knot_s: float = 30.0, poly_degree: int = 5,
                                 n_iter: int = 2, fit_mask=None) -> tuple[np.ndarray, dict]:
    """Spin harmonics of ``|B|`` with coefficients drifting on B-splines, removed as vectors.

    As :func:`harmonic_vector_correction` with ``drifting`` only, but the coefficients
    ``c_k(t)`` are cubic B-splines with knots every ``knot_s`` seconds
    (:func:`~magcal.missions.elfin.vector.drift_basis`) instead of cubics over the zone:
    in the sunlit ELFIN-A passes (zones 7 and 8 of 2022-01-12) the 1x/2x terms change
    within a minute (:mod:`magcal.missions.elfin.diagnostics.sun`: this, not a Sun-locked term, is
    what the data support). The slow part (a polynomial of ``poly_degree``) is fitted
    alongside and left alone.

    Parameters
    ----------
    t_s : array_like (n,)
        Times, seconds.
    b_body : array_like (n, 3)
        Calibrated field in the spinning frame (``z`` = spin axis), nT.
    ref_magnitude_nT : array_like (n,)
        |IGRF|.
    harmonics : sequence of int
        Harmonics of the field's spin-plane angle ``psi`` (1: spin-plane offsets, 2: gain
        ratio and non-orthogonality).
    knot_s : float
        Knot spacing of the drift.
    poly_degree : int
        Degree of the slow part fitted alongside.
    n_iter : int
        Refits (the second removes what the first leaves at second order).
    fit_mask : array_like of bool, optional
        Samples used in the fit (default all); the correction is applied to all.

    Returns
    -------
    corrected : ndarray (n, 3)
    info : dict
        ``scalar_rms_before_nT``/``_after_nT``, ``scalar_fast_before_nT``/``_after_nT``
        and ``drift_rms_nT`` (``{k: RMS of the removed term}``, first pass).

    Examples
    --------
    >>> t = np.arange(0.0, 360.0, 0.1)
    >>> psi = 2 * np.pi * t / 2.85
    >>> true = np.column_stack([45000 * np.cos(psi), 45000 * np.sin(psi), 2000 + 0 * t])
    >>> g = 4e-4 * np.cos(2 * np.pi * t / 200)               # gain ratio, 200 s period
    >>> bad = true * np.c_[1 + g, 1 - g, np.ones_like(t)]
    >>> fixed, info = drifting_harmonic_correction(t, bad, np.linalg.norm(true, axis=1))
    >>> info["scalar_fast_before_nT"] > 5, info["scalar_fast_after_nT"] < 0.1
    (True, True)
    """
    from magcal.missions.elfin.vector import drift_basis

    t = np.asarray(t_s, dtype=float)
    b = np.array(b_body, dtype=float)
    ref = np.asarray(ref_magnitude_nT, dtype=float)
    use = np.ones(t.size, bool) if fit_mask is None else np.asarray(fit_mask, bool)
    basis = drift_basis(t, use, knot_s=knot_s)
    x = 2.0 * (t - t[use][0]) / max(t[use][-1] - t[use][0], 1e-12) - 1.0
    slow = np.vander(x, poly_degree + 1)
    r0 = np.linalg.norm(b, axis=1) - ref
    first = None
    for _ in range(max(1, n_iter)):
        beta = b[:, 0] + 1j * b[:, 1]
        psi = np.angle(beta)
        mag = np.linalg.norm(b, axis=1)
        cols = [slow] + [f(k * psi)[:, None] * basis for k in harmonics for f in (np.cos, np.sin)]
        w = lstsq(np.column_stack(cols)[use], (mag - ref)[use])
        w = w[slow.shape[1]:].reshape(len(harmonics), 2, -1)
        delta = np.zeros(t.size, complex)
        removed = {}
        for k, (wc, ws) in zip(harmonics, w):
            c = basis @ wc - 1j * (basis @ ws)                 # term Re(c e^{i k psi})
            removed[int(k)] = rms(np.real(c * np.exp(1j * k * psi))[use])
            delta -= np.conj(c) * np.exp(-1j * (k - 1) * psi) * _over_perp(mag, beta)
        first = first or removed
        b[:, 0] += delta.real
        b[:, 1] += delta.imag
    r1 = np.linalg.norm(b, axis=1) - ref
    return b, {"scalar_rms_before_nT": rms(r0[use]), "scalar_rms_after_nT": rms(r1[use]),
               "scalar_fast_before_nT": rms(fast_part(t[use], r0[use], poly_degree)),
               "scalar_fast_after_nT": rms(fast_part(t[use], r1[use], poly_degree)),
               "drift_rms_nT": first}


def correct_fast_drift(cal, **kw):
    """Apply :func:`drifting_harmonic_correction` zone by zone to an ElfinCalibration.

    Parameters
    ----------
    cal : magcal.missions.elfin.ElfinCalibration
        Usually after the gain drift and before the vector step.
    **kw
        Passed to :func:`drifting_harmonic_correction`.

    Returns
    -------
    corrected : ElfinCalibration
    table : DataFrame
        Per zone: the :func:`drifting_harmonic_correction` numbers and the vector RMS
        before/after (despun, nT).
    """
    from magcal.missions.elfin.drift import map_zones

    def step(t, z, used):
        phase = z["phase"].to_numpy(float)
        desp = z[["bx_despun", "by_despun", "bz_despun"]].to_numpy(float)
        ref = z[["igrf_x_despun", "igrf_y_despun", "igrf_z_despun"]].to_numpy(float)
        body, info = drifting_harmonic_correction(t, spin(desp, phase),
                                                  np.linalg.norm(ref, axis=1),
                                                  fit_mask=used, **kw)
        new_d = despin(body, phase)
        return new_d, {**info, "vector_rms_before_nT": rms((desp - ref)[used]),
                       "vector_rms_after_nT": rms((new_d - ref)[used])}

    return map_zones(cal, step, "fast_drift", kw, scalar=True)
