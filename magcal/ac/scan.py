"""Sliding-window PiCoG scan (Constantinescu et al. 2020, §4.2 and Fig. 3).

For every window ``w`` of ``window_n`` samples (sliding by ``step`` samples) the scan
finds the maximum-variance directions of sensor ``i`` and of the difference
``d = b_i - b_j`` and the scaling factor ``alpha_w``. The most probable direction on a
1x1 degree (elevation, azimuth) grid is then taken, and alpha is averaged over the
windows whose directions lie within ``cone_deg`` (2.5 deg) of it.

Speed: the window covariances come from cumulative sums of the first and second
products of the 6 channels (3 of ``b_i``, 3 of ``d``), so each window costs O(1)
whatever its length; the eigen-decompositions run batched on ``(n_windows, 3, 3)``
arrays. Memory is linear in the input.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from magcal.ac.core import (canonical_sign, direction_angles_deg, first_order_from_moments,
                            unit_from_angles_deg)
from magcal.errors import InputError

#: Eigenvalue ratio (largest / intermediate) below which a window's maximum-variance
#: direction counts as ill defined.
MIN_EIGEN_RATIO = 1.5


@dataclass(frozen=True)
class ScanResult:
    """Per-window results of a sliding-window scan (kept for plots such as Fig. 3).

    Arrays have one entry per window; ``valid`` marks windows with enough valid samples
    and a non-degenerate difference variance.
    """

    window_n: int
    step: int
    start: np.ndarray          #: index of the first sample of each window
    direction_i: np.ndarray    #: (n_windows, 3), sense fixed by a common hemisphere
    direction_ij: np.ndarray   #: (n_windows, 3)
    alpha: np.ndarray          #: decorrelation alpha per window
    alpha_variance: np.ndarray #: Eq. 14 alpha per window
    correlation: np.ndarray
    valid: np.ndarray
    #: largest / intermediate variance of the difference per window (how well the
    #: maximum-variance direction ``e_ij`` is defined; near 1: not defined)
    eigen_ratio_ij: np.ndarray | None = None
    #: the same for sensor ``i`` (meaningful for ``direction="variance"``)
    eigen_ratio_i: np.ndarray | None = None
    direction: str = "variance"

    @property
    def n_windows(self) -> int:
        return int(self.start.size)

    def ill_defined(self, min_eigen_ratio: float = MIN_EIGEN_RATIO) -> np.ndarray:
        """Valid windows whose maximum-variance direction is not well defined.

        A direction is ill defined when the ratio of the two largest eigenvalues of
        its covariance is below ``min_eigen_ratio``: the difference direction always,
        the sensor direction too with ``direction="variance"``.
        """
        if self.eigen_ratio_ij is None:
            return np.zeros(self.n_windows, dtype=bool)
        bad = self.eigen_ratio_ij < min_eigen_ratio
        if self.direction == "variance" and self.eigen_ratio_i is not None:
            bad |= self.eigen_ratio_i < min_eigen_ratio
        return self.valid & bad

    def angles_deg(self, which: str = "i") -> tuple[np.ndarray, np.ndarray]:
        """(theta, phi) of the per-window directions, ``which`` = ``"i"`` or ``"ij"``."""
        v = self.direction_i if which == "i" else self.direction_ij
        return direction_angles_deg(v)


@dataclass(frozen=True)
class ScanSummary:
    """Parameters chosen from a scan."""

    direction_i: np.ndarray       #: refined: mean of the selected window directions
    direction_ij: np.ndarray
    direction_i_mode: np.ndarray  #: centre of the most populated 1x1 deg cell
    direction_ij_mode: np.ndarray
    alpha: float                  #: mean alpha over the selected windows
    alpha_std: float
    n_windows: int                #: valid windows
    n_selected: int               #: windows within the cone of both directions
    cone_deg: float
    selected: np.ndarray          #: bool per window
    n_ill_defined: int = 0        #: valid windows with an ill-defined direction
    min_eigen_ratio: float = 0.0  #: threshold used for ``n_ill_defined``
    ill_defined_excluded: bool = False  #: whether those windows were left out


def _window_covariances(b_i, b_j, window_n, step, min_valid_fraction):
    b_i = np.asarray(b_i, dtype=float)
    b_j = np.asarray(b_j, dtype=float)
    n = b_i.shape[0]
    if b_i.shape != b_j.shape or b_i.ndim != 2 or b_i.shape[1] != 3:
        raise InputError(f"sensor arrays must both be (n, 3); got {b_i.shape} and {b_j.shape}")
    window_n = int(window_n)
    if window_n < 3:
        raise InputError(f"window of {window_n} samples is too short (need at least 3)")
    if window_n > n:
        raise InputError(f"window of {window_n} samples is longer than the data ({n} samples)")
    z = np.concatenate([b_i, b_i - b_j], axis=1)
    ok = np.all(np.isfinite(z), axis=1)
    if not ok.any():
        raise InputError("no sample where both sensors are valid")
    z = z - z[ok].mean(axis=0)
    z[~ok] = 0.0
    cnt = np.concatenate([[0], np.cumsum(ok, dtype=np.int64)])
    cs1 = np.zeros((n + 1, 6))
    np.cumsum(z, axis=0, out=cs1[1:])
    cs2 = np.zeros((n + 1, 6, 6))
    np.cumsum(z[:, :, None] * z[:, None, :], axis=0, out=cs2[1:])
    start = np.arange(0, n - window_n + 1, int(step))
    stop = start + window_n
    nn = (cnt[stop] - cnt[start]).astype(float)
    good = nn >= max(3.0, min_valid_fraction * window_n)
    nsafe = np.where(good, nn, 1.0)
    m1 = (cs1[stop] - cs1[start]) / nsafe[:, None]
    cov = (cs2[stop] - cs2[start]) / nsafe[:, None, None] - m1[:, :, None] * m1[:, None, :]
    cov[~good] = np.eye(6)  # placeholder, masked out below
    return start, cov, good


def scan_first_order(b_i, b_j, window_n: int, *, step: int = 1,
                     min_valid_fraction: float = 0.9,
                     direction: str = "variance") -> ScanResult:
    """Sliding-window first-order estimates for the pair (i, j).

    Parameters
    ----------
    b_i, b_j : ndarray, shape (n, 3)
        Sensor to clean and cleaning sensor (nT), uniformly sampled.
    window_n : int
        Window length in samples.
    step : int
        Window shift in samples (1: every sample, as in the paper).
    min_valid_fraction : float
        Windows with fewer valid samples (both sensors finite) are marked invalid.
    direction : {"variance", "coherent"}
        Direction of the disturbance at sensor ``i``: its maximum-variance direction
        (the paper) or the direction of its part coherent with the difference
        (ambient-free), see :func:`magcal.ac.core.first_order_from_moments`.

    Returns
    -------
    ScanResult

    Raises
    ------
    InputError
        Window longer than the data or shorter than 3 samples, or no valid window.

    Examples
    --------
    >>> rng = np.random.default_rng(1)
    >>> s = rng.normal(size=(500, 1)); u = np.array([0.0, 0.0, 1.0])
    >>> amb = rng.normal(scale=0.01, size=(500, 3))
    >>> res = scan_first_order(amb + 4 * s * u, amb + s * u, 100)
    >>> res.n_windows, bool(np.allclose(res.alpha, 4 / 3, atol=1e-2))
    (401, True)
    """
    start, cov, good = _window_covariances(b_i, b_j, window_n, step, min_valid_fraction)
    fit = first_order_from_moments(cov[:, :3, :3], cov[:, 3:, 3:], cov[:, :3, 3:],
                                   direction=direction)
    valid = good & ~fit.degenerate & np.isfinite(fit.alpha)
    if not valid.any():
        raise InputError("no valid window: too many missing samples or no variance in the "
                         "difference of the two sensors")
    e_i, e_ij = fit.direction_i, fit.direction_ij
    # a common hemisphere for each direction: the axial mean over valid windows
    ref_i = np.linalg.eigh(np.einsum("nk,nl->kl", e_i[valid], e_i[valid]))[1][:, 2]
    ref_ij = np.linalg.eigh(np.einsum("nk,nl->kl", e_ij[valid], e_ij[valid]))[1][:, 2]
    s_i = np.where(e_i @ ref_i < 0, -1.0, 1.0)
    s_ij = np.where(e_ij @ ref_ij < 0, -1.0, 1.0)
    flip = s_i * s_ij
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio_ij = fit.eigenvalues_ij[:, 0] / fit.eigenvalues_ij[:, 1]
        ratio_i = fit.eigenvalues_i[:, 0] / fit.eigenvalues_i[:, 1]
    ratio_ij = np.where(fit.eigenvalues_ij[:, 1] > 0, ratio_ij, np.inf)
    ratio_i = np.where(fit.eigenvalues_i[:, 1] > 0, ratio_i, np.inf)
    return ScanResult(window_n=int(window_n), step=int(step), start=start,
                      direction_i=e_i * s_i[:, None], direction_ij=e_ij * s_ij[:, None],
                      alpha=fit.alpha * flip, alpha_variance=fit.alpha_variance * flip,
                      correlation=fit.correlation * flip, valid=valid,
                      eigen_ratio_ij=ratio_ij, eigen_ratio_i=ratio_i, direction=direction)


def direction_density(directions: np.ndarray, grid_deg: float = 1.0):
    """Number density of directions on a (theta, phi) grid.

    Returns
    -------
    counts : ndarray, shape (n_theta, n_phi)
    theta_edges, phi_edges : ndarray
        Bin edges in degrees (theta -90..90, phi -180..180).

    Examples
    --------
    >>> counts, te, pe = direction_density(np.array([[1.0, 0, 0], [1.0, 0, 0]]))
    >>> int(counts.max()), counts.shape
    (2, (180, 360))
    """
    theta, phi = direction_angles_deg(directions)
    te = np.linspace(-90.0, 90.0, int(round(180 / grid_deg)) + 1)
    pe = np.linspace(-180.0, 180.0, int(round(360 / grid_deg)) + 1)
    counts, _, _ = np.histogram2d(theta, phi, bins=[te, pe])
    return counts, te, pe


def _mode_direction(directions, grid_deg):
    counts, te, pe = direction_density(directions, grid_deg)
    k = np.unravel_index(np.argmax(counts), counts.shape)
    return unit_from_angles_deg(0.5 * (te[k[0]] + te[k[0] + 1]), 0.5 * (pe[k[1]] + pe[k[1] + 1]))


def _within(directions, center, cone_deg):
    cosang = np.abs(directions @ center)
    return cosang >= np.cos(np.radians(cone_deg))


def _mean_direction(directions, fallback):
    if directions.shape[0] == 0:
        return fallback
    m = directions.sum(axis=0)
    return m / np.linalg.norm(m)


def summarize_scan(scan: ScanResult, *, cone_deg: float = 2.5, grid_deg: float = 1.0,
                   alpha_kind: str = "alpha", min_eigen_ratio: float = MIN_EIGEN_RATIO,
                   exclude_ill_defined: bool = False) -> ScanSummary:
    """Most probable directions and the mean alpha within ``cone_deg`` of them.

    With paper directions (``scan.direction == "variance"``) the sensor direction is
    the centre of the most populated ``grid_deg`` cell; the
    difference direction is the most populated cell among the windows in the cone of
    the sensor direction. Both are then refined to the mean of the selected window
    directions; alpha is the mean over windows within the cone of both.

    With coherent directions the windows are selected by the difference direction
    alone and the correction vector ``alpha e_i`` is averaged as a vector (see
    :func:`_summarize_coherent`).

    Windows whose direction is ill defined (eigenvalue ratio below
    ``min_eigen_ratio``, see :meth:`ScanResult.ill_defined`) are counted in
    ``n_ill_defined``; with ``exclude_ill_defined`` they are also left out.

    Examples
    --------
    >>> rng = np.random.default_rng(1)
    >>> s = rng.normal(size=(500, 1)); u = np.array([0.0, 0.0, 1.0])
    >>> amb = rng.normal(scale=0.01, size=(500, 3))
    >>> summ = summarize_scan(scan_first_order(amb + 4 * s * u, amb + s * u, 100))
    >>> round(summ.alpha, 2), np.round(summ.direction_i, 2).tolist()
    (1.33, [0.0, 0.0, 1.0])
    """
    ill = scan.ill_defined(min_eigen_ratio)
    v = scan.valid & ~ill if exclude_ill_defined else scan.valid
    if not v.any():
        raise InputError(f"every scan window has an ill-defined direction (largest to "
                         f"intermediate variance below {min_eigen_ratio})")
    e_i = scan.direction_i[v]
    e_ij = scan.direction_ij[v]
    alpha = getattr(scan, alpha_kind)[v]
    if scan.direction == "coherent":
        return _summarize_coherent(scan, v, e_i, e_ij, alpha, cone_deg, grid_deg, ill,
                                   min_eigen_ratio, exclude_ill_defined)
    mode_i = canonical_to(_mode_direction(e_i, grid_deg), e_i)
    in_i = _within(e_i, mode_i, cone_deg)
    pool = e_ij[in_i] if in_i.any() else e_ij
    mode_ij = canonical_to(_mode_direction(pool, grid_deg), e_ij)
    sel = in_i & _within(e_ij, mode_ij, cone_deg)
    if not sel.any():
        raise InputError(f"no scan window has both directions within {cone_deg} deg of the "
                         "most probable ones: the disturbance direction is not stable")
    dir_i = _mean_direction(e_i[sel], mode_i)
    dir_ij = _mean_direction(e_ij[sel], mode_ij)
    selected = np.zeros(scan.n_windows, dtype=bool)
    selected[np.flatnonzero(v)[sel]] = True
    a = alpha[sel]
    return ScanSummary(direction_i=dir_i, direction_ij=dir_ij, direction_i_mode=mode_i,
                       direction_ij_mode=mode_ij, alpha=float(a.mean()),
                       alpha_std=float(a.std()), n_windows=int(scan.valid.sum()),
                       n_selected=int(sel.sum()), cone_deg=float(cone_deg), selected=selected,
                       n_ill_defined=int(ill.sum()), min_eigen_ratio=float(min_eigen_ratio),
                       ill_defined_excluded=bool(exclude_ill_defined))


def _summarize_coherent(scan, v, e_i, e_ij, alpha, cone_deg, grid_deg, ill, min_eigen_ratio,
                        exclude_ill_defined):
    """Coherent directions: windows are selected by the difference direction only (where
    the ambient field cancels); the correction vector ``k = alpha e_i`` is averaged over
    them as a vector, so windows where sensor i barely responds cannot pull the
    direction ``e_i`` to one side."""
    mode_ij = canonical_to(_mode_direction(e_ij, grid_deg), e_ij)
    sel = _within(e_ij, mode_ij, cone_deg)
    if not sel.any():
        raise InputError(f"no scan window has its difference direction within {cone_deg} "
                         "deg of the most probable one: the disturbance direction is not "
                         "stable")
    dir_ij = _mean_direction(e_ij[sel], mode_ij)
    k_w = alpha[sel, None] * e_i[sel]
    k = k_w.mean(axis=0)
    nk = float(np.linalg.norm(k))
    dir_i = canonical_sign(k / nk) if nk > 0 else canonical_sign(_mean_direction(e_i[sel],
                                                                                 e_i[sel][0]))
    a_w = k_w @ dir_i
    mode_i = canonical_to(_mode_direction(e_i[sel], grid_deg), e_i[sel])
    selected = np.zeros(scan.n_windows, dtype=bool)
    selected[np.flatnonzero(v)[sel]] = True
    return ScanSummary(direction_i=dir_i, direction_ij=dir_ij, direction_i_mode=mode_i,
                       direction_ij_mode=mode_ij, alpha=float(a_w.mean()),
                       alpha_std=float(a_w.std()), n_windows=int(scan.valid.sum()),
                       n_selected=int(sel.sum()), cone_deg=float(cone_deg), selected=selected,
                       n_ill_defined=int(ill.sum()), min_eigen_ratio=float(min_eigen_ratio),
                       ill_defined_excluded=bool(exclude_ill_defined))


def canonical_to(center, directions):
    """Flip ``center`` into the hemisphere where most ``directions`` lie."""
    return center if np.sum(directions @ center) >= 0 else -center


def scan_loop_reference(b_i, b_j, window_n: int, *, step: int = 1):
    """Straightforward per-window loop with ``numpy.cov`` and ``numpy.linalg.eigh``.

    The baseline for tests and the benchmark (independent of the closed-form solver).
    Returns ``(alpha, direction_i, direction_ij)`` per window, each direction with its
    largest component positive.
    """
    b_i = np.asarray(b_i, dtype=float)
    b_j = np.asarray(b_j, dtype=float)
    n = b_i.shape[0]
    out_a, out_i, out_ij = [], [], []
    for s in range(0, n - int(window_n) + 1, int(step)):
        x = b_i[s:s + window_n]
        d = x - b_j[s:s + window_n]
        c = np.cov(np.concatenate([x, d], axis=1).T)
        e_i = np.linalg.eigh(c[:3, :3])[1][:, 2]
        w_d, v_d = np.linalg.eigh(c[3:, 3:])
        e_ij = v_d[:, 2]
        e_i = e_i * np.sign(e_i[np.argmax(np.abs(e_i))])
        e_ij = e_ij * np.sign(e_ij[np.argmax(np.abs(e_ij))])
        out_a.append(e_i @ c[:3, 3:] @ e_ij / w_d[2])
        out_i.append(e_i)
        out_ij.append(e_ij)
    return np.array(out_a), np.array(out_i), np.array(out_ij)
