"""Thin estimator around the alignment functions (fit, then transform)."""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.spatial.transform import Rotation

from magcal.alignment.checks import (add_systematic, inflate, local_time_check,
                                     select_lt_harmonics, whole_vs_windows,
                                     window_consistency)
from magcal.alignment.determinability import (MAX_ANGLE_DEG, check_after, check_before,
                                              identity_fit, not_determinable)
from magcal.alignment.gls import DEFAULT_NOISE_MODEL, fit_alignment, prepare
from magcal.alignment.noise import COMPONENTS
from magcal.alignment.posterior import sample_posterior
from magcal.alignment.windows import angles_by_window
from magcal.errors import InputError, MagcalError

#: Local-time harmonics fitted by ``lt_harmonics="auto"`` (records of 3 days or more).
AUTO_LT_HARMONICS = 3
#: Shortest record (days) for which ``"auto"`` fits local-time harmonics.
AUTO_LT_MIN_DAYS = 3.0


def resolve_lt_harmonics(lt_harmonics, span_days: float) -> int:
    """``"auto"`` -> 3 candidate harmonics for records of at least 3 days, else 0; ints pass.

    With ``"auto"`` the :class:`Aligner` keeps the candidates only when the data show a
    local-time field (:func:`magcal.alignment.checks.select_lt_harmonics`).

    Three harmonics: the paper's local-time residuals (Fig. 19) have a daily wave in Hp
    and He and two or more maxima a day in Hn; measured on the simulated month, two
    harmonics leave He 3 sigma off, three recover every angle, six change nothing more.
    Below three days a daily field cannot be told from the offset and the slow noise.
    """
    if lt_harmonics == "auto":
        return AUTO_LT_HARMONICS if span_days >= AUTO_LT_MIN_DAYS else 0
    k = int(lt_harmonics)
    if k < 0:
        raise InputError(f"lt_harmonics must be 'auto' or >= 0, got {lt_harmonics}")
    return k


def nuisance_record(requested, k: int, span_days: float, selection, window_days) -> dict:
    """Which nuisance terms were fitted and why (JSON-ready).

    ``selection`` is the record of :func:`magcal.alignment.checks.select_lt_harmonics`
    when the data decided; otherwise the reason is the setting or the record length.
    """
    if selection is not None:
        out = dict(selection)
    elif requested != "auto":
        out = {"candidate_harmonics": int(k), "kept": bool(k),
               "reason": f"lt_harmonics = {k} set by the user"}
    else:
        out = {"candidate_harmonics": 0, "kept": False,
               "reason": f"record of {span_days:.2f} days: shorter than "
                         f"{AUTO_LT_MIN_DAYS:g} days, a local-time field cannot be told from "
                         "the offset and the slow noise"}
    out["windows"] = {
        "window_days": window_days,
        "reason": ("consecutive windows fitted as a consistency check; intervals widen only "
                   "when the windows disagree beyond their errors (window_consistency) or "
                   "the whole record departs from them (whole_vs_windows)") if window_days
        else "no windows: record shorter than 9 days (auto) or windows disabled"}
    return out


def precision_record(result, closed, without_lt=None) -> dict:
    """The precision the data allow next to the stated one (JSON-ready).

    ``crb_std_deg`` is the Cramér-Rao bound of the chosen model: the inverse Fisher
    information at the fitted parameters with the noise model taken as known (the
    closed form's covariance). ``std_deg`` (reported) adds what the bound leaves out:
    the uncertainty of the noise model (Student t), window inflation and systematics,
    or is the posterior's spread. ``crb_std_without_lt_deg`` is the bound with no
    local-time nuisance (rotation and offset only), the precision the record would allow
    if the reference lacked no local-time field.
    """
    def comp(values):
        return {c: float(v) for c, v in zip(COMPONENTS, values)}

    out = {"crb_std_deg": comp(closed.std_deg), "std_deg": comp(result.std_deg),
           "std_over_crb": comp(result.std_deg / closed.std_deg)}
    if without_lt is not None:
        out["crb_std_without_lt_deg"] = comp(without_lt.std_deg)
        out["std_over_crb_without_lt"] = comp(result.std_deg / without_lt.std_deg)
    return out


