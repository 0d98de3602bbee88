"""Do local-time harmonics move the angles? A Hausman test that needs no noise model.

Dropping the local-time nuisance harmonics narrows the angles' intervals, but if the
data hold a daily field the reference lacks, the fit without them is biased: the
angles move between the two fits. The change is judged against its own standard
deviation. Under the fitted noise model the nested fits' variances give it
(``var_with - var_without``), but when the model misses low-frequency noise (1/f, two
time scales) that variance is too small and harmonics were kept in 12-17 of 50
noise-only records under the default OU model. Here the variance of the change comes
from the residual's own spectrum (:func:`magcal.alignment.sandwich.difference_variance`),
as the stated covariance does.
"""

from __future__ import annotations

import numpy as np

from magcal.alignment.result import AlignmentResult

ANGLES = ("w_Hp", "w_He", "w_Hn")


def theta_of(result: AlignmentResult) -> np.ndarray:
    """Parameter vector of a fit without local-time terms (``param_names`` order)."""
    values = {}
    for k, c in enumerate(("Hp", "He", "Hn")):
        values[f"w_{c}"] = np.deg2rad(result.angles_deg[k])
        if result.offset_nT is not None:
            values[f"o_{c}"] = result.offset_nT[k]
    if result.scale is not None:
        values["scale"] = result.scale
    return np.array([values[n] for n in result.param_names], dtype=float)


def lt_shift_sigma(without_lt: AlignmentResult, with_lt: AlignmentResult, times, data, ref,
                   lon_deg=None) -> np.ndarray | None:
    """The angles' change when the harmonics of ``with_lt`` are dropped, in units of
    the change's spectral standard deviation (per angle).

    Parameters
    ----------
    without_lt, with_lt : AlignmentResult
        Closed-form fits of the same data without and with local-time harmonics.
    times, data, ref, lon_deg
        As given to :func:`magcal.alignment.gls.fit_alignment`.

    Returns
    -------
    ndarray, shape (3,) or None
        None when the rotation was not fitted or the spectrum cannot be estimated (the
        caller then uses the model-based nested variances).

    Examples
    --------
    >>> from magcal.alignment.gls import fit_alignment
    >>> from magcal.alignment.synthetic import synthetic_pair
    >>> case = synthetic_pair(np.random.default_rng(0), n=1500, cadence_s=300.0)
    >>> plain = fit_alignment(case.times, case.data, case.ref)
    >>> with_lt = fit_alignment(case.times, case.data, case.ref, lt_harmonics=3)
    >>> bool(np.all(np.abs(lt_shift_sigma(plain, with_lt, case.times, case.data,
    ...                                   case.ref)) < 3))
    True
    """
    from magcal.alignment.gls import (ROBUST_K, lt_basis, n_lt_harmonics,
                                      ou_whitened_series, outlier_rows, param_names,
                                      predict_and_jacobian, prepare)
    from magcal.alignment.sandwich import difference_variance

    names0 = tuple(without_lt.param_names)
    k = n_lt_harmonics(with_lt.param_names)
    if not k or n_lt_harmonics(names0) or not set(ANGLES) <= set(names0):
        return None
    t, d, r, keep = prepare(times, data, ref)
    names = param_names(True, "o_Hp" in names0, "scale" in names0, k)
    basis = lt_basis(times, keep, k, lon_deg)
    theta = np.concatenate([theta_of(without_lt), np.zeros(len(names) - len(names0))])
    mu, jac = predict_and_jacobian(theta, names, r, basis)
    use = ~outlier_rows(d - mu, ROBUST_K)
    noise = without_lt.noise
    if noise.kind != "ou":
        from magcal.alignment.ouwhite import whitened_series

        ys, xs = whitened_series(t[use], (d - mu)[use], jac[use], noise)
    else:
        ys, xs = ou_whitened_series(t[use], (d - mu)[use], jac[use], noise)
    sub = list(range(len(names0)))
    rows = [names.index(a) for a in ANGLES]
    var = difference_variance(ys, xs, sub, rows)
    if var is None or not np.all(np.isfinite(var) & (var > 0)):
        return None
    return (without_lt.angles_deg - with_lt.angles_deg) / np.rad2deg(np.sqrt(var))
