"""PiCoG variance analysis and the first-order correction (Constantinescu et al. 2020, §3).

Everything here works on plain arrays: ``b_i`` and ``b_j`` are ``(n, 3)`` field samples
of two sensors in one common frame (nT). The difference ``d = b_i - b_j`` holds only the
spacecraft disturbances (Eq. 9). The first-order correction of sensor ``i`` with
sensor ``j`` (Eqs. 13-17) is

    B1_i = B0_i + A d,    A = -alpha e_i e_ij^T,

where ``e_i`` is the maximum-variance direction of ``b_i`` (x axis of its variance
principal system, VPS), ``e_ij`` the maximum-variance direction of ``d`` and ``alpha``
the scaling factor.

The paper's ``e_i`` includes the ambient field, so a varying ambient field (daily
variation, substorms) steers it away from the disturbance (§5). With
``direction="coherent"`` ``e_i`` is instead the direction of ``k = C_id e_ij /
lambda_ij``, the part of ``b_i`` that varies with the difference principal component:
the ambient field cancels in the cross-covariance, and ``A = -k e_ij^T`` keeps the
rank-one form of Eq. 17 with ``alpha = |k|``. ``alpha`` starts from the amplitude ratio of
Eq. 14 with the sign that removes the disturbance (the sign of the covariance of the two principal
components) and is refined by making the corrected component uncorrelated with the
difference component, which has the closed form ``alpha = cov(x, d_x) / var(d_x)``.

The moment-based function :func:`first_order_from_moments` is batched over leading
axes, so the sliding-window scan (:mod:`magcal.ac.scan`) and the single-interval fit
share one implementation.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from magcal.errors import InputError

#: Relative size below which the difference variance counts as zero (no disturbance).
DEGENERATE_RTOL = 1e-12
#: Ways of finding the disturbance direction at the sensor being cleaned.
DIRECTION_METHODS = ("variance", "coherent")


def canonical_sign(v: np.ndarray, reference: np.ndarray | None = None) -> np.ndarray:
    """Fix the arbitrary sense of axial unit vectors.

    Parameters
    ----------
    v : ndarray, shape (..., 3)
        Unit vectors (directions defined up to sign).
    reference : ndarray, shape (3,), optional
        With a reference, each vector is flipped to have a non-negative projection on
        it; without, the component of largest magnitude is made positive.

    Returns
    -------
    ndarray, shape (..., 3)

    Examples
    --------
    >>> canonical_sign(np.array([0.0, -1.0, 0.2])).tolist()
    [-0.0, 1.0, -0.2]
    """
    v = np.asarray(v, dtype=float)
    if reference is not None:
        s = np.sign(v @ np.asarray(reference, dtype=float))
    else:
        idx = np.argmax(np.abs(v), axis=-1)
        s = np.sign(np.take_along_axis(v, idx[..., None], axis=-1)[..., 0])
    s = np.where(s == 0, 1.0, s)
    return v * s[..., None]


def direction_angles_deg(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Elevation ``theta`` (from the x-y plane) and azimuth ``phi`` of unit vectors, deg.

    Examples
    --------
    >>> th, ph = direction_angles_deg(np.array([0.0, 1.0, 0.0]))
    >>> float(th), float(ph)
    (0.0, 90.0)
    """
    v = np.asarray(v, dtype=float)
    theta = np.degrees(np.arcsin(np.clip(v[..., 2], -1.0, 1.0)))
    phi = np.degrees(np.arctan2(v[..., 1], v[..., 0]))
    return theta, phi


def unit_from_angles_deg(theta_deg, phi_deg) -> np.ndarray:
    """Unit vector(s) from elevation and azimuth in degrees (inverse of
    :func:`direction_angles_deg`).

    Examples
    --------
    >>> np.round(unit_from_angles_deg(0.0, 90.0), 12).tolist()
    [0.0, 1.0, 0.0]
    """
    th = np.radians(np.asarray(theta_deg, dtype=float))
    ph = np.radians(np.asarray(phi_deg, dtype=float))
    return np.stack([np.cos(th) * np.cos(ph), np.cos(th) * np.sin(ph), np.sin(th)], axis=-1)


