"""Vector-only ELFIN errors: body-fixed spin harmonics the scalar cannot see, and tilt.

After the linear calibration, the spin-harmonic correction and the gain drift
(:mod:`magcal.missions.elfin.drift`) the ELFIN-A scalar residual is about 8 nT but the
vector residual against IGRF about 38 nT per component (2022-01-12). Almost all of it is
perpendicular to the field (6-17 nT along it), and most of that sits *within* the spin
in the spinning frame (``z`` = spin axis, ``beta = Bx + i By``, ``psi = arg beta``):

* in the spin plane, ``e^{3i psi}`` and ``e^{-i psi}`` terms of equal size (15-20 nT):
  a wobble of the field's angle at twice the spin frequency (``i beta`` times a real 2x
  modulation: invisible in ``|B|``);
* along the spin axis a 1x term (35-55 nT in 8 zones): a spin-axis sensor coupling to
  the spin-plane field that drifts within the pass.

Neither can come from the reference, the attitude or a natural field: those are fixed
in inertial space or slow, so in the spinning frame they appear only as ``e^{i psi}``
(spin plane) and as a slow spin-axis term, which are left out of the fit here on
purpose. The coefficients drift as polynomials in time, or on cubic B-splines
(``knot_s``: the spin-axis 1x coupling moves along one body direction and changes sign
every ~100 s in the eclipse passes, faster than a cubic; 30 s knots take the day's
vector median from 21.7 to 17.7 nT). What remains is slow and
transverse: the spin axis's direction (:func:`refine_tilt`, two angles per zone bounded
by the attitude file's 0.2 deg) and natural fields that IGRF lacks.

Data: ELFIN SOC (PI V. Angelopoulos, UCLA), "Open Data for Scientific Use".
"""

from __future__ import annotations

import numpy as np

from magcal.lstsq import lstsq
from magcal.missions.elfin.drift import map_zones, unit_time
from magcal.missions.elfin.scalar import fast_part, rms


def drift_basis(t_s, use, *, degree: int = 3, knot_s: float | None = None) -> np.ndarray:
    """Columns for a coefficient that drifts in time: powers of ``T`` or cubic B-splines.

    ``T`` runs from -1 to 1 over the samples selected by ``use``. With ``knot_s`` the
    columns are cubic B-splines with knots every ``knot_s`` seconds over the same span
    (each column is zero outside its four knot intervals; times outside the span are
    clipped to it; no knot where ``use`` has no samples:
    :func:`~magcal.missions.elfin.phase.spline_knots`), otherwise ``1, T, .., T^degree``.

    Examples
    --------
    >>> t = np.arange(0.0, 100.0, 0.5)
    >>> drift_basis(t, t >= 0, degree=2).shape, drift_basis(t, t >= 0, knot_s=30.0).shape
    ((200, 3), (200, 6))
    >>> bool(np.allclose(drift_basis(t, t >= 0, knot_s=30.0).sum(axis=1), 1.0))
    True
    """
    t = np.asarray(t_s, dtype=float)
    if knot_s is None:
        return np.column_stack([unit_time(t, use) ** d for d in range(degree + 1)])
    from scipy.interpolate import BSpline

    from magcal.missions.elfin.phase import spline_knots

    knots = spline_knots(t[use], knot_s)        # none where ``use`` has no samples
    return BSpline.design_matrix(np.clip(t, knots[0], knots[-1]), knots, 3).toarray()


