"""Sensor-to-common-frame rotations estimated from the data against a reference field.

When an instrument delivers each sensor in its own frame and the per-sensor
common-frame products are missing (GOES-R L2 files: ``b_ib_brf`` is fill), the rotation
of each sensor into the common frame is estimated against a reference field already in
that frame (the file's combined ``b_brf``). Two models are fitted, by least squares:

* rotation only, ``ref ~= R @ b`` (Wahba's problem, :meth:`Rotation.align_vectors`);
* rotation and sensor offset, ``ref ~= R @ (b - o)``: needed when the sensor and the
  reference differ by a constant (uncalibrated offsets, a gradiometer combination).

With a nearly constant field (minutes of data at geostationary orbit) the rotation
about the field direction and the offset are poorly determined: the result carries
the angle uncertainties from the Jacobian, the condition number, and the residual RMS
of both models so the user sees what the data can give.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from magcal.errors import InputError
from magcal.stats import finite_rms

#: An offset model is chosen when it lowers the residual RMS by at least this factor.
OFFSET_GAIN = 2.0
#: Below this residual (nT) a rotation alone is exact: no offset is fitted.
EXACT_NT = 1e-6


@dataclass(frozen=True)
class RotationFit:
    """A fitted sensor-to-common-frame rotation (and optional sensor offset).

    Attributes
    ----------
    matrix : ndarray, shape (3, 3)
        ``R``: common = R @ (sensor - offset).
    offset_nT : ndarray, shape (3,)
        Sensor offset in the sensor frame (zeros when not fitted).
    fit_offset : bool
        Whether the offset was fitted.
    rms_nT : float
        RMS of reference minus the rotated sensor (all components) for the chosen model.
    rms_rotation_only_nT, rms_with_offset_nT : float
        The same for both models.
    angle_std_deg : ndarray, shape (3,)
        1-sigma uncertainty of the rotation vector components (about the common
        frame's axes), from the Jacobian and the residual scatter.
    condition : float
        Condition number of the Jacobian (large: a nearly constant field leaves some
        parameters poorly determined).
    n_used : int
        Samples with finite sensor and reference values.
    field_variation_nT : float
        RMS variation of the reference about its mean (how much the field direction
        changes in the record).
    """

    matrix: np.ndarray
    offset_nT: np.ndarray
    fit_offset: bool
    rms_nT: float
    rms_rotation_only_nT: float
    rms_with_offset_nT: float
    angle_std_deg: np.ndarray
    condition: float
    n_used: int
    field_variation_nT: float

    def apply(self, b_sensor) -> np.ndarray:
        """Sensor readings (n, 3) in the common frame."""
        return (np.asarray(b_sensor, dtype=float) - self.offset_nT) @ self.matrix.T

    def to_json(self) -> dict:
        return {"matrix": self.matrix.tolist(), "offset_nT": self.offset_nT.tolist(),
                "fit_offset": self.fit_offset, "rms_nT": self.rms_nT,
                "rms_rotation_only_nT": self.rms_rotation_only_nT,
                "rms_with_offset_nT": self.rms_with_offset_nT,
                "angle_std_deg": self.angle_std_deg.tolist(), "condition": self.condition,
                "n_used": self.n_used, "field_variation_nT": self.field_variation_nT,
                "euler_zyx_deg": Rotation.from_matrix(self.matrix).as_euler(
                    "ZYX", degrees=True).tolist()}


def estimate_rotation(b_sensor, b_reference, fit_offset="auto") -> RotationFit:
    """Fit the rotation of a sensor into the frame of a reference field.

    Parameters
    ----------
    b_sensor, b_reference : array_like, shape (n, 3)
        Simultaneous sensor readings (sensor frame) and reference field (common frame),
        nT; rows with a NaN in either are left out.
    fit_offset : bool or "auto"
        Fit a sensor offset too; ``"auto"`` keeps it when it lowers the residual RMS by
        at least :data:`OFFSET_GAIN` (the data then show a constant difference) and the
        rotation alone is not exact (:data:`EXACT_NT`).

    Returns
    -------
    RotationFit

    Raises
    ------
    InputError
        Fewer than 10 usable samples, or shapes that do not match.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> ref = rng.normal(size=(200, 3)) * 30 + [0, 0, 100]
    >>> R = Rotation.from_euler("z", 90, degrees=True).as_matrix()
    >>> sensor = ref @ R  # sensor = R.T @ ref
    >>> fit = estimate_rotation(sensor, ref, fit_offset=False)
    >>> np.allclose(fit.matrix, R), fit.rms_nT < 1e-9
    (True, True)
    """
    b = np.asarray(b_sensor, dtype=float)
    r = np.asarray(b_reference, dtype=float)
    if b.shape != r.shape or b.ndim != 2 or b.shape[1] != 3:
        raise InputError(f"sensor {b.shape} and reference {r.shape} must both be (n, 3)")
    ok = np.isfinite(b).all(axis=1) & np.isfinite(r).all(axis=1)
    b, r = b[ok], r[ok]
    if len(b) < 10:
        raise InputError(f"only {len(b)} samples with both sensor and reference finite "
                         "(need 10) to estimate a rotation")
    rot0, _ = Rotation.align_vectors(r, b)
    m0 = rot0.as_matrix()
    rms0 = finite_rms(r - b @ m0.T)
    m1, o1 = _gauss_newton(b, r, m0)
    rms1 = finite_rms((b - o1) @ m1.T - r)
    use_offset = (bool(fit_offset) if fit_offset != "auto"
                  else rms1 * OFFSET_GAIN < rms0 and rms0 > EXACT_NT)
    matrix, offset = (m1, o1) if use_offset else (m0, np.zeros(3))
    resid = (b - offset) @ matrix.T - r
    jtj = _normal_matrix(b - offset, matrix, use_offset)
    n_dof = max(r.size - jtj.shape[0], 1)
    cov = np.linalg.pinv(jtj) * float(np.sum(resid ** 2)) / n_dof
    return RotationFit(
        matrix=matrix, offset_nT=offset, fit_offset=use_offset,
        rms_nT=finite_rms(resid), rms_rotation_only_nT=rms0, rms_with_offset_nT=rms1,
        angle_std_deg=np.degrees(np.sqrt(np.diag(cov)[:3])),
        condition=float(np.sqrt(np.linalg.cond(jtj))), n_used=int(len(b)),
        field_variation_nT=finite_rms(r - r.mean(axis=0)))


def _skew_blocks(v: np.ndarray) -> np.ndarray:
    """(n, 3, 3) cross-product matrices [v]x."""
    z = np.zeros(len(v))
    return np.stack([np.stack([z, -v[:, 2], v[:, 1]], -1),
                     np.stack([v[:, 2], z, -v[:, 0]], -1),
                     np.stack([-v[:, 1], v[:, 0], z], -1)], 1)


def _jacobian(b_minus_o: np.ndarray, matrix: np.ndarray, with_offset: bool) -> np.ndarray:
    """(n, 3, k) derivative of R (b - o) - r by a small rotation (and the offset)."""
    v = b_minus_o @ matrix.T
    j_rot = -_skew_blocks(v)
    if not with_offset:
        return j_rot
    return np.concatenate([j_rot, -np.broadcast_to(matrix, (len(v), 3, 3))], axis=2)


def _normal_matrix(b_minus_o, matrix, with_offset) -> np.ndarray:
    j = _jacobian(b_minus_o, matrix, with_offset)
    return np.einsum("nik,nil->kl", j, j)


def _gauss_newton(b, r, matrix, n_iter: int = 300):
    """Rotation and offset by Levenberg-Marquardt on small rotations (6 parameters)."""
    offset = np.zeros(3)
    cost = np.sum(((b - offset) @ matrix.T - r) ** 2)
    lam = 1e-6
    for _ in range(n_iter):
        e = (b - offset) @ matrix.T - r
        j = _jacobian(b - offset, matrix, True)
        jtj = np.einsum("nik,nil->kl", j, j)
        g = np.einsum("nik,ni->k", j, e)
        step = -np.linalg.solve(jtj + lam * np.diag(np.diag(jtj)), g)
        m_new = Rotation.from_rotvec(step[:3]).as_matrix() @ matrix
        o_new = offset + step[3:]
        c_new = np.sum(((b - o_new) @ m_new.T - r) ** 2)
        if c_new < cost:
            converged = cost - c_new < 1e-12 * max(cost, 1e-300)
            matrix, offset, cost, lam = m_new, o_new, c_new, lam / 10
            if converged:
                break
        else:
            lam *= 10
            if lam > 1e8:
                break
    return matrix, offset
