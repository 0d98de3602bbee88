"""Spin-plane gain drift within an ELFIN pass: the slow part of the scalar residual.

After the linear calibration and the spin-harmonic correction
(:mod:`magcal.missions.elfin.harmonic`) the ELFIN-A scalar residual ``|B| - |IGRF|``
keeps a *slow part* of about 60 nT RMS per science zone (quadratic to cubic in time
over the ~6 min pass). What the data say about it (2022-01-12, see
``workflows/elfin_scalar_floor.py --slow``):

* it lives in the magnitude of the spin-plane field (the spin-axis component adds
  < 3 nT to it), which a constant-gain calibration fixes to ``G |counts_perp|`` whatever
  the attitude: it is not an attitude error;
* reference errors do not explain it (:mod:`magcal.missions.elfin.diagnostics.reference`): a time
  offset, a rotated position frame or the external field would need one coefficient
  for the day, and the coefficients they need differ in sign from zone to zone or are
  unphysical;
* the spin-plane gains are seen to drift within each pass without any reference: the
  2x-spin harmonic of the scalar residual (a gain ratio/non-orthogonality change, which
  a smooth reference error cannot make) drifts by 56-79 nT RMS, and the time shape of
  that drift follows the slow part (:func:`drift_shape_agreement`: |correlation| 0.95-1.00
  in 10 of 12 zones, ratio about 1);
* in the vector residual of the linear calibration the drifts of the ``e^{i psi}`` and
  ``e^{-i psi}`` terms are equal (:func:`drift_pair`, within 15 % in 10 of 12 zones):
  the signature of a gain that changes along one direction of the spin plane (a
  sensor's gain drifting with, e.g., temperature), whose isotropic half is the slow
  part. The two zones that differ (9 and 10, entering eclipse at the zone start) have
  the smallest slow part.

So the slow part is modelled as the isotropic half of the same gain drift: the
spin-plane components are divided by ``1 + g(T)``, ``g`` a polynomial in ``T``
(-1..1 over the zone), fitted to the scalar residual through
``d|B| = g |B_perp|^2 / |B|``. Together with the drifting 2x term of the harmonic
correction (the traceless half) this is a drifting symmetric 2x2 spin-plane gain matrix.
Limits: the isotropic drift is only seen against the model field, so a reference error
that is slow within a pass (IGRF, external field: of order 10 nT) is absorbed into it.

Data: ELFIN SOC (PI V. Angelopoulos, UCLA), "Open Data for Scientific Use".
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pandas as pd

from magcal.lstsq import lstsq
from magcal.missions.elfin.scalar import fast_part, fit_spin_harmonics, rms
from magcal.stats import normal_mad


def unit_time(t, use) -> np.ndarray:
    """Time scaled to -1..1 over the samples selected by ``use`` (polynomial drifts)."""
    t = np.asarray(t, dtype=float)
    t0, t1 = t[use][0], t[use][-1]
    return 2.0 * (t - t0) / max(t1 - t0, 1e-12) - 1.0


def tukey_weights(t_s, resid, use, c: float, smooth_s: float = 3.0) -> np.ndarray:
    """Tukey biweights of a residual smoothed over ``smooth_s`` seconds (about a spin).

    ``w = (1 - (r / (c sigma))^2)^2`` for ``|r| < c sigma``, else 0, with ``r`` the
    residual's running mean over ``smooth_s`` (so that the spin harmonics left in it do
    not count as outliers) and ``sigma`` 1.4826 times its median absolute deviation on
    ``use``. A localised natural field (tens of seconds of tens of nT on a few-nT floor)
    is weighted out instead of fitted.

    Examples
    --------
    >>> t = np.arange(0.0, 300.0, 0.1)
    >>> r = np.random.default_rng(0).normal(0, 3, t.size)
    >>> r[(t > 140) & (t < 160)] += 100.0
    >>> w = tukey_weights(t, r, t >= 0, 4.685)
    >>> float(w[(t > 142) & (t < 158)].max()), bool(np.median(w[t < 100]) > 0.9)
    (0.0, True)
    """
    from scipy.ndimage import uniform_filter1d

    t = np.asarray(t_s, dtype=float)
    use = np.asarray(use, bool)
    dt = float(np.median(np.diff(t[use]))) if use.sum() > 1 else 1.0
    width = max(1, int(round(smooth_s / max(dt, 1e-9))))
    r = uniform_filter1d(np.asarray(resid, dtype=float), width, mode="nearest")
    sigma = float(normal_mad(r[use]))
    u = r / max(c * sigma, 1e-12)
    return np.where(np.abs(u) < 1.0, (1.0 - u ** 2) ** 2, 0.0)


def _shape_residual(b, r0, a, use) -> np.ndarray:
    """Scalar residual left by the two-number drift ``g_0 + sign * shape`` (first order;
    ``g_0`` the median, so that a natural field does not move it)."""
    h = (b[:, 0] ** 2 + b[:, 1] ** 2) / np.linalg.norm(b, axis=1)
    sign = 1.0 if float(a[use] @ r0[use]) >= 0 else -1.0
    e = r0 - sign * a
    return e - float(np.median(e[use] / h[use])) * h     # robust g_0: a pulse does not move it


def _live_columns(shapes, use) -> np.ndarray:
    """The columns of ``shapes`` (n, m) not zero on every ``use`` sample (another
    zone's shapes are zero here and would make the fit singular)."""
    a = np.asarray(shapes, dtype=float).reshape(len(use), -1)
    return a[:, np.any(a[use] != 0.0, axis=0)]


def fit_gain_drift(t_s, b_body, ref_magnitude_nT, *, degree: int = 3, fit_mask=None,
                   n_iter: int = 2, shape=None, robust_c: float = 0.0,
                   robust_iter: int = 5, natural=None,
                   gain_shapes=None) -> tuple[np.ndarray, dict]:
    """Remove a slowly drifting isotropic spin-plane gain from body-frame vectors.

    Model: the measured spin-plane components are ``(1 + g(T))`` times the true ones,
    ``g(T) = sum_d g_d T^d`` (``d = 0..degree``); to first order the scalar residual is
    ``g(T) |B_perp|^2 / |B|`` (linear least squares on the fitted samples). The
    spin-axis component is left alone.

    Parameters
    ----------
    t_s : array_like (n,)
        Times, seconds.
    b_body : array_like (n, 3)
        Calibrated field in the spinning frame, ``z`` along the spin axis (nT).
    ref_magnitude_nT : array_like (n,)
        Reference magnitude (|IGRF|).
    degree : int
        Polynomial degree of the gain drift in time (0: a constant gain change).
    fit_mask : array_like of bool, optional
        Samples used in the fit (default all); the correction is applied to all.
    n_iter : int
        Refits (the second removes what the first leaves at second order).
    shape : array_like (n,), optional
        A reference-free time shape of the drift (:func:`harmonic_shape`, the 2x-spin
        harmonic's drift): then ``g(T) = g_0 + g_1 shape`` (two numbers per zone)
        with ``g_1`` fixed by the gain's geometry (a one-direction gain change has equal
        isotropic and 2x halves, so the drift of ``|B|`` is ``+-shape``; only the sign
        and ``g_0`` are fitted), so that a natural field along B, which changes ``|B|``
        but makes no 2x-spin harmonic, is not fitted away as a gain drift.
    robust_c : float
        If positive, the polynomial drift is fitted by iteratively reweighted least
        squares with Tukey biweights of this many robust sigmas
        (:func:`tukey_weights`, ``robust_iter`` passes): a localised natural field
        along B (a pulse of a minute or two on the few-nT floor the drift leaves) is
        weighted out instead of taken as a gain change. A drift as slow as the pass
        is still fitted (it is what the robust scale measures against). With
        ``shape`` too, the first weights come from the residual the reference-free
        shape leaves (which a natural field along B stands out of, as the shape does
        not follow it) and the drift is the weighted cubic.

    Returns
    -------
    corrected : ndarray (n, 3)
    info : dict
        ``gain_coefficients`` (``g_d``, first pass plus refits), ``gain_drift_pp``
        (peak-to-peak of ``g`` over the fitted samples, fraction), ``gain_mid``
        (``g`` at mid-zone) and the scalar RMS, fast and slow parts before and after.

    Examples
    --------
    >>> t = np.arange(0.0, 360.0, 0.1)
    >>> T = 2 * t / t[-1] - 1
    >>> psi = 2 * np.pi * t / 2.85
    >>> true = np.column_stack([45000 * np.cos(psi), 45000 * np.sin(psi), 2000 + 0 * t])
    >>> bad = true * np.c_[1 + 1e-3 * T ** 2, 1 + 1e-3 * T ** 2, np.ones_like(t)]
    >>> fixed, info = fit_gain_drift(t, bad, np.linalg.norm(true, axis=1))
    >>> bool(np.abs(fixed - true).max() < 0.01), round(info["gain_drift_pp"], 6)
    (True, 0.001)
    """
    t = np.asarray(t_s, dtype=float)
    b = np.array(b_body, dtype=float)
    ref = np.asarray(ref_magnitude_nT, dtype=float)
    use = np.ones(t.size, bool) if fit_mask is None else np.asarray(fit_mask, bool)
    T = unit_time(t, use)
    r0 = np.linalg.norm(b, axis=1) - ref
    start = None
    if robust_c > 0 and shape is not None:
        # the reference-free shape is the robust fit's start, not its model
        start, shape = _shape_residual(b, r0, np.asarray(shape, dtype=float), use), None
    if shape is None:
        powers = np.column_stack([T ** d for d in range(degree + 1)])
        if gain_shapes is not None:
            powers = np.column_stack([powers, _live_columns(gain_shapes, use)])
    else:
        # isotropic and 2x halves of a one-direction gain change are equal: the drift is
        # +-shape in |B| (nT); only its sign and a constant gain are fitted
        a = np.asarray(shape, dtype=float)
        h = (b[:, 0] ** 2 + b[:, 1] ** 2) / np.linalg.norm(b, axis=1)
        sign = 1.0 if float(a[use] @ r0[use]) >= 0 else -1.0
        powers = np.column_stack([np.ones_like(t), sign * a / h])
        degree = 0
    nat = np.zeros((t.size, 0)) if natural is None or shape is not None \
        else _live_columns(natural, use)
    total = np.ones(t.size)
    coef = np.zeros(powers.shape[1])
    amplitude = np.zeros(nat.shape[1])
    weight = np.ones(t.size)
    if robust_c > 0 and shape is None:
        mag = np.linalg.norm(b, axis=1)
        design = powers * ((b[:, 0] ** 2 + b[:, 1] ** 2) / mag)[:, None]
        first = np.ones(t.size) if start is None else tukey_weights(t, start, use, robust_c)
        weight = first
        for _ in range(max(1, robust_iter)):
            sw = np.sqrt(weight[use])[:, None]
            w = lstsq(design[use] * sw, (mag - ref)[use] * sw[:, 0])
            # what the start weighted out stays out: the cubic cannot take it back
            weight = np.minimum(first, tukey_weights(t, mag - ref - design @ w, use, robust_c))
    sw = np.sqrt(weight[use])
    for _ in range(max(1, n_iter)):
        mag = np.linalg.norm(b, axis=1)
        design = powers * ((b[:, 0] ** 2 + b[:, 1] ** 2) / mag)[:, None]
        if shape is None:
            full = np.column_stack([design, nat])
            w = lstsq(full[use] * sw[:, None], (mag - ref)[use] * sw)
            w, a_nat = w[:powers.shape[1]], w[powers.shape[1]:]
            amplitude = a_nat          # left in the data: each pass sees all of it
            g = powers @ w
        else:
            fixed = powers[:, 1] if not coef.any() else 0.0 * powers[:, 1]
            g0 = lstsq(design[use, :1], (mag - ref - fixed * design[:, 0])[use])
            w = np.r_[g0, 0.0 if coef.any() else 1.0]
            g = g0[0] + fixed
        b[:, :2] /= (1.0 + g)[:, None]
        total *= 1.0 + g
        coef += w
    r1 = np.linalg.norm(b, axis=1) - ref
    gain = total - 1.0
    info = {"gain_coefficients": coef.tolist(),
            "natural_amplitudes": amplitude.tolist(),
            "gain_drift_pp": float(np.ptp(gain[use])),
            "gain_mid": float(np.interp(0.0, T[use], gain[use])),
            "weighted_out_fraction": float(np.mean(weight[use] < 0.5)),
            "scalar_rms_before_nT": rms(r0[use]), "scalar_rms_after_nT": rms(r1[use]),
            "scalar_fast_before_nT": rms(fast_part(t[use], r0[use])),
            "scalar_fast_after_nT": rms(fast_part(t[use], r1[use])),
            "scalar_slow_before_nT": rms(r0[use] - fast_part(t[use], r0[use])),
            "scalar_slow_after_nT": rms(r1[use] - fast_part(t[use], r1[use]))}
    return b, info


def drift_shape_agreement(t_s, b_body, ref_magnitude_nT, *, fit_mask=None,
                          drift_degree: int = 3, poly_degree: int = 5) -> dict:
    """Does the slow scalar residual follow the drift of the 2x-spin harmonic?

    The 2x harmonic of the scalar residual (in the spin-plane angle of the field)
    measures a change of the spin-plane gain ratio/non-orthogonality, and no smooth
    reference error can make it. If one driver (e.g. temperature) changes the gains of
    the spin-plane sensors by ``kappa_j theta(t)``, the traceless (2x) and isotropic
    (slow) halves share the shape ``theta(t)``. This takes the 2x coefficient's
    trajectory ``c_2(t)`` (complex, cubic in time) on the residual of a *linear*
    calibration, its principal direction and the amplitude ``a(t)`` along it, and
    compares ``a`` with the slow part ``S`` (both with what a constant gain and a
    constant can absorb, ``1`` and ``|B|``, projected out).

    Parameters
    ----------
    t_s, b_body, ref_magnitude_nT, fit_mask :
        As in :func:`fit_gain_drift`; ``b_body`` from the linear calibration.
    drift_degree, poly_degree :
        Passed to :func:`~magcal.missions.elfin.scalar.fit_spin_harmonics` (slow part:
        the polynomial of ``poly_degree``).

    Returns
    -------
    dict
        ``drift2_rms_nT`` (RMS of ``|c_2 - mean|``), ``drift2_line_fraction`` (share of
        that drift along its principal direction), ``slow_rms_nT`` and
        ``slow_unabsorbed_nT`` (``S`` before/after projecting out ``1, |B|``),
        ``correlation`` (of the projected ``S`` and ``a``; its sign is that of the
        arbitrary principal direction), ``ratio`` (least-squares ``|S / a|``) and
        ``slow_left_nT`` (what ``S`` keeps after ``1, |B|, a`` with one ratio).
    """
    t = np.asarray(t_s, dtype=float)
    b = np.asarray(b_body, dtype=float)
    ref = np.asarray(ref_magnitude_nT, dtype=float)
    use = np.ones(t.size, bool) if fit_mask is None else np.asarray(fit_mask, bool)
    t, b, ref = t[use], b[use], ref[use]
    r = np.linalg.norm(b, axis=1) - ref
    psi = np.angle(b[:, 0] + 1j * b[:, 1])
    model = fit_spin_harmonics(t, r, psi, fixed=(4,), drifting=(1, 2),
                               drift_degree=drift_degree, poly_degree=poly_degree)
    c2 = model.coefficients[2]
    xy = np.column_stack([c2.real - c2.real.mean(), c2.imag - c2.imag.mean()])
    _, sv, vt = np.linalg.svd(xy, full_matrices=False)
    amp = xy @ vt[0]
    slow = r - fast_part(t, r, poly_degree)
    absorb = np.column_stack([np.ones_like(t), ref - ref.mean()])

    def project(v):
        return v - absorb @ lstsq(absorb, v)

    s_p, a_p = project(slow), project(amp)
    ratio = float(a_p @ s_p / max(a_p @ a_p, 1e-30))
    return {"drift2_rms_nT": rms(np.abs(c2 - c2.mean())),
            "drift2_line_fraction": float(sv[0] ** 2 / max(np.sum(sv ** 2), 1e-30)),
            "slow_rms_nT": rms(slow), "slow_unabsorbed_nT": rms(s_p),
            "correlation": float(np.corrcoef(s_p, a_p)[0, 1]),
            "ratio": abs(ratio), "slow_left_nT": rms(s_p - ratio * a_p)}


def harmonic_shape(t_s, b_body, ref_magnitude_nT, *, fit_mask=None,
                   drift_degree: int = 3, poly_degree: int = 5) -> np.ndarray:
    """Time shape of the 2x-spin harmonic's drift in the scalar residual, at all samples.

    The amplitude ``a(t)`` of :func:`drift_shape_agreement` (the drift of the complex 2x
    coefficient along its principal direction), fitted on ``fit_mask`` and interpolated
    to every sample. Reference-free: a natural field changes ``|B|`` at twice the spin
    frequency only at second order, a spin-plane gain change at first order.

    Returns
    -------
    ndarray (n,)
        ``a(t)`` (nT, sign arbitrary) with its mean removed.
    """
    t = np.asarray(t_s, dtype=float)
    b = np.asarray(b_body, dtype=float)
    ref = np.asarray(ref_magnitude_nT, dtype=float)
    use = np.ones(t.size, bool) if fit_mask is None else np.asarray(fit_mask, bool)
    r = np.linalg.norm(b[use], axis=1) - ref[use]
    psi = np.angle(b[use, 0] + 1j * b[use, 1])
    model = fit_spin_harmonics(t[use], r, psi, fixed=(4,), drifting=(1, 2),
                               drift_degree=drift_degree, poly_degree=poly_degree)
    c2 = model.coefficients[2]
    xy = np.column_stack([c2.real - c2.real.mean(), c2.imag - c2.imag.mean()])
    vt = np.linalg.svd(xy, full_matrices=False)[2]
    return np.interp(t, t[use], xy @ vt[0])


def drift_pair(t_s, b_body, ref_body, *, fit_mask=None, degree: int = 3) -> dict:
    """Drifting ``e^{i psi}`` and ``e^{-i psi}`` parts of the spin-plane vector residual.

    A spin-plane gain matrix that changes by ``D(t)`` adds ``a(t) beta + s(t)
    conj(beta)`` to the field (``a``: isotropic gain and rotation, ``s``: gain
    ratio/non-orthogonality). A change along one direction ``n`` only, ``D = theta(t) n
    n^T``, gives ``|a| = |s| = theta |beta| / 2``: equal drifts of the two terms. The
    residual ``b - ref`` in the spinning frame is fitted with ``c_k(T) e^{i k psi}``,
    ``k`` in (-3, -1, 0, 1, 3, 5), ``c_k`` complex polynomials of ``degree``; the RMS of
    ``c_1`` and ``c_-1`` about their means is returned. (The spin phase is fitted
    with the calibration, so a rotation drift is mostly in the phase: ``c_1`` is
    mostly the gain.)

    Returns
    -------
    dict
        ``drift_k1_nT``, ``drift_km1_nT``.
    """
    t = np.asarray(t_s, dtype=float)
    use = np.ones(t.size, bool) if fit_mask is None else np.asarray(fit_mask, bool)
    b, ref = np.asarray(b_body, dtype=float)[use], np.asarray(ref_body, dtype=float)[use]
    e = (b - ref)[:, 0] + 1j * (b - ref)[:, 1]
    psi = np.angle(b[:, 0] + 1j * b[:, 1])
    powers = np.column_stack([unit_time(t, use)[use] ** d for d in range(degree + 1)])
    ks = (-3, -1, 0, 1, 3, 5)
    design = np.column_stack([np.exp(1j * k * psi)[:, None] * powers for k in ks])
    w = lstsq(design, e).reshape(len(ks), -1)
    drift = {k: rms(np.abs(powers @ wk - np.mean(powers @ wk))) for k, wk in zip(ks, w)}
    return {"drift_k1_nT": drift[1], "drift_km1_nT": drift[-1]}


def _zone_body(z):
    from magcal.spin.despin import spin

    t = (z.index.asi8 - z.index.asi8[0]) / 1e9
    desp = z[["bx_despun", "by_despun", "bz_despun"]].to_numpy(float)
    ref = z[["igrf_x_despun", "igrf_y_despun", "igrf_z_despun"]].to_numpy(float)
    phase = z["phase"].to_numpy(float)
    return t, spin(desp, phase), np.linalg.norm(ref, axis=1), phase, desp, ref


def fit_samples(z, scalar: bool = False) -> np.ndarray:
    """Samples a step fits on: ``used`` and, where the field has it, ``fit`` (0/1, rows
    left out of every fit but kept in the product).

    With ``scalar`` (the steps fitted to ``|B|`` only: spin harmonics, gain drift, fast
    drift) the column ``fit_scalar`` is read instead where the field has it: a field
    across B, which leaves ``|B|`` alone to first order, need not be left out of them
    (:mod:`magcal.missions.elfin.detect` flags ``|B|`` and the vector apart).
    """
    use = z["used"].to_numpy() == 1
    col = "fit_scalar" if scalar and "fit_scalar" in z.columns else "fit"
    return use & (z[col].to_numpy() == 1) if col in z.columns else use


def map_zones(cal, step, note: str, params: dict, *, scalar: bool = False):
    """Run ``step`` on each zone of an ElfinCalibration and write back its vectors.

    Parameters
    ----------
    cal : magcal.missions.elfin.ElfinCalibration
    step : callable
        ``step(t_s, zone_frame, used) -> (b_despun, info)``: the zone's corrected despun
        vectors (all samples) and a dict of numbers for the table.
    note : str
        Key under which ``params`` are recorded in the calibration's parameters.
    params : dict
        The step's parameters (recorded as strings).
    scalar : bool
        The step fits ``|B|`` only (:func:`fit_samples`).

    Returns
    -------
    corrected : ElfinCalibration
        ``bx_despun ..`` and ``bx_gei ..`` replaced (GEI through the zone's own despun
        basis, as the calibration defined it).
    table : DataFrame
        One row per zone: ``zone`` and the step's ``info``.
    """
    from magcal.missions.elfin.phase import despun_basis

    f = cal.field.copy()
    # the new columns gathered per zone and set once (a .loc write per zone and column
    # group cost as much as the step's own fits)
    despun = f[["bx_despun", "by_despun", "bz_despun"]].to_numpy(float, copy=True)
    gei = f[["bx_gei", "by_gei", "bz_gei"]].to_numpy(float, copy=True)
    rows = []
    for k in sorted(f["zone"].unique()):
        sel = (f["zone"] == k).to_numpy()
        z = f.loc[sel]
        t = (z.index.asi8 - z.index.asi8[0]) / 1e9
        new_d, info = step(t, z, fit_samples(z, scalar))
        basis = despun_basis(z[["spin_axis_gei_x", "spin_axis_gei_y",
                                "spin_axis_gei_z"]].to_numpy(float))
        despun[sel] = new_d
        gei[sel] = np.einsum("nji,nj->ni", basis, new_d)
        rows.append({"zone": int(k), **info})
    f[["bx_despun", "by_despun", "bz_despun"]] = despun
    f[["bx_gei", "by_gei", "bz_gei"]] = gei
    out = {**cal.parameters, note: {k: str(v) for k, v in params.items()} or "defaults"}
    return replace(cal, field=f, parameters=out), pd.DataFrame(rows)


def correct_gain_drift(cal, *, shape_from=None, robust_start_from=None, **kw):
    """Apply :func:`fit_gain_drift` zone by zone to an ElfinCalibration.

    Parameters
    ----------
    cal : magcal.missions.elfin.ElfinCalibration
        Usually after :func:`~magcal.missions.elfin.harmonic.correct_elfin_calibration`.
    shape_from : ElfinCalibration, optional
        The *linear* calibration of the same rows: the drift then follows each zone's
        2x-spin harmonic (:func:`harmonic_shape`) instead of a cubic in time.
    robust_start_from : ElfinCalibration, optional
        The linear calibration whose 2x-spin shape starts a robust cubic fit
        (``robust_c`` in ``kw``; see :func:`fit_gain_drift`).
    **kw
        Passed to :func:`fit_gain_drift`.

    Returns
    -------
    corrected : ElfinCalibration
        ``bx_despun ..`` and ``bx_gei ..`` corrected (same despun basis as the input).
    table : DataFrame
        Per zone: the gain drift (peak-to-peak, fraction; mid-zone value), scalar RMS,
        fast and slow parts before/after, vector RMS before/after (despun, nT).
    """
    from magcal.missions.elfin.pulses import DRIFT_COLUMNS, NATURAL_COLUMNS, shape_columns
    from magcal.spin.despin import despin

    def step(t, z, used):
        _, body, ref_mag, phase, desp, ref = _zone_body(z)
        shape = None
        if shape_from is not None or robust_start_from is not None:
            shape_from_ = shape_from if shape_from is not None else robust_start_from
            lin = shape_from_.field.loc[shape_from_.field["zone"] == z["zone"].iloc[0]]
            _, lbody, lref, *_ = _zone_body(lin)
            shape = harmonic_shape(t, lbody, lref, fit_mask=used)
        fixed, info = fit_gain_drift(t, body, ref_mag, fit_mask=used, shape=shape,
                                     natural=shape_columns(z, NATURAL_COLUMNS),
                                     gain_shapes=shape_columns(z, DRIFT_COLUMNS), **kw)
        new_d = despin(fixed, phase)
        return new_d, {**info, "vector_rms_before_nT": rms((desp - ref)[used]),
                       "vector_rms_after_nT": rms((new_d - ref)[used])}

    return map_zones(cal, step, "gain_drift",
                     {**kw, "shape": "2x-spin harmonic" if shape_from is not None
                      else "cubic" if kw.get("degree", 3) == 3
                      else f"polynomial of degree {kw['degree']}"},
                     scalar=True)


def drift_agreement_table(cal, **kw) -> pd.DataFrame:
    """:func:`drift_shape_agreement` and :func:`drift_pair` for every zone.

    ``cal`` is the *linear* ElfinCalibration (before any correction).
    """
    from magcal.spin.despin import spin

    rows = []
    for k in sorted(cal.field["zone"].unique()):
        z = cal.field[cal.field["zone"] == k]
        t, body, ref_mag, phase, _, ref = _zone_body(z)
        used = fit_samples(z)
        rows.append({"zone": int(k),
                     **drift_shape_agreement(t, body, ref_mag, fit_mask=used, **kw),
                     **drift_pair(t, body, spin(ref, phase), fit_mask=used)})
    return pd.DataFrame(rows)