def variance_system(b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Variance principal system (VPS) of a vector series.

    Parameters
    ----------
    b : ndarray, shape (n, 3)
        Vector samples; rows with NaN are ignored.

    Returns
    -------
    eigenvalues : ndarray, shape (3,)
        Variances along the VPS axes, largest first (nT^2).
    rotation : ndarray, shape (3, 3)
        Rows are the VPS axes (x: maximum, z: minimum variance) in the input frame;
        ``rotation @ v`` transforms a vector into the VPS. Right-handed.

    Examples
    --------
    >>> t = np.arange(100.0)
    >>> b = np.c_[0.1 * np.cos(t), 5 * np.sin(t), np.zeros(100)]
    >>> lam, r = variance_system(b)
    >>> np.abs(np.round(r[0], 3)).tolist()
    [0.0, 1.0, 0.0]
    """
    b = np.asarray(b, dtype=float)
    ok = np.all(np.isfinite(b), axis=1)
    if ok.sum() < 3:
        raise InputError(f"variance analysis needs at least 3 valid samples, got {ok.sum()}")
    c = np.cov(b[ok].T)
    w, v = np.linalg.eigh(c)
    r = v[:, ::-1].T.copy()
    r[0] = canonical_sign(r[0])
    r[1] = canonical_sign(r[1])
    r[2] = np.cross(r[0], r[1])
    return w[::-1], r


def sym3_max_eig(c: np.ndarray, rtol_gap: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues (largest first) and the largest eigenvector of symmetric 3x3 matrices.

    Closed form (trigonometric solution of the characteristic cubic, eigenvector from the
    largest cross product of the rows of ``C - lambda_1 I``), vectorised over leading
    axes; entries with nearly equal leading eigenvalues fall back to ``numpy.linalg.eigh``.

    Parameters
    ----------
    c : ndarray, shape (..., 3, 3)
    rtol_gap : float
        Relative gap ``(l1 - l2) / l1`` below which eigh is used instead.

    Returns
    -------
    eigenvalues : ndarray (..., 3), descending
    vector : ndarray (..., 3), unit eigenvector of the largest eigenvalue (sign arbitrary)

    Examples
    --------
    >>> lam, v = sym3_max_eig(np.diag([1.0, 3.0, 2.0]))
    >>> np.round(lam, 12).tolist(), np.abs(v).tolist()
    ([3.0, 2.0, 1.0], [0.0, 1.0, 0.0])
    """
    c = np.asarray(c, dtype=float)
    shape = c.shape[:-2]
    a = c.reshape(-1, 3, 3)
    a00, a11, a22 = a[:, 0, 0], a[:, 1, 1], a[:, 2, 2]
    a01, a02, a12 = a[:, 0, 1], a[:, 0, 2], a[:, 1, 2]
    q = (a00 + a11 + a22) / 3.0
    b00, b11, b22 = a00 - q, a11 - q, a22 - q
    p2 = (b00 ** 2 + b11 ** 2 + b22 ** 2 + 2.0 * (a01 ** 2 + a02 ** 2 + a12 ** 2)) / 6.0
    p = np.sqrt(p2)
    ps = np.where(p > 0, p, 1.0)
    det = (b00 * (b11 * b22 - a12 * a12) - a01 * (a01 * b22 - a12 * a02)
           + a02 * (a01 * a12 - b11 * a02)) / ps ** 3
    phi = np.arccos(np.clip(det / 2.0, -1.0, 1.0)) / 3.0
    l1 = q + 2.0 * p * np.cos(phi)
    l3 = q + 2.0 * p * np.cos(phi + 2.0 * np.pi / 3.0)
    l2 = 3.0 * q - l1 - l3
    lam = np.stack([l1, l2, l3], axis=-1)
    m = a - l1[:, None, None] * np.eye(3)
    r0, r1, r2 = m[:, 0], m[:, 1], m[:, 2]
    cands = np.stack([np.cross(r0, r1), np.cross(r0, r2), np.cross(r1, r2)], axis=1)
    norms = np.einsum("nkj,nkj->nk", cands, cands)
    best = np.argmax(norms, axis=1)
    vec = cands[np.arange(a.shape[0]), best]
    nrm = np.sqrt(norms[np.arange(a.shape[0]), best])
    scale = np.maximum(np.abs(l1), np.abs(l3))
    bad = ~(l1 - l2 > rtol_gap * np.where(scale > 0, scale, 1.0)) | ~(nrm > 0)
    vec = vec / np.where(nrm > 0, nrm, 1.0)[:, None]
    if bad.any():
        w, v = np.linalg.eigh(a[bad])
        lam[bad] = w[:, ::-1]
        vec[bad] = v[:, :, 2]
    return lam.reshape(shape + (3,)), vec.reshape(shape + (3,))


def correction_matrix(alpha: float, direction_i, direction_ij) -> np.ndarray:
    """Correction matrix of Eq. 17: ``A = -alpha e_i e_ij^T``.

    Examples
    --------
    >>> correction_matrix(2.0, [1, 0, 0], [0, 1, 0]).tolist()
    [[-0.0, -2.0, -0.0], [-0.0, -0.0, -0.0], [-0.0, -0.0, -0.0]]
    """
    return -float(alpha) * np.outer(np.asarray(direction_i, float), np.asarray(direction_ij, float))


@dataclass(frozen=True)
class MomentFit:
    """Batched first-order estimates from covariance matrices (arrays over windows)."""

    alpha: np.ndarray            #: refined alpha (decorrelation), shape (...)
    alpha_variance: np.ndarray   #: Eq. 14 amplitude ratio with sign, shape (...)
    direction_i: np.ndarray      #: disturbance direction at sensor i, shape (..., 3)
    direction_ij: np.ndarray     #: max-variance direction of the difference, (..., 3)
    eigenvalues_i: np.ndarray    #: variances of sensor i along its VPS, (..., 3)
    eigenvalues_ij: np.ndarray   #: variances of the difference along its VPS, (..., 3)
    correlation: np.ndarray      #: correlation of the two principal components, (...)
    degenerate: np.ndarray       #: True where the difference has no variance, (...)


def first_order_from_moments(c_ii: np.ndarray, c_dd: np.ndarray, c_id: np.ndarray, *,
                             reference_i=None, reference_ij=None,
                             direction: str = "variance") -> MomentFit:
    """First-order PiCoG estimates from second moments (batched).

    Parameters
    ----------
    c_ii : ndarray, shape (..., 3, 3)
        Covariance of sensor ``i``.
    c_dd : ndarray, shape (..., 3, 3)
        Covariance of the difference ``d = b_i - b_j``.
    c_id : ndarray, shape (..., 3, 3)
        Cross-covariance ``E[(b_i - mean)(d - mean)^T]``.
    reference_i, reference_ij : ndarray (3,), optional
        Hemisphere references fixing the sense of the directions (see
        :func:`canonical_sign`); by default the largest component is positive.
    direction : {"variance", "coherent"}
        How the direction ``e_i`` at sensor ``i`` is found. ``"variance"`` (the paper):
        maximum-variance direction of sensor ``i``, which includes the ambient field.
        ``"coherent"``: direction of the part of sensor ``i`` that varies with the
        difference principal component, ``k = C_id e_ij / lambda_ij``; the ambient
        field cancels in ``C_id`` (it is uncorrelated with the disturbance), so a
        varying ambient field no longer steers ``e_i``. Then ``alpha = e_i . k``, so
        ``A d = -k d_x`` (the decorrelation alpha of the paper, along ``k``).

    Returns
    -------
    MomentFit

    Examples
    --------
    >>> c_ii = np.diag([4.0, 0.1, 0.1]); c_dd = np.diag([1.0, 0.0, 0.0])
    >>> c_id = np.diag([2.0, 0.0, 0.0])
    >>> fit = first_order_from_moments(c_ii, c_dd, c_id)
    >>> float(fit.alpha), float(fit.alpha_variance)
    (2.0, 2.0)
    """
    c_ii = np.asarray(c_ii, dtype=float)
    c_dd = np.asarray(c_dd, dtype=float)
    c_id = np.asarray(c_id, dtype=float)
    if direction not in DIRECTION_METHODS:
        raise InputError(f"direction must be one of {DIRECTION_METHODS}, got {direction!r}")
    lam_i, vi = sym3_max_eig(c_ii)
    lam_d, vd = sym3_max_eig(c_dd)
    e_ij = canonical_sign(vd, reference_ij)
    if direction == "coherent":
        k = np.einsum("...kl,...l->...k", c_id, e_ij)
        nk = np.linalg.norm(k, axis=-1, keepdims=True)
        e_i = canonical_sign(k / np.where(nk > 0, nk, 1.0), reference_i)
        var_x = np.einsum("...k,...kl,...l->...", e_i, c_ii, e_i)
    else:
        e_i = canonical_sign(vi, reference_i)
        var_x = lam_i[..., 0]
    cov_xd = np.einsum("...k,...kl,...l->...", e_i, c_id, e_ij)
    scale = np.abs(np.trace(c_ii, axis1=-2, axis2=-1)) + np.abs(np.trace(c_dd, axis1=-2, axis2=-1))
    degenerate = ~(lam_d[..., 0] > DEGENERATE_RTOL * scale)
    with np.errstate(divide="ignore", invalid="ignore"):
        safe_d = np.where(degenerate, np.nan, lam_d[..., 0])
        alpha = cov_xd / safe_d
        alpha_var = np.sign(cov_xd) * np.sqrt(np.clip(var_x, 0, None) / safe_d)
        corr = cov_xd / np.sqrt(np.clip(var_x, 0, None) * safe_d)
    return MomentFit(alpha=alpha, alpha_variance=alpha_var, direction_i=e_i, direction_ij=e_ij,
                     eigenvalues_i=lam_i, eigenvalues_ij=lam_d, correlation=corr,
                     degenerate=degenerate)


def pair_moments(b_i: np.ndarray, b_j: np.ndarray, mask: np.ndarray | None = None):
    """Covariances ``(c_ii, c_dd, c_id, n_used)`` of a sensor pair over valid rows."""
    b_i = np.asarray(b_i, dtype=float)
    b_j = np.asarray(b_j, dtype=float)
    if b_i.shape != b_j.shape or b_i.ndim != 2 or b_i.shape[1] != 3:
        raise InputError(f"sensor arrays must both be (n, 3); got {b_i.shape} and {b_j.shape}")
    ok = np.all(np.isfinite(b_i), axis=1) & np.all(np.isfinite(b_j), axis=1)
    if mask is not None:
        ok &= np.asarray(mask, dtype=bool)
    n = int(ok.sum())
    if n < 3:
        raise InputError(f"too few valid samples to fit ({n}; need at least 3 where both "
                         "sensors are valid)")
    x = b_i[ok] - b_i[ok].mean(axis=0)
    d = b_i[ok] - b_j[ok]
    d = d - d.mean(axis=0)
    return x.T @ x / n, d.T @ d / n, x.T @ d / n, n


@dataclass(frozen=True)
class FirstOrderFit:
    """One first-order PiCoG correction of sensor ``i`` with sensor ``j``.

    Attributes
    ----------
    alpha : float
        Scaling factor used (refined by decorrelation unless ``alpha_method="variance"``).
    alpha_variance : float
        Eq. 14 estimate ``sign * sqrt(Var(B_i,x) / Var(dB_x))``.
    direction_i, direction_ij : ndarray (3,)
        Maximum-variance directions of sensor ``i`` and of the difference.
    eigenvalues_i, eigenvalues_ij : ndarray (3,)
        VPS variances (nT^2), largest first.
    correlation : float
        Correlation of the two principal components (near +-1: the disturbance dominates).
    n_used : int
        Samples used.
    """

    alpha: float
    alpha_variance: float
    direction_i: np.ndarray
    direction_ij: np.ndarray
    eigenvalues_i: np.ndarray
    eigenvalues_ij: np.ndarray
    correlation: float
    n_used: int
    extra: dict = field(default_factory=dict)

    @property
    def A(self) -> np.ndarray:  # noqa: N802 - the paper's symbol
        """Correction matrix (Eq. 17)."""
        return correction_matrix(self.alpha, self.direction_i, self.direction_ij)

    @property
    def direction_quality(self) -> float:
        """Ratio of the largest to the intermediate variance of the difference."""
        lam = self.eigenvalues_ij
        return float(lam[0] / lam[1]) if lam[1] > 0 else float("inf")


def fit_first_order(b_i, b_j, *, mask=None, alpha_method: str = "decorrelate",
                    direction: str = "variance") -> FirstOrderFit:
    """Fit the first-order PiCoG correction of ``b_i`` using ``b_j`` (Eqs. 13-17).

    Parameters
    ----------
    b_i, b_j : ndarray, shape (n, 3)
        The sensor to clean and the cleaning sensor, same frame and times (nT). Rows
        where either has NaN are skipped.
    mask : ndarray of bool, shape (n,), optional
        Restrict the fit to these rows (e.g. an interval).
    alpha_method : {"decorrelate", "variance"}
        ``"decorrelate"`` (default) refines Eq. 14 so that the corrected principal
        component is uncorrelated with the difference; ``"variance"`` keeps Eq. 14.
    direction : {"variance", "coherent"}
        ``e_i`` from the variance of sensor ``i`` (the paper) or from its part coherent
        with the difference (ambient-free; see :func:`first_order_from_moments`).

    Returns
    -------
    FirstOrderFit

    Raises
    ------
    InputError
        Too few valid samples, or no variance in the difference (identical sensors or
        no disturbance: alpha is undefined).

    Examples
    --------
    One linearly polarised disturber seen 3x stronger by sensor i than by sensor j:

    >>> rng = np.random.default_rng(0)
    >>> s = rng.normal(size=2000)
    >>> u = np.array([0.0, 0.6, 0.8])
    >>> ambient = np.array([100.0, -20.0, 50.0])
    >>> b_i = ambient + 3 * s[:, None] * u
    >>> b_j = ambient + 1 * s[:, None] * u
    >>> fit = fit_first_order(b_i, b_j)
    >>> round(fit.alpha, 12)  # a / (a - 1) for a = 3 (Eq. 19)
    1.5
    >>> cleaned = b_i + (b_i - b_j) @ fit.A.T
    >>> bool(np.allclose(cleaned, ambient))
    True
    """
    if alpha_method not in ("decorrelate", "variance"):
        raise InputError(f"alpha_method must be 'decorrelate' or 'variance', got {alpha_method!r}")
    c_ii, c_dd, c_id, n = pair_moments(b_i, b_j, mask)
    m = first_order_from_moments(c_ii, c_dd, c_id, direction=direction)
    if bool(m.degenerate):
        raise InputError("the difference between the two sensors has no variance (no "
                         "disturbance to remove): alpha is undefined")
    alpha = float(m.alpha if alpha_method == "decorrelate" else m.alpha_variance)
    return FirstOrderFit(alpha=alpha, alpha_variance=float(m.alpha_variance),
                         direction_i=m.direction_i, direction_ij=m.direction_ij,
                         eigenvalues_i=m.eigenvalues_i, eigenvalues_ij=m.eigenvalues_ij,
                         correlation=float(m.correlation), n_used=n)


def apply_first_order(b_i, b_j, A) -> np.ndarray:
    """Corrected field ``b_i + A (b_i - b_j)`` (Eq. 16); NaN where either input is NaN.

    Examples
    --------
    >>> apply_first_order(np.ones((1, 3)), np.zeros((1, 3)), -np.eye(3)).tolist()
    [[0.0, 0.0, 0.0]]
    """
    b_i = np.asarray(b_i, dtype=float)
    return b_i + (b_i - np.asarray(b_j, dtype=float)) @ np.asarray(A, dtype=float).T
