"""Thin estimator around the alignment functions (fit, then transform)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from magcal.alignment.gls import fit_alignment
from magcal.alignment.posterior import sample_posterior
from magcal.errors import MagcalError


class Aligner:
    """Estimate the rotation of data against a reference, with honest uncertainty.

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

    Attributes
    ----------
    result_ : AlignmentResult
    closed_form_ : AlignmentResult
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
                 min_autocorr_times: float = 50.0, max_steps: int = 40000):
        self.fit_offset = fit_offset
        self.fit_scale = fit_scale
        self.mcmc = mcmc
        self.rng = rng
        self.n_walkers = n_walkers
        self.min_autocorr_times = min_autocorr_times
        self.max_steps = max_steps

    def fit(self, times, data, ref) -> "Aligner":
        """Fit on matched ``data`` and ``ref`` (n, 3) at ``times``; return self."""
        closed = fit_alignment(times, data, ref, fit_offset=self.fit_offset,
                               fit_scale=self.fit_scale)
        result = closed
        if self.mcmc:
            if self.rng is None:
                raise MagcalError("Aligner(mcmc=True) needs rng=numpy.random.default_rng(seed)")
            result = sample_posterior(times, data, ref, self.rng, fit_offset=self.fit_offset,
                                      fit_scale=self.fit_scale, n_walkers=self.n_walkers,
                                      min_autocorr_times=self.min_autocorr_times,
                                      max_steps=self.max_steps, start=closed)
        self.closed_form_ = closed
        self.result_ = result
        self.angles_deg_ = result.angles_deg
        self.std_deg_ = result.std_deg
        return self

    def transform(self, data) -> np.ndarray:
        """Undo the fitted rotation, offset and scale: ``R(w)^-1 (data - offset) / scale``."""
        res = self.result_
        d = np.asarray(data, dtype=float)
        offset = np.zeros(3) if res.offset_nT is None else res.offset_nT
        scale = 1.0 if res.scale is None else res.scale
        return Rotation.from_rotvec(res.rotvec_rad).inv().apply(d - offset) / scale
