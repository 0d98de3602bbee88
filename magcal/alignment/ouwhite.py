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

    ``xhat_t = phi_t (1 - k_t) xhat_{t-1} + k_t y_t``; innovation
    ``y_t - phi_t xhat_{t-1}`` with variance ``f_t`` (times the total variance ``v``).
    """

    phi: np.ndarray
    k: np.ndarray
    f: np.ndarray

    @property
    def log_det(self) -> float:
        """``sum(log f)``: log determinant of the unit-variance covariance."""
        return float(np.sum(np.log(self.f)))

    def whiten(self, x) -> np.ndarray:
        """Standardised innovations of ``x`` (:func:`whiten`)."""
        return whiten(x, self)


#: Samples of a run of equal spacing stepped one at a time before the rest of the run is
#: left to :func:`riccati_variances` (when the gains have not settled by then).
STEPPED = 256

#: Mean run length (samples of equal spacing) below which :func:`kalman_gains` steps the
#: whole record in blocks (:func:`riccati_variances_varying`) instead of run by run: 5 %
#: of the samples missing at random leaves runs of about 20, where the gains never
#: settle and 43,200 samples took 50 ms stepped one at a time.
SHORT_RUNS = 32


def kalman_gains(times_s, tau_s: float, rho: float, tol: float = 1e-14) -> Gains:
    """Kalman gains of an OU (variance ``1 - rho``) plus white (``rho``) series.

    Within a run of equal spacings the gains converge geometrically; once converged
    the rest of the run is filled without iterating, so a regularly sampled record
    costs a few hundred scalar steps whatever its length. Where they converge slowly
    (a nearly white record with a long correlation time: tens of thousands of
    samples, 12 ms a call stepped one at a time), the run's remainder goes to
    :func:`riccati_variances` after :data:`STEPPED` samples.

    Examples
    --------
    Pure OU with unit spacing and time constant: innovation variance ``1 - e^-2``.

    >>> kalman_gains(np.arange(4.0), 1.0, 0.0).f.round(4)
    array([1.    , 0.8647, 0.8647, 0.8647])
    """
    phi = lag_correlation(times_s, tau_s)
    n = phi.size
    s2, w2 = 1.0 - rho, rho
    change = np.flatnonzero(np.diff(phi) != 0) + 1
    if w2 > 0 and change.size > max(n // SHORT_RUNS, 64):
        # scattered gaps: runs too short for the gains to settle, stepped in blocks
        before, _ = riccati_variances_varying(phi, s2, w2, 0.0)
        pm = phi * phi * before + s2 * (1.0 - phi * phi)
        f = pm + w2
        return Gains(phi=phi, k=pm / f, f=np.maximum(f, 1e-300))
    k = np.empty(n)
    f = np.empty(n)
    bounds = np.concatenate([[0], change, [n]])
    p = 0.0
    for j in range(bounds.size - 1):
        i0, i1 = int(bounds[j]), int(bounds[j + 1])
        ph = float(phi[i0])
        q = s2 * (1.0 - ph * ph)
        prev = -1.0
        i = i0
        while i < i1:
            if i - i0 == STEPPED:
                before, p = riccati_variances(ph, i1 - i, s2, w2, p)
                pm = ph * ph * before + q
                f[i:i1] = pm + w2
                k[i:i1] = pm / f[i:i1]
                break
            pm = ph * ph * p + q
            fi = pm + w2
            ki = pm / fi
            p = (1.0 - ki) * pm
            k[i], f[i] = ki, fi
            i += 1
            if abs(ki - prev) <= tol * max(ki, 1e-300) and i < i1:
                k[i:i1], f[i:i1] = ki, fi
                break
            prev = ki
    f = np.maximum(f, 1e-300)
    return Gains(phi=phi, k=k, f=f)


def riccati_variances(phi: float, n: int, s2: float, w2: float, p0: float):
    """Filtered variance of an OU state (stationary variance ``s2``, lag correlation
    ``phi`` between ``n`` equally spaced samples) observed with white noise of variance
    ``w2``, from the variance ``p0``.

    Returns the variance before each sample, shape (n,), and after the last one.

    One step maps the variance ``p`` to ``w2 m / (m + w2)`` with
    ``m = phi^2 p + q``, ``q = s2 (1 - phi^2)``: the Moebius map of the non-negative
    matrix ``M = [[w2 phi^2, w2 q], [phi^2, q + w2]]``. The powers of ``M`` up to about
    sqrt(n) (normalised as they grow, which a Moebius map ignores) give the variance
    at every sample of a block from its start, all blocks at once; a pass over the
    blocks with the block's own power carries the variance from one to the next. All
    entries are non-negative, so nothing cancels: the result is the sequential
    recursion to rounding.

    Examples
    --------
    Unit OU variance, half white noise, uncorrelated samples (``phi = 0``): every
    sample starts from the prior 1, so the variance after it is ``1 * 0.5 / 1.5``.

    >>> before, after = riccati_variances(0.0, 3, 1.0, 0.5, 0.0)
    >>> before.round(4), round(after, 4)
    (array([0.    , 0.3333, 0.3333]), 0.3333)
    """
    q = s2 * (1.0 - phi * phi)
    step = np.array([[w2 * phi * phi, w2 * q], [phi * phi, q + w2]])
    size = max(int(np.ceil(np.sqrt(n))), 1)
    powers = np.empty((size + 1, 2, 2))
    powers[0] = np.eye(2)
    for j in range(size):
        nxt = step @ powers[j]
        powers[j + 1] = nxt / nxt.max()
    nb = -(-n // size)
    starts = np.empty(nb)
    p = float(p0)
    block = powers[size]
    for b in range(nb):
        starts[b] = p
        p = (block[0, 0] * p + block[0, 1]) / (block[1, 0] * p + block[1, 1])
    m = powers[:size]
    before = ((m[None, :, 0, 0] * starts[:, None] + m[None, :, 0, 1])
              / (m[None, :, 1, 0] * starts[:, None] + m[None, :, 1, 1])).reshape(-1)
    # after the last sample: the last block's start carried over its remaining samples
    last = n - (nb - 1) * size
    tail = powers[last]
    s = starts[-1]
    after = float((tail[0, 0] * s + tail[0, 1]) / (tail[1, 0] * s + tail[1, 1]))
    return before[:n], after


def riccati_variances_varying(phi, s2: float, w2: float, p0: float):
    """:func:`riccati_variances` for a lag correlation ``phi`` (n,) that changes from
    sample to sample (scattered gaps: thousands of runs of a few equal spacings each,
    too short for the gains to settle).

    Each sample's step is the Moebius map of its own non-negative matrix; the products
    of these matrices over short blocks are formed for all blocks at once (normalised
    as they grow), a pass over the blocks carries the variance from one to the next,
    and each sample's variance follows from its block's start. All
    entries are non-negative, so nothing cancels: the sequential recursion to rounding.

    Returns the variance before each sample, shape (n,), and after the last one.

    Examples
    --------
    Constant ``phi``: the same variances as :func:`riccati_variances`.

    >>> before, after = riccati_variances_varying(np.full(5, 0.9), 1.0, 0.5, 0.0)
    >>> bool(np.allclose(before, riccati_variances(0.9, 5, 1.0, 0.5, 0.0)[0]))
    True
    """
    ph2 = np.asarray(phi, dtype=float) ** 2
    n = ph2.size
    # a block step (one batched product) costs about 60 carries of a block start (plain
    # floats): blocks of sqrt(n / 60) samples balance the two
    size = max(int(np.ceil(np.sqrt(n / 60.0))), 1)
    nb = -(-n // size)
    q = s2 * (1.0 - ph2)
    step = np.empty((nb * size, 2, 2))
    step[:n, 0, 0], step[:n, 0, 1] = w2 * ph2, w2 * q
    step[:n, 1, 0], step[:n, 1, 1] = ph2, q + w2
    step[n:] = np.eye(2)  # padding: the identity map
    step = step.reshape(nb, size, 2, 2)
    prefix = np.empty((nb, size + 1, 2, 2))
    prefix[:, 0] = np.eye(2)
    for j in range(size):
        nxt = step[:, j] @ prefix[:, j]
        prefix[:, j + 1] = nxt / nxt.max(axis=(1, 2), keepdims=True)
    starts = np.empty(nb)
    p = float(p0)
    for b, (a, bb, c, d) in enumerate(prefix[:, size].reshape(nb, 4).tolist()):
        starts[b] = p
        p = (a * p + bb) / (c * p + d)
    m = prefix[:, :size]
    s = starts[:, None]
    before = ((m[..., 0, 0] * s + m[..., 0, 1]) / (m[..., 1, 0] * s + m[..., 1, 1]))
    return before.reshape(-1)[:n], float(p)


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
    e = kalman_innovations(y, gains.phi[:, None], gains.k[:, None],
                           constant_runs(gains.phi, gains.k))
    u = e / np.sqrt(gains.f)[:, None]
    return u[:, 0] if one else u


def constant_runs(*series, min_length: int = 2) -> tuple:
    """``(start, stop)`` ranges of at least ``min_length`` samples over which every one
    of the equally long ``series`` is constant."""
    n = len(series[0])
    change = np.zeros(max(n - 1, 0), dtype=bool)
    for x in series:
        change |= np.diff(x) != 0
    bounds = np.concatenate([[0], np.flatnonzero(change) + 1, [n]])
    # the runs' lengths filtered in numpy: a record with scattered gaps has tens of
    # thousands of bounds, of which few start a run long enough
    keep = np.diff(bounds) >= min_length
    return tuple(zip(bounds[:-1][keep].tolist(), bounds[1:][keep].tolist()))


#: Stretches up to this long are stepped one sample at a time (a block's or a
#: diagonalisation's set-up costs more).
STEP_ONE_BY_ONE = 64


def kalman_innovations(y, phi, k, steady=()) -> np.ndarray:
    """Innovations of a Kalman filter with a diagonal transition and known gains.

    ``e_i = y_i - sum_r phi_ir s_(i-1)r`` and ``s_i = diag(phi_i) s_(i-1) + k_i e_i``
    from a zero state, for every column of ``y`` (n, m); ``phi`` and ``k`` are (n, d)
    (d states observed through their sum). ``steady`` lists sorted ``(start, stop)``
    ranges over which ``phi`` and ``k`` are constant: there the recursion is a
    constant linear filter, diagonalised into d first-order ``lfilter`` passes (when
    longer than :data:`STEP_ONE_BY_ONE`). The samples between them (the transients
    after gaps, which fill a quiet-time selection, or a whole nearly white record
    whose gains settle too slowly) go to :func:`_varying_block`.

    Examples
    --------
    One state, ``k = 0``: the innovation is ``y`` minus the decayed previous state,
    which stays zero; ``k = 1``: the previous sample decayed by ``phi``.

    >>> y = np.array([[1.0], [2.0], [3.0]])
    >>> kalman_innovations(y, np.full((3, 1), 0.5), np.zeros((3, 1)))[:, 0]
    array([1., 2., 3.])
    >>> kalman_innovations(y, np.full((3, 1), 0.5), np.ones((3, 1)), ((0, 3),))[:, 0]
    array([1. , 1.5, 2. ])
    """
    y = np.asarray(y, dtype=float)
    phi, k = np.asarray(phi, dtype=float), np.asarray(k, dtype=float)
    n, m = y.shape
    e = np.empty((n, m))
    state = np.zeros((phi.shape[1], m))
    i = 0
    # a short constant run costs more diagonalised than stepped with its neighbours
    steady = [(i0, i1) for i0, i1 in steady if i1 - i0 > STEP_ONE_BY_ONE]
    for i0, i1 in (*steady, (n, n)):
        if i0 > i:
            e[i:i0], state = _varying_block(y[i:i0], phi[i:i0], k[i:i0], state)
        if i1 > i0:
            e[i0:i1], state = _steady_block(y[i0:i1], state, phi[i0], k[i0])
        i = max(i, i1)
    return e


def _steady_block(y, state, phi, k):
    """Innovations of a run with constant gains: ``m_t = A m_(t-1) + k y_t`` with
    ``A = (I - k h) diag(phi)``, diagonalised (``A = V diag(lam) V^-1``) into first-order
    recursions of ``z = V^-1 m``; the innovation is ``y_t - h diag(phi) V z_(t-1)``."""
    d = phi.size
    a = (np.eye(d) - np.outer(k, np.ones(d))) * phi[None, :]
    lam, vec = np.linalg.eig(a)
    if not np.any(np.iscomplex(lam)):  # the usual case: real roots in (0, 1)
        lam, vec = lam.real, vec.real
    vinv = np.linalg.inv(vec)
    b = vinv @ k
    z0 = vinv @ state
    c = phi @ vec
    yy = y.astype(lam.dtype, copy=False)
    e = yy.copy()
    e[0] -= c @ z0
    last = np.empty_like(z0)
    for j in range(d):
        z = lfilter([b[j]], [1.0, -lam[j]], yy, axis=0, zi=(lam[j] * z0[j])[None, :])[0]
        e[1:] -= c[j] * z[:-1]
        last[j] = z[-1]
    return np.real(e), np.real(vec @ last)


def _varying_block(y, phi, k, state):
    """Innovations and final state of the recursion of :func:`kalman_innovations` over
    samples whose gains change from one to the next, from ``state`` (d, m).

    The recursion is linear in its start, so the stretch is cut into about sqrt(n)
    blocks stepped side by side: each block from a zero state, together with the
    response of its innovations to a unit start; one pass over the blocks then chains
    the starts and adds their response. sqrt(n) vectorised steps instead of n scalar
    ones (a nearly white 20 000-sample record took 80 ms stepped one at a time).
    """
    n, m = y.shape
    d = phi.shape[1]
    if n <= STEP_ONE_BY_ONE:
        # s_i = A_i s_(i-1) + k_i y_i with A_i = (I - k_i h) diag(phi_i); then the
        # innovations at once from the states before each sample
        trans = (np.eye(d)[None] - k[:, :, None]) * phi[:, None, :]
        drive = k[:, :, None] * y[:, None, :]
        before = np.empty((n, d, m))
        for i in range(n):
            before[i] = state
            state = trans[i] @ state + drive[i]
        return y - np.einsum("ir,irm->im", phi, before), state
    size = int(np.ceil(np.sqrt(n)))
    nb = -(-n // size)
    pad = nb * size - n
    # padded samples (phi = 1, k = 0, y = 0) leave the last block's state as it is
    ph = np.concatenate([phi, np.ones((pad, d))]).reshape(nb, size, d)
    kk = np.concatenate([k, np.zeros((pad, d))]).reshape(nb, size, d)
    yy = np.concatenate([y, np.zeros((pad, m))]).reshape(nb, size, m)
    part = np.zeros((nb, d, m))                              # state from a zero start
    trans = np.broadcast_to(np.eye(d), (nb, d, d)).copy()    # state per unit start
    e = np.empty((nb, size, m))
    g = np.empty((nb, size, d))                              # innovation per unit start
    for j in range(size):
        pj, kj = ph[:, j, :, None], kk[:, j, :, None]
        pred = pj * part
        ej = yy[:, j] - pred.sum(axis=1)
        e[:, j] = ej
        part = pred + kj * ej[:, None, :]
        ptr = pj * trans
        gj = ptr.sum(axis=1)
        g[:, j] = gj
        trans = ptr - kj * gj[:, None, :]
    start = np.empty((nb, d, m))
    for b in range(nb):
        start[b] = state
        state = trans[b] @ state + part[b]
    e -= np.einsum("bjr,brm->bjm", g, start)
    return e.reshape(nb * size, m)[:n], state


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
        u = (noise.gains(c, t).whiten(np.column_stack([resid[:, c], jac[:, c, :]]))
             / np.sqrt(noise.total_var[c]))
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
