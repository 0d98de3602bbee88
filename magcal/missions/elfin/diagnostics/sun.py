"""Is the extra fast part of the sunlit ELFIN passes locked to the Sun?

On 2022-01-12 the two passes in full sunlight (zones 7 and 8, dawn) keep a fast part of
``|B| - |IGRF|`` of 17 and 14 nT after the calibration, against 5-8 nT in the others.
Solar-array currents would make a spacecraft field that depends on how the panels face
the Sun, i.e. on the angle ``chi`` of the Sun in the spinning body frame, and that adds
to ``|B|`` as ``b_hat . dB``. :func:`sun_locked_test` fits the fast part per zone with

* ``sun``: ``sum_k [cos k chi, sin k chi] x b_hat`` (body frame, ``k = 1..harmonics``);
* ``control``: the same with ``2 psi - chi`` instead of ``chi`` (``psi``: the field's
  angle in the spin plane): an angle that drifts against the field exactly as fast as
  the Sun's does, but in the other sense, and is tied to nothing physical;
* ``field``: the same with ``psi`` (what the harmonic correction already models);
* ``drift``: the field-locked 1x and 2x harmonics with coefficients drifting on cubic
  B-splines (knots every ``knot_s``), no Sun at all.

If the Sun drove it, ``sun`` would beat ``control`` in the sunlit zones and not in the
eclipse ones. Within a pass the Sun's angle and the field's differ by a slowly turning
35-41 deg, so a term locked to either is a field-locked term with a drifting
coefficient; only the control can tell them apart.

The Sun direction is the GSE X axis (Earth to Sun) through spacepy/IRBEM; the sunlit
share of a zone is the state file's Sun flag.

Data: ELFIN SOC (PI V. Angelopoulos, UCLA), "Open Data for Scientific Use".
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from magcal.missions.elfin.scalar import fast_part, rms


def sun_direction_gei(times) -> np.ndarray:
    """Unit vectors Earth to Sun in GEI (the GSE X axis, spacepy/IRBEM).

    Examples
    --------
    >>> s = sun_direction_gei(np.array(["2022-01-12T12:00:00"], dtype="datetime64[ns]"))
    >>> bool(-0.4 < s[0, 2] < -0.3)        # January: the Sun about 21.7 deg south
    True
    """
    from magcal.frames.geo import convert_vectors

    n = len(times)
    return convert_vectors(np.tile([1.0, 0.0, 0.0], (n, 1)), times, "GSE", "GEI")


def _locked(angle, b_hat, harmonics):
    cols = [b_hat]
    for k in range(1, harmonics + 1):
        for trig in (np.cos, np.sin):
            cols.append(trig(k * angle)[:, None] * b_hat)
    return np.column_stack(cols)


def _left(t, fast, design):
    w = np.linalg.lstsq(design, fast, rcond=None)[0]
    return rms(fast - fast_part(t, design @ w))


def sun_locked_zone(t_s, b_body, ref_magnitude_nT, sun_body, *, harmonics: int = 2,
                    knot_s: float = 60.0) -> dict:
    """Fast part of ``|B| - |ref|`` left by Sun-locked, control and field-locked models.

    Parameters
    ----------
    t_s : array_like (n,)
        Times, seconds.
    b_body : array_like (n, 3)
        Calibrated field in the spinning frame (``z`` = spin axis), nT.
    ref_magnitude_nT : array_like (n,)
        |IGRF|.
    sun_body : array_like (n, 3)
        Sun direction in the same spinning frame.
    harmonics : int
        Harmonics of each angle (2: a panel's cosine law and its first overtone). With
        more, each model has so many columns that on a 40 deg drift the control fits an
        injected Sun-locked field almost as well as the Sun does (6 harmonics: 0.69
        against 0.50 nT of noise; 2: 2.8 against 0.5), and the test loses its power.
    knot_s : float
        Knot spacing of the ``drift`` model.

    Returns
    -------
    dict
        ``fast_nT`` and ``sun_nT``, ``control_nT``, ``field_nT``, ``drift_nT`` (RMS of the
        fast part each leaves) and ``chi_minus_psi_range_deg``.
    """
    from magcal.missions.elfin.vector import drift_basis

    t = np.asarray(t_s, dtype=float)
    b = np.asarray(b_body, dtype=float)
    sun = np.asarray(sun_body, dtype=float)
    mag = np.linalg.norm(b, axis=1)
    fast = fast_part(t, mag - np.asarray(ref_magnitude_nT, dtype=float))
    b_hat = b / mag[:, None]
    psi = np.arctan2(b[:, 1], b[:, 0])
    chi = np.arctan2(sun[:, 1], sun[:, 0])
    basis = drift_basis(t, np.ones(t.size, bool), knot_s=knot_s)
    drift = np.column_stack([f(k * psi)[:, None] * basis for k in (1, 2) for f in (np.cos, np.sin)])
    return {"fast_nT": rms(fast),
            "sun_nT": _left(t, fast, _locked(chi, b_hat, harmonics)),
            "control_nT": _left(t, fast, _locked(2 * psi - chi, b_hat, harmonics)),
            "field_nT": _left(t, fast, _locked(psi, b_hat, harmonics)),
            "drift_nT": _left(t, fast, drift),
            "chi_minus_psi_range_deg": float(np.degrees(np.ptp(np.unwrap(chi - psi))))}


def sun_locked_test(cal, state: pd.DataFrame, **kw) -> pd.DataFrame:
    """:func:`sun_locked_zone` for every zone of an ElfinCalibration.

    Parameters
    ----------
    cal : magcal.missions.elfin.ElfinCalibration
        The delivered product.
    state : DataFrame
        From :func:`~magcal.missions.elfin.files.read_elfin_state` (the ``sun`` flag).
    **kw
        Passed to :func:`sun_locked_zone`.

    Returns
    -------
    DataFrame
        One row per zone: ``zone``, ``sun_fraction`` and the :func:`sun_locked_zone` numbers.
    """
    from magcal.missions.elfin.phase import despun_basis
    from magcal.spin.despin import spin

    f = cal.field
    ts = state.index.asi8 / 1e9
    rows = []
    for k in sorted(f["zone"].unique()):
        z = f[(f["zone"] == k) & (f["used"] == 1)]
        t = (z.index.asi8 - z.index.asi8[0]) / 1e9
        phase = z["phase"].to_numpy(float)
        step = max(1, len(z) // 100)                       # the Sun moves 0.04 deg per 10 s
        sun = sun_direction_gei(z.index[::step])
        sun = np.column_stack([np.interp(t, t[::step], sun[:, j]) for j in range(3)])
        basis = despun_basis(z[["spin_axis_gei_x", "spin_axis_gei_y", "spin_axis_gei_z"]]
                             .to_numpy(float))
        sun_body = spin(np.einsum("nij,nj->ni", basis, sun), phase)
        b_body = spin(z[["bx_despun", "by_despun", "bz_despun"]].to_numpy(float), phase)
        ref = np.linalg.norm(z[["igrf_x_despun", "igrf_y_despun", "igrf_z_despun"]]
                             .to_numpy(float), axis=1)
        frac = float(np.nanmean(np.interp(z.index.asi8 / 1e9, ts, state["sun"].to_numpy(float))))
        rows.append({"zone": int(k), "sun_fraction": frac,
                     **sun_locked_zone(t, b_body, ref, sun_body, **kw)})
    return pd.DataFrame(rows)