def vector_harmonic_correction(t_s, b_body, ref_body, *, plane=(-1, 3), axial=(1,),
                               degree: int = 3, knot_s: float | None = None,
                               fit_mask=None) -> tuple[np.ndarray, dict]:
    """Remove body-fixed spin harmonics from the vector residual in the spinning frame.

    Model of the residual ``b - ref``: spin plane ``sum_k c_k(T) e^{i k psi}`` for ``k``
    in ``plane``, spin axis ``sum_k Re(d_k(T) e^{i k psi})`` for ``k`` in ``axial``, with
    ``psi`` the angle of the *measured* field in the spin plane and ``c_k, d_k``
    complex polynomials of ``degree`` in ``T`` (-1..1 over the fitted samples). Linear
    least squares; ``k = 1`` (plane) and ``k = 0`` (axis) are refused because the
    reference, attitude and natural fields live there: they are fitted alongside, with
    the same drift basis, and left in the field, so that a harmonic cannot take part of
    a slow residual where spin-phase sectors are missing from ``fit_mask`` (clipped
    counts: a 0.1 deg cubic phase error, 30 nT, lost 11 nT to the harmonics without).

    Parameters
    ----------
    t_s : array_like (n,)
        Times, seconds.
    b_body, ref_body : array_like (n, 3)
        Calibrated and reference field in the spinning frame (``z`` = spin axis), nT.
    plane, axial : sequence of int
        Harmonics fitted in the spin plane and along the spin axis.
    degree : int
        Degree of the coefficients' drift in time.
    knot_s : float, optional
        Drift as cubic B-splines with knots every ``knot_s`` seconds instead of the
        polynomial (:func:`drift_basis`). On ELFIN-A the spin-axis 1x coefficient moves
        along one body direction and changes sign every ~100 s in the eclipse zones
        (:func:`magcal.missions.elfin.diagnostics.evidence.axial_coupling_line`), faster
        than a cubic follows; 30 s knots keep it far (> 10x) from the slow band where reference,
        attitude and natural fields live.
    fit_mask : array_like of bool, optional
        Samples used in the fit (default all); the correction is applied to all.

    Returns
    -------
    corrected : ndarray (n, 3)
    info : dict
        ``plane_rms_nT`` and ``axial_rms_nT`` (``{k: RMS of the removed term}``) and the
        vector RMS (per component) before and after on the fitted samples.

    Raises
    ------
    ValueError
        If ``plane`` holds 1 or ``axial`` holds 0.

    Examples
    --------
    >>> t = np.arange(0.0, 300.0, 0.1)
    >>> psi = 2 * np.pi * t / 2.85
    >>> ref = np.column_stack([45000 * np.cos(psi), 45000 * np.sin(psi), 2000 + 0 * t])
    >>> b = ref.copy()
    >>> b[:, 2] += 40 * np.cos(psi - 0.3)               # spin-axis sensor tilt, 1x
    >>> fixed, info = vector_harmonic_correction(t, b, ref)
    >>> bool(np.abs(fixed - ref).max() < 1e-6), round(info["axial_rms_nT"][1], 1)
    (True, 28.3)
    """
    if 1 in plane or 0 in axial:
        raise ValueError("plane k = 1 and axial k = 0 hold the reference/attitude error: "
                         "not fitted")
    t = np.asarray(t_s, dtype=float)
    b = np.array(b_body, dtype=float)
    ref = np.asarray(ref_body, dtype=float)
    use = np.ones(t.size, bool) if fit_mask is None else np.asarray(fit_mask, bool)
    powers = drift_basis(t, use, degree=degree, knot_s=knot_s)
    psi = np.angle(b[:, 0] + 1j * b[:, 1])
    e = b - ref
    info = {"plane_rms_nT": {}, "axial_rms_nT": {},
            "vector_rms_before_nT": rms(e[use])}
    # the refused terms (plane k = 1, axis k = 0: slow in the despun frame) are fitted
    # alongside and not removed: over whole spins they are orthogonal to the harmonics,
    # but where spin-phase sectors are missing (clipped counts) a harmonic fitted
    # without them takes part of a slow residual (the phase error the refit removes)
    if plane:
        cols = [np.exp(1j * k * psi)[:, None] * powers for k in plane]
        nuisance = np.exp(1j * psi)[:, None] * powers
        w = lstsq(np.column_stack(cols + [nuisance])[use], (e[:, 0] + 1j * e[:, 1])[use])
        w = w[:len(plane) * powers.shape[1]].reshape(len(plane), -1)
        model = sum(c @ wk for c, wk in zip(cols, w))
        b[:, 0] -= model.real
        b[:, 1] -= model.imag
        info["plane_rms_nT"] = {int(k): rms(np.abs(c @ wk)[use]) / np.sqrt(2)
                                for k, c, wk in zip(plane, cols, w)}
    if axial:
        cols = [np.column_stack([np.cos(k * psi)[:, None] * powers,
                                 np.sin(k * psi)[:, None] * powers]) for k in axial]
        w = lstsq(np.column_stack(cols + [powers])[use], e[use, 2])
        w = w[:-powers.shape[1]].reshape(len(axial), -1)
        b[:, 2] -= sum(c @ wk for c, wk in zip(cols, w))
        info["axial_rms_nT"] = {int(k): rms((c @ wk)[use]) for k, c, wk in zip(axial, cols, w)}
    info["vector_rms_after_nT"] = rms((b - ref)[use])
    return b, info


