"""Cross-check of the ELFIN IGRF calibration with the spin-ripple method (no model field).

The spin-ripple fit (:func:`magcal.spin.ripple.fit_spin_ripple`, Kivelson et al. 1992)
needs readings in a frame whose third axis is the spin axis and a spin phase that
increases. For ELFIN counts (sensor axes far from the spin axis, spin sense either way)
each zone's counts are turned by a fixed rotation ``R`` whose third row is the
spin-axis row of the IGRF calibration (the functional that gives ``B_z``), scaled by a
nominal ``scale`` nT/count, and the phase sign and the triad are flipped together when
the phase decreases. The phase is that of the IGRF calibration (ELFIN has no
spin-phase variable); its spline (30 s knots) cannot follow a spin-period tone, so the
ripple is left to the ripple fit.

Compared, per zone, are the quantities the ripple fit determines:

* the spin-plane anisotropy of the calibration (gain ratio and non-orthogonality):
  ``a = (G11 - G22) / (G11 + G22)``, ``b = 2 G12 / (G11 + G22)`` with ``G`` the
  spin-plane metric ``C_xy^T C_xy`` on the rotated readings' first two axes;
* the effective spin-plane offset (nT) at the zone's mean spin-axis reading, in the
  IGRF calibration's gain (the common spin-plane gain is not determinable from ripple).

Data: ELFIN SOC (PI V. Angelopoulos, UCLA), "Open Data for Scientific Use".
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from magcal.missions.elfin.phase import split_zones
from magcal.spin.ripple import PARAM_NAMES, fit_spin_ripple


def _anisotropy(g) -> np.ndarray:
    tr = g[0, 0] + g[1, 1]
    return np.array([(g[0, 0] - g[1, 1]) / tr, 2 * g[0, 1] / tr])


def ripple_zone(t_s, counts, phase_rad, coupling, offsets_counts, *,
                scale: float = 0.01) -> dict:
    """Spin-ripple calibration of one zone and its comparison with an IGRF one.

    Parameters
    ----------
    t_s, phase_rad : array_like (n,)
        Times and spin phase of the samples used.
    counts : array_like (n, 3)
        Raw readings.
    coupling, offsets_counts :
        The IGRF calibration ``B_body = C (b - O)`` (rows: body X, Y, Z = spin axis).
    scale : float
        Nominal nT per count for the ripple fit's input.

    Returns
    -------
    dict
        ``anisotropy_ripple``, ``anisotropy_igrf`` (a, b), ``anisotropy_std`` (from the
        ripple covariance, propagated numerically), ``offset_ripple_nT``,
        ``offset_igrf_nT`` (effective spin-plane offsets, same frame and gain),
        ``offset_std_nT``, ``tone_after_nT`` and the rotation tilt and sense found.
    """
    t = np.asarray(t_s, dtype=float)
    c = np.asarray(counts, dtype=float)
    ph = np.asarray(phase_rad, dtype=float)
    cmat = np.asarray(coupling, dtype=float)
    r3 = cmat[2] / np.linalg.norm(cmat[2])
    r1 = np.cross(r3, np.eye(3)[int(np.argmin(np.abs(r3)))])
    r1 /= np.linalg.norm(r1)
    rot = np.vstack([r1, np.cross(r3, r1), r3])
    if ph[-1] < ph[0]:                       # spin about -Z: turn the triad 180 deg about X
        ph = -ph
        rot = np.diag([1.0, -1.0, -1.0]) @ rot
    b = scale * (c @ rot.T)
    cal = fit_spin_ripple(t, b, ph)
    m = cmat @ rot.T / scale                 # IGRF calibration on the rotated readings
    o_igrf = scale * rot @ np.asarray(offsets_counts, dtype=float)
    axis_reading = np.array([0.0, 0.0, float(np.mean(b[:, 2]))])

    def compare(coup, offs):
        g = coup[:2].T @ coup[:2]
        # common spin-plane gain of the IGRF calibration over the ripple's (not determinable)
        gain = abs(np.linalg.det(m[:2, :2]) / np.linalg.det(coup[:2, :2])) ** 0.5
        u, _, vt = np.linalg.svd(m[:2, :2] @ np.linalg.pinv(coup[:2, :2]))
        return _anisotropy(g[:2, :2]), gain * (u @ vt) @ (coup[:2] @ (axis_reading - offs))

    aniso_r, off_r = compare(cal.coupling, cal.offsets_nT)
    # uncertainties: propagate the ripple covariance by finite differences
    theta = np.r_[cal.coupling.ravel(), cal.offsets_nT]
    idx = [PARAM_NAMES.index(n) for n in cal.determined]
    jac = []
    for i in idx:
        step = np.zeros(12)
        step[i] = 1e-6 * max(1.0, abs(theta[i]))
        th = theta + step
        a, o = compare(th[:9].reshape(3, 3), th[9:])
        jac.append(np.r_[a - aniso_r, o - off_r] / step[i])
    jac = np.array(jac).T
    cov = jac @ cal.covariance @ jac.T
    std = np.sqrt(np.clip(np.diag(cov), 0, None))
    aniso_v = _anisotropy((m[:2].T @ m[:2])[:2, :2])
    off_v = m[:2] @ (axis_reading - o_igrf)
    return {"anisotropy_ripple": aniso_r, "anisotropy_igrf": aniso_v, "anisotropy_std": std[:2],
            "offset_ripple_nT": off_r, "offset_igrf_nT": off_v, "offset_std_nT": std[2:],
            "tone_after_nT": cal.spin_tone_after_nT, "converged": cal.converged}


def ripple_crosscheck(cal, fgs: pd.DataFrame, *, scale: float = 0.01) -> pd.DataFrame:
    """Spin-ripple cross-check of every zone of an ELFIN IGRF calibration.

    Parameters
    ----------
    cal : magcal.missions.elfin.ElfinCalibration
        From :func:`~magcal.missions.elfin.linear.calibrate_elfin` on ``fgs`` (all zones).
    fgs : DataFrame
        The counts it was made from.

    Returns
    -------
    DataFrame
        One row per zone: anisotropy (a, b) from ripple and IGRF with the ripple's
        standard deviation, their difference in standard deviations, effective
        spin-plane offsets (nT) and their difference.
    """
    t_all = (fgs.index.asi8 - fgs.index.asi8[0]) / 1e9
    ranges = split_zones(t_all, cal.parameters.get("min_gap_s", 60.0))
    counts = fgs[["b1", "b2", "b3"]].to_numpy()
    rows = []
    starts = np.array([fgs.index.asi8[a] for a, _ in ranges])
    for z, k in zip(cal.zones, sorted(cal.field["zone"].unique())):
        f = cal.field[cal.field["zone"] == k]
        # the zone's rows of fgs: the range its middle falls in (zone numbers need not
        # be positions in fgs: a subset of zones, or zones taken out)
        a, b = ranges[int(np.searchsorted(starts, f.index.asi8[len(f) // 2], "right")) - 1]
        used = f["used"].to_numpy() == 1
        t = (f.index.asi8 - f.index.asi8[0]) / 1e9
        res = ripple_zone(t[used], counts[a:b][used], f["phase"].to_numpy()[used],
                          z.coupling, z.offsets_counts, scale=scale)
        da = res["anisotropy_ripple"] - res["anisotropy_igrf"]
        rows.append({"zone": int(k),
                     "aniso_a_ripple": res["anisotropy_ripple"][0],
                     "aniso_a_igrf": res["anisotropy_igrf"][0],
                     "aniso_b_ripple": res["anisotropy_ripple"][1],
                     "aniso_b_igrf": res["anisotropy_igrf"][1],
                     "aniso_std": float(np.max(res["anisotropy_std"])),
                     "aniso_diff_sigma": float(np.max(np.abs(da) / res["anisotropy_std"])),
                     "offset_ripple_nT": np.linalg.norm(res["offset_ripple_nT"]),
                     "offset_igrf_nT": np.linalg.norm(res["offset_igrf_nT"]),
                     "offset_diff_nT": float(np.linalg.norm(res["offset_ripple_nT"]
                                                            - res["offset_igrf_nT"])),
                     "offset_std_nT": float(np.max(res["offset_std_nT"]))})
    return pd.DataFrame(rows)
