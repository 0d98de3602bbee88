"""Result object of an alignment fit (closed form or posterior)."""

from __future__ import annotations

import dataclasses

import numpy as np

from magcal.alignment.noise import COMPONENTS, OUNoise
from magcal.io.jsonio import product_dict


def _by_component(values):
    if values is None:
        return None
    return {c: float(v) for c, v in zip(COMPONENTS, values)}


@dataclasses.dataclass(frozen=True)
class AlignmentResult:
    """Rotation (and offset, scale) of data against a reference, with uncertainties.

    Convention: ``data ~= scale * R(w) @ ref + offset`` with ``w`` the rotation vector
    about (Hp, He, Hn) (CONTRACTS §3). Angles are in degrees.

    Attributes
    ----------
    angles_deg : ndarray, shape (3,)
        Rotation vector in degrees (zeros when the rotation was not fitted).
    cov_deg2 : ndarray, shape (3, 3)
        Covariance of the angles (deg^2); NaN when not fitted.
    ci95_deg : ndarray, shape (3, 2)
        95 % interval per angle.
    offset_nT, offset_std_nT : ndarray, shape (3,) or None
    scale, scale_std : float or None
    n_used : int
        Samples used (both series finite).
    method : str
        ``"wahba+ou-gls"`` (closed form with correlated-noise generalised least squares)
        or ``"emcee"`` (posterior sampling).
    noise : OUNoise
        Fitted residual noise model.
    residual_rms_nT : ndarray, shape (3,)
    param_names : tuple of str
    param_cov : ndarray, shape (p, p)
        Covariance of all fitted parameters (angles in rad).
    dof_deg : ndarray, shape (3,) or None
        Degrees of freedom of each angle variance (Satterthwaite, from the uncertainty
        of the fitted noise model); the 95 % interval uses Student t with these.
    converged, autocorr_steps : bool or None, float or None
        Only for ``method="emcee"``: chain longer than 50 integrated autocorrelation
        times, and the largest autocorrelation time in steps.
    mcmc : dict or None
        Sampler details (steps, walkers, burn-in, acceptance, per-parameter tau).
    samples : ndarray or None
        Flattened posterior samples in ``param_names`` order (angles in degrees); not
        written to JSON.
    local_time : dict or None
        Fitted local-time nuisance field (see
        :func:`magcal.alignment.localtime.describe_harmonics`), when harmonics were fitted.
    warnings : tuple of str
        Reasons not to take the numbers at face value (see
        :mod:`magcal.alignment.checks`); empty when none.
    checks : dict or None
        JSON-ready diagnostics behind the warnings (local-time check, window
        consistency, inflation applied).
    provenance : dict or None
    determinability : Determinability or None
        Whether the data determine the rotation
        (:mod:`magcal.alignment.determinability`); when not, the angles, their
        covariance and interval are NaN.
    """

    angles_deg: np.ndarray
    cov_deg2: np.ndarray
    ci95_deg: np.ndarray
    offset_nT: np.ndarray | None
    offset_std_nT: np.ndarray | None
    scale: float | None
    scale_std: float | None
    n_used: int
    method: str
    noise: OUNoise
    residual_rms_nT: np.ndarray
    param_names: tuple
    param_cov: np.ndarray
    dof_deg: np.ndarray | None = None
    converged: bool | None = None
    autocorr_steps: float | None = None
    mcmc: dict | None = None
    samples: np.ndarray | None = dataclasses.field(default=None, repr=False)
    local_time: dict | None = None
    warnings: tuple = ()
    checks: dict | None = None
    provenance: dict | None = None
    determinability: object | None = None
    #: Covariance of all parameters under the fitted noise model itself (``param_names``
    #: order, angles in rad), when the stated ``param_cov`` is another (the spectral
    #: sandwich, :mod:`magcal.alignment.sandwich`); None when they are the same.
    model_param_cov: np.ndarray | None = dataclasses.field(default=None, repr=False)
    #: Rows of the input (``data``'s row order, all rows) that the robust screen of
    #: :func:`magcal.alignment.gls.fit_alignment` left out as outliers (bool, shape
    #: (n,)); None when no screen ran. Not written to JSON (the count is in
    #: ``warnings`` and, from :class:`~magcal.alignment.estimator.Aligner`, ``screened``).
    left_out: np.ndarray | None = dataclasses.field(default=None, repr=False)

    @property
    def determinable(self) -> bool:
        """False when the determinability checks found the rotation not determinable."""
        return self.determinability is None or bool(self.determinability.determinable)

    @property
    def model_std_deg(self) -> np.ndarray | None:
        """The angles' std under the fitted noise model itself (degrees), or None.

        The local-time shift test needs these: nested fits' model-based variances
        differ by the variance of the angles' difference, sandwiches do not.
        """
        if self.model_param_cov is None or "w_Hp" not in self.param_names:
            return None
        rows = [self.param_names.index(n) for n in ("w_Hp", "w_He", "w_Hn")]
        return np.rad2deg(np.sqrt(np.diag(self.model_param_cov)[rows]))

    @property
    def std_deg(self) -> np.ndarray:
        """Standard deviation of each angle (degrees)."""
        return np.sqrt(np.diag(self.cov_deg2))

    @property
    def rotvec_rad(self) -> np.ndarray:
        """The rotation vector in radians."""
        return np.deg2rad(self.angles_deg)

    def significant(self, n_std: float = 2.0) -> np.ndarray:
        """Which angles differ from zero by more than ``n_std`` standard deviations."""
        return np.abs(self.angles_deg) > n_std * self.std_deg

    def with_provenance(self, provenance: dict) -> AlignmentResult:
        """Copy of the result carrying a provenance record."""
        return dataclasses.replace(self, provenance=provenance)

    def to_json(self) -> dict:
        """JSON-ready product dictionary (CONTRACTS §3 keys first)."""
        out = {
            "angles_deg": _by_component(self.angles_deg),
            "std_deg": _by_component(self.std_deg),
            "ci95_deg": {c: [float(lo), float(hi)]
                         for c, (lo, hi) in zip(COMPONENTS, self.ci95_deg)},
            "n_used": int(self.n_used),
            "method": self.method,
        }
        if self.method == "emcee":
            out["converged"] = bool(self.converged)
            out["autocorr_steps"] = self.autocorr_steps
        out["determinable"] = self.determinable
        out["reason"] = None if self.determinability is None else self.determinability.reason
        out.update({
            "convention": "data ~= scale * R(w) @ reference + offset; w = rotation vector "
                          "about (Hp, He, Hn), scipy Rotation.from_rotvec",
            "covariance_deg2": self.cov_deg2,
            "significant_2std": {c: bool(s) for c, s in zip(COMPONENTS, self.significant())},
            "offset_nT": _by_component(self.offset_nT),
            "offset_std_nT": _by_component(self.offset_std_nT),
            "scale": self.scale,
            "scale_std": self.scale_std,
            "noise": self.noise.to_dict(),
            "residual_rms_nT": _by_component(self.residual_rms_nT),
            "dof": _by_component(self.dof_deg),
            "parameters": list(self.param_names),
        })
        out["warnings"] = list(self.warnings)
        if self.local_time is not None:
            out["local_time_field"] = self.local_time
        if self.determinability is not None:
            out["determinability"] = self.determinability.to_json()
        if self.checks is not None:
            out.update(self.checks)
        if self.mcmc is not None:
            out["mcmc"] = self.mcmc
        if self.provenance is not None:
            out["provenance"] = self.provenance
        return product_dict(out)