def refine_tilt(b_despun, ref_despun, *, bound_deg: float = 0.2, fit_mask=None,
                steps=None):
    """Small rotation about the despun X and Y axes (a spin-axis tilt) within a bound.

    The calibrated vectors are rotated by ``-w`` (``w = (wx, wy, 0)``, radians) with
    ``b - w x b`` fitted to the reference by bounded linear least squares (a box of
    ``bound_deg`` on each angle: the attitude file's stated 0.2 deg). The rotation about
    the spin axis is the spin phase, fitted before.

    Returns
    -------
    corrected : ndarray (n, 3)
    angles_deg : ndarray (2,)
    at_bound : bool
        True if an angle sits on the bound (the data want more than the attitude file's
        uncertainty allows).

    ``steps`` (n, m): level steps of the spin-axis field
    (:func:`~magcal.missions.elfin.levels.step_columns`), fitted with the angles
    without a bound and left in the field, so that a natural field's new level after
    an interval left out of the fit is not taken as a tilt.

    Examples
    --------
    >>> th = np.radians(0.1)
    >>> ref = np.column_stack([45000 * np.cos(np.linspace(0, 1, 50)),
    ...                        45000 * np.sin(np.linspace(0, 1, 50)), np.full(50, 2000.0)])
    >>> b = ref + np.cross([th, 0.0, 0.0], ref)
    >>> fixed, ang, hit = refine_tilt(b, ref)
    >>> bool(np.allclose(ang, [0.1, 0.0], atol=1e-4)), hit
    (True, False)
    """
    from scipy.optimize import lsq_linear

    b = np.asarray(b_despun, dtype=float)
    ref = np.asarray(ref_despun, dtype=float)
    use = np.ones(len(b), bool) if fit_mask is None else np.asarray(fit_mask, bool)
    cx = np.cross([1.0, 0.0, 0.0], b)
    cy = np.cross([0.0, 1.0, 0.0], b)
    cols = [cx[use].ravel(), cy[use].ravel()]
    for h in np.asarray(steps, float).T if steps is not None else ():
        on_axis = np.zeros((len(b), 3))
        on_axis[:, 2] = h
        cols.append(on_axis[use].ravel())
    lim = np.radians(bound_deg)
    free = np.full(len(cols) - 2, np.inf)
    sol = lsq_linear(np.column_stack(cols), (b - ref)[use].ravel(),
                     bounds=(np.r_[-lim, -lim, -free], np.r_[lim, lim, free]))
    w = sol.x[:2]
    at_bound = bool(np.any(sol.active_mask[:2] != 0))    # the solver's own verdict
    return b - (w[0] * cx + w[1] * cy), np.degrees(w), at_bound


