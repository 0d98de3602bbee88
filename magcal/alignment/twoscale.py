"""Two Ornstein-Uhlenbeck time scales plus white noise: Kalman whitening, Whittle fit.

A model's miss of the field is rarely one OU process: the demo's residual has a fast
part (minutes, substorm and wave fields the model lacks) and a slow one (hours to
days, the ring current and local-time fields), and power-law (1/f^a) residuals are a
continuum of scales. With one time scale the GLS whitening fits neither: on 1/f^2
noise the efficient estimate under OU + white scattered 1.24-1.31x the Cramer-Rao
bound, under two OU scales plus white 1.05-1.10x (issue 21, oracle parameters).

Each component is ``x1 + x2 + w``: OU parts with variances ``v1, v2`` and correlation
times ``tau1 < tau2``, ``w`` white with variance ``vw``. The state ``(x1, x2)`` has a
diagonal transition, so the exact Kalman filter needs only a 2x2 Riccati recursion
(data independent, computed once per noise model; within a run of equal spacing the
gains converge and are filled in at once). The innovations are then a constant linear
recursion, diagonalised into two first-order ``lfilter`` passes; the transients between
(the record's start and the samples after each gap) are stepped in about sqrt(n)
blocks side by side (:func:`magcal.alignment.ouwhite.kalman_innovations`).

The noise parameters are fitted by the debiased Whittle likelihood (Sykulski et al.
2019, JRSS B 81, 251): the residual's periodogram on its sampling grid, gaps zero
filled, against the expected periodogram of the model under the same gaps (the
autocovariance times the sampling mask's autocorrelation, Fourier transformed; each
OU part's expectation is tabulated over its correlation time once per sampling and
interpolated, :class:`_OUSpectra`). That costs milliseconds where the exact
likelihood's transients cost seconds, and the fit only has to be good enough for
efficient whitening: the stated covariance is the spectral sandwich
(:mod:`magcal.alignment.sandwich`), which does not rest on it.
"""

from __future__ import annotations

import dataclasses
import math
from typing import ClassVar

import numpy as np
import scipy.fft

from magcal.alignment.neldermead import nelder_mead
from magcal.alignment.noise import COMPONENTS, effective_count, noise_warning
from magcal.alignment.ouwhite import as_columns, kalman_innovations

#: Smallest ratio of the slow to the fast correlation time (keeps the two scales apart
#: and the steady-state recursion diagonalisable).
MIN_RATIO = 1.5
#: Smallest share of the total variance of each part (keeps every part positive).
MIN_SHARE = 1e-6
#: Grid points per periodogram segment of the Whittle fit (longer records are cut).
SEGMENT = 2 ** 15


@dataclasses.dataclass(frozen=True)
class StateGains:
    """Data-independent Kalman quantities of a unit-variance two-scale model.

    Per sample ``i``: the transitions ``phi[i]`` (2,) of the two OU states from the
    previous sample, the gain ``k[i]`` (2,) and the innovation variance ``f[i]``.
    ``steady`` lists the ``(start, stop)`` sample ranges over which the gains are
    constant (filtered in closed form); all other samples are stepped one at a time.
    """

    phi: np.ndarray
    k: np.ndarray
    f: np.ndarray
    steady: tuple

    @property
    def log_det(self) -> float:
        """``sum(log f)``: log determinant of the unit-variance covariance."""
        return float(np.sum(np.log(self.f)))

    def whiten(self, x) -> np.ndarray:
        """Standardised innovations of ``x`` (n,) or the columns of ``x`` (n, m)."""
        return whiten_state(x, self)


