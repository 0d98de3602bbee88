"""Alignment posterior under a fixed Kalman noise model (OU + white, two time scales).

The OU posterior (:class:`magcal.alignment.posterior.AlignmentPosterior`) samples the
noise parameters with the angles because the OU likelihood has cheap lag statistics for
any correlation time. The Kalman models (:mod:`magcal.alignment.ouwhite`,
:mod:`magcal.alignment.twoscale`) have none: their noise is held at the closed form's
fit (empirical Bayes) and the chain samples the angles, offsets and scale. Sampling the
OU likelihood instead, as ``--mcmc`` did, discarded the chosen noise model: on the demo
quarter the two-scale closed form's angles (0.09, 0.14, -0.02 deg, consistent with
the 7-day windows) became the OU posterior's (-0.56, -0.25, 0.80 deg), which fit
worse than no rotation.

Whitening is linear, so ``W (d - s R r - o) = W d - s R (W r) - o (W 1)``: per
component the whitened Gram matrix of ``[d_c, r, 1, H]`` is computed once and each
walker's likelihood is a quadratic form in ``(1, -s R_c, -o_c)``, with the local-time
coefficients ``H`` integrated out analytically (flat prior) as in the OU posterior.
"""

from __future__ import annotations

import numpy as np

from magcal.alignment.ouwhite import WhitenedBase
from magcal.alignment.posterior import MAX_ANGLE_RAD, WalkerPosterior, _rotation_matrices


class FixedNoisePosterior(WalkerPosterior):
    """Vectorised log-posterior of the alignment under a fixed Kalman noise model.

    Parameters as :class:`~magcal.alignment.posterior.AlignmentPosterior` (samples,
    model parameter names without local-time terms, local-time ``basis`` integrated
    out), plus ``noise``: the closed form's fitted :class:`OUWhiteNoise` or
    :class:`TwoScaleNoise` (``gains(c, t)`` and ``total_var``), held fixed; the walkers
    carry the model parameters only.

    Examples
    --------
    The log-likelihood is the whitened residual sum of squares (times -1/2): zero for
    data that are the reference plus the sampled offset.

    >>> from magcal.alignment.ouwhite import noise_from_components
    >>> t = np.arange(200.0) * 60.0
    >>> rng = np.random.default_rng(0)
    >>> ref = rng.normal(size=(200, 3)) * 100
    >>> noise = noise_from_components([(1.0, 600.0, 0.1, False)] * 3, t)
    >>> post = FixedNoisePosterior(t, ref + 1.0, ref, ("w_Hp", "w_He", "w_Hn", "o_Hp",
    ...                            "o_He", "o_Hn"), noise)
    >>> truth = np.array([[0, 0, 0, 1.0, 1.0, 1.0]])
    >>> bool(abs(post.log_likelihood(truth)[0]) < 1e-6)
    True
    """

    def __init__(self, times_s, data, ref, names, noise, basis=None):
        t = np.asarray(times_s, dtype=float)
        self._index(names)
        self.all_names = self.names
        self.noise = noise
        self.basis = np.zeros((t.size, 0)) if basis is None else np.asarray(basis, float)
        self.n_basis = self.basis.shape[1]
        white = WhitenedBase(t, np.asarray(data, dtype=float), np.asarray(ref, dtype=float),
                             self.basis, noise)
        self._gram = np.stack([white.gram(c) for c in range(3)])  # (3, m, m)

    @property
    def ndim(self) -> int:
        return len(self.names)

    def log_prior(self, theta) -> np.ndarray:
        """Log-prior (0 or -inf): angles within 45 deg, scale in [0.5, 2]."""
        theta = np.atleast_2d(np.asarray(theta, dtype=float))
        w, _, s = self._model_params(theta)
        ok = (np.abs(w).max(axis=1) < MAX_ANGLE_RAD) & (s > 0.5) & (s < 2.0)
        return np.where(ok, 0.0, -np.inf)

    def log_likelihood(self, theta) -> np.ndarray:
        """Log-likelihood (constants dropped) for parameters of shape (walkers, ndim)."""
        theta = np.atleast_2d(np.asarray(theta, dtype=float))
        w, o, s = self._model_params(theta)
        rot = _rotation_matrices(w) * s[:, None, None]
        nw = theta.shape[0]
        gamma = np.concatenate([np.ones((nw, 3, 1)), -rot, -o[:, :, None]], axis=2)
        nr = gamma.shape[2]
        g = self._gram
        q = np.einsum("wci,cij,wcj->wc", gamma, g[:, :nr, :nr], gamma)
        if self.n_basis:
            b = np.einsum("cij,wcj->wci", g[:, nr:, :nr], gamma)
            sol = np.linalg.solve(g[None, :, nr:, nr:], b[..., None])[..., 0]
            q = q - np.einsum("wci,wci->wc", b, sol)
        return -0.5 * np.sum(q, axis=1)
