"""Model selection for the discovery loop: blocked cross-validation from block Gram matrices.

The residual noise of a magnetometer against a model is strongly correlated in time
(ULF waves, substorms, storms), so white-noise information criteria over-select. The
loop therefore judges every candidate by *leave-one-block-out* cross-validation with
contiguous blocks in time (days by default): the design is fitted without block ``b``
and scored on ``b``. Per-block Gram matrices ``X_b' X_b``, ``X_b' y_b`` and ``y_b' y_b``
are computed once per column, so scoring any subset of columns costs a few small
solves, independent of the number of samples.

Evidence for adding a candidate is the paired per-block gain in held-out squared error,
``d_b = SSE_b(base) - SSE_b(base + candidate)``: its sum (the cross-validated gain) and
the t-statistic ``z = mean(d) / (std(d) / sqrt(B))`` across blocks. Days are close to
independent where samples are not, so ``z`` carries the time correlation correctly.
An effective-sample-size-corrected BIC is reported beside it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

DAY_S = 86400.0
#: Smallest Bartlett variance factor accepted for a coefficient (see model_covariance).
TAU_FLOOR = 0.001


def time_blocks(times_s, block_s: float = DAY_S, min_blocks: int = 8) -> np.ndarray:
    """Contiguous block number of each sample (blocks of ``block_s``, at least ``min_blocks``).

    Parameters
    ----------
    times_s : array_like, shape (n,)
        Increasing sample times in seconds.
    block_s : float
        Nominal block length (one day by default).
    min_blocks : int
        If the span holds fewer blocks, the block length is shortened to span/min_blocks.

    Returns
    -------
    ndarray of int, shape (n,)
        Block index, 0 .. B-1, non-decreasing; empty blocks are dropped.

    Examples
    --------
    >>> t = np.arange(0, 10 * 86400, 3600.0)
    >>> b = time_blocks(t)
    >>> int(b.max()) + 1, int(np.sum(b == 0))
    (10, 24)
    """
    t = np.asarray(times_s, dtype=float)
    span = t[-1] - t[0] if t.size else 0.0
    length = min(float(block_s), span / min_blocks) if span > 0 else 1.0
    raw = np.floor((t - t[0]) / length).astype(int)
    _, inverse = np.unique(raw, return_inverse=True)
    return inverse.astype(int)


#: Lags :func:`integrated_autocorr_time` computes first, all of them when its window lies
#: beyond: the discovery loop's residuals (strongly correlated) have it below 2048 lags
#: four times in five.
_FIRST_LAGS = 2048


def _lag_sums(v: np.ndarray, lags: int) -> np.ndarray:
    """Lagged product sums ``sum_t v[t] v[t + k]`` of the columns of ``v`` (n, m) at lags
    ``k = 0 .. lags - 1`` (no centring), by one FFT of at least ``n + lags`` points: that
    much zero padding keeps the circular correlation free of wrap-around at these lags,
    so a few lags of a long series cost half the transform of all of them."""
    from scipy.fft import irfft, next_fast_len, rfft

    n = v.shape[0]
    nfft = next_fast_len(max(n + lags, 2), real=True)
    f = rfft(v, nfft, axis=0)
    return irfft(f.real ** 2 + f.imag ** 2, nfft, axis=0)[:lags]


def integrated_autocorr_time(x, c: float = 5.0) -> float:
    """Integrated autocorrelation time of a series (Sokal's automatic window).

    Returns ``tau = 1 + 2 sum_k rho_k`` summed up to the first lag ``M >= c * tau``;
    ``n / tau`` is the effective number of independent samples.

    Examples
    --------
    >>> rng = np.random.default_rng(1)
    >>> round(integrated_autocorr_time(rng.normal(size=20000)), 1)
    1.0
    """
    v = np.asarray(x, dtype=float)
    v = v[np.isfinite(v)]
    n = v.size
    if n < 4:
        return 1.0
    v = v - v.mean()
    # the window M is usually within a few hundred lags: the lags up to a bound first
    # (an FFT of n + bound points instead of 2n), all of them only when M lies beyond
    lags = min(n, _FIRST_LAGS)
    while True:
        acf = _lag_sums(v[:, None], lags)[:, 0]
        if acf[0] <= 0:
            return 1.0
        taus = 2.0 * np.cumsum(acf / acf[0]) - 1.0
        window = np.arange(lags) >= c * taus
        if window.any():
            return float(max(taus[int(np.argmax(window))], 1.0))
        if lags == n:
            return float(max(taus[n - 1], 1.0))
        lags = n


def autocorrelation(x, max_lag: int | None = None, *, centre: bool = True) -> np.ndarray:
    """Normalised autocorrelation of a series (NaN treated as zero after centring).

    A 2-D ``x`` gives the autocorrelation of each column (lags along axis 0), in one
    batched FFT. ``centre=False`` keeps the mean: the lagged sums of a regression
    coefficient's weights, whose mean is part of its variance in correlated noise
    (Bartlett's formula; a level's weights are all mean).

    Examples
    --------
    >>> np.round(autocorrelation(np.array([1.0, -1.0, 1.0, -1.0]), 2), 2)
    array([ 1.  , -0.75,  0.5 ])
    """
    v = np.asarray(x, dtype=float)
    one = v.ndim == 1
    v = v[:, None] if one else v
    ok = np.isfinite(v)
    if centre:
        cnt = ok.sum(axis=0)
        v = v - np.where(cnt > 0, np.where(ok, v, 0.0).sum(axis=0) / np.maximum(cnt, 1), 0.0)
    v = np.where(ok, v, 0.0)
    n = v.shape[0]
    acf = _lag_sums(v, n if max_lag is None else min(n, max_lag + 1))
    zero = acf[0] <= 0
    acf = acf / np.where(zero, 1.0, acf[0])
    acf[:, zero] = 0.0
    return acf[:, 0] if one else acf


def regression_n_eff(residual, signal, window=None, *, centre_signal: bool = True) -> float:
    """Effective sample size for estimating ``signal`` in correlated ``residual``.

    Bartlett's formula: the variance of a regression coefficient grows by
    ``tau = 1 + 2 sum_k rho_e(k) rho_x(k)`` (noise and regressor autocorrelations), so
    a white regressor (a spin tone) keeps nearly all ``n`` samples while a slow one
    (a diurnal term) in red noise keeps ``n / tau_e``. Components are weighted by the
    signal energy. ``centre_signal=False`` for a level, whose signal is all mean (and
    keeps ``n / tau_e``): a term fitted beside the level varies about it, and is centred.

    Examples
    --------
    >>> rng = np.random.default_rng(2)
    >>> e = np.convolve(rng.normal(size=20000), np.ones(50) / 50, "same")[:, None]
    >>> white = rng.normal(size=(20000, 1))
    >>> slow = np.sin(np.arange(20000) / 500.0)[:, None]
    >>> regression_n_eff(e, white) > 10 * regression_n_eff(e, slow)
    True
    """
    r = np.asarray(residual, dtype=float)
    f = np.asarray(signal, dtype=float)
    total_w = 0.0
    acc = 0.0
    n_valid = np.isfinite(r).sum()
    for c in range(r.shape[1]):
        w = float(np.nansum(f[:, c] ** 2))
        if w <= 0:
            continue
        tau_e = integrated_autocorr_time(r[:, c])
        m = int(min(r.shape[0] - 1, max(5 * tau_e, 10))) if window is None else int(window)
        rho_e = autocorrelation(r[:, c], m)
        rho_f = autocorrelation(f[:, c], m, centre=centre_signal)
        k = min(rho_e.size, rho_f.size)
        tau = 1.0 + 2.0 * float(np.sum(rho_e[1:k] * rho_f[1:k]))
        acc += w * max(tau, 1.0)
        total_w += w
    tau = acc / total_w if total_w > 0 else 1.0
    return float(n_valid / tau)


@dataclass(frozen=True)
class CVScore:
    """Cross-validated and in-sample scores of one set of columns.

    Attributes
    ----------
    columns : tuple of int
        Column indices in the :class:`BlockedGram`.
    beta, beta_std : ndarray
        Full-data least-squares coefficients and their block-jackknife standard errors.
    sse_blocks : ndarray (B,)
        Held-out squared error of each block.
    sse_in : float
        In-sample squared error of the full fit.
    """

    columns: tuple[int, ...]
    beta: np.ndarray
    beta_std: np.ndarray
    sse_blocks: np.ndarray
    sse_in: float
    beta_folds: np.ndarray | None = None
    block_var: np.ndarray | None = None

    def n_eff_blocks(self, params) -> float:
        """Effective number of blocks behind the coefficients ``params`` (positions).

        Satterthwaite's ``(sum_b v_b)^2 / sum_b v_b^2`` with ``v_b`` the variance that
        block ``b`` contributes to a coefficient (its leverage times its residual mean
        square). Equal to the number of blocks when every
        block carries the same information, near 1 when one block decides the
        coefficient (a step in the first hours, a scale term seen only on storm days).
        For several coefficients, one plus the harmonic mean of ``n_eff - 1`` (the
        degrees of freedom of their jackknife covariance).
        """
        pos = list(params)
        if self.block_var is None or not pos:
            return float(len(self.sse_blocks))
        v = self.block_var[:, pos]
        num = v.sum(axis=0) ** 2
        den = (v ** 2).sum(axis=0)
        ok = den > 0
        if not ok.any():
            return float(len(self.sse_blocks))
        per = np.maximum(num[ok] / den[ok] - 1.0, 1e-3)
        # several coefficients: match the variance of tr(C^-1 C_hat) of a Wishart matrix
        # (degrees of freedom = harmonic mean of the per-coefficient ones)
        return float(1.0 + per.size / np.sum(1.0 / per))

    @property
    def sse_cv(self) -> float:
        return float(self.sse_blocks.sum())


@dataclass(frozen=True)
class Comparison:
    """Comparison of a candidate against a base (positive gain = better).

    Attributes
    ----------
    gain : float
        Cross-validated gain: sum over blocks of SSE_base - SSE_candidate (nT^2).
    z : float
        Significance of the added parameters, as a one-sided normal z: block-jackknife
        Wald test (Hotelling T^2 -> F(p, B - p)), robust to noise correlated within days.
    z_cv : float
        t-statistic of the per-block held-out gains.
    """

    gain: float
    z: float
    z_cv: float
    n_blocks: int
    blocks_better: int
    n_eff_blocks: float = float("nan")
    log_p: float = 0.0
    z_jackknife: float = float("nan")

    def as_dict(self) -> dict:
        return {"cv_gain_nT2": self.gain, "z": self.z, "log_p": self.log_p,
                "z_jackknife": self.z_jackknife, "z_cv": self.z_cv,
                "n_blocks": self.n_blocks, "n_eff_blocks": self.n_eff_blocks,
                "blocks_better": self.blocks_better}


def _paired_t(d: np.ndarray) -> float:
    b = d.size
    sd = float(np.std(d, ddof=1)) if b > 1 else 0.0
    mean = float(d.mean())
    if sd > 0:
        return mean / (sd / np.sqrt(b))
    return np.inf if mean > 0 else (0.0 if mean == 0 else -np.inf)


def _block_mean_square(r: np.ndarray, blocks: np.ndarray, n_blocks: int) -> np.ndarray:
    ok = np.isfinite(r)
    v = np.where(ok, r, 0.0)
    out = np.zeros((n_blocks, r.shape[1]))
    for c in range(r.shape[1]):
        cnt = np.bincount(blocks, weights=ok[:, c].astype(float), minlength=n_blocks)
        sq = np.bincount(blocks, weights=v[:, c] ** 2, minlength=n_blocks)
        out[:, c] = sq / np.maximum(cnt, 1)
    return out


def _covariance_inputs(gram: BlockedGram, score: CVScore, blocks: np.ndarray):
    """What :func:`model_covariance` starts from: the inverse normal matrix of the
    score's columns (inverted scaled to unit diagonal), the fit's residual (NaN where
    missing) and its mean square per block and component."""
    cols = list(score.columns)
    G = gram.G[:, cols][:, :, cols].sum(axis=0)
    d = np.sqrt(np.diag(G))
    d[d == 0] = 1.0
    Minv = np.linalg.inv(G / np.outer(d, d) + 1e-10 * np.eye(len(cols))) / np.outer(d, d)
    resid = gram.residual(cols, score.beta)
    return Minv, resid, _block_mean_square(resid, blocks, gram.n_blocks)


def model_covariance(gram: "BlockedGram", score: CVScore, params, blocks,
                     max_lag: int = 1440) -> np.ndarray:
    """Model-based covariance of the coefficients ``params`` (positions in ``score``).

    Coefficient ``j`` is ``sum_t a_j(t) y(t)`` with ``a_j = X (X'X)^-1 e_j``. With the
    residual of the fit having mean square ``s2[b, c]`` in block ``b`` and component
    ``c`` and autocorrelation ``rho_c``, its variance is
    ``sum_c tau_jc sum_b s2[b, c] |a_j|^2_(b, c)`` with Bartlett's
    ``tau_jc = 1 + 2 sum_k rho_c(k) rho_(a_j, c)(k)`` (``rho_(a_j, c)`` the lagged sums of
    the weights themselves, not centred: a level's are all mean; covariances alike, with
    ``sqrt(tau_jc tau_kc)``; components independent). Unlike the block jackknife it
    uses the scatter within blocks, so it stays precise when a few blocks (storm days)
    carry the coefficient; it assumes the noise is stationary within each block.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> t = np.arange(20000.0)
    >>> g = BlockedGram(rng.normal(0, 2.0, (t.size, 1)), time_blocks(t))
    >>> cols = g.add(np.ones((1, t.size, 1)))
    >>> s = g.score(cols)
    >>> cov = model_covariance(g, s, [0], time_blocks(t))
    >>> bool(abs(np.sqrt(cov[0, 0]) / (2.0 / np.sqrt(t.size)) - 1) < 0.05)
    True
    """
    cols = list(score.columns)
    blocks = np.asarray(blocks)
    Minv, resid, s2 = _covariance_inputs(gram, score, blocks)
    params = list(params)
    # a_j for every coefficient at once: (p, q) weights on the (q, n*m) columns
    A = (Minv[:, params].T @ gram.column_matrix(cols)).reshape(len(params), gram.n, gram.m)
    p = len(params)
    cov = np.zeros((p, p))
    for c in range(gram.m):
        active = [i for i in range(p) if A[i, :, c].any()]
        if not active:
            continue
        tau_e = integrated_autocorr_time(resid[:, c])
        rho_e = autocorrelation(resid[:, c], int(min(max(5 * tau_e, 10), max_lag)))
        k = rho_e.size
        a_c = A[active, :, c].T  # (n, active)
        # the weights' own lagged sums, mean included: centred, a level's weights (a
        # constant, or one with gaps) lost their correlation and the variance its
        # factor tau (a level in red noise of 60 samples' time: 8x too small an error)
        rho_a = autocorrelation(a_c, k - 1, centre=False)
        # below 1 for a regressor that varies faster than the noise (a spin tone in
        # red noise sees only the noise's fast part); floored against a noisy sum
        tau = np.maximum(TAU_FLOOR, 1.0 + 2.0 * (rho_e[1:k] @ rho_a[1:k]))
        # sum_b s2[b, c] sum_(t in b) a_i a_j = sum_t s2[block(t), c] a_i(t) a_j(t)
        weighted = a_c.T @ (a_c * s2[blocks, c][:, None])
        cov[np.ix_(active, active)] += np.sqrt(np.outer(tau, tau)) * weighted
    return cov


def wald_test(score: CVScore, params, cov_model=None,
              effective: bool = False) -> tuple[float, float]:
    """Wald test that the coefficients ``params`` (positions) are zero, under the
    correlated-noise model.

    Hotelling's ``T^2 = beta' C^-1 beta`` with ``C`` the block-jackknife covariance over
    the leave-one-block-out fits (contiguous days: the correlation of the noise within a
    day is carried by the blocks), its standard errors floored by the model-based ones of
    :func:`model_covariance` (``cov_model``: residual level per block, Bartlett's
    autocorrelation factor), turned into ``F = (B - p) / (p (B - 1)) T^2`` with
    ``(p, B - p)`` degrees of freedom.

    Returns
    -------
    z : float
        One-sided normal quantile of the p-value (not capped).
    log_p : float
        Natural log of the p-value (the loop ranks candidates by it).

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> folds = rng.normal(1.0, 0.01, size=(30, 1))
    >>> s = CVScore((0,), np.array([1.0]), np.array([0.05]), np.zeros(30), 0.0, folds)
    >>> z, log_p = wald_test(s, [0])
    >>> z > 5, log_p < -20
    (True, True)
    """
    from scipy import stats

    pos = list(params)
    p = len(pos)
    folds = score.beta_folds
    B = folds.shape[0]
    nu = min(float(B), score.n_eff_blocks(pos)) if effective else float(B)
    if p == 0 or nu - p < 1:
        return 0.0, 0.0
    beta = score.beta[pos]
    dev = folds[:, pos] - folds[:, pos].mean(axis=0)
    cov = (B - 1) / B * dev.T @ dev
    scale = np.sqrt(np.diag(cov))
    if cov_model is not None:
        # a jackknife from few informative blocks is noisy (small by chance, nearly
        # singular across coefficients): standard errors never below the model-based
        # ones, correlations from the model
        cm = np.asarray(cov_model, dtype=float)
        sm = np.sqrt(np.maximum(np.diag(cm), 0.0))
        if np.all(sm > 0):
            scale = np.maximum(scale, sm)
            cov = cm / np.outer(sm, sm) * np.outer(scale, scale)
    if not np.all(scale > 0):
        return 0.0, 0.0
    corr = cov / np.outer(scale, scale) + 1e-9 * np.eye(p)
    t2 = float((beta / scale) @ np.linalg.solve(corr, beta / scale))
    f = (nu - p) / (p * (nu - 1)) * t2
    log_p = float(stats.f.logsf(f, p, nu - p))
    if not np.isfinite(log_p):  # far tail: F(p, d) -> d/2 log(1 + p f / d) leading term
        d = nu - p
        log_p = float(-(p + d) / 2 * np.log1p(p * f / d) + (d / 2) * np.log(max(d, 1.0)))
    return _z_from_log_p(log_p), log_p


def wald_z(score: CVScore, params, effective: bool = False, cov_model=None) -> float:
    """:func:`wald_test`'s z, capped at 40.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> folds = rng.normal(1.0, 0.01, size=(30, 1))
    >>> s = CVScore((0,), np.array([1.0]), np.array([0.05]), np.zeros(30), 0.0, folds)
    >>> wald_z(s, [0]) > 5
    True
    """
    return float(min(wald_test(score, params, cov_model, effective)[0], 40.0))


def _z_from_log_p(log_p: float) -> float:
    """Normal quantile of a (log) upper-tail probability, asymptotic for tiny ones."""
    from scipy import stats

    if log_p > -700:
        return float(stats.norm.isf(np.exp(log_p)))
    # Mills ratio: log sf(z) ~ -z^2/2 - log(z sqrt(2 pi))
    z = float(np.sqrt(-2 * log_p))
    for _ in range(5):
        z = float(np.sqrt(max(-2 * (log_p + np.log(z * np.sqrt(2 * np.pi))), 1.0)))
    return float(z)


def compare(base: CVScore, cand: CVScore, params=None, cov_model=None) -> Comparison:
    """Compare a candidate with the base it extends.

    ``params`` are the positions of the candidate's new coefficients in ``cand.beta``
    (default: those after the base's); ``cov_model`` their model-based covariance
    (:func:`model_covariance`), a floor under the jackknife variances.
    """
    d = base.sse_blocks - cand.sse_blocks
    if params is None:
        params = range(len(base.beta), len(cand.beta))
    params = list(params)
    z_jack = wald_z(cand, params)
    z, log_p = wald_test(cand, params, cov_model)
    return Comparison(gain=float(d.sum()), z=z, z_cv=float(_paired_t(d)),
                      n_blocks=int(d.size), blocks_better=int(np.sum(d > 0)),
                      n_eff_blocks=cand.n_eff_blocks(params), log_p=log_p,
                      z_jackknife=z_jack)


def paired_z(worse: CVScore, better: CVScore) -> float:
    """t-statistic of the per-block held-out gains of ``better`` over ``worse``."""
    return float(_paired_t(worse.sse_blocks - better.sse_blocks))


class BlockedGram:
    """Per-block Gram matrices of a growing set of columns against one data vector.

    Parameters
    ----------
    y : ndarray, shape (n, m)
        The data to explain (measured - model); NaN entries are excluded.
    blocks : ndarray of int, shape (n,)
        Non-decreasing block index per sample (see :func:`time_blocks`).

    Examples
    --------
    >>> t = np.arange(1000.0)
    >>> y = np.column_stack([2.0 + 0.01 * t, -1.0 + 0 * t])
    >>> g = BlockedGram(y, time_blocks(t, block_s=100.0))
    >>> ones = np.zeros((2, 1000, 2)); ones[0, :, 0] = 1; ones[1, :, 1] = 1
    >>> cols = g.add(ones)
    >>> np.round(g.score(cols).beta, 6)
    array([ 6.995, -1.   ])
    """

    def __init__(self, y, blocks):
        y = np.asarray(y, dtype=float)
        self.n, self.m = y.shape
        self.mask = np.isfinite(y)
        self.y = np.where(self.mask, y, 0.0).reshape(-1)
        blocks = np.asarray(blocks)
        edges = np.flatnonzero(np.diff(blocks)) + 1
        starts = np.concatenate([[0], edges])
        stops = np.concatenate([edges, [self.n]])
        self.slices = [slice(a * self.m, b * self.m) for a, b in zip(starts, stops)]
        self.n_blocks = len(self.slices)
        self.yy = np.array([self.y[s] @ self.y[s] for s in self.slices])
        self.count = np.array([self.mask.reshape(-1)[s].sum() for s in self.slices])
        self._chunks: list[np.ndarray] = []
        self.G = np.zeros((self.n_blocks, 0, 0))
        self.c = np.zeros((self.n_blocks, 0))

    @property
    def n_columns(self) -> int:
        return self.c.shape[1]

    @property
    def n_valid(self) -> int:
        return int(self.count.sum())

    def add(self, columns, against=None) -> tuple[int, ...]:
        """Add columns of shape (q, n, m); return their indices.

        With ``against`` (existing column indices), cross products are computed with
        those columns only and the others are NaN: such columns may be scored together
        with ``against`` only (cheap for short-lived candidates).
        """
        q_cols = np.asarray(columns, dtype=float).reshape(len(columns), -1)
        q_cols = np.where(self.mask.reshape(-1)[None, :], q_cols, 0.0)
        q = q_cols.shape[0]
        p = self.n_columns
        B = self.n_blocks
        qq = np.zeros((B, q, q))
        qc = np.zeros((B, q))
        if against is None:
            cross = np.zeros((B, p, q))
        else:
            cross = np.full((B, p, q), np.nan)
            against = list(against)
            xa = self.column_matrix(against) if against else np.zeros((0, q_cols.shape[1]))
        for b, s in enumerate(self.slices):
            qb = q_cols[:, s]
            qq[b] = qb @ qb.T
            qc[b] = qb @ self.y[s]
            if against is not None:
                if against:
                    cross[b, against] = xa[:, s] @ qb.T
                continue
            start = 0
            for chunk in self._chunks:
                k = chunk.shape[0]
                cross[b, start:start + k] = chunk[:, s] @ qb.T
                start += k
        G = np.zeros((B, p + q, p + q))
        G[:, :p, :p] = self.G
        G[:, :p, p:] = cross
        G[:, p:, :p] = np.transpose(cross, (0, 2, 1))
        G[:, p:, p:] = qq
        self.G = G
        self.c = np.concatenate([self.c, qc], axis=1)
        self._chunks.append(q_cols)
        return tuple(range(p, p + q))

    def _lookup(self, col: int):
        start = 0
        for ci, chunk in enumerate(self._chunks):
            if col < start + chunk.shape[0]:
                return ci, col - start
            start += chunk.shape[0]
        raise IndexError(col)

    def column_matrix(self, columns) -> np.ndarray:
        """The (q, n*m) masked values of some columns."""
        out = np.empty((len(columns), self.n * self.m))
        for i, col in enumerate(columns):
            ci, j = self._lookup(col)
            out[i] = self._chunks[ci][j]
        return out

    def fitted(self, columns, beta) -> np.ndarray:
        """``X beta`` as an (n, m) array (zero where the data are missing)."""
        out = np.zeros(self.n * self.m)
        for col, b in zip(columns, beta):
            ci, j = self._lookup(col)
            out += b * self._chunks[ci][j]
        return out.reshape(self.n, self.m)

    def residual(self, columns, beta) -> np.ndarray:
        """``y - X beta`` as (n, m) with NaN where the data are missing."""
        r = self.y.reshape(self.n, self.m) - self.fitted(columns, beta)
        return np.where(self.mask, r, np.nan)

    def jackknife_dof(self, columns) -> np.ndarray:
        """Degrees of freedom of each coefficient's block-jackknife standard error.

        Bell and McCaffrey's (2002) Satterthwaite approximation for a cluster-robust
        variance (Imbens and Kolesar 2016, Rev. Econ. Stat. 98, 701): under a working
        model of independent, equal-variance samples the leverage-adjusted variance
        estimate of coefficient ``j`` is a sum of squares ``sum_b (g_b' y)^2`` whose
        B x B matrix ``W' (I - H) W`` (``w_b = (I - H_bb)^-1/2 X_b M e_j``, H the hat
        matrix, M the inverse normal matrix) has eigenvalues ``l``; the degrees of
        freedom are ``(sum l)^2 / sum l^2``. ``B - 1`` for a level in equal blocks; near
        1 when one block carries the coefficient (a storm-time term), where the normal
        quantile's shortfall would otherwise go unstated. Everything follows from the
        per-block Gram matrices (``X_b' f(X_b M X_b') = f(X_b' X_b M) X_b'``), in
        ``O(B p^3 + p B^3)``.

        Examples
        --------
        >>> g = BlockedGram(np.sin(np.arange(800.0))[:, None], np.repeat(np.arange(8), 100))
        >>> cols = g.add(np.ones((1, 800, 1)))
        >>> np.round(g.jackknife_dof(cols), 6)  # a level in 8 equal blocks: B - 1
        array([7.])
        """
        idx = list(columns)
        p, nb = len(idx), self.n_blocks
        if p == 0:
            return np.zeros(0)
        G = self.G[:, idx][:, :, idx]
        Gt = G.sum(axis=0)
        d = np.sqrt(np.diag(Gt))
        d[d == 0] = 1.0
        Gs = G / np.outer(d, d)[None]          # scaled to a unit-diagonal total
        ev, U = np.linalg.eigh(Gs.sum(axis=0) + 1e-10 * np.eye(p))
        ev = np.maximum(ev, 1e-300)
        m_half = (U / np.sqrt(ev)) @ U.T        # M^1/2 of the scaled problem
        m_inv_half = (U * np.sqrt(ev)) @ U.T
        M = m_half @ m_half
        S = m_half[None] @ Gs @ m_half[None]
        lam, V = np.linalg.eigh((S + S.transpose(0, 2, 1)) / 2)
        lam = np.clip(lam, 0.0, 1.0 - 1e-12)
        # f(G_b M) = M^-1/2 f(S_b) M^1/2 with f = (1 - x)^-1/2; and the symmetric
        # (I - G_b M)^-1 G_b = M^-1/2 [S_b / (1 - S_b)] M^-1/2
        F = m_inv_half[None] @ ((V / np.sqrt(1.0 - lam)[:, None, :]) @ V.transpose(0, 2, 1)) \
            @ m_half[None]
        FG = m_inv_half[None] @ ((V * (lam / (1.0 - lam))[:, None, :]) @ V.transpose(0, 2, 1)) \
            @ m_inv_half[None]
        out = np.empty(p)
        for j in range(p):
            ml = M[:, j]
            ww = np.einsum("i,bij,j->b", ml, FG, ml)
            xw = np.einsum("bij,bjk,k->bi", F, Gs, ml)
            K = np.diag(ww) - xw @ M @ xw.T
            ev_k = np.linalg.eigvalsh((K + K.T) / 2.0)
            den = float(np.sum(ev_k ** 2))
            out[j] = float(np.sum(ev_k) ** 2 / den) if den > 0 else float(nb - 1)
        return np.minimum(out, nb - 1.0)

    def score(self, columns) -> CVScore:
        """Leave-one-block-out CV score and full fit of a set of columns."""
        idx = list(columns)
        p = len(idx)
        if p == 0:
            return CVScore((), np.zeros(0), np.zeros(0), self.yy.copy(), float(self.yy.sum()),
                           np.zeros((self.n_blocks, 0)))
        G = self.G[:, idx][:, :, idx]
        c = self.c[:, idx]
        Gt = G.sum(axis=0)
        ct = c.sum(axis=0)
        d = np.sqrt(np.diag(Gt))
        d[d == 0] = 1.0
        eye = np.eye(p) * 1e-10
        full_n = Gt / np.outer(d, d) + eye
        beta = np.linalg.solve(full_n, ct / d) / d
        A = (Gt[None] - G) / np.outer(d, d)[None] + eye[None]
        rhs = (ct[None] - c) / d[None]
        beta_b = np.linalg.solve(A, rhs[..., None])[..., 0] / d[None]
        sse_b = (self.yy - 2 * np.einsum("bp,bp->b", beta_b, c)
                 + np.einsum("bp,bpq,bq->b", beta_b, G, beta_b))
        sse_in = float(self.yy.sum() - 2 * beta @ ct + beta @ Gt @ beta)
        B = self.n_blocks
        jack = np.sqrt((B - 1) / B * np.sum((beta_b - beta_b.mean(axis=0)) ** 2, axis=0))
        # per-block variance contributions to each coefficient: s_b^2 [M G_b M]_jj with
        # M = (X'X)^-1 and s_b^2 the block's in-sample residual mean square
        M = np.linalg.inv(full_n) / np.outer(d, d)
        lev = np.einsum("jk,bkl,lj->bj", M, G, M)
        sse_in_b = self.yy - 2 * c @ beta + np.einsum("p,bpq,q->b", beta, G, beta)
        s2 = np.maximum(sse_in_b, 0.0) / np.maximum(self.count, 1)
        block_var = np.maximum(lev, 0.0) * s2[:, None]
        return CVScore(tuple(idx), beta, jack, sse_b, max(sse_in, 0.0), beta_b, block_var)


def orthogonal_share(gram: BlockedGram, base, columns) -> float:
    """Relative norm of the part of ``columns`` orthogonal to the ``base`` columns.

    With ``C`` the candidate's columns and ``X`` the base's (indices in ``gram``), the
    part of ``C`` that ``X`` cannot reproduce has the Gram matrix (Schur complement)
    ``S = C'C - C'X (X'X)^+ X'C``. Scaled by the columns' own norms, the square root of
    the smallest eigenvalue of ``S`` is returned: the relative norm of the least
    determined direction the candidate adds, 1 for a column orthogonal to the base, 0
    for one in its span (or a zero column), whatever the columns' units. A candidate
    with a share near 0 makes the joint design rank-deficient: the data cannot tell its
    coefficient from the base's.

    Examples
    --------
    >>> t = np.arange(1000.0)
    >>> g = BlockedGram(np.zeros((1000, 1)), time_blocks(t, block_s=100.0))
    >>> one, = g.add(np.ones((1, 1000, 1)))
    >>> flat, = g.add(np.full((1, 1000, 1), 50.0))     # a scale on a constant model
    >>> ramp, = g.add((t / 1000.0)[None, :, None])
    >>> float(orthogonal_share(g, [one], [flat])) < 1e-6
    True
    >>> round(float(orthogonal_share(g, [one], [ramp])), 3)  # sqrt(1/12) over sqrt(1/3)
    0.5
    """
    cols = list(columns)
    if not cols:
        return 1.0
    base = [b for b in base if b not in cols]
    idx = base + cols
    G = gram.G[:, idx][:, :, idx].sum(axis=0)
    nb = len(base)
    S = G[nb:, nb:]
    norm = np.sqrt(np.diag(S).copy())
    if not np.all(norm > 0):
        return 0.0
    if base:
        Gbb = G[:nb, :nb]
        Gbc = G[:nb, nb:]
        d = np.sqrt(np.diag(Gbb))
        d[d == 0] = 1.0
        # the base scaled to unit diagonal, its null directions (a base already
        # degenerate) left out by the pseudo-inverse
        proj = np.linalg.pinv(Gbb / np.outer(d, d), rcond=1e-12, hermitian=True)
        S = S - (Gbc / d[:, None]).T @ proj @ (Gbc / d[:, None])
    S = S / np.outer(norm, norm)
    ev = np.linalg.eigvalsh((S + S.T) / 2.0)
    return float(np.sqrt(max(ev[0], 0.0)))


def delta_bic_eff(sse_base: float, sse_cand: float, extra_params: int, n_eff: float) -> float:
    """BIC difference (candidate - base) with the effective sample size ``n_eff``.

    Negative values favour the candidate.

    Examples
    --------
    >>> round(delta_bic_eff(100.0, 50.0, 2, 100.0), 2)
    -60.1
    """
    n_eff = max(float(n_eff), 2.0)
    if sse_base <= 0:
        return np.inf
    ratio = max(sse_cand, 1e-300) / sse_base
    return float(n_eff * np.log(ratio) + extra_params * np.log(n_eff))
