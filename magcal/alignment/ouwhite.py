"""Ornstein-Uhlenbeck plus white noise: exact likelihood by a scalar Kalman filter.

Real model-minus-data residuals always carry some white noise (instrument noise,
digitisation, fast field the model lacks) on top of the slow Ornstein-Uhlenbeck part.
A pure OU fit reads the white part as fast decorrelation: with 2 % of the variance
white (OU tau 60 min, 2 nT, plus 0.3 nT white, 1-min samples) the fitted correlation
time drops from 3600 s to about 1450 s, the effective sample count is 2.5x too high,
and whitening by differences amplifies the white part so that the angles scatter twice
as much as they need to (issue 21).

Here each component is ``x_t + w_t`` with ``x`` OU (variance ``v (1 - rho)``,
correlation time ``tau``) and ``w`` white (variance ``v rho``). Its exact likelihood
factorises into Kalman-filter innovations. The filter gains do not depend on the data,
so whitening is a linear filter applied alike to the residual and to the columns of
the design (generalised least squares becomes ordinary least squares on the whitened
rows), and irregular sampling and gaps are handled exactly (a gap only changes the
lag correlation ``exp(-dt / tau)`` of the next step). With ``rho = 0`` the model is the
plain OU model of :mod:`magcal.alignment.noise`.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import ClassVar

import numpy as np
from scipy.optimize import minimize
from scipy.signal import lfilter

from magcal.alignment.noise import effective_count, lag_correlation, noise_dict, noise_warning

RHO_MAX = 0.999


@dataclasses.dataclass(frozen=True)
class Gains:
    """Data-independent Kalman quantities of a unit-variance OU + white model.

    ``xhat_t = a_t xhat_{t-1} + k_t y_t``; innovation ``y_t - phi_t xhat_{t-1}`` with
    variance ``f_t`` (times the total variance ``v``).
    """

    phi: np.ndarray
    a: np.ndarray
    k: np.ndarray
    f: np.ndarray

    @property
    def log_det(self) -> float:
        """``sum(log f)``: log determinant of the unit-variance covariance."""
        return float(np.sum(np.log(self.f)))

    def whiten(self, x) -> np.ndarray:
        """Standardised innovations of ``x`` (:func:`whiten`)."""
        return whiten(x, self)


def kalman_gains(times_s, tau_s: float, rho: float, tol: float = 1e-14) -> Gains:
    """Kalman gains of an OU (variance ``1 - rho``) plus white (``rho``) series.

    Within a run of equal spacings the gains converge geometrically; once converged
    the rest of the run is filled without iterating, so a regularly sampled record
    costs a few hundred scalar steps whatever its length.

    Examples
    --------
    Pure OU with unit spacing and time constant: innovation variance ``1 - e^-2``.

    >>> kalman_gains(np.arange(4.0), 1.0, 0.0).f.round(4)
    array([1.    , 0.8647, 0.8647, 0.8647])
    """
    phi = lag_correlation(times_s, tau_s)
    n = phi.size
    s2, w2 = 1.0 - rho, rho
    a = np.empty(n)
    k = np.empty(n)
    f = np.empty(n)
    change = np.flatnonzero(np.diff(phi) != 0) + 1
    bounds = np.concatenate([[0], change, [n]])
    p = 0.0
    for j in range(bounds.size - 1):
        i0, i1 = int(bounds[j]), int(bounds[j + 1])
        ph = float(phi[i0])
        q = s2 * (1.0 - ph * ph)
        prev = -1.0
        i = i0
        while i < i1:
            pm = ph * ph * p + q
            fi = pm + w2
            ki = pm / fi
            p = (1.0 - ki) * pm
            a[i], k[i], f[i] = ph * (1.0 - ki), ki, fi
            i += 1
            if abs(ki - prev) <= tol * max(ki, 1e-300) and i < i1:
                a[i:i1], k[i:i1], f[i:i1] = a[i - 1], ki, fi
                break
            prev = ki
    f = np.maximum(f, 1e-300)
    return Gains(phi=phi, a=a, k=k, f=f)


def as_columns(x) -> tuple[np.ndarray, bool]:
    """``x`` as an (n, m) float array, and whether it was one series (n,)."""
    x = np.asarray(x, dtype=float)
    one = x.ndim == 1
    return (x[:, None] if one else x), one


def whiten(x, gains: Gains) -> np.ndarray:
    """Standardised innovations of ``x`` (n,) or the columns of ``x`` (n, m).

    If ``x`` follows the model with unit total variance, the output is i.i.d. N(0, 1).

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> t = np.arange(20000.0) * 60.0
    >>> x = simulate(rng, t, 2.0, 3600.0, 0.3)
    >>> g = kalman_gains(t, 3600.0, 0.3 ** 2 / (4.0 + 0.3 ** 2))
    >>> float(np.std(whiten(x, g)) / np.sqrt(4.09)).__round__(1)
    1.0
    """
    y, one = as_columns(x)
    n = y.shape[0]
    xhat = np.empty_like(y)
    change = np.flatnonzero((np.diff(gains.a) != 0) | (np.diff(gains.k) != 0)) + 1
    bounds = np.concatenate([[0], change, [n]])
    state = np.zeros(y.shape[1])
    for j in range(bounds.size - 1):
        i0, i1 = int(bounds[j]), int(bounds[j + 1])
        a, k = gains.a[i0], gains.k[i0]
        if i1 - i0 == 1:
            state = a * state + k * y[i0]
            xhat[i0] = state
        else:
            xhat[i0:i1] = lfilter([k], [1.0, -a], y[i0:i1], axis=0,
                                  zi=(a * state)[None, :])[0]
            state = xhat[i1 - 1]
    pred = np.zeros_like(y)
    pred[1:] = gains.phi[1:, None] * xhat[:-1]
    u = (y - pred) / np.sqrt(gains.f)[:, None]
    return u[:, 0] if one else u


def restricted_nll(log_tau, rho, x, times_s, design=None) -> tuple[float, float]:
    """Profile negative restricted log-likelihood and the fitted total variance ``v``."""
    g = kalman_gains(times_s, float(np.exp(log_tau)), rho)
    n = x.size
    if design is None:
        u = whiten(x, g)
        rss, log_det, q = float(u @ u), 0.0, 0
    else:
        uu = whiten(np.column_stack([x, design]), g)
        uy, ux = uu[:, 0], uu[:, 1:]
        q = ux.shape[1]
        scale = np.sqrt(np.sum(ux ** 2, axis=0))
        uxs = ux / scale
        # normal equations of the unit-scaled columns (a few columns, well conditioned
        # after scaling): cheaper than lstsq's SVD, which under contended multithreaded
        # BLAS cost 20 ms a call (20 s an alignment with harmonics, issue 21 benchmark)
        gram = uxs.T @ uxs
        rhs = uxs.T @ uy
        sol = np.linalg.solve(gram, rhs)
        rss = float(uy @ uy - rhs @ sol)
        if not rss > 1e-10 * float(uy @ uy):  # cancellation: recompute directly
            rss = float(np.sum((uy - uxs @ sol) ** 2))
        log_det = float(np.linalg.slogdet(gram)[1] + 2 * np.sum(np.log(scale)))
    dof = n - q
    v = max(rss, 1e-300) / dof
    return 0.5 * dof * np.log(v) + 0.5 * g.log_det + 0.5 * log_det, v


def fit_component(x, times_s, design=None, start_tau_s: float | None = None):
    """Restricted ML ``(std_ou_nT, tau_s, white_std_nT, at_bound)`` of one residual.

    Searches ``log tau`` and ``logit rho`` (Nelder-Mead from a small grid).
    """
    x = np.asarray(x, dtype=float)
    t = np.asarray(times_s, dtype=float)
    dt_min = float(np.min(np.diff(t))) if t.size > 1 else 1.0
    lo, hi = np.log(0.1 * dt_min), np.log(max(t[-1] - t[0], 10 * dt_min))

    def obj(p):
        lt = float(np.clip(p[0], lo, hi))
        rho = RHO_MAX / (1.0 + np.exp(-p[1]))
        return restricted_nll(lt, rho, x, t, design)[0] + 1e3 * (p[0] - lt) ** 2

    tau0 = start_tau_s if start_tau_s else 30 * dt_min
    starts = [(np.log(tau0) + dl, lr) for dl in (0.0, 1.0) for lr in (-6.0, -3.0)]
    best = min(starts, key=obj)
    res = minimize(obj, np.array(best), method="Nelder-Mead",
                   options={"xatol": 0.01, "fatol": 1e-3, "maxiter": 200})
    lt = float(np.clip(res.x[0], lo, hi))
    rho = RHO_MAX / (1.0 + np.exp(-res.x[1]))
    _, v = restricted_nll(lt, rho, x, t, design)
    return (float(np.sqrt(v * (1 - rho))), float(np.exp(lt)), float(np.sqrt(v * rho)),
            bool(lt > hi - 0.05))


@dataclasses.dataclass(frozen=True)
class OUWhiteNoise:
    """Per-component OU plus white noise model of the residuals.

    Attributes
    ----------
    std_nT : ndarray, shape (3,)
        Standard deviation of the OU part (nT).
    tau_s : ndarray, shape (3,)
        OU correlation time (s).
    white_std_nT : ndarray, shape (3,)
        Standard deviation of the white part (nT).
    effective_n : ndarray, shape (3,)
        Effective number of independent samples for a mean (OU part, median spacing,
        plus the white part's share).
    tau_at_bound : tuple of bool
    """

    std_nT: np.ndarray
    tau_s: np.ndarray
    white_std_nT: np.ndarray
    effective_n: np.ndarray
    tau_at_bound: tuple
    #: The ``noise_model`` name of :func:`magcal.alignment.gls.fit_alignment`.
    kind: ClassVar[str] = "ou+white"

    @property
    def total_var(self) -> np.ndarray:
        """Total variance per component (nT^2)."""
        return self.std_nT ** 2 + self.white_std_nT ** 2

    def gains(self, c: int, times_s) -> Gains:
        """Unit-variance Kalman gains of component ``c``."""
        rho = float(self.white_std_nT[c] ** 2 / self.total_var[c])
        return kalman_gains(times_s, float(self.tau_s[c]), min(rho, RHO_MAX))

    def to_dict(self) -> dict:
        """Plain dictionary keyed by component name."""
        return noise_dict("ornstein-uhlenbeck plus white per component (Kalman likelihood)",
                          self, extra=("white_std_nT",))

    def warning(self) -> str | None:
        """A caution when the noise model cannot be trusted, else None."""
        return noise_warning(self.tau_at_bound, self.effective_n)


def noise_from_components(fits, times_s) -> OUWhiteNoise:
    """:class:`OUWhiteNoise` from per-component :func:`fit_component` tuples."""
    t = np.asarray(times_s, dtype=float)
    std = np.array([f[0] for f in fits])
    tau = np.array([f[1] for f in fits])
    white = np.array([f[2] for f in fits])
    return OUWhiteNoise(std_nT=std, tau_s=tau, white_std_nT=white,
                        effective_n=effective_count(std[:, None], tau[:, None], white, t),
                        tau_at_bound=tuple(f[3] for f in fits))


def simulate(rng: np.random.Generator, times_s, std_nT: float, tau_s: float,
             white_std_nT: float) -> np.ndarray:
    """Draw an OU (``std_nT``, ``tau_s``) plus white (``white_std_nT``) series."""
    from magcal.alignment.noise import simulate_ou

    t = np.asarray(times_s, dtype=float)
    return simulate_ou(rng, t, std_nT, tau_s) + white_std_nT * rng.standard_normal(t.size)


def fit_noise_ouw(residuals, times_s, jacobian=None, start=None) -> OUWhiteNoise:
    """Fit :class:`OUWhiteNoise` to (n, 3) residuals (restricted likelihood per component).

    ``jacobian`` (n, 3, p): per component a basis of its columns is the REML design;
    ``start`` (a previous noise model) seeds the correlation-time search.
    """
    from magcal.alignment.noise import component_basis

    r = np.asarray(residuals, dtype=float)
    t = np.asarray(times_s, dtype=float)
    fits = []
    for c in range(r.shape[1]):
        basis = None if jacobian is None else component_basis(jacobian, c)
        tau0 = None if start is None else float(start.tau_s[c])
        fits.append(fit_component(r[:, c], t, design=basis, start_tau_s=tau0))
    return noise_from_components(fits, t)


def whitened_series(t, resid, jac, noise):
    """Per component, the residual and the Jacobian whitened by the Kalman filter and
    scaled to unit variance: ``([uy_c], [ux_c])``, shapes (n,) and (n, p).

    ``noise`` is any model with ``gains(c, t)`` (whose result has ``whiten``) and
    ``total_var``: :class:`OUWhiteNoise` or
    :class:`~magcal.alignment.twoscale.TwoScaleNoise`.
    """
    ys, xs = [], []
    for c in range(3):
        u = noise.gains(c, t).whiten(np.column_stack([resid[:, c], jac[:, c, :]])) / np.sqrt(noise.total_var[c])
        ys.append(u[:, 0])
        xs.append(u[:, 1:])
    return ys, xs


class WhitenedBase:
    """The data and the regressors' base whitened once per noise model.

    Every column of the alignment model and of its Jacobian (see
    :func:`magcal.alignment.gls.predict_and_jacobian`) is a linear combination of the
    reference's three components, a constant and the local-time harmonics; whitening
    is linear, so a Gauss-Newton step needs only those base columns whitened, combined
    with the step's coefficients (found by least squares on the unwhitened base). A
    Kalman whitening per component costs a pass over the record (0.1-0.3 s on a quarter
    of 1-min samples with gaps); a fit took 15 of them and the quarter's alignment
    60 s, now three per noise model.

    Parameters
    ----------
    t : ndarray, shape (n,)
    d, ref : ndarray, shape (n, 3)
    basis : ndarray, shape (n, 2K) or None
    noise : OUWhiteNoise or TwoScaleNoise
    """

    def __init__(self, t, d, ref, basis, noise):
        n = t.size
        cols = [ref, np.ones((n, 1))]
        if basis is not None and basis.shape[1]:
            cols.append(basis)
        self._base = np.concatenate(cols, axis=1)
        self._checked = False
        # per component the whitened [d_c, base] at unit variance
        self._white = [noise.gains(c, t).whiten(np.column_stack([d[:, c], self._base]))
                       / np.sqrt(noise.total_var[c]) for c in range(3)]

    @functools.cached_property
    def _pinv(self) -> np.ndarray:
        return np.linalg.pinv(self._base)

    def gram(self, c: int) -> np.ndarray:
        """Whitened Gram matrix of ``[d_c, ref, 1, basis]`` of component ``c``."""
        return self._white[c].T @ self._white[c]

    def series(self, mu, jac):
        """``(ys, xs)`` as :func:`whitened_series` for the model ``mu`` (n, 3) and
        Jacobian ``jac`` (n, 3, p)."""
        ys, xs = [], []
        for c in range(3):
            cols = np.column_stack([mu[:, c], jac[:, c, :]])
            coef = self._pinv @ cols
            if not self._checked:
                miss = np.max(np.abs(self._base @ coef - cols))
                if not miss <= 1e-8 * max(float(np.max(np.abs(cols))), 1.0):
                    raise ValueError("the model's columns are not in the span of the "
                                     f"reference, a constant and the harmonics ({miss:.3g})")
            w = self._white[c][:, 1:] @ coef
            ys.append(self._white[c][:, 0] - w[:, 0])
            xs.append(w[:, 1:])
        self._checked = True
        return ys, xs

    def normals(self, mu, jac):
        """GLS normal matrix, right-hand side and objective (whitened residual sum of
        squares) for the model ``mu`` and Jacobian ``jac``."""
        ys, xs = self.series(mu, jac)
        a = sum(x.T @ x for x in xs)
        b = sum(x.T @ y for x, y in zip(xs, ys))
        return a, b, float(sum(y @ y for y in ys))
