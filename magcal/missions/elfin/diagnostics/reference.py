"""Could a reference error make the slow part of the ELFIN scalar residual?

The slow part (what is left of ``|B| - |IGRF|`` after a 5th-order polynomial is taken
as the fast part) is about 60 nT RMS per science zone. Candidate reference errors, each
a change of ``|B_model|`` along the orbit per unit of the error:

* ``along_1s``: the counts' time tags 1 s late against the orbit (or a 1 s along-track
  position error);
* ``rot_x_1mrad``, ``rot_y_1mrad``, ``rot_z_1mrad``: the position frame rotated by
  1 mrad about GEI X, Y, Z (a J2000/true-of-date mix-up is 0.3 deg mostly about Z;
  an Earth-rotation-angle error of 13.7 s is 1 mrad about Z);
* ``radial_1km``, ``cross_1km``: position errors (orbit file);
* ``t89``: the T89 external field at the day's Kp minus IGRF (coefficient 1 is the
  physical size);
* ``ring_1nT``: a uniform 1 nT field along -Z_GSM (ring current, Dst);

and, for comparison, two instrument candidates with one shape for the day
(:func:`instrument_candidates`): a gain following the Sun flag (eclipse/sunlight) and a
warm-up after the instrument is switched on.

A real reference error has one coefficient for the day. :func:`screen_slow_part` fits
each candidate to the slow parts of all zones at once (per zone only a constant and a
constant gain, ``1`` and ``|B|``, which the calibration absorbs) and per zone, so that
its coefficient and its stability can be read off.

Data: ELFIN SOC (PI V. Angelopoulos, UCLA), "Open Data for Scientific Use".
"""

from __future__ import annotations

import warnings

import numpy as np
import pandas as pd

from magcal.missions.elfin.scalar import fast_part, rms

CANDIDATES = ("along_1s", "rot_x_1mrad", "rot_y_1mrad", "rot_z_1mrad", "radial_1km",
              "cross_1km", "t89", "ring_1nT", "sun_lowpass", "warm_up")


