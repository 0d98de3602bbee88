"""Why the ELFIN vector residual exceeds the scalar one: a split that decides the target.

The issue's target is a vector residual against IGRF within 1.5x of the scalar one. The
scalar residual ``|B| - |IGRF|`` is the component of the error *along* the field (to
first order); the vector residual adds the two components *across* it, where attitude
errors and natural fields that IGRF lacks live, and which the scalar cannot see. This
module splits the vector residual of a calibrated product, zone by zone:

* along B / across B (per component, so that an isotropic error gives a ratio of 1);
* spin-averaged (a boxcar of one spin: what is slow to the spinning sensor) and
  within-spin (the rest: the instrument's time scale);
* inside / outside intervals flagged as natural transverse fields
  (:func:`natural_field_intervals`: auroral-latitude current-sheet signatures, i.e.
  spin-averaged across-B structure on scales of tens of seconds at |magnetic latitude|
  >= 60 deg; magnetic latitude of a centred dipole along IGRF's dipole axis, through
  the SM frame, :func:`dipole_latitude`).

and tests what the flagged structure is: a natural field across B leaves ``|B|`` alone,
an instrument offset along the spin axis changes it by ``dZ B_Z / |B|``
(:func:`transverse_test`). What it then tries on the rest, outside the flags (printed by
``workflows/elfin_scalar_floor.py --vector-evidence``): the spin-axis 1x coupling drifting
faster than a cubic (:func:`axial_coupling_line`; removed by
:func:`~magcal.missions.elfin.vector.correct_vector` with ``knot_s``), a tilt of the
spin axis free of the 0.2 deg bound, and a tilt drifting linearly within the pass.

What it measured on 2022-01-12 (zone medians; product: the default chain with the vector
step on 30 s splines, the fast drift and the phase refit; ``workflows/elfin_scalar_floor.py
--vector-evidence``): vector / scalar 2.08 overall (2/12 zones within 1.5x), 1.87 outside
the current-sheet flags (4/12), but 1.26 within the spin (12/12, max 1.42) and 1.24 in the
spin plane (11/12). The excess is the spin-averaged spin-axis component (8-43 nT) that
``|B|`` hardly sees (``|B_Z| / |B|`` 1-9 %): the spin axis lies within 2 deg of the orbit
normal, i.e. east-west, the direction of the fields of auroral field-aligned currents.
A constant tilt free of the bound leaves 1.57 (5/12); a tilt drifting within the pass
1.30 (10/12) but needs up to 0.56 deg against an attitude file that moves by 0.012 deg
per pass, and fitted on the sub-auroral third it predicts 3.7x in the auroral part. A
drifting spin-axis offset would look the same as a natural east-west field: the scalar
cannot tell them apart (the transverse test predicts 0.4-2 nT in ``|B|``). So against
IGRF the 1.5x target is met where the scalar has information (within the spin, in the
spin plane) and is not decidable along the spin axis.

Data: ELFIN SOC (PI V. Angelopoulos, UCLA), "Open Data for Scientific Use".
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from magcal.missions.elfin.scalar import fast_part, rms


def dipole_latitude(times, pos_gei_km) -> np.ndarray:
    """Magnetic latitude (deg) of a centred dipole along IGRF's dipole axis of the date.

    The position is rotated into SM (spacepy/IRBEM: ``Z`` along the IGRF dipole axis),
    where the latitude is ``asin(z / r)``. Not AACGM: at 500 km and 55-75 deg the two
    differ by a few degrees, which does not matter for a 60 deg threshold.

    Examples
    --------
    >>> t = np.array(["2022-01-12T17:30:00"], dtype="datetime64[ns]")
    >>> lat = dipole_latitude(t, [[0.0, 0.0, 6871.0]])       # over the north pole
    >>> 75 < float(lat[0]) < 90
    True
    """
    from magcal.frames.geo import convert_vectors

    sm = convert_vectors(np.atleast_2d(np.asarray(pos_gei_km, dtype=float)), times, "GEI", "SM")
    return np.degrees(np.arcsin(sm[:, 2] / np.linalg.norm(sm, axis=1)))


def spin_average(t_s, values, window_s: float) -> np.ndarray:
    """Running mean over ``window_s`` seconds centred on each sample (gaps allowed).

    Examples
    --------
    >>> t = np.arange(0.0, 30.0, 0.1)
    >>> x = 5.0 + np.cos(2 * np.pi * t / 2.0)            # a 2 s oscillation about 5
    >>> bool(np.abs(spin_average(t, x, 2.0)[20:-20] - 5.0).max() < 0.06)
    True
    """
    t = np.asarray(t_s, dtype=float)
    x = np.asarray(values, dtype=float)
    x2 = x.reshape(x.shape[0], -1)
    c = np.vstack([np.zeros((1, x2.shape[1])), np.cumsum(x2, axis=0)])
    lo = np.searchsorted(t, t - window_s / 2, side="left")
    hi = np.searchsorted(t, t + window_s / 2, side="right")
    return ((c[hi] - c[lo]) / (hi - lo)[:, None]).reshape(x.shape)


def natural_field_intervals(t_s, across_slow, mlat_deg, *, min_lat_deg: float = 60.0,
                            background_s: float = 120.0, window_s: float = 20.0,
                            threshold_nT: float = 10.0, pad_s: float = 5.0) -> np.ndarray:
    """Samples inside auroral current-sheet signatures of the spin-averaged residual.

    The *structure* is the spin-averaged across-B residual minus its own running mean
    over ``background_s`` (so only scales of tens of seconds remain: a current sheet
    crossed at 7.5 km/s in 10-60 s). A sample is flagged where the RMS of the structure
    per component over ``window_s`` exceeds ``threshold_nT`` and ``|mlat| >=
    min_lat_deg``; flags are widened by ``pad_s`` on each side.

    Parameters
    ----------
    t_s : array_like (n,)
        Times, seconds.
    across_slow : array_like (n, 3)
        Spin-averaged residual across B (nT), any frame.
    mlat_deg : array_like (n,)
        Magnetic latitude (:func:`dipole_latitude`).

    Returns
    -------
    ndarray of bool (n,)

    Examples
    --------
    >>> t = np.arange(0.0, 300.0, 0.1)
    >>> bump = np.zeros((t.size, 3))
    >>> bump[:, 2] = 100 * np.exp(-0.5 * ((t - 200) / 8) ** 2)   # a 30 s sheet at 200 s
    >>> flag = natural_field_intervals(t, bump, np.full(t.size, 70.0))
    >>> bool(170 < t[flag].min() < 190 < 210 < t[flag].max() < 230)
    True
    >>> bool(natural_field_intervals(t, bump, np.full(t.size, 50.0)).any())
    False
    """
    t = np.asarray(t_s, dtype=float)
    a = np.asarray(across_slow, dtype=float)
    struct = a - spin_average(t, a, background_s)
    local = np.sqrt(spin_average(t, np.sum(struct ** 2, axis=1) / a.shape[1], window_s))
    core = (local > threshold_nT) & (np.abs(np.asarray(mlat_deg, dtype=float)) >= min_lat_deg)
    if not core.any() or pad_s <= 0:
        return core
    near = spin_average(t, core.astype(float), 2 * pad_s)   # > 0 within pad_s of a flag
    return near > 0


def transverse_test(t_s, e_despun, ref_despun, flagged, *, background_s: float = 120.0,
                    spin_s: float = 2.85) -> dict:
    """Is the flagged structure across B (natural) or a spin-axis offset (instrument)?

    An offset ``dZ`` of the spin-axis sensor changes ``|B|`` by ``dZ B_Z / |B|``; a
    natural field across B changes it only to second order. Inside the flags the
    spin-averaged structure of ``|B|`` (scalar ``s``) is regressed on the prediction
    ``p = dZ B_Z / |B|`` (``dZ``: structure of the despun Z residual): a coefficient near
    1 says instrument, near 0 says a field across B.

    Returns
    -------
    dict
        ``coefficient`` and its ``coefficient_std`` (white-noise, per spin), ``z_structure_nT``
        (RMS of ``dZ``), ``predicted_scalar_nT`` (RMS of ``p``: what ``|B|`` would show if
        it were instrumental) and ``scalar_structure_nT`` (RMS of ``s``); NaN without flags.
    """
    t = np.asarray(t_s, dtype=float)
    m = np.asarray(flagged, bool)
    nan = {k: float("nan") for k in ("coefficient", "coefficient_std", "z_structure_nT",
                                      "predicted_scalar_nT", "scalar_structure_nT")}
    if m.sum() < 50:
        return nan
    e, r = np.asarray(e_despun, float), np.asarray(ref_despun, float)
    mag = np.linalg.norm(r, axis=1)
    scal = np.linalg.norm(r + e, axis=1) - mag

    def structure(x):
        s = spin_average(t, x, spin_s)
        return s - spin_average(t, s, background_s)

    dz, s = structure(e[:, 2]), structure(scal)
    p = dz * r[:, 2] / mag
    pm, sm = p[m], s[m]
    coef = float(pm @ sm / max(pm @ pm, 1e-30))
    n_ind = max(int((t[m][-1] - t[m][0]) / spin_s), 2)          # about one value per spin
    sigma = rms(sm - coef * pm) / np.sqrt(max(pm @ pm, 1e-30) / pm.size * n_ind)
    return {"coefficient": coef, "coefficient_std": float(sigma), "z_structure_nT": rms(dz[m]),
            "predicted_scalar_nT": rms(pm), "scalar_structure_nT": rms(sm)}


def axial_coupling_line(t_s, b_body, ref_body, *, knot_s: float = 30.0) -> dict:
    """Trajectory of the spin-axis 1x coefficient: does it move along one body direction?

    The spin-axis residual in the spinning frame is fitted with ``Re(d(t) e^{-i psi})``
    plus a slow term, ``d`` and the slow term cubic B-splines (knots every ``knot_s``).
    A coupling of the spin-axis sensor to the field along one body direction with a
    changing size gives ``d(t)`` on a line through 0 (``line_fraction`` near 1); a
    coning of the spin axis gives a circle (0.5).

    Returns
    -------
    dict
        ``rms_nT`` and ``max_nT`` of ``|d|``, ``line_fraction`` (share of ``sum |d|^2``
        along its principal direction), ``direction_deg`` (that direction, body frame,
        mod 180) and ``sign_changes`` (of ``d`` along it).
    """
    from magcal.missions.elfin.vector import drift_basis

    t = np.asarray(t_s, dtype=float)
    b, ref = np.asarray(b_body, float), np.asarray(ref_body, float)
    use = np.ones(t.size, bool)
    basis = drift_basis(t, use, knot_s=knot_s)
    psi = np.angle(b[:, 0] + 1j * b[:, 1])
    design = np.column_stack([basis, np.cos(psi)[:, None] * basis, np.sin(psi)[:, None] * basis])
    w = np.linalg.lstsq(design, (b - ref)[:, 2], rcond=None)[0]
    n = basis.shape[1]
    d = basis @ (w[n:2 * n] + 1j * w[2 * n:])
    xy = np.column_stack([d.real, d.imag])
    _, sv, vt = np.linalg.svd(xy, full_matrices=False)
    along = xy @ vt[0]
    return {"rms_nT": rms(np.abs(d)), "max_nT": float(np.abs(d).max()),
            "line_fraction": float(sv[0] ** 2 / max(np.sum(sv ** 2), 1e-30)),
            "direction_deg": float(np.degrees(np.arctan2(vt[0, 1], vt[0, 0])) % 180.0),
            "sign_changes": int(np.sum(np.diff(np.sign(along)) != 0))}


def residual_split(t_s, b, ref, *, spin_s: float, flagged=None) -> dict:
    """RMS of the residual ``b - ref`` split along/across B, slow/within-spin, in/outside.

    Parameters
    ----------
    t_s : array_like (n,)
        Times, seconds.
    b, ref : array_like (n, 3)
        Calibrated and reference field, same frame (nT).
    spin_s : float
        Spin period: the boxcar that separates spin-averaged from within-spin.
    flagged : array_like of bool, optional
        Natural-field samples (default none).

    Returns
    -------
    dict
        Per-component RMS (nT): ``vector`` (all three components), ``along``, ``across``
        (per component of the two), their ``_slow`` and ``_fast`` parts; ``scalar`` and
        ``scalar_fast5`` (after a 5th-order polynomial, the issue's fast part) and
        ``scalar_fast`` (within-spin); the same ``vector``/``scalar`` with ``_out`` and
        ``_in`` (outside/inside the flags); ``ratio`` = vector / scalar for all, ``_out``
        and ``_fast`` (within-spin both); ``flagged_fraction``.
    """
    t = np.asarray(t_s, dtype=float)
    b, ref = np.asarray(b, float), np.asarray(ref, float)
    m = np.zeros(t.size, bool) if flagged is None else np.asarray(flagged, bool)
    e = b - ref
    unit = ref / np.linalg.norm(ref, axis=1, keepdims=True)
    along = np.sum(e * unit, axis=1)
    across = e - along[:, None] * unit
    scal = np.linalg.norm(b, axis=1) - np.linalg.norm(ref, axis=1)
    slow = {name: spin_average(t, x, spin_s) for name, x in
            (("e", e), ("along", along), ("across", across), ("scal", scal))}

    def per_comp(x, k=3):
        return float(np.sqrt(np.nansum(np.square(x)) / max(x.shape[0] * k, 1)))

    out = {
        "vector": rms(e), "along": rms(along), "across": per_comp(across, 2),
        "along_slow": rms(slow["along"]), "along_fast": rms(along - slow["along"]),
        "across_slow": per_comp(slow["across"], 2),
        "across_fast": per_comp(across - slow["across"], 2),
        "vector_slow": rms(slow["e"]), "vector_fast": rms(e - slow["e"]),
        "scalar": rms(scal), "scalar_fast5": rms(fast_part(t, scal)),
        "scalar_fast": rms(scal - slow["scal"]),
        "vector_out": rms(e[~m]), "scalar_out": rms(scal[~m]),
        "vector_in": rms(e[m]), "scalar_in": rms(scal[m]),
        "across_in": per_comp(across[m], 2), "across_out": per_comp(across[~m], 2),
        "flagged_fraction": float(m.mean()),
    }
    out["ratio"] = out["vector"] / out["scalar"]
    out["ratio_out"] = out["vector_out"] / out["scalar_out"]
    out["ratio_fast"] = out["vector_fast"] / out["scalar_fast"]
    return out


def _tilt(b, ref, use, T=None):
    """Least-squares spin-axis tilt (constant, or constant + linear in ``T``), degrees."""
    cx, cy = np.cross([1.0, 0.0, 0.0], b), np.cross([0.0, 1.0, 0.0], b)
    cols = [cx, cy] if T is None else [cx, cy, cx * T[:, None], cy * T[:, None]]
    design = np.column_stack([c[use].ravel() for c in cols])
    w = np.linalg.lstsq(design, (b - ref)[use].ravel(), rcond=None)[0]
    return b - sum(wi * c for wi, c in zip(w, cols)), np.degrees(w)


def vector_evidence(cal, mlat_deg, *, spin_s: float | None = None, knot_s: float = 30.0,
                    min_lat_deg: float = 60.0, **flag_kw) -> pd.DataFrame:
    """Per zone: the split of :func:`residual_split`, the flags, and what the rest needs.

    Parameters
    ----------
    cal : magcal.missions.elfin.ElfinCalibration
        The delivered product (after the vector step).
    mlat_deg : array_like (n,)
        Magnetic latitude at every row of ``cal.field`` (:func:`dipole_latitude`).
    spin_s : float, optional
        Spin period; default from each zone's phase.
    knot_s : float
        Knot spacing of :func:`axial_coupling_line`.
    min_lat_deg : float
        Auroral latitude: flags only above it; below it the sub-auroral part of the pass.
    **flag_kw
        Passed to :func:`natural_field_intervals`.

    Returns
    -------
    DataFrame
        One row per zone: ``zone``, ``spin_s``, ``mlat_max``, the :func:`residual_split`
        numbers; in the despun frame ``plane`` (spin-plane RMS per component), ``axis``
        and ``axis_slow`` (spin axis, all and spin-averaged), ``ratio_plane`` (plane /
        scalar) and ``bz_fraction`` (median ``|B_Z| / |B|``: how much of a spin-axis error
        the scalar sees); :func:`transverse_test` (prefixed ``transverse_``),
        :func:`axial_coupling_line` (prefixed ``axial1x_``), and, outside the flags,
        ``tilt_free_deg`` (constant tilt without the bound, on top of the product's) with
        ``ratio_out_tilt_free``, and ``tilt_drift_deg`` (constant and linear-in-time
        angles) with ``ratio_out_tilt_drift``; ``across_slow_sub`` and
        ``across_slow_auroral`` (spin-averaged across-B per component below and above
        ``min_lat_deg``); ``tilt_sub_deg``, a drifting tilt fitted below ``min_lat_deg``
        only, with ``ratio_sub_tilt_drift`` there and ``ratio_auroral_tilt_predicted``
        above (an attitude motion would carry over; a field of the sub-auroral part would
        not).
    """
    from magcal.spin.despin import spin

    f = cal.field
    lat = np.asarray(mlat_deg, dtype=float)
    rows = []
    for k in sorted(f["zone"].unique()):
        sel = ((f["zone"] == k) & (f["used"] == 1)).to_numpy()
        z = f[sel]
        t = (z.index.asi8 - z.index.asi8[0]) / 1e9
        b = z[["bx_despun", "by_despun", "bz_despun"]].to_numpy(float)
        ref = z[["igrf_x_despun", "igrf_y_despun", "igrf_z_despun"]].to_numpy(float)
        phase = z["phase"].to_numpy(float)
        period = spin_s or float(2 * np.pi * t[-1] / abs(phase[-1] - phase[0]))
        e = b - ref
        unit = ref / np.linalg.norm(ref, axis=1, keepdims=True)
        across = e - np.sum(e * unit, axis=1)[:, None] * unit
        slow_across = spin_average(t, across, period)
        flags = natural_field_intervals(t, slow_across, lat[sel], min_lat_deg=min_lat_deg,
                                        **flag_kw)
        split = residual_split(t, b, ref, spin_s=period, flagged=flags)
        out = ~flags
        T = 2.0 * t / t[-1] - 1.0
        b_free, ang_free = _tilt(b, ref, out)
        b_drift, ang_drift = _tilt(b, ref, out, T)
        scal_out = split["scalar_out"]
        axis_slow = spin_average(t, e[:, 2], period)
        frame = {"plane": rms(e[:, :2]), "axis": rms(e[:, 2]), "axis_slow": rms(axis_slow),
                 "ratio_plane": rms(e[:, :2]) / split["scalar"],
                 "bz_fraction": float(np.median(np.abs(ref[:, 2]) / np.linalg.norm(ref, axis=1)))}
        sub = np.abs(lat[sel]) < min_lat_deg
        scal = np.linalg.norm(b, axis=1) - np.linalg.norm(ref, axis=1)
        sub_rows = {"across_slow_sub": float("nan"), "across_slow_auroral": float("nan"),
                    "tilt_sub_deg": [], "ratio_sub_tilt_drift": float("nan"),
                    "ratio_auroral_tilt_predicted": float("nan")}
        if sub.sum() > 100 and (~sub).sum() > 100:
            b_sub, ang_sub = _tilt(b, ref, sub, T)
            sub_rows = {
                "across_slow_sub": rms(slow_across[sub]) * np.sqrt(1.5),
                "across_slow_auroral": rms(slow_across[~sub]) * np.sqrt(1.5),
                "tilt_sub_deg": ang_sub.tolist(),
                "ratio_sub_tilt_drift": rms((b_sub - ref)[sub]) / rms(scal[sub]),
                "ratio_auroral_tilt_predicted": rms((b_sub - ref)[~sub]) / rms(scal[~sub])}
        rows.append({
            "zone": int(k), "spin_s": period, "mlat_max": float(np.abs(lat[sel]).max()),
            **split, **frame,
            **{f"transverse_{n}": v for n, v in
               transverse_test(t, e, ref, flags, spin_s=period).items()},
            **{f"axial1x_{n}": v for n, v in
               axial_coupling_line(t, spin(b, phase), spin(ref, phase), knot_s=knot_s).items()},
            "tilt_free_deg": ang_free.tolist(),
            "ratio_out_tilt_free": rms((b_free - ref)[out]) / scal_out,
            "tilt_drift_deg": ang_drift.tolist(),
            "ratio_out_tilt_drift": rms((b_drift - ref)[out]) / scal_out,
            **sub_rows,
        })
    return pd.DataFrame(rows)


#: Ratios of :func:`vector_evidence`, in the order the verdict reads them.
RATIOS = ("ratio", "ratio_out", "ratio_fast", "ratio_plane", "ratio_out_tilt_free",
          "ratio_out_tilt_drift", "ratio_sub_tilt_drift", "ratio_auroral_tilt_predicted")


def evidence_verdict(table: pd.DataFrame, *, target: float = 1.5,
                     attitude_deg: float = 0.2) -> dict:
    """Zone medians of the ratios, zones within ``target``, and what attitude they need.

    Returns
    -------
    dict
        ``{ratio: {"median", "max", "zones_within"}}`` for each of :data:`RATIOS`, and
        ``tilt_drift_max_deg`` (largest angle of the drifting tilt outside the flags) with
        ``zones_beyond_attitude`` (zones where it exceeds ``attitude_deg``, plus what the
        product's own tilt already took).
    """
    out = {}
    for name in RATIOS:
        v = table[name].to_numpy(float)
        out[name] = {"median": float(np.nanmedian(v)), "max": float(np.nanmax(v)),
                     "zones_within": int(np.sum(v <= target)), "zones": int(np.sum(np.isfinite(v)))}
    drift = np.abs(np.vstack(table["tilt_drift_deg"]))
    # the angle at the zone's ends: constant + linear part
    ends = np.maximum(np.abs(drift[:, 0]) + np.abs(drift[:, 2]),
                      np.abs(drift[:, 1]) + np.abs(drift[:, 3]))
    out["tilt_drift_max_deg"] = float(ends.max())
    out["zones_beyond_attitude"] = int(np.sum(ends > attitude_deg))
    out["target"] = target
    return out


def field_latitude(cal, state: pd.DataFrame) -> np.ndarray:
    """:func:`dipole_latitude` at every row of ``cal.field`` (from the 1 s state records)."""
    pos = state[["pos_gei_x", "pos_gei_y", "pos_gei_z"]].to_numpy(float)
    lat = dipole_latitude(state.index, pos)
    ts = state.index.asi8 / 1e9
    return np.interp(cal.field.index.asi8 / 1e9, ts, lat)
