"""Correlated-noise model for model-minus-data residuals.

Model-minus-data errors at geostationary orbit are not white instrument noise: they are
several nT (SOSMAG paper §5.3: 6.7, 2.3 and 2.0 nT in Hp, He, Hn) and persist for
hours. Treating 43,200 one-minute residuals as independent would make every angle look
far better determined than it is. Each component is therefore modelled as an
Ornstein-Uhlenbeck process (a continuous-time AR(1)): stationary standard deviation
``std_nT`` and correlation ``exp(-|dt| / tau_s)``. Irregular sampling and gaps are handled
exactly, since the lag-one correlation of each step is ``exp(-dt / tau_s)``.

The exact likelihood of an OU process factorises into independent innovations, so
*whitening* the residuals (and the regressors of a linear model) turns generalised least
squares into ordinary least squares; :func:`ou_whiten` does that.
"""

from __future__ import annotations

import dataclasses
from typing import ClassVar

import numpy as np

COMPONENTS = ("Hp", "He", "Hn")


def as_seconds(times) -> np.ndarray:
    """Times as float seconds since the first sample.

    Parameters
    ----------
    times : array_like of datetime64, pandas DatetimeIndex, or float seconds

    Returns
    -------
    ndarray of float, shape (n,)

    Examples
    --------
    >>> as_seconds(np.array(["2019-01-01T00:00", "2019-01-01T00:01"], dtype="datetime64[ns]"))
    array([ 0., 60.])
    """
    t = np.asarray(times)
    if np.issubdtype(t.dtype, np.datetime64):
        t = t.astype("datetime64[ns]")
        return (t - t[0]).astype("int64").astype(float) * 1e-9
    return np.asarray(t, dtype=float)


def lag_correlation(times_s, tau_s) -> np.ndarray:
    """Correlation between consecutive samples, ``exp(-dt / tau_s)``; first entry 0.

    Parameters
    ----------
    times_s : array_like, shape (n,)
        Strictly increasing sample times in seconds.
    tau_s : float
        Correlation time in seconds.

    Returns
    -------
    ndarray, shape (n,)

    Examples
    --------
    >>> lag_correlation([0.0, 60.0, 120.0], 60.0).round(4)
    array([0.    , 0.3679, 0.3679])
    """
    t = np.asarray(times_s, dtype=float)
    phi = np.zeros(t.shape)
    if tau_s > 0:
        phi[1:] = np.exp(-np.diff(t) / tau_s)
    return phi


def ou_whiten(x, times_s, tau_s) -> tuple[np.ndarray, float]:
    """Whiten a series (or the columns of a design matrix) for an OU process.

    ``u[0] = x[0]``, ``u[t] = (x[t] - phi[t] x[t-1]) / sqrt(1 - phi[t]**2)``. If ``x`` is an
    OU process with standard deviation ``s`` the ``u`` are independent N(0, s**2).

    Parameters
    ----------
    x : array_like, shape (n,) or (n, k)
    times_s : array_like, shape (n,)
    tau_s : float
        Correlation time (s); 0 means white noise (no change).

    Returns
    -------
    u : ndarray, same shape as ``x``
    log_jacobian : float
        ``sum(log(sqrt(1 - phi**2)))`` (enters the likelihood as ``-log_jacobian``).

    Examples
    --------
    >>> u, _ = ou_whiten([1.0, 1.0, 1.0], [0.0, 1.0, 2.0], 1e9)
    >>> bool(abs(u[1]) < 1e-3)
    True
    """
    return whiten_with(x, lag_correlation(times_s, tau_s))


def whiten_with(x, phi) -> tuple[np.ndarray, float]:
    """:func:`ou_whiten` with precomputed lag correlations ``phi`` (see :func:`lag_correlation`)."""
    x = np.asarray(x, dtype=float)
    k = np.sqrt(1.0 - phi ** 2)
    shape = (-1,) + (1,) * (x.ndim - 1)
    u = np.empty_like(x)
    u[0] = x[0]
    u[1:] = (x[1:] - phi[1:].reshape(shape) * x[:-1]) / k[1:].reshape(shape)
    return u, float(np.sum(np.log(k[1:])))