def state_gains(times_s, tau_s, share, tol: float = 1e-12) -> StateGains:
    """Kalman gains of a unit-variance series ``x1 + x2 + w``.

    Parameters
    ----------
    times_s : array_like, shape (n,)
        Strictly increasing sample times (s).
    tau_s : (float, float)
        Correlation times of the two OU parts (s), distinct.
    share : (float, float, float)
        Variance shares of the two OU parts and the white part (sum 1).

    Examples
    --------
    With the second and white parts absent this is the plain OU filter: innovation
    variance ``1 - exp(-2 dt / tau)`` after the first sample.

    >>> g = state_gains(np.arange(4.0), (1.0, 10.0), (1.0, 0.0, 0.0))
    >>> g.f.round(4)
    array([1.    , 0.8647, 0.8647, 0.8647])
    """
    t = np.asarray(times_s, dtype=float)
    n = t.size
    dt = np.diff(t)
    phi = np.zeros((n, 2))
    phi[1:, 0] = np.exp(-dt / tau_s[0])
    phi[1:, 1] = np.exp(-dt / tau_s[1])
    v1, v2, vw = (float(s) for s in share)
    k = np.empty((n, 2))
    f = np.empty(n)
    change = np.flatnonzero(np.any(np.diff(phi, axis=0) != 0, axis=1)) + 1
    bounds = np.concatenate([[0], change, [n]]).astype(int)
    steady = []
    p11 = p12 = p22 = 0.0
    for j in range(bounds.size - 1):
        i0, i1 = int(bounds[j]), int(bounds[j + 1])
        a1, a2 = float(phi[i0, 0]), float(phi[i0, 1])
        q1, q2 = v1 * (1.0 - a1 * a1), v2 * (1.0 - a2 * a2)
        prev1 = prev2 = np.inf
        i = i0
        while i < i1:
            m11 = a1 * a1 * p11 + q1
            m12 = a1 * a2 * p12
            m22 = a2 * a2 * p22 + q2
            s = m11 + 2.0 * m12 + m22 + vw
            k1, k2 = (m11 + m12) / s, (m12 + m22) / s
            p11, p12, p22 = m11 - k1 * k1 * s, m12 - k1 * k2 * s, m22 - k2 * k2 * s
            k[i, 0], k[i, 1], f[i] = k1, k2, s
            i += 1
            if (i < i1 and abs(k1 - prev1) <= tol * (abs(k1) + 1e-300)
                    and abs(k2 - prev2) <= tol * (abs(k2) + 1e-300)):
                k[i:i1] = (k1, k2)
                f[i:i1] = s
                steady.append((i, i1))
                break
            prev1, prev2 = k1, k2
    return StateGains(phi=phi, k=k, f=np.maximum(f, 1e-300), steady=tuple(steady))


def whiten_state(x, gains: StateGains) -> np.ndarray:
    """Standardised innovations of ``x`` under :class:`StateGains` (see ``whiten``).

    Examples
    --------
    A simulated two-scale series whitens to unit variance.

    >>> rng = np.random.default_rng(1)
    >>> t = np.arange(20000.0) * 60.0
    >>> x = simulate(rng, t, (600.0, 21600.0), (1.0, 2.0, 0.2))
    >>> g = state_gains(t, (600.0, 21600.0), np.array([1.0, 4.0, 0.04]) / 5.04)
    >>> round(float(np.std(whiten_state(x, g)) / np.sqrt(5.04)), 1)
    1.0
    """
    y, one = as_columns(x)
    u = kalman_innovations(y, gains.phi, gains.k, gains.steady) / np.sqrt(gains.f)[:, None]
    return u[:, 0] if one else u


def simulate(rng: np.random.Generator, times_s, tau_s, std_nT) -> np.ndarray:
    """Draw ``x1 + x2 + w``: OU parts of std ``std_nT[:2]`` and times ``tau_s``, white
    of std ``std_nT[2]``, exactly at ``times_s``."""
    from magcal.alignment.noise import simulate_ou

    t = np.asarray(times_s, dtype=float)
    return (simulate_ou(rng, t, std_nT[0], tau_s[0]) + simulate_ou(rng, t, std_nT[1], tau_s[1])
            + std_nT[2] * rng.standard_normal(t.size))


def sampling_grid(times_s) -> tuple[float, np.ndarray]:
    """Median spacing and each sample's index on that grid (duplicates dropped later)."""
    t = np.asarray(times_s, dtype=float)
    dt = float(np.median(np.diff(t))) if t.size > 1 else 1.0
    return dt, np.rint((t - t[0]) / dt).astype(np.int64)