def screened_record(closed) -> dict | None:
    """What the closed form's robust screen left out (JSON-ready), None when nothing.

    The count and rule are those of :func:`magcal.alignment.gls.fit_alignment`; with
    ``--mcmc`` the posterior is sampled on the same rows.
    """
    from magcal.alignment.gls import ROBUST_K, ROBUST_K_REFERENCE

    if closed.left_out is None or not closed.left_out.any():
        return None
    return {"samples": int(closed.left_out.sum()),
            "test": f"residual beyond {ROBUST_K_REFERENCE:g} robust std of data - "
                    f"reference, then beyond {ROBUST_K:g} robust std of the fit "
                    "(median absolute deviation)",
            "applies_to": "closed form and posterior (the identity is fitted with its own screen)"}


def resolve_window_days(window_days, span_days: float):
    """``"auto"`` -> 7-day windows from 21 days on, thirds of the record from 9 days on,
    else no windows; a number passes; None disables."""
    if window_days is None:
        return None
    if window_days == "auto":
        if span_days >= 21.0:
            return 7.0
        if span_days >= 9.0:
            return span_days / 3.0 + 1e-6
        return None
    return float(window_days)


class Aligner:
    """Estimate the rotation of data against a reference, with honest uncertainty.

    Besides the rotation, :meth:`fit` (by default) fits a field fixed in local time as
    nuisance (a model such as T89/T04 lacks one at geostationary orbit and it would
    otherwise be absorbed as a rotation), checks how much the angles depend on it, fits
    the angles in separate windows and inflates the intervals when the windows disagree
    beyond their errors. Every such finding is a sentence in ``result_.warnings``.

    Parameters
    ----------
    fit_offset : bool
        Fit a constant offset together with the rotation (default True).
    fit_scale : bool
        Fit a common scale factor.
    mcmc : bool
        Sample the full posterior with emcee after the closed form.
    rng : numpy.random.Generator, optional
        Needed when ``mcmc`` is True.
    n_walkers, min_autocorr_times, max_steps : int, float, int
        Sampler settings (see :func:`magcal.alignment.posterior.sample_posterior`).
    lt_harmonics : "auto" or int
        Local-time harmonics per component fitted as nuisance; ``"auto"``: 3 candidate
        harmonics for records of 3 days or more (see :func:`resolve_lt_harmonics`), kept
        only when the data show a local-time field
        (:func:`magcal.alignment.checks.select_lt_harmonics`); 0 disables.
    window_days : "auto", float or None
        Window length for the consistency check (see :func:`resolve_window_days`).
    inflate_inconsistent : bool
        Widen the intervals by the Birge ratio when the windows disagree.
    max_angle_deg : float
        Physically sensible range of each angle: a rotation the data cannot confine to
        it is reported as not determinable (default 45, the posterior's prior range).
    noise_model : {"ou+ou+white", "ou", "ou+white"}
        Residual noise model (:func:`magcal.alignment.gls.fit_alignment`; default two
        OU time scales plus white noise, see there).

    Attributes
    ----------
    result_ : AlignmentResult
        The reported result (inflated when the windows disagree).
    closed_form_ : AlignmentResult
        The closed-form fit (the identity fit when the rotation was not fitted).
    identity_ : AlignmentResult
        Fit of the nuisance terms alone (no rotation), the baseline the rotation must beat.
    determinability_ : Determinability
    windows_ : WindowAngles or None
    lt_harmonics_ : int
    angles_deg_, std_deg_ : ndarray, shape (3,)

    Examples
    --------
    >>> from magcal.alignment.synthetic import synthetic_pair
    >>> case = synthetic_pair(np.random.default_rng(0), n=2000, cadence_s=300.0,
    ...                       rotvec_deg=(3.0, 0.0, 0.0), noise_tau_s=(1800.0,) * 3)
    >>> al = Aligner().fit(case.times, case.data, case.ref)
    >>> bool(abs(al.angles_deg_[0] - 3.0) < 4 * al.std_deg_[0])
    True
    """

    def __init__(self, fit_offset: bool = True, fit_scale: bool = False, mcmc: bool = False,
                 rng: np.random.Generator | None = None, n_walkers: int = 32,
                 min_autocorr_times: float = 50.0, max_steps: int = 40000,
                 lt_harmonics="auto", window_days="auto", inflate_inconsistent: bool = True,
                 max_angle_deg: float = MAX_ANGLE_DEG,
                 noise_model: str = DEFAULT_NOISE_MODEL):
        self.fit_offset = fit_offset
        self.fit_scale = fit_scale
        self.mcmc = mcmc
        self.rng = rng
        self.n_walkers = n_walkers
        self.min_autocorr_times = min_autocorr_times
        self.max_steps = max_steps
        self.lt_harmonics = lt_harmonics
        self.window_days = window_days
        self.inflate_inconsistent = inflate_inconsistent
        self.max_angle_deg = max_angle_deg
        self.noise_model = noise_model

    def fit(self, times, data, ref, lon_deg=None) -> Aligner:
        """Fit on matched ``data`` and ``ref`` (n, 3) at ``times``; return self.

        ``lon_deg`` (east longitude, scalar or per sample) puts the local-time field in
        local time; without it the harmonics are in UT (same fit at a fixed longitude).

        Before the rotation is fitted, :func:`~magcal.alignment.determinability.check_before`
        decides whether the data can determine it at all (record length against the
        nuisance periods, Cramér-Rao bound with the nuisance terms fitted); afterwards
        :func:`~magcal.alignment.determinability.check_after` requires a sensible
        interval and a fit no worse than the identity. A rotation that fails is reported
        with NaN angles, the reason in ``result_.determinability`` and a warning; the
        offset, noise and residual are then those of the identity fit (``identity_``).
        """
        t_s, _, _, _ = prepare(times, data, ref)
        span_days = float(t_s[-1] - t_s[0]) / 86400.0
        k = resolve_lt_harmonics(self.lt_harmonics, span_days)
        kw = {"fit_offset": self.fit_offset, "fit_scale": self.fit_scale, "lon_deg": lon_deg,
              "noise_model": self.noise_model}
        fits, selection = {}, None
        if self.lt_harmonics == "auto" and k:
            fits = {k: fit_alignment(times, data, ref, lt_harmonics=k, **kw),
                    0: fit_alignment(times, data, ref, lt_harmonics=0, **kw)}
            from magcal.alignment.harmonic_test import lt_field_test
            from magcal.alignment.shift_test import lt_shift_sigma

            field = lt_field_test(fits[0], times, data, ref, k, lon_deg=lon_deg)
            shift = lt_shift_sigma(fits[0], fits[k], times, data, ref, lon_deg=lon_deg)
            keep, selection = select_lt_harmonics(fits[k], fits[0], field_test=field,
                                                  shift_sigma=shift)
            k = k if keep else 0
        identity = identity_fit(times, data, ref, lt_harmonics=k if span_days >= 1.0 else 0,
                                **kw)
        verdict = check_before(times, data, ref, identity, lt_harmonics=k,
                               max_angle_deg=self.max_angle_deg, **kw)
        self.windows_ = None
        if verdict.determinable:
            closed, result, warnings, checks = self._fit_rotation(times, data, ref, k,
                                                                  span_days, kw, fits)
            verdict = check_after(result, verdict)
        else:
            closed, warnings, checks = None, [], {}
        checks["nuisance_selection"] = nuisance_record(
            self.lt_harmonics, k, span_days, selection,
            resolve_window_days(self.window_days, span_days))
        if verdict.determinable:
            result = dataclasses.replace(result, determinability=verdict)
        else:
            result = not_determinable(identity, verdict)
            closed = closed if closed is not None else result
            warnings = [f"rotation not determinable: {verdict.reason}"] + warnings
        result = dataclasses.replace(result, warnings=tuple(warnings), checks=checks or None)
        self.lt_harmonics_ = k
        self.identity_ = identity
        self.closed_form_ = closed
        self.result_ = result
        self.determinability_ = verdict
        self.angles_deg_ = result.angles_deg
        self.std_deg_ = result.std_deg
        return self

    def _fit_rotation(self, times, data, ref, k, span_days, kw, fits):
        """Closed form, local-time check, posterior and window checks of a determinable
        rotation: ``(closed_form, result, warnings, checks)``; ``fits`` holds closed forms
        already made, by number of harmonics."""
        def closed_form(n_harmonics):
            if n_harmonics not in fits:
                fits[n_harmonics] = fit_alignment(times, data, ref, lt_harmonics=n_harmonics,
                                                  **kw)
            return fits[n_harmonics]

        closed = closed_form(k)
        warnings, checks = [], {}
        screened = screened_record(closed)
        if screened is not None:  # the closed form's count, reported for every method
            warnings += [w for w in closed.warnings if "left out as outliers" in w]
            checks["screened"] = screened
        if k == 0 and span_days < AUTO_LT_MIN_DAYS and self.lt_harmonics == "auto":
            checks["local_time_check"] = {
                "harmonics_fitted": False,
                "note": f"record of {span_days:.1f} days: shorter than "
                        f"{AUTO_LT_MIN_DAYS:g} days, a local-time field cannot be separated"}
        elif span_days >= AUTO_LT_MIN_DAYS or k:
            other = closed_form(0 if k else AUTO_LT_HARMONICS)
            with_lt, without = (closed, other) if k else (other, closed)
            check, warn = local_time_check(with_lt, without, fitted=bool(k))
            checks["local_time_check"] = check
            warnings += warn
        result = closed
        if self.mcmc:
            if self.rng is None:
                raise MagcalError("Aligner(mcmc=True) needs rng=numpy.random.default_rng(seed)")
            # the posterior sees the rows the closed form kept: its outliers are left
            # out here too (NaN rows are dropped like missing ones)
            kept = data if closed.left_out is None else np.where(
                closed.left_out[:, None], np.nan, np.asarray(data, dtype=float))
            result = sample_posterior(times, kept, ref, self.rng, fit_offset=self.fit_offset,
                                      fit_scale=self.fit_scale, n_walkers=self.n_walkers,
                                      min_autocorr_times=self.min_autocorr_times,
                                      max_steps=self.max_steps, start=closed,
                                      lt_harmonics=k, lon_deg=kw["lon_deg"],
                                      noise_model=self.noise_model)
            if not result.converged:
                warnings.append(result.mcmc["message"])
        wd = resolve_window_days(self.window_days, span_days)
        if wd:
            result = self._window_checks(times, data, ref, result, wd, k, kw, checks, warnings)
        checks["precision"] = precision_record(result, closed, fits.get(0))
        return closed, result, warnings, checks

    def _window_checks(self, times, data, ref, result, wd, k, kw, checks, warnings):
        """Angles by window, their consistency and the whole-vs-windows comparison; the
        result with intervals inflated as the checks say (``checks``/``warnings`` are
        extended in place)."""
        self.windows_ = angles_by_window(
            times, data, ref, window_s=wd * 86400.0, min_samples=100,
            lt_harmonics=min(k, AUTO_LT_HARMONICS) if wd >= AUTO_LT_MIN_DAYS else 0, **kw)
        cons, warn = window_consistency(self.windows_)
        checks["window_consistency"] = cons
        warnings += warn
        whole, warn, syst = whole_vs_windows(result, self.windows_)
        checks["whole_vs_windows"] = whole
        warnings += warn
        uninflated = {
            "std_deg": dict(zip(COMPONENTS, map(float, result.std_deg))),
            "ci95_deg": {c: [float(lo), float(hi)] for c, (lo, hi)
                         in zip(COMPONENTS, result.ci95_deg)}}
        if self.inflate_inconsistent and "inflation" in cons:
            factors = [cons["inflation"][c] for c in COMPONENTS]
            result = inflate(result, factors, cons["dof"])
            checks["window_consistency"]["inflation_applied"] = any(f != 1.0 for f in factors)
        if self.inflate_inconsistent:
            result = add_systematic(result, syst)
            whole["systematic_applied"] = bool(np.any(syst > 0))
        if not np.allclose(result.std_deg, list(uninflated["std_deg"].values())):
            checks["uninflated"] = uninflated
        return result

    def transform(self, data) -> np.ndarray:
        """Undo the fitted rotation, offset and scale: ``R(w)^-1 (data - offset) / scale``.

        The fitted local-time field is a property of the reference, not of the data,
        and is not removed.
        """
        res = self.result_
        if not res.determinable:
            raise MagcalError(f"no rotation to undo: {res.determinability.reason}")
        d = np.asarray(data, dtype=float)
        offset = np.zeros(3) if res.offset_nT is None else res.offset_nT
        scale = 1.0 if res.scale is None else res.scale
        return Rotation.from_rotvec(res.rotvec_rad).inv().apply(d - offset) / scale
