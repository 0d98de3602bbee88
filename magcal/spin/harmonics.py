"""Spin-harmonic content of signals, spin by spin (the numeric core of the ripple fit).

Samples are grouped into blocks of whole spins by their spin phase. In each block every
signal is fitted by least squares with ``[1, t, cos p, sin p, ..., cos Hp, sin Hp]``;
the constant and the trend are nuisance terms, the harmonic coefficients are kept.
Fitting (rather than summing a DFT) keeps non-equispaced sampling and gaps from leaking
the large constant field into the harmonics.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from magcal.errors import InputError
from magcal.spin.despin import TWO_PI


@dataclass(frozen=True)
class SpinBlocks:
    """Assignment of samples to whole-spin blocks.

    Attributes
    ----------
    index : ndarray of int, shape (n,)
        Block number of each sample, -1 for samples not used.
    starts : ndarray of int
        Position of the first used sample of each block within the used samples.
    n_blocks : int
        Usable blocks.
    n_dropped_gap : int
        Blocks dropped because of a gap inside the spin (or too few samples).
    n_dropped_partial : int
        Incomplete blocks at the start or end of the record (or of a segment).
    """

    index: np.ndarray
    starts: np.ndarray
    n_blocks: int
    n_dropped_gap: int
    n_dropped_partial: int

    @property
    def used(self) -> np.ndarray:
        """Boolean mask of the samples in usable blocks."""
        return self.index >= 0


def spin_blocks(phase_rad, *, spins_per_block: int = 1, max_gap_rad: float = np.pi / 4,
                min_samples: int = 8) -> SpinBlocks:
    """Group samples into blocks of ``spins_per_block`` whole spins.

    A block is usable when its first and last samples lie within ``max_gap_rad`` of
    its phase boundaries, no step between samples exceeds ``max_gap_rad`` and it holds
    at least ``min_samples`` samples.

    Examples
    --------
    >>> import numpy as np
    >>> blk = spin_blocks(np.linspace(0, 10 * 2 * np.pi, 1000, endpoint=False))
    >>> blk.n_blocks, blk.n_dropped_gap
    (10, 0)
    """
    p = np.asarray(phase_rad, dtype=float)
    if p.ndim != 1 or p.size < 2:
        raise InputError("need at least two samples with a spin phase")
    if not np.all(np.isfinite(p)):
        raise InputError("spin phase has missing values", column="phase")
    if np.any(np.diff(p) <= 0):
        raise InputError("spin phase must increase from sample to sample (unwrapped)",
                         column="phase")
    width = TWO_PI * spins_per_block
    raw = np.floor(p / width).astype(np.int64)
    bounds = np.flatnonzero(np.diff(raw)) + 1
    seg_start = np.concatenate([[0], bounds])
    seg_end = np.concatenate([bounds, [p.size]])
    index = np.full(p.size, -1, dtype=np.int64)
    n_ok = n_gap = n_partial = 0
    starts = []
    pos = 0
    for a, b in zip(seg_start, seg_end):
        lo = raw[a] * width
        hi = lo + width
        head = p[a] - lo
        tail = hi - p[b - 1]
        inner = np.max(np.diff(p[a:b])) if b - a > 1 else np.inf
        if head > max_gap_rad or tail > max_gap_rad:
            # Partial at the record edges, a gap across a block boundary otherwise.
            if a == 0 or b == p.size:
                n_partial += 1
            else:
                n_gap += 1
            continue
        if inner > max_gap_rad or (b - a) < min_samples:
            n_gap += 1
            continue
        index[a:b] = n_ok
        starts.append(pos)
        pos += b - a
        n_ok += 1
    return SpinBlocks(index=index, starts=np.asarray(starts, dtype=np.int64), n_blocks=n_ok,
                      n_dropped_gap=n_gap, n_dropped_partial=n_partial)


def block_harmonics(t_s, phase_rad, signals, blocks: SpinBlocks, *,
                    n_harmonics: int = 2, trend_degree: int = 1, extra=None) -> np.ndarray:
    """Least-squares spin-harmonic coefficients of each signal in each block.

    Parameters
    ----------
    t_s, phase_rad : array_like, shape (n,)
        Times (s) and spin phase.
    signals : array_like, shape (n, m)
        Signals to analyse.
    blocks : SpinBlocks
        From :func:`spin_blocks`.
    n_harmonics : int
        Highest spin harmonic ``H``.
    trend_degree : int
        Degree of the nuisance polynomial in time per block (1: constant and trend).
    extra : array_like, shape (n, e), optional
        Further regressors fitted in each block; their coefficients follow the
        harmonics in the result.

    Returns
    -------
    ndarray, shape (n_blocks, 2 H + e, m)
        Coefficients of ``cos p, sin p, cos 2p, sin 2p, ...`` (then of the ``extra``
        regressors) in each block.

    Examples
    --------
    >>> import numpy as np
    >>> p = np.linspace(0, 4 * np.pi, 400, endpoint=False)
    >>> t = p.copy()
    >>> x = 5 + 2 * np.cos(p) - 0.5 * np.sin(2 * p)
    >>> h = block_harmonics(t, p, x[:, None], spin_blocks(p))
    >>> h[:, :, 0].round(10) + 0.0
    array([[ 2. ,  0. ,  0. , -0.5],
           [ 2. ,  0. ,  0. , -0.5]])
    """
    coef, _ = _block_fit(t_s, phase_rad, signals, blocks, n_harmonics, trend_degree, extra)
    return coef[:, trend_degree + 1:, :]


def block_levels(t_s, phase_rad, signals, blocks: SpinBlocks, *, n_harmonics: int = 2
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Level of each signal at the mean time of each block, and those times.

    The constant of the same least-squares fit as :func:`block_harmonics` (time measured
    from the block's mean sample time), so that spin tones do not leak into the level
    when a block's samples do not cover the spin evenly.

    Returns
    -------
    levels : ndarray, shape (n_blocks, m)
    times : ndarray, shape (n_blocks,)

    Examples
    --------
    >>> import numpy as np
    >>> p = np.linspace(0, 4 * np.pi, 400, endpoint=False)
    >>> levels, times = block_levels(p, p, (5 + p + 2 * np.cos(p))[:, None], spin_blocks(p))
    >>> bool(np.allclose(levels[:, 0], 5 + times))
    True
    """
    coef, tmean = _block_fit(t_s, phase_rad, signals, blocks, n_harmonics, 1, None)
    return coef[:, 0, :], tmean


