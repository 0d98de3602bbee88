"""Evidence for and against mechanisms of the ELFIN scalar residual (issue 15).

Each function measures one discriminating property of ``|B| - |B_IGRF|``:

* :func:`locking_table`: is the spin-harmonic residual locked to the sensor (harmonics
  of the field's angle in the spinning frame) or to inertial space / the Sun (harmonics
  of the spin phase)? A sensor non-linearity or a field fixed in the spacecraft locks to
  the first, a sun-synchronous spacecraft field or a reference error to the second.
* :func:`power_law`: how a harmonic's amplitude grows with |B| across zones (a cubic
  non-linearity gives a scalar 4x term growing as |B|^3).
* :func:`timestamp_effect`: the linear floor with and without the time-stamp repair.

Data: ELFIN SOC (PI V. Angelopoulos, UCLA), "Open Data for Scientific Use".
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from magcal.missions.elfin.scalar import (
    _harmonics,
    _unit_time,
    fast_part,
    linear_scalar_fit,
    rms,
    scalar_zones,
)
from magcal.spin.despin import spin


def _rms_after(t, r, angle, harmonics, poly_degree):
    x = _unit_time(t)
    design = np.column_stack([np.vander(x, poly_degree + 1), _harmonics(angle, harmonics)])
    return rms(r - design @ np.linalg.lstsq(design, r, rcond=None)[0])


def locking_table(cal, *, harmonics=(1, 2, 3, 4), poly_degree: int = 5) -> pd.DataFrame:
    """Scalar residual of a linear ELFIN calibration explained by sensor vs inertial harmonics.

    Parameters
    ----------
    cal : magcal.missions.elfin.ElfinCalibration
        The linear calibration (before any spin-harmonic correction).

    Returns
    -------
    DataFrame
        Per zone: ``fast_nT`` (after the time polynomial), ``sensor_locked_nT`` (after
        constant harmonics of the spinning-frame angle), ``inertial_locked_nT`` (after
        constant harmonics of the spin phase), ``both_nT``.
    """
    rows = []
    for k, f in cal.field.groupby("zone"):
        f = f[f["used"] == 1]
        t = (f.index.asi8 - f.index.asi8[0]) / 1e9
        desp = f[["bx_despun", "by_despun", "bz_despun"]].to_numpy()
        ref = f[["igrf_x_despun", "igrf_y_despun", "igrf_z_despun"]].to_numpy()
        phase = f["phase"].to_numpy()
        body = spin(desp, phase)
        r = np.linalg.norm(desp, axis=1) - np.linalg.norm(ref, axis=1)
        psi = np.arctan2(body[:, 1], body[:, 0])
        x = _unit_time(t)
        design = np.column_stack([np.vander(x, poly_degree + 1), _harmonics(psi, harmonics),
                                  _harmonics(phase, harmonics)])
        both = rms(r - design @ np.linalg.lstsq(design, r, rcond=None)[0])
        rows.append({"zone": int(k), "fast_nT": rms(fast_part(t, r, poly_degree)),
                     "sensor_locked_nT": _rms_after(t, r, psi, harmonics, poly_degree),
                     "inertial_locked_nT": _rms_after(t, r, phase, harmonics, poly_degree),
                     "both_nT": both})
    return pd.DataFrame(rows)


def power_law(amplitude, magnitude) -> tuple[float, float]:
    """Exponent ``n`` of ``amplitude ~ magnitude^n`` (log-log least squares) and the
    correlation coefficient of the logs.

    Examples
    --------
    >>> n, r = power_law([1.0, 8.0, 27.0], [1.0, 2.0, 3.0])
    >>> round(n, 6), round(r, 6)
    (3.0, 1.0)
    """
    la, lm = np.log(np.asarray(amplitude, float)), np.log(np.asarray(magnitude, float))
    return float(np.polyfit(lm, la, 1)[0]), float(np.corrcoef(lm, la)[0, 1])


def _floor(zone) -> float:
    return rms(linear_scalar_fit(zone.counts, zone.igrf_nT).residual_nT)


def timestamp_effect(fgs, state) -> pd.DataFrame:
    """Linear scalar floor per zone with and without the paired time-stamp repair.

    The scalar residual does not depend on a time error common to the three axes except
    through the reference's change along the orbit (tens of nT/s), so a repair that
    matters shows here only if the stamps or the axes are wrong by much more.
    """
    from magcal.missions.elfin.phase import repair_timestamps, split_zones

    t_all = (fgs.index.asi8 - fgs.index.asi8[0]) / 1e9
    n_jumps = [len(repair_timestamps(t_all[a:b])[1]) for a, b in split_zones(t_all)]
    rows = []
    for fixed, raw in zip(scalar_zones(fgs, state), scalar_zones(fgs, state, repair_times=False)):
        rows.append({"zone": fixed.number, "n_jumps": n_jumps[fixed.number],
                     "floor_repaired_nT": _floor(fixed), "floor_raw_nT": _floor(raw)})
    return pd.DataFrame(rows)
