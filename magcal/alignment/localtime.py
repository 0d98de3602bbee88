"""Local-time nuisance field for alignment against a model that lacks it.

At geostationary orbit the model field's own variation is mostly diurnal, and so is the
field the models miss (SOSMAG paper §5.3, Fig. 19: data minus T04 varies with local
time by 8-10 nT peak-to-peak in Hp, about 5 nT in He, 1-2 nT in Hn, the same on GOES-14,
so it is the model's). A rotation ``w x B_model`` is then nearly a daily signal too, and
a fit that lacks a local-time term turns the missing field into a rotation of several
degrees with an error bar of hundredths (measured on the simulated month: Hn -5.6 +-
0.07 deg for a true 0). Fitting ``K`` harmonics of local time per component as nuisance
parameters removes that path: what remains to determine the angles is the part of the
model variation that is *not* fixed in local time (its day-to-day change with activity),
and the interval widens to what the data can really say.

For a spacecraft at fixed longitude local time is universal time plus ``lon / 15`` h, so
harmonics of UT days span the same functions; the longitude only sets the phase in
which the fitted field is reported.
"""

from __future__ import annotations

import numpy as np

from magcal.frames.localtime import DAY_S, harmonic_basis, local_time_hours

__all__ = [
    "DAY_S",
    "describe_harmonics",
    "harmonic_basis",
    "harmonic_names",
    "harmonic_profile",
    "local_time_hours",
    "peak_to_peak",
]


def harmonic_names(n_harmonics: int, components=("Hp", "He", "Hn")) -> tuple:
    """Parameter names ``lt_<comp>_cos<k>``, ``lt_<comp>_sin<k>`` in fit order."""
    return tuple(f"lt_{c}_{f}{k}" for c in components for k in range(1, n_harmonics + 1)
                 for f in ("cos", "sin"))


def harmonic_profile(coef, lt_grid_h=None) -> tuple[np.ndarray, np.ndarray]:
    """Evaluate fitted harmonics on a local-time grid.

    Parameters
    ----------
    coef : array_like, shape (3, 2K)
        Per component ``[cos1, sin1, cos2, sin2, ...]`` (nT).
    lt_grid_h : array_like, optional
        Default 0, 0.25, ..., 23.75 h.

    Returns
    -------
    lt_grid_h : ndarray, shape (m,)
    profile_nT : ndarray, shape (m, 3)
    """
    c = np.atleast_2d(np.asarray(coef, dtype=float))
    grid = np.arange(0.0, 24.0, 0.25) if lt_grid_h is None else np.asarray(lt_grid_h, float)
    basis = harmonic_basis(grid, c.shape[1] // 2)
    return grid, basis @ c.T


def peak_to_peak(coef) -> np.ndarray:
    """Peak-to-peak (nT) of each component's fitted local-time field, shape (3,).

    Examples
    --------
    >>> peak_to_peak([[4.0, 0.0], [0.0, 2.5], [0.0, 0.0]]).round(6)
    array([8., 5., 0.])
    """
    _, prof = harmonic_profile(coef, np.linspace(0.0, 24.0, 2881))
    return prof.max(axis=0) - prof.min(axis=0)


def describe_harmonics(coef, cov, lon_deg=None) -> dict:
    """JSON-ready summary of a fitted local-time field.

    Parameters
    ----------
    coef : array_like, shape (3, 2K)
        Coefficients (nT) per component, ``[cos1, sin1, ...]``.
    cov : array_like, shape (6K, 6K)
        Their covariance (component-major, as :func:`harmonic_names`).
    lon_deg : float or array_like, optional
        East longitude, one value or one per sample (as a ``lon_deg`` column gives it):
        the median is reported, and the range when it varies.

    Returns
    -------
    dict
        ``n_harmonics``, ``time_base``, ``coefficients_nT``, ``coefficients_std_nT``,
        ``peak_to_peak_nT``, and per component the Wald ``chi2`` of "no local-time
        field", its ``dof`` and ``p_value`` (under the fitted noise model).

    Examples
    --------
    >>> d = describe_harmonics([[4.0, 0.0], [0.0, 0.0], [0.0, 0.0]], np.eye(6) * 0.01)
    >>> d["peak_to_peak_nT"]["Hp"], d["chi2"]["Hp"]
    (8.0, 1600.0)
    """
    from scipy.stats import chi2 as chi2_dist

    c = np.atleast_2d(np.asarray(coef, dtype=float))
    cov = np.asarray(cov, dtype=float)
    k2 = c.shape[1]
    comps = ("Hp", "He", "Hn")
    chi2, pval, std = {}, {}, {}
    for i, name in enumerate(comps):
        sl = slice(i * k2, (i + 1) * k2)
        block = cov[sl, sl]
        chi2[name] = float(c[i] @ np.linalg.solve(block, c[i]))
        pval[name] = float(chi2_dist.sf(chi2[name], k2))
        std[name] = [float(v) for v in np.sqrt(np.diag(block))]
    pp = peak_to_peak(c)
    lon = lon_range = None
    if lon_deg is not None:
        values = np.atleast_1d(np.asarray(lon_deg, dtype=float))
        lon = float(np.median(values))
        if np.ptp(values) > 0:
            lon_range = [float(values.min()), float(values.max())]
    return {
        "n_harmonics": k2 // 2,
        "time_base": ("local time (UT + lon / 15 h, lon {:g} deg{})".format(
            lon, "" if lon_range is None else " median, per sample") if lon is not None
                      else "UT (no longitude given; for a fixed longitude only the phase "
                           "differs from local time)"),
        "lon_deg": lon,
        "lon_deg_range": lon_range,
        "coefficients_nT": {n: [float(v) for v in c[i]] for i, n in enumerate(comps)},
        "coefficients_std_nT": std,
        "order": "cos1, sin1, cos2, sin2, ... of 2 pi LT / 24",
        "peak_to_peak_nT": {n: float(v) for n, v in zip(comps, pp)},
        "chi2": chi2, "dof": k2, "p_value": pval,
    }