def _rotation(axis: int, angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    m = np.eye(3)
    m[i, i], m[i, j], m[j, i], m[j, j] = c, -s, s, c
    return m


def _model_magnitude(times, pos_gei_km, model="IGRF", kp=None) -> np.ndarray:
    from magcal.frames.geo import EARTH_RADIUS_KM, convert_vectors
    from magcal.models.irbem import field_geo

    pos_geo = convert_vectors(pos_gei_km, times, "GEI", "GEO") / EARTH_RADIUS_KM
    inputs = None if kp is None else {"Kp": np.asarray(kp, dtype=float)}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")          # IRBEM range notes; NaN is checked below
        b = field_geo(times, pos_geo, model=model, inputs=inputs)
    return np.linalg.norm(b, axis=1)


def reference_perturbations(times, pos_gei_km, vel_gei_km_s, kp=None) -> dict:
    """Change of ``|B_model|`` at orbit records per unit of each candidate error.

    Parameters
    ----------
    times : DatetimeIndex (n,)
        UTC times of the records.
    pos_gei_km, vel_gei_km_s : array_like (n, 3)
        GEI position and velocity.
    kp : array_like (n,), optional
        Kp at the records (for ``t89``; without it ``t89`` is left out).

    Returns
    -------
    dict
        ``{name: ndarray (n,)}`` for the names in :data:`CANDIDATES`, plus ``igrf``
        (``|IGRF|`` itself).
    """
    from magcal.frames.geo import EARTH_RADIUS_KM, convert_vectors
    from magcal.models.irbem import field_geo

    pos = np.asarray(pos_gei_km, dtype=float)
    vel = np.asarray(vel_gei_km_s, dtype=float)
    base = _model_magnitude(times, pos)
    out = {"igrf": base, "along_1s": _model_magnitude(times, pos + vel) - base}
    for axis, name in enumerate(("rot_x_1mrad", "rot_y_1mrad", "rot_z_1mrad")):
        out[name] = _model_magnitude(times, pos @ _rotation(axis, 1e-3).T) - base
    radial = pos / np.linalg.norm(pos, axis=1)[:, None]
    normal = np.cross(pos, vel)
    normal /= np.linalg.norm(normal, axis=1)[:, None]
    out["radial_1km"] = _model_magnitude(times, pos + radial) - base
    out["cross_1km"] = _model_magnitude(times, pos + normal) - base
    if kp is not None:
        out["t89"] = _model_magnitude(times, pos, "T89", kp) - base
    b_geo = field_geo(times, convert_vectors(pos, times, "GEI", "GEO") / EARTH_RADIUS_KM,
                      model="IGRF")
    z_gsm = convert_vectors(np.tile([0.0, 0.0, 1.0], (len(pos), 1)), times, "GSM", "GEO")
    out["ring_1nT"] = -np.sum(b_geo * z_gsm, axis=1) / np.linalg.norm(b_geo, axis=1)
    return out


def zone_slow_parts(cal, state: pd.DataFrame, kp=None, *, poly_degree: int = 5,
                    step: int = 10) -> list[dict]:
    """Per zone: times, slow part of ``|B| - |IGRF|``, ``|IGRF|`` and the candidates.

    Parameters
    ----------
    cal : magcal.missions.elfin.ElfinCalibration
        The calibration whose scalar residual is screened.
    state : DataFrame
        From :func:`magcal.missions.elfin.files.read_elfin_state`.
    kp : pandas.Series, optional
        3-hourly Kp (:func:`magcal.indices.kp.read_kp`), for the ``t89`` candidate.
    poly_degree : int
        The slow part is the polynomial of this degree fitted to the residual.
    step : int
        Keep every ``step``-th sample (the slow part is smooth; 10 Hz is not needed).
    """
    from magcal.indices.kp import kp_at

    f = cal.field
    zones = []
    for k in sorted(f["zone"].unique()):
        z = f[(f["zone"] == k) & (f["used"] == 1)]
        t = (z.index.asi8 - z.index.asi8[0]) / 1e9
        b = z[["bx_gei", "by_gei", "bz_gei"]].to_numpy(float)
        ref = np.linalg.norm(z[["igrf_x_gei", "igrf_y_gei", "igrf_z_gei"]].to_numpy(float), axis=1)
        s = np.linalg.norm(b, axis=1) - ref
        slow = s - fast_part(t, s, poly_degree)
        sel = (state.index >= z.index[0] - pd.Timedelta("3s")) & (
            state.index <= z.index[-1] + pd.Timedelta("3s"))
        rec = state[sel]
        pos = rec[["pos_gei_x", "pos_gei_y", "pos_gei_z"]].to_numpy(float)
        vel = rec[["vel_gei_x", "vel_gei_y", "vel_gei_z"]].to_numpy(float)
        kp_rec = None if kp is None else kp_at(kp, rec.index)
        eff = reference_perturbations(rec.index, pos, vel, kp_rec)
        ts = (rec.index.asi8 - z.index.asi8[0]) / 1e9
        keep = slice(None, None, step)
        thermal = instrument_candidates(t, z.index.asi8[0], ref, state)
        zones.append({"zone": int(k), "t": t[keep], "slow": slow[keep], "ref": ref[keep],
                      **{n: np.interp(t[keep], ts, v) for n, v in eff.items() if n != "igrf"},
                      **{n: v[keep] for n, v in thermal.items()}})
    return zones


def instrument_candidates(t_s, start_ns: int, ref_nT, state: pd.DataFrame, *,
                          sun_tau_s: float = 300.0, warm_tau_s: float = 60.0) -> dict:
    """Thermal-like gain changes (relative 1e-3, times ``|B|``) for the same screen.

    * ``sun_lowpass``: the state file's Sun flag through a first-order low-pass of
      ``sun_tau_s`` (a temperature following sunlight and eclipse over the whole day);
    * ``warm_up``: ``1 - exp(-t / warm_tau_s)`` from the zone start (the instrument is
      switched on for each science zone).

    Returns
    -------
    dict
        ``{name: ndarray (n,)}``, nT per 1e-3 of gain change.
    """
    from scipy.signal import lfilter

    t = np.asarray(t_s, dtype=float)
    ref = np.asarray(ref_nT, dtype=float)
    sun = state["sun"].to_numpy(float)
    sun = np.where(np.isfinite(sun), sun, 0.0)
    day_s = (state.index.asi8 - state.index.asi8[0]) / 1e9
    a = np.exp(-np.median(np.diff(day_s)) / sun_tau_s)
    low = lfilter([1 - a], [1, -a], sun, zi=[sun[0] * a])[0]
    at = (start_ns - state.index.asi8[0]) / 1e9 + t
    return {"sun_lowpass": np.interp(at, day_s, low) * ref * 1e-3,
            "warm_up": (1.0 - np.exp(-(t - t[0]) / warm_tau_s)) * ref * 1e-3}


def _absorb(z) -> np.ndarray:
    return np.column_stack([np.ones_like(z["t"]), (z["ref"] - z["ref"].mean()) / 1000.0])


def pooled_fit(zones, names) -> tuple[np.ndarray, list]:
    """One coefficient per candidate for all zones, ``1, |B|`` free per zone.

    Returns
    -------
    coefficients : ndarray (len(names),)
    left : list of float
        RMS of each zone's slow part after the fit (nT).
    """
    blocks, ys, n_abs = [], [], 2 * len(zones)
    for i, z in enumerate(zones):
        a = np.zeros((z["t"].size, n_abs))
        a[:, 2 * i:2 * i + 2] = _absorb(z)
        shared = np.column_stack([z[n] for n in names]) if names else np.empty((z["t"].size, 0))
        blocks.append(np.column_stack([a, shared]))
        ys.append(z["slow"])
    x, y = np.vstack(blocks), np.concatenate(ys)
    w = np.linalg.lstsq(x, y, rcond=None)[0]
    resid = y - x @ w
    edges = np.cumsum([0] + [len(v) for v in ys])
    return w[n_abs:], [rms(resid[a:b]) for a, b in zip(edges[:-1], edges[1:])]


def screen_slow_part(zones, names=CANDIDATES) -> pd.DataFrame:
    """Each candidate reference error fitted to the slow parts, for the day and per zone.

    Parameters
    ----------
    zones : list of dict
        From :func:`zone_slow_parts`.
    names : sequence of str
        Candidates (columns of the zone dictionaries).

    Returns
    -------
    DataFrame
        One row per candidate (first row ``none``: only ``1, |B|`` per zone):
        ``day_coefficient`` (one for all zones), ``slow_left_median_nT`` (median over
        zones after it), ``zone_coefficients`` (fitted zone by zone: a real error has
        the same value in every zone), ``zone_sign_changes`` (zones whose coefficient
        has the other sign than the day's), ``range_nT`` (median over zones of the
        candidate's peak-to-peak change at unit size).
    """
    _, left = pooled_fit(zones, [])
    rows = [{"candidate": "none", "day_coefficient": float("nan"),
             "slow_left_median_nT": float(np.median(left)), "zone_coefficients": [],
             "zone_sign_changes": 0, "range_nT": 0.0}]
    for n in names:
        if not all(n in z for z in zones):
            continue
        coef, left = pooled_fit(zones, [n])
        per = []
        for z in zones:
            x = np.column_stack([_absorb(z), z[n]])
            per.append(float(np.linalg.lstsq(x, z["slow"], rcond=None)[0][-1]))
        rows.append({"candidate": n, "day_coefficient": float(coef[0]),
                     "slow_left_median_nT": float(np.median(left)),
                     "zone_coefficients": per,
                     "zone_sign_changes": int(np.sum(np.sign(per) != np.sign(coef[0]))),
                     "range_nT": float(np.median([np.ptp(z[n]) for z in zones]))})
    return pd.DataFrame(rows)