@dataclasses.dataclass(frozen=True)
class LagStats:
    """Lag-0 and lag-1 cross products of a vector series, grouped by sample spacing.

    For an OU process the whitened Gram matrix ``U.T @ U`` of any set of columns
    ``v`` (target and regressors) depends on the correlation time only through
    ``phi = exp(-dt / tau)`` of each spacing. Grouping the products by distinct spacing
    (one group for regularly sampled data, a few more with gaps) makes every later
    evaluation, for any ``tau``, cost ``O(groups)`` instead of ``O(n)``: this is what
    makes the noise fit and the vectorised posterior fast.

    Attributes
    ----------
    n : int
    dt_s : ndarray, shape (g,)
        Distinct spacings.
    count : ndarray, shape (g,)
    m00, m01, m11 : ndarray, shape (g, k, k)
        Sums over samples ``t >= 1`` in each group of ``v_t v_t^T``, ``v_t v_{t-1}^T``
        and ``v_{t-1} v_{t-1}^T``.
    first : ndarray, shape (k, k)
        ``v_0 v_0^T``.
    """

    n: int
    dt_s: np.ndarray
    count: np.ndarray
    m00: np.ndarray
    m01: np.ndarray
    m11: np.ndarray
    first: np.ndarray

    def phi(self, tau_s):
        """Lag correlations per group; ``tau_s`` scalar or shape (w,) -> (..., g)."""
        tau = np.asarray(tau_s, dtype=float)[..., None]
        return np.exp(-self.dt_s / tau)

    def grams(self, tau_s) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`gram` for an array of correlation times: shapes (m, k, k) and (m,)."""
        phi = self.phi(np.atleast_1d(tau_s))
        k2 = 1.0 - phi ** 2
        sym = self.m01 + np.swapaxes(self.m01, 1, 2)
        g = self.first + (np.einsum("mg,gij->mij", 1.0 / k2, self.m00)
                          - np.einsum("mg,gij->mij", phi / k2, sym)
                          + np.einsum("mg,gij->mij", phi ** 2 / k2, self.m11))
        return g, 0.5 * np.sum(self.count * np.log(k2), axis=-1)

    def gram(self, tau_s) -> tuple[np.ndarray, float]:
        """Whitened Gram matrix ``U.T @ U`` (k, k) and ``sum(log sqrt(1 - phi**2))``."""
        phi = self.phi(tau_s)
        k2 = 1.0 - phi ** 2
        sym = self.m01 + np.swapaxes(self.m01, 1, 2)
        g = self.first + np.einsum("g,gij->ij", 1.0 / k2,
                                   self.m00 - phi[:, None, None] * sym
                                   + (phi ** 2)[:, None, None] * self.m11)
        return g, float(0.5 * np.sum(self.count * np.log(k2)))

    def sub(self, idx) -> LagStats:
        """Statistics of a subset of the columns."""
        ix = np.ix_(range(self.dt_s.size), idx, idx)
        return LagStats(self.n, self.dt_s, self.count, self.m00[ix], self.m01[ix],
                        self.m11[ix], self.first[np.ix_(idx, idx)])


def lag_stats(v, times_s, dt_decimals: int = 6) -> LagStats:
    """Build :class:`LagStats` of the columns of ``v`` sampled at ``times_s``.

    Spacings are grouped after rounding to ``dt_decimals`` decimals of a second.

    Examples
    --------
    >>> st = lag_stats(np.ones((4, 1)), [0.0, 1.0, 2.0, 4.0])
    >>> st.dt_s, st.count
    (array([1., 2.]), array([2, 1]))
    """
    v = np.asarray(v, dtype=float)
    if v.ndim == 1:
        v = v[:, None]
    t = np.asarray(times_s, dtype=float)
    dt = np.round(np.diff(t), dt_decimals)
    groups, inverse, count = np.unique(dt, return_inverse=True, return_counts=True)
    k = v.shape[1]
    g = groups.size
    cur, prev = v[1:], v[:-1]
    m00 = np.zeros((g, k, k))
    m01 = np.zeros((g, k, k))
    m11 = np.zeros((g, k, k))
    if g == 1:
        m00[0], m01[0], m11[0] = cur.T @ cur, cur.T @ prev, prev.T @ prev
    else:
        # one matrix product per spacing group (np.add.at over outer products is ~50x
        # slower for the many groups a Kp-selected record has)
        order = np.argsort(inverse, kind="stable")
        bounds = np.concatenate([[0], np.cumsum(count)])
        for j in range(g):
            sel = order[bounds[j]:bounds[j + 1]]
            a, b = cur[sel], prev[sel]
            m00[j], m01[j], m11[j] = a.T @ a, a.T @ b, b.T @ b
    return LagStats(n=int(v.shape[0]), dt_s=groups, count=count, m00=m00, m01=m01,
                    m11=m11, first=np.outer(v[0], v[0]))


def _restricted_parts(stats: LagStats, log_tau, design_idx):
    """(residual sum of squares after projection, log-jacobian, log det, dof)."""
    gram, log_jac = stats.gram(np.exp(log_tau))
    rss = gram[0, 0]
    log_det = 0.0
    if design_idx:
        gxx = gram[np.ix_(design_idx, design_idx)]
        gxy = gram[design_idx, 0]
        scale = np.sqrt(np.diag(gxx))
        gs = gxx / np.outer(scale, scale)
        sol = np.linalg.lstsq(gs, gxy / scale, rcond=None)[0]
        rss = rss - float((gxy / scale) @ sol)
        log_det = float(np.linalg.slogdet(gs)[1] + 2.0 * np.sum(np.log(scale)))
    return max(float(rss), 1e-300), log_jac, log_det, stats.n - len(design_idx)


def restricted_nll_stats(log_sigma2, log_tau, stats: LagStats, design_idx=()) -> float:
    """Negative restricted log-likelihood of an OU residual from :class:`LagStats`.

    Column 0 of ``stats`` is the residual, ``design_idx`` the fitted regressors
    (projected out; their whitened Gram enters as ``0.5 log det``). Constants dropped.

    Parameters
    ----------
    log_sigma2, log_tau : float
        Natural logarithms of the variance (nT^2) and correlation time (s).
    stats : LagStats
    design_idx : sequence of int
    """
    rss, log_jac, log_det, dof = _restricted_parts(stats, log_tau, list(design_idx))
    return float(0.5 * dof * log_sigma2 + 0.5 * rss / np.exp(log_sigma2) + log_jac
                 + 0.5 * log_det)


def component_basis(jacobian, c, rtol: float = 1e-8):
    """Independent regressors of component ``c``: a basis of the columns of ``jacobian[:, c, :]``.

    The columns can be linearly dependent (a rotation changes each component only
    through the other two), so the restricted likelihood uses an orthogonal basis of
    their span. Returns an (n, q) array, or None when the component has no regressor.
    """
    cols = np.asarray(jacobian)[:, c, :]
    if not np.any(cols):
        return None
    norms = np.sqrt(np.sum(cols ** 2, axis=0))
    scaled = cols[:, norms > 0] / norms[norms > 0]
    _, sv, vt = np.linalg.svd(scaled, full_matrices=False)
    keep = sv > rtol * sv[0]
    return scaled @ vt[keep].T


def fit_ou_stats(stats: LagStats, design_idx=(), tau_bounds_s=None, duration_s=None):
    """Restricted maximum-likelihood ``(std_nT, tau_s, at_bound)`` from :class:`LagStats`.

    See :func:`fit_ou`.
    """
    design_idx = list(design_idx)
    if tau_bounds_s is None:
        lo = 0.1 * float(np.min(stats.dt_s))
        hi = max(float(duration_s if duration_s is not None
                       else np.sum(stats.dt_s * stats.count)), 10 * lo)
        tau_bounds_s = (lo, hi)

    def prof(log_taus):
        grams, log_jac = stats.grams(np.exp(log_taus))
        rss = grams[:, 0, 0]
        log_det = np.zeros(len(log_taus))
        if design_idx:
            gxx = grams[:, design_idx][:, :, design_idx]
            gxy = grams[:, design_idx, 0]
            scale = np.sqrt(np.einsum("mii->mi", gxx))
            gs = gxx / (scale[:, :, None] * scale[:, None, :])
            sol = np.linalg.solve(gs, (gxy / scale)[..., None])[..., 0]
            rss = rss - np.einsum("mi,mi->m", gxy / scale, sol)
            log_det = np.linalg.slogdet(gs)[1] + 2.0 * np.sum(np.log(scale), axis=1)
        dof = stats.n - len(design_idx)
        s2 = np.maximum(rss, 1e-300) / dof
        return 0.5 * dof * np.log(s2) + 0.5 * dof + log_jac + 0.5 * log_det, s2

    lo, hi = np.log(tau_bounds_s[0]), np.log(tau_bounds_s[1])
    grid = np.linspace(lo, hi, 25)
    values, _ = prof(grid)
    i = int(np.nanargmin(values))
    fine = np.linspace(grid[max(i - 1, 0)], grid[min(i + 1, grid.size - 1)], 25)
    values, s2 = prof(fine)
    j = int(np.nanargmin(values))
    log_tau = float(fine[j])
    if 0 < j < fine.size - 1:  # parabolic refinement through the three best points
        y0, y1, y2 = values[j - 1:j + 2]
        denom = y0 - 2 * y1 + y2
        if denom > 0:
            h = fine[1] - fine[0]
            log_tau = float(fine[j] + 0.5 * h * (y0 - y2) / denom)
    _, s2 = prof(np.array([log_tau]))
    return float(np.sqrt(s2[0])), float(np.exp(log_tau)), bool(log_tau > hi - 0.05)


def fit_ou(residual, times_s, design=None, tau_bounds_s=None) -> tuple[float, float, bool]:
    """Restricted maximum-likelihood OU standard deviation and correlation time.

    The standard deviation is profiled out analytically; the correlation time is found
    on a logarithmic grid and refined with a bounded scalar search. With ``design``
    (the regressors of a fitted linear model) the restricted (REML) likelihood is used:
    fitted parameters absorb part of the slow residual power, and plain maximum
    likelihood would then underestimate both the noise level and its correlation time,
    making every uncertainty derived from them too small.

    Parameters
    ----------
    residual : array_like, shape (n,)
        Residual series (nT).
    times_s : array_like, shape (n,)
    design : array_like, shape (n, q), optional
        Regressors whose coefficients were fitted (e.g. a column of ones for a mean).
    tau_bounds_s : (float, float), optional
        Search range; default from a tenth of the smallest spacing to the record length.

    Returns
    -------
    std_nT : float
    tau_s : float
    at_bound : bool
        True when ``tau_s`` lies at the upper bound: the residual is correlated over the
        whole record and its uncertainty cannot be estimated from it.

    Examples
    --------
    >>> rng = np.random.default_rng(1)
    >>> t = np.arange(20000.0) * 60.0
    >>> x = simulate_ou(rng, t, std_nT=2.0, tau_s=600.0)
    >>> s, tau, _ = fit_ou(x, t, design=np.ones((t.size, 1)))
    >>> bool(abs(s - 2.0) < 0.2 and abs(tau - 600.0) < 100.0)
    True
    """
    x = np.asarray(residual, dtype=float)
    t = np.asarray(times_s, dtype=float)
    cols = [x[:, None]]
    q = 0
    if design is not None:
        d = np.asarray(design, dtype=float).reshape(x.size, -1)
        cols.append(d)
        q = d.shape[1]
    stats = lag_stats(np.concatenate(cols, axis=1), t)
    return fit_ou_stats(stats, list(range(1, 1 + q)), tau_bounds_s=tau_bounds_s,
                        duration_s=float(t[-1] - t[0]))


def simulate_ou(rng: np.random.Generator, times_s, std_nT: float, tau_s: float) -> np.ndarray:
    """Draw an exact stationary OU series at the given times.

    Parameters
    ----------
    rng : numpy.random.Generator
    times_s : array_like, shape (n,)
    std_nT, tau_s : float
        Stationary standard deviation and correlation time.

    Returns
    -------
    ndarray, shape (n,)

    Examples
    --------
    >>> x = simulate_ou(np.random.default_rng(0), np.arange(5.0), 1.0, 0.0)
    >>> x.shape
    (5,)
    """
    t = np.asarray(times_s, dtype=float)
    phi = lag_correlation(t, tau_s)
    innov = rng.standard_normal(t.size) * std_nT * np.sqrt(1.0 - phi ** 2)
    if t.size > 1 and np.allclose(phi[1:], phi[1]):
        from scipy.signal import lfilter

        return lfilter([1.0], [1.0, -phi[1]], innov)
    out = np.empty(t.size)
    prev = 0.0
    for k in range(t.size):
        prev = phi[k] * prev + innov[k]
        out[k] = prev
    return out


@dataclasses.dataclass(frozen=True)
class OUNoise:
    """Per-component OU noise model of the residuals.

    Attributes
    ----------
    std_nT : ndarray, shape (3,)
        Stationary standard deviation per component (Hp, He, Hn).
    tau_s : ndarray, shape (3,)
        Correlation time per component.
    effective_n : ndarray, shape (3,)
        Effective number of independent samples for a mean,
        ``n (1 - phi) / (1 + phi)`` with ``phi`` at the median spacing.
    tau_at_bound : tuple of bool
        Components whose correlation time reached the record length (unreliable).
    """

    std_nT: np.ndarray
    tau_s: np.ndarray
    effective_n: np.ndarray
    tau_at_bound: tuple
    #: The ``noise_model`` name of :func:`magcal.alignment.gls.fit_alignment`.
    kind: ClassVar[str] = "ou"

    def to_dict(self) -> dict:
        """Plain dictionary keyed by component name."""
        return noise_dict("ornstein-uhlenbeck per component", self)

    def warning(self) -> str | None:
        """A caution when the noise model cannot be trusted, else None."""
        return noise_warning(self.tau_at_bound, self.effective_n)


def noise_warning(tau_at_bound, effective_n) -> str | None:
    """A caution when a fitted noise model cannot be trusted, else None.

    Shared by the OU and the OU + white models: both state their correlation times'
    bound hits and effective sample sizes per component.
    """
    if any(tau_at_bound):
        return ("residuals correlated over the whole record: the uncertainty cannot be "
                "estimated from these data and is a lower bound")
    if np.min(effective_n) < 30:
        return ("fewer than 30 independent samples in a component: correlation time "
                "and hence the uncertainty are themselves uncertain (measured: 95 % "
                "intervals hold the truth in about 92 % of cases at 30)")
    return None


def noise_dict(model: str, noise, extra: tuple[str, ...] = ()) -> dict:
    """A fitted noise model as a plain dictionary keyed by component name.

    ``extra`` names further per-component array attributes (for example
    ``white_std_nT``) written after ``tau_s``.
    """
    out = {"model": model,
           "std_nT": dict(zip(COMPONENTS, map(float, noise.std_nT))),
           "tau_s": dict(zip(COMPONENTS, map(float, noise.tau_s)))}
    for name in extra:
        out[name] = dict(zip(COMPONENTS, map(float, getattr(noise, name))))
    out["effective_n"] = dict(zip(COMPONENTS, map(float, noise.effective_n)))
    out["tau_at_bound"] = dict(zip(COMPONENTS, map(bool, noise.tau_at_bound)))
    out["warning"] = noise.warning()
    return out


def fit_noise(residuals, times_s, jacobian=None) -> OUNoise:
    """Fit :class:`OUNoise` to an (n, 3) residual array.

    Parameters
    ----------
    residuals : array_like, shape (n, 3)
    times_s : array_like, shape (n,)
    jacobian : array_like, shape (n, 3, p), optional
        Derivatives of the fitted model; per component, a basis of its columns is the
        design of the restricted likelihood (see :func:`fit_ou`).

    Examples
    --------
    >>> rng = np.random.default_rng(2)
    >>> t = np.arange(5000.0) * 60.0
    >>> r = np.stack([simulate_ou(rng, t, s, 1800.0) for s in (6.7, 2.3, 2.0)], axis=1)
    >>> fit_noise(r, t).std_nT.round(0)
    array([7., 2., 2.])
    """
    r = np.asarray(residuals, dtype=float)
    t = np.asarray(times_s, dtype=float)
    fits = []
    for c in range(r.shape[1]):
        basis = None if jacobian is None else component_basis(jacobian, c)
        fits.append(fit_ou(r[:, c], t, design=basis))
    return noise_from_fits(fits, t)


def effective_count(ou_std_nT, ou_tau_s, white_std_nT, times_s) -> np.ndarray:
    """Effective sample count of a mean per component under OU parts plus white noise.

    ``ou_std_nT`` and ``ou_tau_s`` have shape (3, k) (k OU parts per component, each
    at the median spacing), ``white_std_nT`` shape (3,). The count is the total
    variance over the variance of the mean, at most the number of samples.

    Examples
    --------
    One OU part of correlation time equal to the spacing, no white part:
    ``n (1 - e^-1) / (1 + e^-1)``.

    >>> effective_count([[1.0]], [[60.0]], [0.0], np.arange(1000) * 60.0).round(1)
    array([462.1])
    """
    t = np.asarray(times_s, dtype=float)
    n = t.size
    dt = float(np.median(np.diff(t))) if n > 1 else 1.0
    ou_var = np.asarray(ou_std_nT, dtype=float) ** 2
    white_var = np.asarray(white_std_nT, dtype=float) ** 2
    phi = np.exp(-dt / np.asarray(ou_tau_s, dtype=float))
    var_mean = (np.sum(ou_var * (1 + phi) / (1 - phi), axis=-1) + white_var) / n
    total = np.sum(ou_var, axis=-1) + white_var
    return np.minimum(total / np.maximum(var_mean, 1e-300), n)


def noise_from_fits(fits, times_s) -> OUNoise:
    """:class:`OUNoise` from per-component ``(std_nT, tau_s, at_bound)`` tuples."""
    t = np.asarray(times_s, dtype=float)
    std = np.array([f[0] for f in fits])
    tau = np.array([f[1] for f in fits])
    dt = float(np.median(np.diff(t))) if t.size > 1 else 1.0
    phi = np.exp(-dt / tau)
    n_eff = t.size * (1.0 - phi) / (1.0 + phi)
    return OUNoise(std_nT=std, tau_s=tau, effective_n=n_eff,
                   tau_at_bound=tuple(f[2] for f in fits))
