"""Which ELFIN calibration parameters are stable from zone to zone, with uncertainties.

The issue asks for one fit across zones where parameters are stable and per-zone
parameters where they are not. This module makes that decision from the data: for each
physical parameter of the per-zone calibration it gives

* a per-zone value and a standard error that accounts for the autocorrelated residuals
  (the Jacobian sandwich with residuals summed over blocks of ``block_s`` seconds within
  the zone, :func:`magcal.missions.elfin.joint._sandwich`; conditional on the spin phase
  and, for the spin-axis row, on the fitted spin-plane components);
* the spread across zones (standard deviation, minimum, maximum) and ``chi2/dof`` of the
  zone values about their inverse-variance weighted mean;
* a verdict: *stable* when ``chi2/dof`` is below the ``level`` quantile of
  ``chi2_{n-1}/(n-1)`` (the zone values scatter no more than their errors allow),
  otherwise *per zone*, with the scatter in excess of the errors.

Parameters, all reconstructed from the products the pipeline keeps:

* linear per-zone fit (:func:`magcal.missions.elfin.linear.fit_zone`, refitted here on its own
  phase, which reproduces it exactly): sensor gains (column norms of ``C``), the
  non-orthogonality angles (90 deg minus the angle between two columns of ``C``; both
  are invariant under the turn about the spin axis that the phase absorbs), body-frame
  offsets at mid-zone and the spin-axis turn over the zone;
* the cubic non-linearity (the 4x amplitude of ``|B|`` at ``|B_perp|`` = 45000 nT,
  :mod:`magcal.missions.elfin.harmonic`), the spin-plane gain drift peak-to-peak
  (:mod:`magcal.missions.elfin.drift`) and the spin-axis tilt of the vector step
  (:mod:`magcal.missions.elfin.vector`).

A large spread can be a degeneracy rather than physics. The spin-axis field changes by
only 240-3300 nT over an ELFIN pass, smoothly, so a multiple of the spin-axis row of
``C`` added to a spin-plane row looks like offset drift: the column norms (gains) of the
sensors with a large spin-axis share are poorly fixed, and the non-orthogonality angles
with them. :func:`gain_degeneracy` gives the numbers (within-zone correlations, the
spread of the row norms and of the spin-plane responses, i.e. the spin-plane columns of
``C^-1``, which that trade leaves unchanged).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from magcal.missions.elfin.linear import _SCALE
from magcal.missions.elfin.joint import _sandwich
from magcal.spin.despin import spin

#: Block length (s) of the sandwich: the residuals are correlated over tens of seconds.
BLOCK_S = 30.0
#: Quantile of chi2_{n-1}/(n-1) below which the zone values count as one value.
LEVEL = 0.99
#: Linear-fit parameters, in the order of :func:`linear_zone_parameters`: gains (column
#: norms of ``C``), non-orthogonality, mid-zone body offsets, spin-axis turn, row norms of
#: ``C`` and the spin-plane responses (norms of the rows of ``C^-1`` restricted to the
#: spin-plane columns: counts per nT of spin-plane field, free of the spin-axis-row trade).
LINEAR_NAMES = ("gain1_nT_per_count", "gain2_nT_per_count", "gain3_nT_per_count",
                "nonorth12_deg", "nonorth13_deg", "nonorth23_deg",
                "offset_x_nT", "offset_y_nT", "offset_z_nT", "spin_axis_turn_deg",
                "row_norm_x_nT_per_count", "row_norm_y_nT_per_count",
                "row_norm_z_nT_per_count", "plane_response1_counts_per_nT",
                "plane_response2_counts_per_nT", "plane_response3_counts_per_nT")


def time_blocks(t_used, block_s: float = BLOCK_S, rows: int = 1) -> list[slice]:
    """Row slices of consecutive ``block_s`` windows of the used samples.

    ``rows`` is the number of residual rows per sample (3 for a vector fit stacked
    sample by sample).

    Examples
    --------
    >>> time_blocks(np.arange(0.0, 10.0), 4.0)
    [slice(0, 4, None), slice(4, 8, None), slice(8, 10, None)]
    """
    t = np.asarray(t_used, dtype=float)
    edges = np.searchsorted(t, np.arange(t[0], t[-1] + block_s, block_s))
    edges = np.unique(np.r_[edges, t.size])
    return [slice(rows * int(a), rows * int(b)) for a, b in zip(edges[:-1], edges[1:]) if b > a]


def _naive(design, resid) -> np.ndarray:
    h = design.T @ design
    return np.linalg.pinv(h) * float(resid @ resid) / max(resid.size - design.shape[1], 1)


def _jacobian(func, w, rel: float = 1e-6) -> np.ndarray:
    """Central-difference Jacobian of ``func`` at ``w`` (steps relative to |w| + 1)."""
    w = np.asarray(w, dtype=float)
    cols = []
    for i in range(w.size):
        h = rel * (abs(w[i]) + 1.0)
        up, dn = w.copy(), w.copy()
        up[i] += h
        dn[i] -= h
        cols.append((func(up) - func(dn)) / (2 * h))
    return np.column_stack(cols)


def _body(w, c_mean, offset_degree, axis_degree, tv):
    """Coupling and body-frame offset (nT) at unit time ``tv`` (as fit_zone's summary)."""
    nxy = 4 + offset_degree
    wx, wy, wz = w[:nxy], w[nxy:2 * nxy], w[2 * nxy:]
    po = tv ** np.arange(offset_degree + 1)
    tilt = tv ** np.arange(1, axis_degree + 1)
    a_xy = np.array([wx[:3], wy[:3]]) / _SCALE
    o_xy = np.array([wx[3:] @ po, wy[3:] @ po])
    u, v = wz[4:4 + axis_degree] @ tilt, wz[4 + axis_degree:4 + 2 * axis_degree] @ tilt
    a3 = wz[:3] / _SCALE + u * a_xy[0] + v * a_xy[1]
    amat = np.vstack([a_xy, a3])
    return amat, np.r_[o_xy, wz[3] + u * o_xy[0] + v * o_xy[1]] - amat @ c_mean


def _physical(w, c_mean, offset_degree, axis_degree) -> np.ndarray:
    """:data:`LINEAR_NAMES` from the stacked regression weights."""
    a, o = _body(w, c_mean, offset_degree, axis_degree, 0.0)
    gains = np.linalg.norm(a, axis=0)
    cos = (a.T @ a) / np.outer(gains, gains)
    nonorth = 90.0 - np.degrees(np.arccos(np.clip(cos[[0, 0, 1], [1, 2, 2]], -1, 1)))
    ends = [np.linalg.solve(a.T, _body(w, c_mean, offset_degree, axis_degree, s)[0][2])
            for s in (-1.0, 1.0)]
    turn = np.degrees(np.arccos(np.clip(ends[0] @ ends[1] / np.linalg.norm(ends[0])
                                        / np.linalg.norm(ends[1]), -1.0, 1.0)))
    return np.r_[gains, nonorth, o, turn, np.linalg.norm(a, axis=1),
                 np.linalg.norm(np.linalg.inv(a)[:, :2], axis=1)]


def linear_zone_parameters(t_s, counts, ref_despun, phase, used, *, offset_degree: int = 2,
                           axis_degree: int = 2, block_s: float = BLOCK_S) -> dict:
    """Physical parameters of one zone's linear fit with block-sandwich uncertainties.

    Refits :func:`magcal.missions.elfin.linear.fit_zone`'s last calibration step on its final
    phase (same design: spin-plane rows ``[counts, 1, T, .., T^offset_degree]``,
    spin-axis row ``[counts, 1, bx T^d, by T^d]``), so the weights are the delivered ones;
    the three rows share blocks, so their cross-covariance is kept.

    Returns
    -------
    dict
        ``names`` (:data:`LINEAR_NAMES`), ``values``, ``std`` (block sandwich),
        ``std_naive`` (white residuals), ``corr`` (correlation matrix of the physical
        parameters, from the sandwich) and ``coupling`` (3, 3).
    """
    t = np.asarray(t_s, dtype=float)
    c = np.asarray(counts, dtype=float)
    used = np.asarray(used, bool)
    c_mean = c[used].mean(axis=0)
    x = (c - c_mean) / _SCALE
    T = 2.0 * (t - t[used][0]) / (t[used][-1] - t[used][0]) - 1.0
    tgt = spin(np.asarray(ref_despun, dtype=float), np.asarray(phase, dtype=float))[used]
    xy = np.column_stack([x, T[:, None] ** np.arange(offset_degree + 1)])[used]
    wx = np.linalg.lstsq(xy, tgt[:, 0], rcond=None)[0]
    wy = np.linalg.lstsq(xy, tgt[:, 1], rcond=None)[0]
    tilt = T[used][:, None] ** np.arange(1, axis_degree + 1)
    z = np.column_stack([x[used], np.ones(used.sum()), (xy @ wx)[:, None] * tilt,
                         (xy @ wy)[:, None] * tilt])
    wz = np.linalg.lstsq(z, tgt[:, 2], rcond=None)[0]
    n, nxy, nz = used.sum(), xy.shape[1], z.shape[1]
    jac = np.zeros((3 * n, 2 * nxy + nz))          # rows sample by sample: x, y, z
    jac[0::3, :nxy], jac[1::3, nxy:2 * nxy], jac[2::3, 2 * nxy:] = xy, xy, z
    resid = np.column_stack([tgt[:, 0] - xy @ wx, tgt[:, 1] - xy @ wy,
                             tgt[:, 2] - z @ wz]).ravel()
    w = np.r_[wx, wy, wz]
    cov_w = _sandwich(jac, resid, time_blocks(t[used], block_s, rows=3))
    cov_naive = np.zeros_like(cov_w)
    for sl, d, r in ((slice(0, nxy), xy, resid[0::3]), (slice(nxy, 2 * nxy), xy, resid[1::3]),
                     (slice(2 * nxy, None), z, resid[2::3])):
        cov_naive[sl, sl] = _naive(d, r)

    def phys(v):
        return _physical(v, c_mean, offset_degree, axis_degree)

    jp = _jacobian(phys, w)
    cov = jp @ cov_w @ jp.T
    std = np.sqrt(np.clip(np.diag(cov), 0, None))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(std, std)
    return {"names": list(LINEAR_NAMES), "values": phys(w), "std": std,
            "std_naive": np.sqrt(np.clip(np.diag(jp @ cov_naive @ jp.T), 0, None)),
            "corr": corr, "coupling": _body(w, c_mean, offset_degree, axis_degree, 0.0)[0]}


def cubic_zone(t_s, b_body, ref_magnitude_nT, used, *, drifting=(1, 2), drift_degree: int = 3,
               poly_degree: int = 5, power: float = 3.0, at_nT: float = 45000.0,
               block_s: float = BLOCK_S) -> tuple[float, float]:
    """4x amplitude of ``|B| - |IGRF|`` scaled to ``|B_perp| = at_nT``, with its
    block-sandwich standard error (the first pass of
    :func:`magcal.missions.elfin.harmonic.harmonic_vector_correction`, same design)."""
    from magcal.missions.elfin.scalar import _harmonics

    use = np.asarray(used, bool)
    t = np.asarray(t_s, dtype=float)[use]
    b = np.asarray(b_body, dtype=float)[use]
    beta = b[:, 0] + 1j * b[:, 1]
    psi = np.angle(beta)
    r = np.linalg.norm(b, axis=1) - np.asarray(ref_magnitude_nT, dtype=float)[use]
    perp = float(np.median(np.abs(beta)))
    x = 2.0 * (t - t[0]) / (t[-1] - t[0]) - 1.0
    powers = x[:, None, None] ** np.arange(drift_degree + 1)
    design = np.column_stack(
        [np.vander(x, poly_degree + 1), _harmonics(psi, (4,)) * ((np.abs(beta) / perp)
                                                                 ** power)[:, None]]
        + [(_harmonics(psi, [k])[:, :, None] * powers).reshape(len(x), -1) for k in drifting])
    w = np.linalg.lstsq(design, r, rcond=None)[0]
    cov = _sandwich(design, r - design @ w, time_blocks(t, block_s))
    i = poly_degree + 1
    amp = float(np.hypot(w[i], w[i + 1]))
    grad = np.array([w[i], w[i + 1]]) / amp
    factor = (at_nT / perp) ** power
    return amp * factor, float(np.sqrt(grad @ cov[i:i + 2, i:i + 2] @ grad)) * factor


def gain_drift_zone(t_s, b_body, ref_magnitude_nT, used, *, degree: int = 3,
                    block_s: float = BLOCK_S) -> tuple[float, float]:
    """Peak-to-peak of the spin-plane gain drift ``g(T)`` and its block-sandwich error
    (the first pass of :func:`magcal.missions.elfin.drift.fit_gain_drift`)."""
    use = np.asarray(used, bool)
    t = np.asarray(t_s, dtype=float)[use]
    b = np.asarray(b_body, dtype=float)[use]
    mag = np.linalg.norm(b, axis=1)
    T = 2.0 * (t - t[0]) / (t[-1] - t[0]) - 1.0
    powers = T[:, None] ** np.arange(degree + 1)
    design = powers * ((b[:, 0] ** 2 + b[:, 1] ** 2) / mag)[:, None]
    r = mag - np.asarray(ref_magnitude_nT, dtype=float)[use]
    w = np.linalg.lstsq(design, r, rcond=None)[0]
    cov = _sandwich(design, r - design @ w, time_blocks(t, block_s))
    grid = np.linspace(-1.0, 1.0, 201)[:, None] ** np.arange(degree + 1)

    def ptp(v):
        return np.atleast_1d(np.ptp(grid @ v))

    j = _jacobian(ptp, w, rel=1e-4)
    return float(ptp(w)[0]), float(np.sqrt((j @ cov @ j.T)[0, 0]))


def tilt_zone(b_despun, ref_despun, used, t_s, *, block_s: float = BLOCK_S):
    """Spin-axis tilt (deg, about despun X and Y) and its block-sandwich errors, at the
    solution of :func:`magcal.missions.elfin.vector.refine_tilt` (``b_despun`` is its
    output: the design ``w x b`` is the same to first order in the tiny angles, and
    ``b - ref`` is the residual it leaves)."""
    use = np.asarray(used, bool)
    b = np.asarray(b_despun, dtype=float)[use]
    resid = (b - np.asarray(ref_despun, dtype=float)[use]).ravel()
    design = np.column_stack([np.cross([1.0, 0.0, 0.0], b).ravel(),
                              np.cross([0.0, 1.0, 0.0], b).ravel()])
    cov = _sandwich(design, resid, time_blocks(np.asarray(t_s, dtype=float)[use], block_s,
                                               rows=3))
    return np.degrees(np.sqrt(np.clip(np.diag(cov), 0, None)))


def spread(values, std, *, level: float = LEVEL) -> dict:
    """Spread of one parameter across zones and the stable/per-zone verdict.

    Parameters
    ----------
    values, std : array_like (n_zones,)
        Zone values and their standard errors.
    level : float
        Quantile of ``chi2_{n-1} / (n-1)`` used as the threshold.

    Returns
    -------
    dict
        ``weighted_mean``, ``weighted_mean_std`` (scaled by sqrt(chi2/dof) when above 1),
        ``std``, ``min``, ``max``, ``median_zone_std``, ``chi2_dof``, ``threshold``,
        ``excess_scatter`` (standard deviation beyond the errors, 0 if none) and
        ``verdict`` ("stable" or "per zone").

    Examples
    --------
    >>> spread([1.0, 1.1, 0.9, 1.0], [0.1] * 4)["verdict"]
    'stable'
    >>> spread([1.0, 2.0, 0.0, 1.0], [0.1] * 4)["verdict"]
    'per zone'
    """
    from scipy.stats import chi2

    x = np.asarray(values, dtype=float)
    s = np.asarray(std, dtype=float)
    w = 1.0 / np.maximum(s, 1e-300) ** 2
    mean = float(np.sum(w * x) / np.sum(w))
    dof = max(x.size - 1, 1)
    red = float(np.sum(w * (x - mean) ** 2) / dof)
    threshold = float(chi2.ppf(level, dof) / dof)
    excess = float(np.sqrt(max(np.var(x, ddof=1) - np.mean(s ** 2), 0.0))) if x.size > 1 else 0.0
    return {"weighted_mean": mean,
            "weighted_mean_std": float(np.sqrt(max(red, 1.0) / np.sum(w))),
            "std": float(np.std(x, ddof=1)) if x.size > 1 else 0.0,
            "min": float(x.min()), "max": float(x.max()), "median_zone_std": float(np.median(s)),
            "chi2_dof": red, "threshold": threshold, "excess_scatter": excess,
            "verdict": "stable" if red < threshold else "per zone"}


def _zone_arrays(z):
    t = (z.index.asi8 - z.index.asi8[0]) / 1e9
    used = z["used"].to_numpy() == 1
    ref = z[["igrf_x_despun", "igrf_y_despun", "igrf_z_despun"]].to_numpy(float)
    desp = z[["bx_despun", "by_despun", "bz_despun"]].to_numpy(float)
    return t, used, ref, desp, z["phase"].to_numpy(float)


def zone_parameters(linear, products: dict | None = None, steps: dict | None = None, *,
                    block_s: float = BLOCK_S) -> tuple[pd.DataFrame, pd.DataFrame, list]:
    """Per-zone values and block-sandwich errors of every parameter.

    Parameters
    ----------
    linear : ElfinCalibration
        The linear per-zone calibration (its ``field`` holds counts, phase, IGRF).
    products : dict, optional
        Product name -> ElfinCalibration of the later steps (``"linear"``,
        ``"harmonic"``, ``"+ vector step"``: the inputs of the cubic and gain-drift fits
        and the tilt's output); parameters of steps absent here are left out.
    steps : dict, optional
        The pipeline's step tables; ``vector_correction`` gives the tilt values.

    Returns
    -------
    values, std : DataFrame
        One row per zone (``zone`` column), one column per parameter.
    corr : list of ndarray
        Per zone, the correlation matrix of :data:`LINEAR_NAMES` (sandwich).
    """
    products = products or {}
    tilts = {}
    if steps and "vector_correction" in steps and "+ vector step" in products:
        tab = steps["vector_correction"]
        tilts = dict(zip(tab["zone"], tab["tilt_deg"]))
    od = int(linear.parameters.get("offset_degree", 2))
    ad = int(linear.parameters.get("axis_degree", 2))
    vals, stds, corrs = [], [], []
    for k in sorted(linear.field["zone"].unique()):
        z = linear.field[linear.field["zone"] == k]
        t, used, ref, _, phase = _zone_arrays(z)
        lin = linear_zone_parameters(t, z[["b1", "b2", "b3"]].to_numpy(float), ref, phase,
                                     used, offset_degree=od, axis_degree=ad, block_s=block_s)
        v = {"zone": int(k), **dict(zip(LINEAR_NAMES, lin["values"]))}
        s = {"zone": int(k), **dict(zip(LINEAR_NAMES, lin["std"]))}
        corrs.append(lin["corr"])
        mag = np.linalg.norm(ref, axis=1)
        for name, src, fit in (("cubic_4x_at_45000nT_nT", "linear", cubic_zone),
                               ("gain_drift_pp", "harmonic", gain_drift_zone)):
            if src in products:
                tz, usedz, _, desp, ph = _zone_arrays(products[src].field.loc[z.index])
                v[name], s[name] = fit(tz, spin(desp, ph), mag, usedz, block_s=block_s)
        if int(k) in tilts:
            v["tilt_x_deg"], v["tilt_y_deg"] = tilts[int(k)]
            tz, usedz, _, desp, _ = _zone_arrays(products["+ vector step"].field.loc[z.index])
            s["tilt_x_deg"], s["tilt_y_deg"] = tilt_zone(desp, ref, usedz, tz, block_s=block_s)
        vals.append(v)
        stds.append(s)
    return pd.DataFrame(vals), pd.DataFrame(stds), corrs


def gain_degeneracy(values: pd.DataFrame, std: pd.DataFrame, corrs: list,
                    bz_range_nT=None, couplings=None) -> dict:
    """Is the gains' spread a trade with other parameters? Numbers to decide it.

    The spin-axis field changes little over a pass (hundreds to a few thousand nT
    against 45000 nT in the spin plane), and smoothly, so a multiple of the spin-axis
    row of ``C`` added to a spin-plane row is nearly the offset drift: the spin-plane
    rows' share of the spin-axis counts, and with it the column norms (gains) of the
    sensors that have a large spin-axis component, are poorly fixed. The spin-plane
    response of each sensor (counts per nT of spin-plane field: the spin-plane columns
    of ``C^-1``) does not move under that trade.

    Returns
    -------
    dict
        Per gain: ``relative_spread`` across zones, ``median_zone_relative_std``, the
        strongest within-zone correlation (median over zones) and its parameter, the
        correlation across zones with the spin-axis row norm; the same spreads for the
        row norms and the spin-plane responses; with ``bz_range_nT`` the correlation of
        the spin-axis row norm's error with ``1 / range``. With ``couplings`` (the
        zones' ``C``): ``spin_axis_to_sensor_deg`` (angle between each sensor axis and
        the normal of the spin plane in count space, per zone) and, per spin-plane
        response, its correlation with ``sin`` of that angle and its relative spread
        once divided by it (what is left when the spin axis's motion relative to the
        sensors is taken out).
    """
    names = list(LINEAR_NAMES)
    out = {}
    stack = np.array(corrs)
    zrow = values["row_norm_z_nT_per_count"]

    def rel(col):
        return {"relative_spread": float(values[col].std() / values[col].mean()),
                "median_zone_relative_std": float((std[col] / values[col]).median())}

    for j in range(3):
        med = np.nanmedian(np.abs(stack[:, j, :]), axis=0)
        med[j] = 0.0
        other = int(np.argmax(med))
        col = names[j]
        out[col] = {**rel(col), "strongest_within_zone_correlation": float(med[other]),
                    "with": names[other],
                    "correlation_across_zones_with_spin_axis_row_norm":
                        float(np.corrcoef(values[col], zrow)[0, 1])}
    for col in names[10:16]:
        out[col] = rel(col)
    if couplings is not None:
        angles, ratio = [], []
        for a, resp in zip(couplings, values[list(names[13:16])].to_numpy()):
            u = np.linalg.inv(a)
            n = np.cross(u[:, 0], u[:, 1])
            th = np.arccos(np.abs(n) / np.linalg.norm(n))
            angles.append(np.degrees(th))
            ratio.append(resp / np.sin(th))
        angles, ratio = np.array(angles), np.array(ratio)
        out["spin_axis_to_sensor_deg"] = angles.tolist()
        for j in range(3):
            col = names[13 + j]
            out[col]["correlation_with_sin_spin_axis_angle"] = float(
                np.corrcoef(values[col], np.sin(np.radians(angles[:, j])))[0, 1])
            out[col]["relative_spread_over_sin_angle"] = float(
                ratio[:, j].std(ddof=1) / ratio[:, j].mean())
    if bz_range_nT is not None:
        out["spin_axis_row_norm_std_vs_inverse_bz_range_correlation"] = float(
            np.corrcoef(std["row_norm_z_nT_per_count"], 1.0 / np.asarray(bz_range_nT))[0, 1])
        out["bz_range_nT"] = [float(r) for r in bz_range_nT]
    return out


def parameter_stability(linear, products: dict | None = None, steps: dict | None = None, *,
                        block_s: float = BLOCK_S, level: float = LEVEL) -> dict:
    """The ``parameter_stability`` document of ``elfin_calibration.json``.

    Returns
    -------
    dict
        ``note``, ``block_s``, ``level``, ``zones`` (values and ``<name>_std`` per zone),
        ``spread`` (parameter -> :func:`spread`), ``stable`` and ``per_zone`` (names),
        ``gain_degeneracy`` (:func:`gain_degeneracy`).
    """
    vals, stds, corrs = zone_parameters(linear, products, steps, block_s=block_s)
    f = linear.field[linear.field["used"] == 1]
    bz_range = [float(np.ptp(f.loc[f["zone"] == k, "igrf_z_despun"])) for k in vals["zone"]]
    names = [c for c in vals.columns if c != "zone"]
    table = vals.copy()
    for n in names:
        table[f"{n}_std"] = stds[n]
    sp = {n: spread(vals[n], stds[n], level=level) for n in names}
    return {
        "note": f"per-zone values with standard errors from the Jacobian sandwich over "
                f"{block_s:g} s blocks (conditional on the spin phase); stable when chi2/dof "
                f"of the zone values about their weighted mean is below the {level:g} "
                "quantile of chi2_(n-1)/(n-1); gains are column norms of C (nT/count), "
                "nonorth_ij = 90 deg minus the angle between columns i and j of C, offsets "
                "in the body frame at mid-zone, tilt from the vector step",
        "block_s": block_s, "level": level,
        "zones": table.to_dict(orient="records"), "spread": sp,
        "stable": [n for n in names if sp[n]["verdict"] == "stable"],
        "per_zone": [n for n in names if sp[n]["verdict"] != "stable"],
        "gain_degeneracy": gain_degeneracy(vals, stds, corrs, bz_range,
                                           [z.coupling for z in linear.zones])}