def correct_vector_zone(t_s, b_despun, phase, ref_despun, *, bound_deg: float = 0.2,
                        fit_mask=None, tone_mask=None, level_step_rows=None,
                        **kw) -> tuple[np.ndarray, dict]:
    """One zone: :func:`vector_harmonic_correction` in the spinning frame, then the tilt.

    Parameters
    ----------
    t_s : array_like (n,)
        Times, seconds.
    b_despun, ref_despun : array_like (n, 3)
        Calibrated and reference field in the despun frame (``Z`` = spin axis), nT.
    phase : array_like (n,)
        Spin phase (rad) that relates the despun and spinning frames.
    bound_deg : float
        Bound of the spin-axis tilt (0: no tilt fitted).
    fit_mask : array_like of bool, optional
        Samples used in the fits.
    tone_mask : array_like of bool, optional
        Samples used in the harmonics' fit instead of ``fit_mask``: the harmonics it
        fits are spin tones in the despun frame, where a natural field is slow, so
        samples left out of the other fits for a natural field (``fit_exclude``) may stay
        in this one, which then holds the tones across a long interval instead of
        bridging them (2022-01-12: bridged intervals of 100-150 s made up to 116 nT of
        spin tones).
    level_step_rows : array_like of bool, optional
        Rows of left-out intervals across which the spin-axis level may change: the
        tilt is fitted with a level step after each run (:func:`refine_tilt`,
        ``steps``; :func:`~magcal.missions.elfin.levels.level_step_rows`).
    **kw
        Passed to :func:`vector_harmonic_correction`.

    Returns
    -------
    corrected : ndarray (n, 3)
        Despun frame.
    info : dict
        That of :func:`vector_harmonic_correction` plus ``tilt_deg``, ``tilt_at_bound``,
        ``n_level_steps`` (fitted with the tilt) and ``vector_rms_after_nT`` after the
        tilt.
    """
    from magcal.spin.despin import despin, spin

    t = np.asarray(t_s, dtype=float)
    ref = np.asarray(ref_despun, dtype=float)
    use = np.ones(t.size, bool) if fit_mask is None else np.asarray(fit_mask, bool)
    tones = use if tone_mask is None else np.asarray(tone_mask, bool)
    body, info = vector_harmonic_correction(t, spin(b_despun, phase), spin(ref, phase),
                                            fit_mask=tones, **kw)
    new_d = despin(body, phase)
    angles, at_bound, steps = np.zeros(2), False, None
    if bound_deg:
        from magcal.missions.elfin.levels import step_columns

        if level_step_rows is not None and np.any(level_step_rows):
            steps = step_columns(level_step_rows)
        new_d, angles, at_bound = refine_tilt(new_d, ref, bound_deg=bound_deg, fit_mask=use,
                                              steps=steps)
    info.update({"tilt_deg": angles.tolist(), "tilt_at_bound": at_bound,
                 "n_level_steps": 0 if steps is None else int(steps.shape[1]),
                 "vector_rms_after_nT": rms((new_d - ref)[use])})
    return new_d, info


def correct_vector(cal, *, bound_deg: float = 0.2, **kw):
    """Apply :func:`correct_vector_zone` zone by zone to an ElfinCalibration.

    Parameters
    ----------
    cal : magcal.missions.elfin.ElfinCalibration
        Usually after the gain drift (:func:`magcal.missions.elfin.drift.correct_gain_drift`).
        Its field's ``level_step`` column (set by the linear fit's ``level_step_rows``)
        gives the tilt its level steps (``level_step_rows`` of
        :func:`correct_vector_zone`).
    bound_deg : float
        Bound of the spin-axis tilt (0: no tilt fitted).
    **kw
        Passed to :func:`vector_harmonic_correction`.

    Returns
    -------
    corrected : ElfinCalibration
    table : DataFrame
        Per zone: the removed harmonics (RMS, nT), the tilt (deg) and whether it is on
        the bound, vector RMS before/after and the scalar RMS and fast part after.
    """
    def step(t, z, used):
        ref = z[["igrf_x_despun", "igrf_y_despun", "igrf_z_despun"]].to_numpy(float)
        new_d, info = correct_vector_zone(
            t, z[["bx_despun", "by_despun", "bz_despun"]].to_numpy(float),
            z["phase"].to_numpy(float), ref, bound_deg=bound_deg, fit_mask=used,
            tone_mask=z["used"].to_numpy() == 1,
            level_step_rows=z["level_step"].to_numpy() == 1 if "level_step" in z else None,
            **kw)
        scal = (np.linalg.norm(new_d, axis=1) - np.linalg.norm(ref, axis=1))[used]
        return new_d, {**info, "scalar_rms_after_nT": rms(scal),
                       "scalar_fast_after_nT": rms(fast_part(t[used], scal))}

    return map_zones(cal, step, "vector_correction",
                     {"bound_deg": bound_deg, **kw})


