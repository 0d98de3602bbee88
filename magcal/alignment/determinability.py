"""Is the rotation determinable from these data, and does the fit beat the identity?

A rotation is seen only through the *variation* of the reference field's direction:
with a constant offset fitted, ``R(w) @ ref + o`` for a reference that hardly changes
over the record is indistinguishable from ``ref + o'``, and harmonics of local time over
less than a day are indistinguishable from the offset and a drift. An estimator that
does not check this returns an arbitrary rotation (tens to millions of degrees) with
small residuals, and it looks significant. Two checks guard the product:

* :func:`check_before` (before the rotation is fitted): the record must span the
  periods of the nuisance terms, and the Cramér-Rao bound of the angles at the identity,
  with the nuisance terms (offset, scale, local-time field) profiled out and the noise
  model of the identity fit, must confine each angle to the physically sensible range
  (:data:`MAX_ANGLE_DEG`, the same range as the posterior's prior). The bound is
  ``(A_ww - A_wn A_nn^-1 A_nw)^-1`` of the whitened Fisher information ``A``.
* :func:`check_after` (on the reported result): the 95 % interval of every angle lies
  inside that range, the covariance exists, and the fitted rotation leaves no larger a
  residual than the identity with the same nuisance terms (:data:`RMS_TOLERANCE`).

A rotation that fails either is reported as not determinable: ``angles_deg``,
``std_deg`` and ``ci95_deg`` become NaN (``null`` in JSON) and the reason is stated;
what the fit gave, if it ran, is kept in :attr:`Determinability.fitted_angles_deg` for
diagnosis only.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from magcal.alignment.gls import (DEFAULT_NOISE_MODEL, _normal_equations, component_stats,
                                  information_inverse, param_names, predict_and_jacobian,
                                  prepare)
from magcal.alignment.localtime import DAY_S
from magcal.alignment.noise import COMPONENTS
from magcal.alignment.result import AlignmentResult
from magcal.io.jsonio import to_jsonable

#: Largest rotation (deg) the small-misalignment model stands for; also the posterior's
#: uniform prior range (:data:`magcal.alignment.posterior.MAX_ANGLE_RAD`).
MAX_ANGLE_DEG = 45.0
#: The fitted rotation may leave at most this fraction more residual RMS than the
#: identity (generalised least squares minimises the whitened, not the plain, residual).
RMS_TOLERANCE = 0.01
#: Two-sided 95 % normal quantile used for the bound's interval.
Z95 = 1.959963984540054


def _comp(values):
    return None if values is None else {c: float(v) for c, v in zip(COMPONENTS, values)}


def _total_rms(rms) -> float:
    return float(np.sqrt(np.mean(np.asarray(rms, dtype=float) ** 2)))


def _span(seconds: float) -> str:
    if seconds < 3600.0:
        return f"{seconds / 60.0:.1f} min"
    if seconds < 2 * DAY_S:
        return f"{seconds / 3600.0:.1f} h"
    return f"{seconds / DAY_S:.1f} days"


@dataclasses.dataclass(frozen=True)
class Determinability:
    """Whether the data determine the rotation, and the numbers behind the verdict.

    Attributes
    ----------
    determinable : bool
    reasons : tuple of str
        Why not (empty when determinable).
    record_span_s : float
    nuisance : tuple of str
        Parameters fitted besides the rotation.
    nuisance_periods_s : tuple of float
        Periods of the local-time harmonics fitted (empty when none).
    crb_std_deg : ndarray, shape (3,)
        Cramér-Rao bound of each angle at the identity with the nuisance terms fitted
        (inf when the information matrix is singular).
    crb_std_rotation_only_deg : ndarray, shape (3,)
        The same bound if only the rotation were fitted.
    information_retained : ndarray, shape (3,)
        ``crb_rotation_only**2 / crb**2``: the fraction of each angle's information the
        nuisance terms leave (1: no confounding; near 0: degenerate with them).
    condition_number : float
        Of the unit-diagonal Fisher information of all fitted parameters.
    reference_variation_nT : ndarray, shape (3,)
        Standard deviation of each reference component over the record: the variation
        through which a rotation shows when an offset is fitted.
    max_angle_deg : float
    identity_rms_nT : ndarray, shape (3,)
        Residual RMS of the identity fit (nuisance terms only).
    rotation_rms_nT : ndarray or None
        Residual RMS with the fitted rotation (None when it was not fitted).
    fitted_angles_deg, fitted_std_deg : ndarray or None
        What the fit gave (None when it was not run).
    """

    determinable: bool
    reasons: tuple
    record_span_s: float
    nuisance: tuple
    nuisance_periods_s: tuple
    crb_std_deg: np.ndarray
    crb_std_rotation_only_deg: np.ndarray
    information_retained: np.ndarray
    condition_number: float
    reference_variation_nT: np.ndarray
    max_angle_deg: float
    identity_rms_nT: np.ndarray
    rotation_rms_nT: np.ndarray | None = None
    fitted_angles_deg: np.ndarray | None = None
    fitted_std_deg: np.ndarray | None = None

    @property
    def reason(self) -> str | None:
        """The reasons as one sentence, or None when determinable."""
        return "; ".join(self.reasons) if self.reasons else None

    def to_json(self) -> dict:
        """JSON-ready dictionary (NaN and inf become null)."""
        return to_jsonable({
            "determinable": self.determinable, "reason": self.reason,
            "record_span_s": self.record_span_s, "nuisance": list(self.nuisance),
            "nuisance_periods_s": list(self.nuisance_periods_s),
            "crb_std_deg": _comp(self.crb_std_deg),
            "crb_std_rotation_only_deg": _comp(self.crb_std_rotation_only_deg),
            "information_retained": _comp(self.information_retained),
            "condition_number": self.condition_number,
            "reference_variation_nT": _comp(self.reference_variation_nT),
            "max_angle_deg": self.max_angle_deg,
            "identity_rms_nT": _comp(self.identity_rms_nT),
            "identity_total_rms_nT": _total_rms(self.identity_rms_nT),
            "rotation_rms_nT": _comp(self.rotation_rms_nT),
            "rotation_total_rms_nT": (None if self.rotation_rms_nT is None
                                      else _total_rms(self.rotation_rms_nT)),
            "fitted_angles_deg": _comp(self.fitted_angles_deg),
            "fitted_std_deg": _comp(self.fitted_std_deg),
        })


def identity_fit(times, data, ref, *, fit_offset: bool = True, fit_scale: bool = False,
                 lt_harmonics: int = 0, lon_deg=None,
                 noise_model: str = DEFAULT_NOISE_MODEL) -> AlignmentResult:
    """Fit of the nuisance terms alone (rotation fixed at the identity): the baseline a
    rotation must beat, and the noise model of the bound.

    Without any nuisance term the residual is ``data - ref`` and only the noise model is
    fitted (``method="identity"``).
    """
    from magcal.alignment.gls import fit_alignment, noise_fitter

    if fit_offset or fit_scale or lt_harmonics:
        return fit_alignment(times, data, ref, fit_rotation=False, fit_offset=fit_offset,
                             fit_scale=fit_scale, lt_harmonics=lt_harmonics, lon_deg=lon_deg,
                             noise_model=noise_model)
    t, d, r, _ = prepare(times, data, ref)
    resid = d - r
    return AlignmentResult(
        angles_deg=np.zeros(3), cov_deg2=np.full((3, 3), np.nan),
        ci95_deg=np.full((3, 2), np.nan), offset_nT=None, offset_std_nT=None, scale=None,
        scale_std=None, n_used=int(d.shape[0]), method="identity",
        noise=noise_fitter(noise_model)(resid, t),
        residual_rms_nT=np.sqrt(np.mean(resid ** 2, axis=0)), param_names=(),
        param_cov=np.zeros((0, 0)))


def rotation_bound(times, data, ref, identity: AlignmentResult, *, fit_offset: bool = True,
                   fit_scale: bool = False, lt_harmonics: int = 0, lon_deg=None):
    """Cramér-Rao bound of the angles at the identity, with and without the nuisance.

    Parameters
    ----------
    times, data, ref
        As for :func:`magcal.alignment.gls.fit_alignment`.
    identity : AlignmentResult
        Fit of the nuisance terms alone (``fit_rotation=False``): its noise model whitens
        the information.
    fit_offset, fit_scale, lt_harmonics, lon_deg
        The nuisance terms of the rotation fit.

    Returns
    -------
    crb_deg : ndarray, shape (3,)
        Bound with the nuisance profiled out (inf where the information is singular).
    crb_rotation_only_deg : ndarray, shape (3,)
    condition_number : float

    Examples
    --------
    >>> from magcal.alignment.gls import fit_alignment
    >>> from magcal.alignment.synthetic import synthetic_pair
    >>> case = synthetic_pair(np.random.default_rng(3), n=2000)
    >>> ident = fit_alignment(case.times, case.data, case.ref, fit_rotation=False,
    ...                       noise_model="ou")
    >>> crb, alone, _ = rotation_bound(case.times, case.data, case.ref, ident)
    >>> crb.round(1), bool(np.all(alone <= crb))
    (array([3.4, 2.6, 3.6]), True)
    """
    from magcal.alignment.gls import lt_basis

    t, d, r, keep = prepare(times, data, ref)
    names = param_names(True, fit_offset, fit_scale, lt_harmonics)
    basis = lt_basis(times, keep, lt_harmonics, lon_deg)
    theta = np.zeros(len(names))
    if fit_scale:
        theta[names.index("scale")] = 1.0 if identity.scale is None else identity.scale
    mu, jac = predict_and_jacobian(theta, names, r, basis)
    if identity.noise.kind != "ou":  # a Kalman noise model: whiten with it
        from magcal.alignment.ouwhite import WhitenedBase

        _, xs = WhitenedBase(t, d, r, basis, identity.noise).series(mu, jac)
        a = sum(x.T @ x for x in xs)
    else:
        a, _ = _normal_equations(component_stats(t, d, mu, jac), identity.noise)
    full = information_inverse(a)
    crb = np.sqrt(np.diag(full)[:3]) if np.all(np.isfinite(full)) else np.full(3, np.inf)
    alone = information_inverse(a[:3, :3])
    crb_alone = (np.sqrt(np.diag(alone)) if np.all(np.isfinite(alone))
                 else np.full(3, np.inf))
    scale = np.sqrt(np.maximum(np.diag(a), 1e-300))
    eig = np.linalg.eigvalsh(a / np.outer(scale, scale))
    cond = float(eig[-1] / eig[0]) if eig[0] > 0 else float("inf")
    return np.rad2deg(crb), np.rad2deg(crb_alone), cond


def check_before(times, data, ref, identity: AlignmentResult, *, fit_offset: bool = True,
                 fit_scale: bool = False, lt_harmonics: int = 0, lon_deg=None,
                 max_angle_deg: float = MAX_ANGLE_DEG,
                 noise_model: str = DEFAULT_NOISE_MODEL) -> Determinability:
    """Decide, before fitting, whether the data can determine the rotation.

    Parameters
    ----------
    times, data, ref
        Matched samples (as for :func:`magcal.alignment.gls.fit_alignment`).
    identity : AlignmentResult
        Nuisance-only fit with the same ``fit_offset``/``fit_scale`` (and the harmonics
        when the record spans their periods).
    lt_harmonics : int
        Local-time harmonics the rotation fit would carry.
    max_angle_deg : float
        Physically sensible range of each angle.

    Returns
    -------
    Determinability
    """
    t, _, r, _ = prepare(times, data, ref)
    span = float(t[-1] - t[0])
    periods = tuple(DAY_S / k for k in range(1, lt_harmonics + 1))
    nuisance = (("offset",) if fit_offset else ()) + (("scale",) if fit_scale else ()) + (
        (f"{lt_harmonics} local-time harmonics",) if lt_harmonics else ())
    reasons = []
    if periods and span < periods[0]:
        reasons.append(
            f"the record spans {_span(span)}, less than the 24 h period of the local-time "
            "harmonics: over it they are degenerate with the offset and the rotation")
        lt_harmonics = 0  # bound of what could be fitted at most
        nuisance = tuple(n for n in nuisance if "harmonics" not in n)
    crb, alone, cond = rotation_bound(times, data, ref, identity, fit_offset=fit_offset,
                                      fit_scale=fit_scale, lt_harmonics=lt_harmonics,
                                      lon_deg=lon_deg)
    with np.errstate(divide="ignore", invalid="ignore"):
        retained = np.where(np.isfinite(crb), (alone / crb) ** 2, 0.0)
    variation = np.std(r, axis=0)
    loose = ~(Z95 * crb < max_angle_deg)
    if np.any(loose):
        axes = ", ".join(f"{c} +-{Z95 * s:.3g}" for c, s, b in zip(COMPONENTS, crb, loose) if b)
        reasons.append(
            f"with {'the ' + ', '.join(nuisance) if nuisance else 'no term but the rotation'}"
            " fitted, the data confine the angles "
            f"only to {axes} deg (95 %, Cramer-Rao bound at the identity), beyond the "
            f"+-{max_angle_deg:g} deg of a misalignment: over {_span(span)} the reference "
            "changes too little (std " + ", ".join(
                f"{c} {v:.3g}" for c, v in zip(COMPONENTS, variation))
            + " nT) against the residual noise (std " + ", ".join(
                f"{c} {v:.3g}" for c, v in zip(COMPONENTS, identity.noise.std_nT)) + " nT)")
    return Determinability(
        determinable=not reasons, reasons=tuple(reasons), record_span_s=span,
        nuisance=nuisance + ((f"{len(periods)} local-time harmonics (not fittable)",)
                             if periods and not lt_harmonics else ()),
        nuisance_periods_s=periods, crb_std_deg=crb,
        crb_std_rotation_only_deg=alone, information_retained=retained,
        condition_number=cond, reference_variation_nT=variation,
        max_angle_deg=float(max_angle_deg), identity_rms_nT=identity.residual_rms_nT)


def check_after(result: AlignmentResult, before: Determinability) -> Determinability:
    """Judge the reported fit: sensible interval, a covariance, no worse than the identity.

    Parameters
    ----------
    result : AlignmentResult
        The rotation fit as it would be reported (after any inflation).
    before : Determinability
        The verdict of :func:`check_before` (determinable).

    Returns
    -------
    Determinability
        ``before`` with the fitted numbers and, if a check fails, the reasons.
    """
    reasons = list(before.reasons)
    angles, std = result.angles_deg, result.std_deg
    ci = np.asarray(result.ci95_deg, dtype=float)
    lim = before.max_angle_deg
    if not np.all(np.isfinite(std)):
        reasons.append("the fitted angles have no covariance (the Fisher information is "
                       "singular): they are not determined by the data")
    elif np.any(np.abs(ci) >= lim):
        axes = ", ".join(f"{c} [{lo:.3g}, {hi:.3g}]" for c, (lo, hi)
                         in zip(COMPONENTS, ci) if max(abs(lo), abs(hi)) >= lim)
        reasons.append(f"the 95 % interval reaches beyond the +-{lim:g} deg of a "
                       f"misalignment ({axes} deg)")
    rms_rot, rms_id = _total_rms(result.residual_rms_nT), _total_rms(before.identity_rms_nT)
    if not rms_rot <= rms_id * (1.0 + RMS_TOLERANCE):
        reasons.append(f"the fitted rotation leaves {rms_rot:.3g} nT RMS, more than the "
                       f"{rms_id:.3g} nT of the identity with the same nuisance terms")
    return dataclasses.replace(
        before, determinable=not reasons, reasons=tuple(reasons),
        rotation_rms_nT=result.residual_rms_nT, fitted_angles_deg=angles,
        fitted_std_deg=std)


def not_determinable(result: AlignmentResult, verdict: Determinability) -> AlignmentResult:
    """``result`` with the angles, their covariance and interval set to NaN and the
    verdict attached (its offset, noise and residual stay as fitted)."""
    nan3 = np.full(3, np.nan)
    return dataclasses.replace(
        result, angles_deg=nan3, cov_deg2=np.full((3, 3), np.nan),
        ci95_deg=np.full((3, 2), np.nan), dof_deg=None, determinability=verdict)