@dataclasses.dataclass(frozen=True)
class WhittleData:
    """A residual's periodogram on its sampling grid and what the expectation needs."""

    dt: float
    periodogram: np.ndarray   # I_k, k = 1 .. N // 2 (nT^2)
    mask_acf: np.ndarray      # g(lag), lag = 0 .. N - 1
    kept: np.ndarray          # 1 - h_k: share of power the fitted regressors leave
    lag: np.ndarray           # lag in seconds, 0 .. (N - 1) dt

    @classmethod
    def from_residual(cls, x, times_s, design=None,
                      segment: int = SEGMENT) -> "WhittleData":
        """Grid, zero-fill and Fourier-transform one residual component.

        Records longer than 1.5 ``segment`` grid points are cut into equal segments
        whose periodograms are summed (Bartlett): the expectation stays exact (the
        mask autocorrelations are summed alike) and each likelihood evaluation costs
        one FFT of a segment instead of the record (a quarter of 1-min data: 4x
        faster), at the price of frequencies below one per segment (23 days at 1 min).
        """
        x = np.asarray(x, dtype=float)
        dt, idx = sampling_grid(times_s)
        idx, first = np.unique(idx, return_index=True)
        x = x[first]
        big = int(idx[-1]) + 1
        n_seg = 1 if big <= 1.5 * segment else int(np.ceil(big / segment))
        length = int(np.ceil(big / n_seg))
        mask = np.zeros(n_seg * length)
        mask[idx] = 1.0
        grid = np.zeros(n_seg * length)
        grid[idx] = x
        mask, grid = mask.reshape(n_seg, length), grid.reshape(n_seg, length)
        nm = mask.sum()
        half = slice(1, length // 2 + 1)
        per = np.sum(np.abs(np.fft.rfft(grid, axis=1)[:, half]) ** 2, axis=0) / nm
        pad = np.fft.rfft(mask, 2 * length, axis=1)
        acf = np.sum(np.fft.irfft(np.abs(pad) ** 2, 2 * length, axis=1)[:, :length],
                     axis=0) / nm
        kept = np.ones(per.size)
        if design is not None and design.shape[1]:
            q, _ = np.linalg.qr(design[first])
            qg = np.zeros((n_seg * length, q.shape[1]))
            qg[idx] = q
            ft = np.fft.rfft(qg.reshape(n_seg, length, -1), axis=1)[:, half]
            # OLS leverage per frequency: the share of white power the regressors take
            lev = np.sum(np.abs(ft) ** 2, axis=(0, 2)) / nm
            kept = np.clip(1.0 - lev, 0.0, 1.0)
        return cls(dt=dt, periodogram=per, mask_acf=acf, kept=kept,
                   lag=np.arange(length) * dt)

    def expected(self, tau_s, share) -> np.ndarray:
        """Expected periodogram (unit total variance) of the two-scale model under the
        sampling mask, at the periodogram's frequencies."""
        c = share[0] * self._decay(tau_s[0]) + share[1] * self._decay(tau_s[1])
        c[0] += share[2]
        return self._spectrum(c)

    def _spectrum(self, c: np.ndarray) -> np.ndarray:
        """Expected periodogram of the autocovariance ``c`` (one value a lag) under the
        sampling mask, at the periodogram's frequencies."""
        cg = c * self.mask_acf
        spec = 2.0 * scipy.fft.rfft(cg).real - cg[0]
        return spec[1:self.periodogram.size + 1]

    def _decay(self, tau_s: float) -> np.ndarray:
        """``exp(-lag / tau_s)``: directly up to :data:`_DIRECT` lags, else by :func:`decay`."""
        if self.lag.size <= _DIRECT:
            return np.exp(-self.lag / tau_s)
        return decay(self.dt, tau_s, self.lag.size)


#: Up to this many lags the expected periodogram takes the exponentials directly
#: (:func:`decay` is no faster there).
_DIRECT = 4096


def decay(dt: float, tau: float, n: int) -> np.ndarray:
    """``exp(-k dt / tau)`` for ``k = 0 .. n - 1``, as the outer product of two series of
    about sqrt(n) exponentials: one multiplication a lag instead of one exponential on
    long records (the Whittle likelihood's hot path); equal to the direct exponentials
    to 1e-12 (relative).

    Examples
    --------
    >>> np.allclose(decay(60.0, 6e4, 10000), np.exp(-np.arange(10000) * 60.0 / 6e4),
    ...             rtol=1e-12, atol=0)
    True
    """
    block = max(int(np.ceil(np.sqrt(n))), 1)
    within = np.exp(-np.arange(block) * (dt / tau))
    across = np.exp(-np.arange(-(-n // block)) * (block * dt / tau))
    return np.multiply.outer(across, within).ravel()[:n]


#: Range of the unbounded shape parameters (beyond it a share is ~1e-5 of the largest).
LOGIT = 12.0


def _outside(p, lo: float, hi: float) -> float:
    """Squared distance of ``p`` from the box :func:`_unpack` clips it to: a penalty that
    brings the simplex back instead of letting it drift along a flat direction (a share
    at its floor), which cost up to 1300 evaluations per fit."""
    total = 0.0
    for value, low, high in zip(p, (lo, -LOGIT, -LOGIT, -LOGIT), (hi, LOGIT, LOGIT, LOGIT)):
        value = float(value)
        total += max(low - value, 0.0) ** 2 + max(value - high, 0.0) ** 2
    return total


def _clip(value, low: float, high: float) -> float:
    """``np.clip`` of one number, without its array overhead (the objective's hot path)."""
    return min(max(float(value), low), high)


def _unpack(p, lo: float, hi: float):
    """Shape parameters -> ((tau1, tau2), shares): log tau1, log of tau2 / tau1 above
    MIN_RATIO, two softmax logits of the shares (the white part's logit is 0).

    Scalar arithmetic through :mod:`math` (the objective's hot path: a few hundred calls
    a fit), the same formulas as the array form it replaced."""
    lt1 = _clip(p[0], lo, hi)
    g = _clip(p[1], -LOGIT, LOGIT)
    soft = max(g, 0.0) + math.log1p(math.exp(-abs(g)))
    lt2 = min(lt1 + _LOG_RATIO + soft, hi + _LOG_RATIO)
    z0, z1 = _clip(p[2], -LOGIT, LOGIT), _clip(p[3], -LOGIT, LOGIT)
    top = max(z0, z1, 0.0)
    w0, w1, w2 = math.exp(z0 - top), math.exp(z1 - top), math.exp(-top)
    total, free = w0 + w1 + w2, 1 - 3 * MIN_SHARE
    share = np.array([MIN_SHARE + free * w0 / total, MIN_SHARE + free * w1 / total,
                      MIN_SHARE + free * w2 / total])
    return (math.exp(lt1), math.exp(lt2)), share


_LOG_RATIO = math.log(MIN_RATIO)


def _pack(tau_s, share) -> np.ndarray:
    """Inverse of :func:`_unpack` (for starting points)."""
    t1, t2 = float(tau_s[0]), float(tau_s[1])
    sh = np.maximum(np.asarray(share, dtype=float), MIN_SHARE)
    return np.array([np.log(t1), np.log(max(np.expm1(np.log(max(t2 / t1 / MIN_RATIO, 1.0))),
                                            1e-6)),
                     np.log(sh[0] / sh[2]), np.log(sh[1] / sh[2])])


#: Spacing in log tau of the tabulated OU spectra (:class:`_OUSpectra`): their cubic
#: interpolation is within 5e-8 (relative) of the exact expected periodogram.
LOG_TAU_STEP = 0.025


def _weights(s: float) -> tuple:
    """Cubic Lagrange weights of the grid points -1, 0, 1, 2 at ``0 <= s < 1``."""
    return (-s * (s - 1) * (s - 2) / 6, (s + 1) * (s - 1) * (s - 2) / 2,
            -(s + 1) * s * (s - 2) / 2, (s + 1) * s * (s - 1) / 6)


class _OUSpectra:
    """Expected periodograms of a unit-variance OU part under one sampling mask,
    tabulated on the grid ``log tau = j * LOG_TAU_STEP`` (rows computed when first
    needed) and interpolated in log tau by cubic Lagrange polynomials.

    The exact expectation costs two exponentials and an FFT over every lag per
    likelihood evaluation; the searches of a record visit one to two hundred grid rows
    (the demo's records: 163 on average), after which each evaluation is two weighted
    sums of four rows (:class:`_Whittle`). The rows depend on
    the sampling only, so the three components of one record share them. Within 5e-8
    (relative) of :meth:`WhittleData.expected` (about 1e-4 in the negative
    log-likelihood of a day of 1-min data, below the search's tolerance of 0.05).
    """

    def __init__(self, data: WhittleData):
        self.data = data
        self.rows: dict[int, np.ndarray] = {}
        self.white = float(data.mask_acf[0])

    def row(self, j: int) -> np.ndarray:
        """Grid row ``j``: the expected periodogram at ``tau = exp(j * LOG_TAU_STEP)``."""
        row = self.rows.get(j)
        if row is None:
            row = self.rows[j] = self.data._spectrum(
                self.data._decay(math.exp(j * LOG_TAU_STEP)))
        return row


class _Whittle:
    """The profile Whittle likelihood of one :class:`WhittleData`, with what every
    evaluation shares (the frequencies kept, their periodogram and leverage) selected
    once: Nelder-Mead calls it a few hundred times per fit.

    ``spectra`` (the tabulated OU spectra of the same sampling) makes each evaluation a
    table look-up: this component's copy of a grid row, its frequencies selected and
    scaled by their leverage, is made when first needed, and an evaluation is two
    four-row products. Without it the expectation is computed exactly
    (:meth:`WhittleData.expected`).
    """

    def __init__(self, data: WhittleData, lo: float, hi: float,
                 spectra: _OUSpectra | None = None):
        self.data, self.lo, self.hi = data, lo, hi
        use = data.kept > 0.5
        self.use = None if use.all() else use
        self.periodogram = data.periodogram[use]
        self.kept = data.kept[use]
        self.n_use = int(use.sum())
        self._buf = np.empty(self.n_use)
        self.spectra = spectra
        if spectra is not None:
            # grid rows of every time the search box allows (and the stencils' margins);
            # only the rows a search visits are written, so only their pages are used
            self.j0 = math.floor(lo / LOG_TAU_STEP) - 3
            size = math.floor((hi + _LOG_RATIO) / LOG_TAU_STEP) + 6 - self.j0
            self.table = np.empty((size, self.n_use))
            self.filled = bytearray(size)
            self.white = spectra.white * self.kept

    def _stencil(self, tau_s: float):
        """Interpolation weights and this component's four grid rows around ``tau_s``."""
        f = math.log(tau_s) / LOG_TAU_STEP
        i = math.floor(f)
        s = f - i
        k = i - 1 - self.j0
        if k < 0 or k + 4 > len(self.filled):
            raise ValueError(f"tau = {tau_s:g} s is outside the search box's table")
        for r in range(k, k + 4):
            if not self.filled[r]:
                row = self.spectra.row(r + self.j0)
                self.table[r] = (row if self.use is None else row[self.use]) * self.kept
                self.filled[r] = 1
        return _weights(s), self.table[k:k + 4]

    def __call__(self, p) -> tuple[float, float]:
        """Negative log-likelihood and the fitted total variance at ``p``."""
        tau, share = _unpack(p, self.lo, self.hi)
        if self.spectra is None:
            spec = self.data.expected(tau, share)
            if self.use is not None:
                spec = spec[self.use]
            s = spec * self.kept
        else:
            w1, rows1 = self._stencil(tau[0])
            w2, rows2 = self._stencil(tau[1])
            a, b = float(share[0]), float(share[1])
            s = np.dot([a * w for w in w1], rows1)
            s += np.dot([b * w for w in w2], rows2)
            s += float(share[2]) * self.white
        # in place and reduced by np.add.reduce: the same pairwise sums as .mean() and
        # .sum(), without their temporaries and wrappers (a fifth of an evaluation)
        np.maximum(s, 1e-300, out=s)
        v = float(np.add.reduce(np.divide(self.periodogram, s, out=self._buf)) / self.n_use)
        return float(self.n_use * np.log(max(v, 1e-300)) + np.add.reduce(np.log(s, out=s))), v


def whittle_objective(p, data: WhittleData, lo: float, hi: float) -> tuple[float, float]:
    """Profile debiased-Whittle negative log-likelihood and the fitted total variance
    (the exact expectation)."""
    return _Whittle(data, lo, hi)(p)


def fit_component(x, times_s, design=None, start=None):
    """Debiased-Whittle fit of one residual component.

    Returns
    -------
    (std_nT, tau_s, at_bound)
        ``std_nT`` (3,): fast OU, slow OU and white standard deviations (nT);
        ``tau_s`` (2,): the two correlation times (s); ``at_bound``: the slow time
        reached the span of the record (or of its Bartlett segments).
    """
    data = WhittleData.from_residual(x, times_s, design)
    return _fit_whittle(data, _OUSpectra(data), start)


def _span(data: WhittleData) -> float:
    """The record's (or its segments') span in seconds, at least ten spacings."""
    return max(float(data.lag[-1]), 10 * data.dt)


def search_box(data: WhittleData) -> tuple[float, float]:
    """Range ``(lo, hi)`` of the fast time's log (s) in the fit: a tenth of the spacing
    to the span (:func:`_span`)."""
    return np.log(0.1 * data.dt), np.log(_span(data))


def _fit_whittle(data: WhittleData, spectra: _OUSpectra, start=None):
    """:func:`fit_component` of a residual's :class:`WhittleData`, with the tabulated
    OU spectra of its sampling."""
    span, (lo, hi) = _span(data), search_box(data)
    likelihood = _Whittle(data, lo, hi, spectra)

    def obj(p):
        return likelihood(p)[0] + 1e3 * _outside(p, lo, hi)

    # Nelder-Mead from the two best points of a small grid: from a single one it stopped
    # in a local optimum (an 8-day slow part of 9 nT for a 6 h one of 2 nT) in 1 of 5
    # records; from a previous fit (the alignment's next noise iteration) once.
    # Tolerances: a change of 0.05 in the log-likelihood moves nothing that matters.
    opts = {"xatol": 0.02, "fatol": 0.05, "maxiter": 800}
    if start is not None:
        # a previous fit is near the optimum: a simplex of 0.1 in each (log) parameter
        # instead of scipy's 5 % of it (3x fewer evaluations)
        p0 = _pack(*start)
        simplex = np.vstack([p0, p0 + 0.1 * np.eye(p0.size)])
        fits = [nelder_mead(obj, p0, simplex=simplex, maxfev=300, **opts)]
    else:
        starts = [_pack((m1 * data.dt, t2), (0.3, 0.6, 0.1))
                  for m1 in (2.0, 10.0) for t2 in (50 * data.dt, 500 * data.dt, span / 5)
                  if t2 > MIN_RATIO * m1 * data.dt]
        fits = [nelder_mead(obj, p0, **opts) for p0 in sorted(starts, key=obj)[:2]]
    res = min(fits, key=lambda f: f.fun)
    tau, share = _unpack(res.x, lo, hi)
    v = likelihood(res.x)[1]
    return np.sqrt(v * share), np.array(tau), bool(np.log(tau[1]) > hi - 0.05)


@dataclasses.dataclass(frozen=True)
class TwoScaleNoise:
    """Per-component two-scale OU plus white noise model of the residuals.

    Attributes
    ----------
    fast_std_nT, slow_std_nT, white_std_nT : ndarray, shape (3,)
        Standard deviations of the fast OU, slow OU and white parts (nT).
    fast_tau_s, slow_tau_s : ndarray, shape (3,)
        Correlation times of the two OU parts (s).
    effective_n : ndarray, shape (3,)
        Effective number of independent samples for a mean.
    tau_at_bound : tuple of bool
        The slow time reached the record's span.
    """

    fast_std_nT: np.ndarray
    slow_std_nT: np.ndarray
    white_std_nT: np.ndarray
    fast_tau_s: np.ndarray
    slow_tau_s: np.ndarray
    effective_n: np.ndarray
    tau_at_bound: tuple
    #: The ``noise_model`` name of :func:`magcal.alignment.gls.fit_alignment`.
    kind: ClassVar[str] = "ou+ou+white"

    @property
    def std_nT(self) -> np.ndarray:
        """Standard deviation of the two OU parts together (nT)."""
        return np.hypot(self.fast_std_nT, self.slow_std_nT)

    @property
    def tau_s(self) -> np.ndarray:
        """The slow correlation time (s): the one that sets the effective sample count."""
        return self.slow_tau_s

    @property
    def total_var(self) -> np.ndarray:
        """Total variance per component (nT^2)."""
        return self.fast_std_nT ** 2 + self.slow_std_nT ** 2 + self.white_std_nT ** 2

    def gains(self, c: int, times_s) -> StateGains:
        """Unit-variance Kalman gains of component ``c``."""
        share = np.array([self.fast_std_nT[c], self.slow_std_nT[c],
                          self.white_std_nT[c]]) ** 2 / self.total_var[c]
        return state_gains(times_s, (float(self.fast_tau_s[c]), float(self.slow_tau_s[c])),
                           share)

    def to_dict(self) -> dict:
        """Plain dictionary keyed by component name."""
        out = {"model": "two ornstein-uhlenbeck time scales plus white per component "
                        "(Kalman whitening, debiased Whittle fit)"}
        for name in ("std_nT", "tau_s", "fast_std_nT", "fast_tau_s", "slow_std_nT",
                     "slow_tau_s", "white_std_nT", "effective_n"):
            out[name] = dict(zip(COMPONENTS, map(float, getattr(self, name))))
        out["tau_at_bound"] = dict(zip(COMPONENTS, map(bool, self.tau_at_bound)))
        out["warning"] = self.warning()
        return out

    def warning(self) -> str | None:
        """A caution when the noise model cannot be trusted, else None."""
        return noise_warning(self.tau_at_bound, self.effective_n)

    def start(self, c: int):
        """Component ``c``'s parameters as a starting point of :func:`fit_component`."""
        share = np.array([self.fast_std_nT[c], self.slow_std_nT[c],
                          self.white_std_nT[c]]) ** 2 / self.total_var[c]
        return (float(self.fast_tau_s[c]), float(self.slow_tau_s[c])), share


def fit_noise_two_scale(residuals, times_s, jacobian=None, start=None) -> TwoScaleNoise:
    """Fit :class:`TwoScaleNoise` to (n, 3) residuals (debiased Whittle per component).

    ``jacobian`` (n, 3, p): the fitted model's derivatives, whose frequencies the
    residual lacks (their leverage corrects the expected periodogram); ``start`` (a
    previous :class:`TwoScaleNoise`) seeds the search. :class:`TwoScaleFitter` does the
    same and keeps the tabulated spectra for the next fit of the same sampling.
    """
    return _fit_noise(residuals, times_s, jacobian, start, None)[0]


class TwoScaleFitter:
    """:func:`fit_noise_two_scale` that keeps the tabulated OU spectra
    (:class:`_OUSpectra`) of the last sampling it fitted: the noise fits of one
    alignment (three per Gauss-Newton fit, on the same times) then compute each grid
    row once instead of once per fit. The results are those of separate calls, to the
    bit; a call on other times starts a new table.
    """

    def __init__(self):
        self._times: np.ndarray | None = None
        self._spectra: _OUSpectra | None = None

    def __call__(self, residuals, times_s, jacobian=None, start=None) -> TwoScaleNoise:
        t = np.asarray(times_s, dtype=float)
        if self._times is None or not np.array_equal(t, self._times):
            self._times, self._spectra = t.copy(), None
        noise, self._spectra = _fit_noise(residuals, t, jacobian, start, self._spectra)
        return noise


def _fit_noise(residuals, times_s, jacobian, start, spectra):
    """:func:`fit_noise_two_scale` with the tabulated spectra ``spectra`` of the same
    sampling (None: made from the first component): ``(noise, spectra)``."""
    from magcal.alignment.noise import component_basis

    r = np.asarray(residuals, dtype=float)
    t = np.asarray(times_s, dtype=float)
    fits = []
    for c in range(r.shape[1]):
        basis = None if jacobian is None else component_basis(jacobian, c)
        data = WhittleData.from_residual(r[:, c], t, basis)
        # one sampling for every component: the tabulated OU spectra are shared
        spectra = _OUSpectra(data) if spectra is None else spectra
        fits.append(_fit_whittle(data, spectra, None if start is None else start.start(c)))
    std = np.array([f[0] for f in fits])
    tau = np.array([f[1] for f in fits])
    n_eff = effective_count(std[:, :2], tau, std[:, 2], t)
    return TwoScaleNoise(fast_std_nT=std[:, 0], slow_std_nT=std[:, 1], white_std_nT=std[:, 2],
                         fast_tau_s=tau[:, 0], slow_tau_s=tau[:, 1], effective_n=n_eff,
                         tau_at_bound=tuple(f[2] for f in fits)), spectra
