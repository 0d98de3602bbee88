"""Non-orthogonal disturbers: the multi-sensor regression gradiometer.

Plain PiCoG corrects one principal component per order, so two disturbers whose
polarisation directions are not orthogonal and whose scaling factors differ (sources far
apart) leave a remnant (Constantinescu et al. 2020, §5: "left for future examination:
transform to a non-orthogonal system aligned with the disturbers' directions").

This module does that transform implicitly. With disturbers ``q`` of time series
``s_q(t)`` and directions ``u_q^k`` at sensor ``k``, the stacked differences
``D = [B_t - B_r1, B_t - B_r2, ...]`` are ``V s(t)`` (the ambient field cancels), with
the columns of ``V`` the (non-orthogonal) difference directions. When ``V`` has full
column rank (at most 3 disturbers per reference sensor, in general position) the target
disturbance ``U s(t) = U V^+ D`` is an exact linear function of ``D``: projecting ``D``
on the non-orthogonal disturber basis (``V^+``) and scaling each disturber by its own
factor. The matrix ``K = U V^+`` is estimated without knowing ``U`` or ``V`` by making the
corrected target uncorrelated with every channel of ``D`` (least squares), the
multi-channel form of PiCoG's decorrelation refinement. More reference sensors add
channels, so more disturbers can be separated.

The ambient field must be uncorrelated with the disturbances over the fit interval;
``detrend_s`` removes running means first so slow ambient variations do not leak in.
"""

from __future__ import annotations

import numpy as np

from magcal.ac.filters import running_mean
from magcal.errors import InputError


def fit_regression(b_target: np.ndarray, references: list, *, mask=None,
                   detrend_n: int | None = None, rcond: float = 1e-10):
    """Regression-gradiometer correction of ``b_target`` with several reference sensors.

    Parameters
    ----------
    b_target : ndarray (n, 3)
    references : list of ndarray (n, 3)
    mask : ndarray of bool (n,), optional
        Rows to fit on (all sensors must also be finite there).
    detrend_n : int, optional
        Subtract centred running means over this many samples before fitting.
    rcond : float
        Relative cut-off for small singular values of the difference covariance.

    Returns
    -------
    mats : list of ndarray (3, 3)
        ``A_m`` such that the cleaned target is ``b_t + sum_m A_m (b_t - b_rm)``;
        the upload matrices are ``M_t = I + sum A_m``, ``M_rm = -A_m`` (sum: I).
    info : dict
        ``n_used``, ``singular_values`` of the normalised difference covariance.

    Examples
    --------
    Two disturbers 40 deg apart with different scaling factors, two sensors:

    >>> rng = np.random.default_rng(0)
    >>> s1, s2 = rng.normal(size=(2, 3000, 1))
    >>> u1 = np.array([1.0, 0, 0]); u2 = np.array([np.cos(0.7), np.sin(0.7), 0])
    >>> amb = 0.3 * rng.normal(size=(3000, 3))
    >>> bt = amb + 1.0 * s1 * u1 + 1.0 * s2 * u2
    >>> br = amb + 5.0 * s1 * u1 + 2.0 * s2 * u2
    >>> (A,), info = fit_regression(bt, [br])
    >>> clean = bt + (bt - br) @ A.T
    >>> float(np.round(np.sqrt(np.mean((bt - amb) ** 2)), 1))   # disturbance rms before
    0.8
    >>> bool(np.sqrt(np.mean((clean - amb) ** 2)) < 0.01)      # after
    True
    """
    b_t = np.asarray(b_target, dtype=float)
    refs = [np.asarray(r, dtype=float) for r in references]
    if not refs:
        raise InputError("the regression gradiometer needs at least one reference sensor")
    d = np.concatenate([b_t - r for r in refs], axis=1)
    ok = np.all(np.isfinite(b_t), axis=1) & np.all(np.isfinite(d), axis=1)
    if mask is not None:
        ok &= np.asarray(mask, dtype=bool)
    n_used = int(ok.sum())
    if n_used < 3 * d.shape[1]:
        raise InputError(f"too few valid samples ({n_used}) for a regression on "
                         f"{d.shape[1]} difference channels")
    x = b_t[ok]
    dd = d[ok]
    if detrend_n and int(detrend_n) > 1:
        x = x - running_mean(x, int(detrend_n))
        dd = dd - running_mean(dd, int(detrend_n))
    x = x - x.mean(axis=0)
    dd = dd - dd.mean(axis=0)
    scale = dd.std(axis=0)
    if not np.any(scale > 0):
        raise InputError("the differences between the sensors have no variance (no "
                         "disturbance to remove)")
    scale = np.where(scale > 0, scale, 1.0)
    dn = dd / scale
    c_dd = dn.T @ dn / n_used
    c_xd = x.T @ dn / n_used
    u, sv, vt = np.linalg.svd(c_dd)
    keep = sv > rcond * sv[0]
    pinv = (vt[keep].T / sv[keep]) @ u[:, keep].T
    k = -(c_xd @ pinv) / scale[None, :]
    mats = [k[:, 3 * m:3 * m + 3] for m in range(len(refs))]
    return mats, {"n_used": n_used, "singular_values": sv.tolist()}


def fit_regression_stage(b_target, references, t_s, *, interval=None, detrend_s=None):
    """Chain adapter: :func:`fit_regression` with an optional interval in seconds."""
    t_s = np.asarray(t_s, dtype=float)
    mask = None
    if interval is not None:
        mask = (t_s >= interval[0]) & (t_s < interval[1])
    detrend_n = None
    if detrend_s:
        dt = float(np.median(np.diff(t_s)))
        detrend_n = int(round(detrend_s / dt))
    return fit_regression(b_target, references, mask=mask, detrend_n=detrend_n)
