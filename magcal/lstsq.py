"""Linear least squares for tall, well-conditioned designs, several times faster.

:func:`numpy.linalg.lstsq` solves by a singular value decomposition of the whole
design (LAPACK ``gelsd``): robust to any rank, but on the tall designs the ELFIN
calibration fits thousands of times (3700 samples by 4 to 66 columns) it is 1.6 to 6.6
times slower than the normal equations (``benchmarks/bench_lstsq.py``, one BLAS
thread; more on a loaded machine). :func:`lstsq` solves the normal
equations, scaled to a unit diagonal, by a Cholesky factorisation and then takes one
step of iterative refinement on the residual (Björck's corrected semi-normal
equations): the error is then that of an orthogonal factorisation while
``eps * cond(A)^2`` stays small. Where the scaled Gram matrix's condition number
exceeds ``max_cond`` (1e8: ``cond(A)`` of about 1e4), where it is not positive definite
(a rank-deficient design: equal columns, harmonics of a phase that misses sectors) or
where an input is not finite, the call is handed to
:func:`numpy.linalg.lstsq` and returns its minimum-norm solution unchanged. Columns of
zeros (terms switched off) get 0, as in that solution, and the others are solved
without them.

:func:`lstsq_stack` is the same method for a stack of small real problems solved
together (the ELFIN timing check's spin windows: a zone's 120 windows of 86 x 19 in one
call), each problem handed to :func:`lstsq` where its scaled Gram matrix is singular or
ill-conditioned.

Pure NumPy and SciPy's LAPACK wrappers; real or complex designs (:func:`lstsq`).
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import lapack

#: Largest condition number (1-norm estimate) of the unit-diagonal Gram matrix solved
#: through the normal equations; above it :func:`numpy.linalg.lstsq` decides.
MAX_COND = 1e8


def lstsq(a, b, *, max_cond: float = MAX_COND) -> np.ndarray:
    """Least-squares solution ``x`` of ``a @ x ~ b`` (the first value of
    :func:`numpy.linalg.lstsq`).

    Parameters
    ----------
    a : array_like (m, n)
        Design, real or complex; ``m >= n``.
    b : array_like (m,) or (m, k)
        Right-hand side(s).
    max_cond : float
        Condition number of the scaled Gram matrix above which the SVD solver of
        :func:`numpy.linalg.lstsq` is used instead.

    Returns
    -------
    x : ndarray (n,) or (n, k)

    Examples
    --------
    >>> t = np.linspace(-1.0, 1.0, 1000)
    >>> a = np.column_stack([np.ones_like(t), t, t ** 2])
    >>> x = lstsq(a, 2.0 - 3.0 * t + 0.5 * t ** 2)
    >>> bool(np.allclose(x, [2.0, -3.0, 0.5], rtol=0, atol=1e-13))
    True
    >>> lstsq(np.column_stack([t, 0 * t]), t)      # rank 1: numpy's minimum-norm answer
    array([1., 0.])
    """
    a = np.asarray(a)
    b = np.asarray(b)
    if np.iscomplexobj(b) and not np.iscomplexobj(a):
        a = a.astype(complex)
    m, n = a.shape
    if n == 0 or m < n or not np.all(np.isfinite(b)):
        return np.linalg.lstsq(a, b, rcond=None)[0]
    ah = a.conj().T if np.iscomplexobj(a) else a.T
    gram = ah @ a
    scale = np.sqrt(np.real(np.diagonal(gram)))
    if not np.all(np.isfinite(gram)):
        return np.linalg.lstsq(a, b, rcond=None)[0]
    if not np.all(scale > 0):
        # columns of zeros (e.g. terms switched off): the minimum-norm answer gives them
        # 0 and the others the answer without them
        live = scale > 0
        x = np.zeros((n,) + b.shape[1:], dtype=np.result_type(a, b, float))
        x[live] = lstsq(a[:, live], b, max_cond=max_cond)
        return x
    unit = gram / np.outer(scale, scale)
    cplx = np.iscomplexobj(unit)
    potrf, pocon, potrs = ((lapack.zpotrf, lapack.zpocon, lapack.zpotrs) if cplx
                           else (lapack.dpotrf, lapack.dpocon, lapack.dpotrs))
    chol, info = potrf(unit, lower=False, clean=False)
    if info != 0:
        return np.linalg.lstsq(a, b, rcond=None)[0]
    rcond, info = pocon(chol, float(np.max(np.sum(np.abs(unit), axis=0))))
    if info != 0 or not rcond * max_cond >= 1.0:
        return np.linalg.lstsq(a, b, rcond=None)[0]

    def solve(rhs):                    # (a^H a) x = rhs, through the scaled factor
        y, _ = potrs(chol, rhs / (scale[:, None] if rhs.ndim == 2 else scale))
        return y / (scale[:, None] if rhs.ndim == 2 else scale)

    x = solve(ah @ b)
    return x + solve(ah @ (b - a @ x))    # one refinement step on the residual


def lstsq_stack(a, b, *, max_cond: float = MAX_COND) -> np.ndarray:
    """:func:`lstsq` of every problem of a stack, the well-conditioned ones at once.

    Parameters
    ----------
    a : array_like (w, m, n)
        Real designs; rows of zeros pad a shorter problem (a zero row changes no
        least-squares answer).
    b : array_like (w, m, k)
        Right-hand sides.
    max_cond : float
        Condition number (2-norm, from the eigenvalues) of a problem's scaled Gram
        matrix above which :func:`lstsq` solves it alone (and hands it to numpy).

    Returns
    -------
    x : ndarray (w, n, k)

    Examples
    --------
    >>> t = np.linspace(-1.0, 1.0, 50)
    >>> a = np.stack([np.column_stack([np.ones_like(t), t]), np.column_stack([t, t])])
    >>> b = np.stack([(1.0 + 2.0 * t)[:, None], t[:, None]])
    >>> np.round(lstsq_stack(a, b)[:, :, 0], 12)       # the second: equal columns
    array([[1. , 2. ],
           [0.5, 0.5]])
    """
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    gram = np.matmul(np.swapaxes(a, 1, 2), a)
    scale = np.sqrt(np.diagonal(gram, axis1=1, axis2=2))
    ok = np.all(scale > 0, axis=1)
    scale = np.where(scale > 0, scale, 1.0)
    unit = gram / (scale[:, :, None] * scale[:, None, :])
    eig = np.linalg.eigvalsh(unit)                      # ascending, per problem
    ok &= eig[:, 0] * max_cond > eig[:, -1]
    x = np.empty((a.shape[0], a.shape[2], b.shape[2]))
    if ok.any():
        au, bu, su, gu = a[ok], b[ok], scale[ok][:, :, None], unit[ok]
        at = np.swapaxes(au, 1, 2)
        first = np.linalg.solve(gu, np.matmul(at, bu) / su) / su
        x[ok] = first + np.linalg.solve(gu, np.matmul(at, bu - np.matmul(au, first)) / su) / su
    for j in np.flatnonzero(~ok):
        x[j] = lstsq(a[j], b[j], max_cond=max_cond)
    return x