def _block_fit(t_s, phase_rad, signals, blocks, n_harmonics, trend_degree, extra):
    """All coefficients (n_blocks, K, m) of the per-block fit and the blocks' mean times."""
    used = blocks.used
    if blocks.n_blocks == 0:
        raise InputError("no complete spins in the data")
    t = np.asarray(t_s, dtype=float)[used]
    p = np.asarray(phase_rad, dtype=float)[used]
    s = np.asarray(signals, dtype=float)
    s = s.reshape(s.shape[0], -1)[used]
    starts = blocks.starts
    # Centre and scale the time within each block for conditioning.
    counts = np.diff(np.concatenate([starts, [t.size]]))
    tmean = np.add.reduceat(t, starts) / counts
    tc = t - np.repeat(tmean, counts)
    tspan = np.maximum(np.maximum.reduceat(np.abs(tc), starts), 1e-12)
    tc = tc / np.repeat(tspan, counts)
    cols = [tc ** d for d in range(trend_degree + 1)]
    for h in range(1, n_harmonics + 1):
        cols.append(np.cos(h * p))
        cols.append(np.sin(h * p))
    if extra is not None:
        ex = np.asarray(extra, dtype=float)
        cols.extend(ex.reshape(ex.shape[0], -1)[used].T)
    a = np.column_stack(cols)                       # (n, K)
    gram = np.add.reduceat(a[:, :, None] * a[:, None, :], starts, axis=0)   # (nb, K, K)
    rhs = np.add.reduceat(a[:, :, None] * s[:, None, :], starts, axis=0)    # (nb, K, m)
    coef = np.linalg.solve(gram, rhs)
    return coef, tmean
