"""Noise families of the alignment coverage experiment (issue 21), with exact bounds.

Each family is a stationary model error added to rotated reference vectors: OU, OU plus
white, two time scales, power law ``1/f^a``, heavy-tailed (Student t, 3 dof) and OU with
10 % of the samples missing in blocks. ``"power-law"`` has ``a = 1.5``; ``"power-law@A"``
takes the exponent ``A`` (the benchmark runs 1 and 2). Gaussian families are drawn from their exact
covariance at the sample times (Cholesky), so the Cramer-Rao bound of the angles is the
exact inverse Fisher matrix ``(sum_c X_c^T C^-1 X_c)^-1`` of the same covariance; for the
heavy-tailed family the bound given is that of Gaussian noise with the same covariance.
"""

from __future__ import annotations

import functools

import numpy as np
from scipy.linalg import cho_factor, cho_solve
from scipy.spatial.transform import Rotation

FAMILIES = ("ou", "ou+white", "two-scales", "power-law", "student-t", "gaps")


def covariance(family: str, times_s, rng: np.random.Generator | None = None) -> np.ndarray:
    """Covariance (nT^2) of one component of ``family`` at ``times_s`` (n, n).

    Examples
    --------
    >>> round(float(covariance("ou", [0.0, 3600.0])[0, 1]), 3)
    1.472
    """
    t = np.asarray(times_s, dtype=float)
    lag = np.abs(t[:, None] - t[None, :])
    if family in ("ou", "gaps", "student-t"):
        return 4.0 * np.exp(-lag / 3600.0)
    if family == "ou+white":
        return 4.0 * np.exp(-lag / 3600.0) + 0.09 * (lag == 0)
    if family == "two-scales":
        return 1.0 * np.exp(-lag / 600.0) + 4.0 * np.exp(-lag / 21600.0) + 0.04 * (lag == 0)
    if family.startswith("power-law"):
        return _power_law_cov(lag, alpha=float(family.split("@")[1]) if "@" in family
                              else 1.5)
    raise ValueError(f"unknown family {family!r}")


def _power_law_cov(lag, alpha: float, f_lo: float = 1.0 / (20 * 86400.0),
                   f_hi: float = 1.0 / 120.0, std_nT: float = 2.0) -> np.ndarray:
    """Covariance of a band-limited ``1/f^alpha`` process (``f_lo..f_hi``) of std ``std_nT``."""
    f = np.geomspace(f_lo, f_hi, 2000)
    psd = f ** -alpha
    w = np.gradient(f) * psd
    w = w * std_nT ** 2 / w.sum()
    uniq, inv = np.unique(lag, return_inverse=True)  # few distinct lags on a grid
    values = np.cos(2 * np.pi * np.outer(uniq, f)) @ w
    return values[inv].reshape(lag.shape) + 0.04 * (lag == 0)


def sample_times(family: str, n: int, cadence_s: float, rng: np.random.Generator):
    """Sample times (s); the ``gaps`` family loses 10 % of them in 10 random blocks."""
    t = np.arange(n) * float(cadence_s)
    if family != "gaps":
        return t
    keep = np.ones(n, dtype=bool)
    block = max(n // 100, 1)
    for s in rng.choice(n - block, 10, replace=False):
        keep[s:s + block] = False
    return t[keep]


def draw(family: str, rng: np.random.Generator, n: int = 1440, cadence_s: float = 600.0,
         rotvec_deg=(1.7, -0.5, -0.5), offset_nT=(3.0, -2.0, 1.0)) -> dict:
    """One seeded draw: times, data, reference, truth and the exact angle bound (deg)."""
    from magcal.alignment.synthetic import geostationary_reference

    t = sample_times(family, n, cadence_s, rng)
    ref = geostationary_reference(t, rng)
    if family == "gaps":
        cov = covariance(family, t)
        chol = np.linalg.cholesky(cov + 1e-9 * np.eye(t.size))
    else:  # same times every draw: the power law's covariance alone costs ~20 s
        cov, chol = _regular_cov(family, int(n), float(cadence_s))
    z = rng.standard_normal((t.size, 3))
    if family == "student-t":  # OU driven by t(3) innovations: heavy tails, same covariance
        z = rng.standard_t(3, (t.size, 3)) / np.sqrt(3.0)
    noise = chol @ z
    rot = Rotation.from_rotvec(np.deg2rad(rotvec_deg))
    data = rot.apply(ref) + np.asarray(offset_nT) + noise
    return {"times_s": t, "data": data, "ref": ref, "truth_deg": np.asarray(rotvec_deg),
            "crb_std_deg": angle_bound(rot.apply(ref), cov)}


@functools.lru_cache(maxsize=4)
def _regular_cov(family: str, n: int, cadence_s: float):
    """Covariance and its Cholesky factor on a regular grid (cached across draws)."""
    cov = covariance(family, np.arange(n) * cadence_s)
    chol = np.linalg.cholesky(cov + 1e-9 * np.eye(n))
    cov.flags.writeable = False
    chol.flags.writeable = False
    return cov, chol


def efficient_error(family: str, dr: dict, cadence_s: float = 600.0) -> np.ndarray:
    """Error (deg) of the efficient estimate of one draw: GLS with the true covariance,
    linearised at the truth (its scatter is the Cramer-Rao bound by construction).

    A benchmark's few draws can be lucky: this error, on the same draws, says how much
    of a coverage above the nominal level is the draws' and not the intervals'.
    """
    t = dr["times_s"]
    if family == "gaps":
        cov = covariance(family, t)
    else:
        cov, _ = _regular_cov(family, int(t.size), float(cadence_s))
    rot = Rotation.from_rotvec(np.deg2rad(dr["truth_deg"]))
    p = rot.apply(dr["ref"])
    jac = _angle_offset_jacobian(p)
    fac = cho_factor(cov + 1e-9 * np.eye(t.size))
    y = dr["data"] - p  # the offset is estimated with the angles, as by the fits
    a = sum(jac[:, c, :].T @ cho_solve(fac, jac[:, c, :]) for c in range(3))
    b = sum(jac[:, c, :].T @ cho_solve(fac, y[:, c]) for c in range(3))
    return np.rad2deg(np.linalg.solve(a, b)[:3])


def _angle_offset_jacobian(p) -> np.ndarray:
    """Jacobian (n, 3, 6) of ``R(w) p + o`` in ``(w, o)`` at small ``w``."""
    n = p.shape[0]
    jac = np.zeros((n, 3, 6))
    skew = np.zeros((n, 3, 3))
    skew[:, 0, 1], skew[:, 0, 2] = -p[:, 2], p[:, 1]
    skew[:, 1, 0], skew[:, 1, 2] = p[:, 2], -p[:, 0]
    skew[:, 2, 0], skew[:, 2, 1] = -p[:, 1], p[:, 0]
    jac[:, :, :3] = -skew
    jac[:, :, 3:] = np.eye(3)
    return jac


def angle_bound(rotated_ref, cov) -> np.ndarray:
    """Cramer-Rao std (deg) of the three angles, with the offset fitted, for noise ``cov``
    on each component (independent components)."""
    n = rotated_ref.shape[0]
    jac = _angle_offset_jacobian(rotated_ref)
    fac = cho_factor(cov + 1e-9 * np.eye(n))
    info = sum(jac[:, c, :].T @ cho_solve(fac, jac[:, c, :]) for c in range(3))
    return np.rad2deg(np.sqrt(np.diag(np.linalg.inv(info))[:3]))