def refine_phase(t_s, b_despun, ref_despun, *, knot_s: float = 60.0,
                 fit_mask=None) -> tuple[np.ndarray, np.ndarray]:
    """Refit the spin phase at the end: a smooth turn about the spin axis.

    The phase of :func:`~magcal.missions.elfin.linear.fit_zone` is fitted (a spline, 30 s knots)
    against IGRF's spin-plane angle on the *linear* calibration, while the spin-plane
    field is still off by the 60 nT that the later steps remove; the in-plane angle then
    moves by a few hundredths of a degree. Here the angle between the calibrated and the
    reference spin-plane field is fitted again by a cubic B-spline with knots every
    ``knot_s`` seconds (no finer than the first phase fit: nothing the calibration did not
    already absorb) and the vectors are turned by it about despun ``Z``; the spin phase
    grows by the same angle (``despin(b_body, phase + c)``).

    Returns
    -------
    corrected : ndarray (n, 3)
    correction_rad : ndarray (n,)
        Added to the spin phase.

    Examples
    --------
    >>> t = np.arange(0.0, 300.0, 0.1)
    >>> ref = np.column_stack([45000 * np.cos(t / 400), 45000 * np.sin(t / 400), 0 * t + 2000])
    >>> err = 1e-3 * (t / 150 - 1) ** 3                    # 0.11 deg p-p phase wander
    >>> b = np.column_stack([np.cos(err) * ref[:, 0] - np.sin(err) * ref[:, 1],
    ...                      np.sin(err) * ref[:, 0] + np.cos(err) * ref[:, 1], ref[:, 2]])
    >>> fixed, corr = refine_phase(t, b, ref)
    >>> bool(np.abs(fixed - ref).max() < 1e-6), bool(np.allclose(corr, -err, atol=1e-12))
    (True, True)
    """
    from magcal.missions.elfin.phase import wrap

    t = np.asarray(t_s, dtype=float)
    b = np.asarray(b_despun, dtype=float)
    ref = np.asarray(ref_despun, dtype=float)
    use = np.ones(t.size, bool) if fit_mask is None else np.asarray(fit_mask, bool)
    basis = drift_basis(t, use, knot_s=knot_s)
    angle = wrap(np.arctan2(ref[:, 1], ref[:, 0]) - np.arctan2(b[:, 1], b[:, 0]))
    corr = basis @ lstsq(basis[use], angle[use])
    c, s = np.cos(corr), np.sin(corr)
    out = b.copy()
    out[:, 0] = c * b[:, 0] - s * b[:, 1]
    out[:, 1] = s * b[:, 0] + c * b[:, 1]
    return out, corr


def correct_phase(cal, *, knot_s: float = 60.0):
    """Apply :func:`refine_phase` zone by zone to an ElfinCalibration (the last step).

    Returns
    -------
    corrected : ElfinCalibration
        Despun and GEI vectors turned, ``phase`` updated.
    table : DataFrame
        Per zone: ``phase_pp_deg`` (peak-to-peak of the correction), vector RMS before and
        after, and the spin-plane RMS per component after (despun X, Y; nT).
    """
    from dataclasses import replace

    corrections = {}

    def step(t, z, used):
        ref = z[["igrf_x_despun", "igrf_y_despun", "igrf_z_despun"]].to_numpy(float)
        desp = z[["bx_despun", "by_despun", "bz_despun"]].to_numpy(float)
        new_d, corr = refine_phase(t, desp, ref, knot_s=knot_s, fit_mask=used)
        corrections[int(z["zone"].iloc[0])] = corr
        return new_d, {"phase_pp_deg": float(np.degrees(np.ptp(corr[used]))),
                       "vector_rms_before_nT": rms((desp - ref)[used]),
                       "vector_rms_after_nT": rms((new_d - ref)[used]),
                       "plane_rms_after_nT": rms((new_d - ref)[used, :2])}

    out, table = map_zones(cal, step, "phase_refit", {"knot_s": knot_s})
    f = out.field.copy()
    for k, corr in corrections.items():
        sel = (f["zone"] == k).to_numpy()
        f.loc[sel, "phase"] = f.loc[sel, "phase"].to_numpy(float) + corr
    return replace(out, field=f), table
