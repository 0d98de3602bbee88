"""Spin-ripple calibration (Kivelson et al. 1992, Appendix 2).

The calibrated field in the rotating frame is ``B = C (b - O)``; despun (CONTRACTS §4)
it should hold no power at the spin frequency and twice the spin frequency. The fit
finds the coupling matrix ``C`` and offsets ``O`` that minimise those spin tones.

Identifiability (Appendix 2): only 8 of the 12 parameters change the spin tones to
first order. A rotation of the triad about the spin axis and a common gain of the spin
plane leave the despun data free of ripple (so only one of c11/c22 and one of c12/c21
can be estimated), ``c33`` scales a nearly constant ``b3``, and ``O3`` shifts ``BZ`` by a
constant (its effect on ``BX, BY`` is the same as that of ``O1, O2``). Following the
paper, ``c11, c12, c33, O3`` are held at their prior values and
``c13, c21, c22, c23, c31, c32, O1, O2`` are estimated.

Speed: the despun spin-harmonic coefficients of every block are linear in ``C`` and in
``d = C O``. The harmonics of twelve fixed signals (``b_j cos p``, ``b_j sin p``,
``b_j``, ``cos p``, ``sin p``, 1) are computed once; after that each Gauss-Newton step
is a small dense least-squares problem, iterated a few times for the bilinear
``C O`` term.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import optimize, stats

from magcal.errors import InputError
from magcal.io.jsonio import product_dict
from magcal.spin.despin import despin
from magcal.spin.harmonics import SpinBlocks, block_harmonics, block_levels, spin_blocks
from magcal.stats import student_scale

#: Names of the 12 calibration parameters, in the order used for vectors.
PARAM_NAMES = ("c11", "c12", "c13", "c21", "c22", "c23", "c31", "c32", "c33", "O1", "O2", "O3")
#: The 8 parameters determined by spin-tone minimisation (paper's choice of fixed ones).
DETERMINABLE = ("c13", "c21", "c22", "c23", "c31", "c32", "O1", "O2")
#: Held at their priors by the ripple fit.
FIXED_BY_RIPPLE = ("c11", "c12", "c33", "O3")
#: Despun component names.
COMPONENTS = ("BX", "BY", "BZ")

#: Long-run variance of the block scores (:func:`solve_ripple`): one cosine term of the
#: equal-weighted cosine estimate per this many blocks (a band up to 1/10 cycle per
#: block, below the natural waves' aliased tones), and at least this many terms.
LRV_BLOCKS_PER_TERM = 5
LRV_MIN_TERMS = 20
#: Errors-in-variables bias term (:func:`solve_ripple`): block harmonics varying more
#: slowly than this many blocks count as the field's signal, faster ones as noise.
BIAS_SMOOTH_BLOCKS = 45
#: Bias correction's guard (:func:`solve_ripple`): a parameter's fitted value is corrected
#: by the estimated bias only when that estimate exceeds this many of its random std,
#: where the waves' tones were found and their end leakage taken out (:func:`wave_tones`).
BIAS_CORRECTION_MIN_RATIO = 0.25
#: The guard where no wave's tone was found, or the waves' end leakage is left in
#: (``correct_leakage=False``). The leakage, linear in the wave and changing with its
#: phase, can cancel the bias: correcting every parameter then lost up to 17 % of RMS
#: error at some wave phases on 1-hour Galileo-like records, this guard at most 3 %.
#: Without waves (ELFIN-like passes) the estimates between 0.25 and 0.75 std are mostly
#: the estimate's own error: correcting them lost 1-2 % of RMS error in c13, c23, O1, O2.
LEAKY_BIAS_CORRECTION_MIN_RATIO = 0.75
#: Waves' end leakage (:func:`wave_tones`): tones are sought above this many times the
#: long-run variance's band (its ``K`` cosines reach ``K / (2 n)`` cycles per block) ...
TONE_BAND_FACTOR = 1.5
#: ... at most this many, each kept if the summed whitened periodogram of the residual
#: harmonics at its peak would be exceeded by white residuals with this probability over
#: the whole record.
TONE_MAX = 6
TONE_FALSE_ALARM = 0.01
#: Curvature leakage (:func:`curvature_leakage`): the field's second derivative at each
#: block is that of a quadratic fitted to the levels of this many blocks around it.
CURVATURE_WINDOW_BLOCKS = 45

# Signals whose block harmonics are precomputed: b_j cos p, b_j sin p, b_j, cos p, sin p, 1.
_N_SIGNALS = 12


def _signals(b, phase) -> np.ndarray:
    c, s = np.cos(phase), np.sin(phase)
    return np.column_stack([b * c[:, None], b * s[:, None], b, c, s, np.ones_like(c)])


def _linear_map() -> np.ndarray:
    """L with W = L @ v, v = [vec(C) (9), d = C O (3)], W (3 components x 12 signals)."""
    lin = np.zeros((3, _N_SIGNALS, 12))
    for j in range(3):
        # BX = sum_j c1j b_j cos - sum_j c2j b_j sin - d1 cos + d2 sin
        lin[0, j, 0 * 3 + j] = 1.0
        lin[0, 3 + j, 1 * 3 + j] = -1.0
        # BY = sum_j c1j b_j sin + sum_j c2j b_j cos - d1 sin - d2 cos
        lin[1, 3 + j, 0 * 3 + j] = 1.0
        lin[1, j, 1 * 3 + j] = 1.0
        # BZ = sum_j c3j b_j - d3
        lin[2, 6 + j, 2 * 3 + j] = 1.0
    lin[0, 9, 9] = -1.0
    lin[0, 10, 10] = 1.0
    lin[1, 10, 9] = -1.0
    lin[1, 9, 10] = -1.0
    lin[2, 11, 11] = -1.0
    return lin


_L = _linear_map()


def _weights_and_jacobian(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Signal weights W (3, 12) of the despun components and dW/dtheta (3, 12, 12)."""
    c = theta[:9].reshape(3, 3)
    o = theta[9:]
    v = np.concatenate([theta[:9], c @ o])
    dv = np.zeros((12, 12))
    dv[:9, :9] = np.eye(9)
    for i in range(3):
        for j in range(3):
            dv[9 + i, 3 * i + j] = o[j]          # d(C O)_i / d c_ij
    dv[9:, 9:] = c                               # d(C O) / d O
    w = _L @ v
    dw = _L @ dv
    return w, dw


@dataclass(frozen=True)
class SpinTone:
    """Coherent spin-tone amplitudes of despun data.

    Attributes
    ----------
    amplitude_nT : ndarray, shape (3, H)
        Amplitude of the block-averaged harmonic at ``1..H`` times the spin frequency
        for ``BX, BY, BZ``.
    noise_floor_nT : ndarray, shape (3, H)
        RMS amplitude that the ambient background alone gives to that average
        (block-to-block scatter / sqrt(number of blocks)).
    """

    amplitude_nT: np.ndarray
    noise_floor_nT: np.ndarray

    def as_dict(self, which: str = "amplitude") -> dict:
        """``{"BX": [a1, a2, ...], ...}``."""
        arr = self.amplitude_nT if which == "amplitude" else self.noise_floor_nT
        return {name: [float(x) for x in arr[k]] for k, name in enumerate(COMPONENTS)}


def _tone_from_coefs(coef: np.ndarray) -> SpinTone:
    """coef (nb, 2H, 3) -> SpinTone."""
    nb = coef.shape[0]
    cos = coef[:, 0::2, :]
    sin = coef[:, 1::2, :]
    amp = np.hypot(cos.mean(axis=0), sin.mean(axis=0)).T
    if nb > 1:
        var = cos.var(axis=0, ddof=1) + sin.var(axis=0, ddof=1)
    else:
        var = np.full(cos.shape[1:], np.nan)
    floor = np.sqrt(var / nb).T
    return SpinTone(amplitude_nT=amp, noise_floor_nT=floor)


def spin_tone(t_s, b_sc, phase_rad, *, n_harmonics: int = 2, spins_per_block: int = 1,
              max_gap_rad: float = np.pi / 4) -> SpinTone:
    """Spin tones of calibrated spacecraft-frame data after despinning.

    Examples
    --------
    >>> import numpy as np
    >>> p = np.linspace(0, 40 * np.pi, 4000, endpoint=False)
    >>> b = np.column_stack([np.full_like(p, 0.3), np.zeros_like(p), np.full_like(p, 9.0)])
    >>> tone = spin_tone(p * 10, b, p)   # a 0.3 nT offset in Bx
    >>> tone.amplitude_nT.round(6)
    array([[0.3, 0. ],
           [0.3, 0. ],
           [0. , 0. ]])
    """
    blocks = spin_blocks(phase_rad, spins_per_block=spins_per_block, max_gap_rad=max_gap_rad)
    coef = block_harmonics(t_s, phase_rad, despin(b_sc, phase_rad), blocks,
                           n_harmonics=n_harmonics)
    return _tone_from_coefs(coef)


@dataclass(frozen=True)
class SpinCalibration:
    """Result of the spin-ripple fit (and of later completion steps).

    Attributes
    ----------
    coupling : ndarray, shape (3, 3)
        ``C`` with ``B = C (b - O)``.
    offsets_nT : ndarray, shape (3,)
        ``O``.
    determined : tuple of str
        Parameters estimated from the data.
    fixed : tuple of str
        Parameters held at their prior values.
    std : dict
        Root mean square error of each determined parameter: the random part's standard
        deviation (scaled by ``t_0.975(dof) / 1.96`` for its degrees of freedom in
        ``std_dof_by_parameter``, so that 1.96 std is Student's 95 % interval), and in
        quadrature the estimated errors-in-variables bias of the parameters not
        corrected for it (:func:`solve_ripple`).
    covariance : ndarray
        Error covariance of the determined parameters, in the order of ``determined``:
        the random covariance plus the outer product of the estimated bias left in.
    spin_tone_before_nT, spin_tone_after_nT, spin_tone_noise_nT : dict
        ``{"BX": [1x, 2x], "BY": [...], "BZ": [...]}`` with the prior parameters, with
        the fitted ones, and the ambient noise floor at those frequencies.
    n_samples, n_blocks, n_blocks_dropped_gap, n_blocks_dropped_partial : int
    n_iterations : int
    converged : bool
    notes : tuple of str
    provenance : dict
    bias_correction : dict
        ``{name: value}`` subtracted from each determined parameter's least-squares value
        (the estimated errors-in-variables bias where it passed the guard, else 0;
        :func:`solve_ripple`). Empty for results not from the ripple fit.
    bias_estimate : dict
        ``{name: value}``: the estimated bias of every determined parameter, corrected or
        not.
    std_dof : int
        The long-run variance's cosine terms (:func:`lrv_terms`): the degrees of freedom
        of the random part of ``std`` where the blocks' influences have one variance; 0
        for results not from the ripple fit.
    leakage_correction : dict
        ``{name: value}`` added to each determined parameter for the natural waves' end
        leakage (:func:`solve_ripple`); all 0 when no wave's tone was found. Empty for
        results not from the ripple fit.
    std_dof_by_parameter : dict
        ``{name: dof}``: the degrees of freedom of the random std of each parameter the
        ripple fit determined (:func:`lrv_dof`; at most ``std_dof``, fewer where the
        variance of its blocks' influences changes over the record), for intervals of
        other levels. Empty for results not from the ripple fit.
    """

    coupling: np.ndarray
    offsets_nT: np.ndarray
    determined: tuple
    fixed: tuple
    std: dict
    covariance: np.ndarray
    spin_tone_before_nT: dict
    spin_tone_after_nT: dict
    spin_tone_noise_nT: dict
    n_samples: int
    n_blocks: int
    n_blocks_dropped_gap: int
    n_blocks_dropped_partial: int
    n_iterations: int
    converged: bool
    notes: tuple = ()
    provenance: dict = field(default_factory=dict)
    bias_correction: dict = field(default_factory=dict)
    bias_estimate: dict = field(default_factory=dict)
    std_dof: int = 0
    leakage_correction: dict = field(default_factory=dict)
    std_dof_by_parameter: dict = field(default_factory=dict)

    def calibrate(self, b) -> np.ndarray:
        """Calibrated spacecraft-frame field ``C (b - O)`` for readings ``b`` (n, 3)."""
        return (np.asarray(b, dtype=float) - self.offsets_nT) @ self.coupling.T

    def parameter(self, name: str) -> float:
        """Value of one of the 12 parameters by name (``"c21"``, ``"O1"``, ...)."""
        k = PARAM_NAMES.index(name)
        return float(self.coupling.ravel()[k]) if k < 9 else float(self.offsets_nT[k - 9])

    def to_json(self) -> dict:
        """CAL.json payload (CONTRACTS §4) with schema and magcal versions."""
        return product_dict({
            "coupling": self.coupling,
            "offsets": self.offsets_nT,
            "determined": list(self.determined),
            "fixed": list(self.fixed),
            "std": self.std,
            "covariance": self.covariance,
            "spin_tone_before_nT": self.spin_tone_before_nT,
            "spin_tone_after_nT": self.spin_tone_after_nT,
            "spin_tone_noise_nT": self.spin_tone_noise_nT,
            "convention": "B = C (b - O); BX = Bx cos p - By sin p, BY = Bx sin p + By cos p",
            "n_samples": self.n_samples,
            "n_blocks": self.n_blocks,
            "n_blocks_dropped_gap": self.n_blocks_dropped_gap,
            "n_blocks_dropped_partial": self.n_blocks_dropped_partial,
            "n_iterations": self.n_iterations,
            "converged": self.converged,
            "notes": list(self.notes),
            "provenance": self.provenance,
            "bias_correction": self.bias_correction,
            "bias_estimate": self.bias_estimate,
            "std_dof": self.std_dof,
            "leakage_correction": self.leakage_correction,
            "std_dof_by_parameter": self.std_dof_by_parameter,
        })


def _check_free(free) -> list[int]:
    free = tuple(free)
    bad = [name for name in free if name not in PARAM_NAMES]
    if bad:
        raise InputError(f"unknown calibration parameter(s) {', '.join(bad)}; "
                         f"names are {', '.join(PARAM_NAMES)}")
    blind = [name for name in free if name in ("c33", "O3")]
    if blind:
        raise InputError(f"{', '.join(blind)} cannot be determined from spin tones "
                         "(Kivelson et al. 1992, App. 2): use the flipper for O3 and a "
                         "laboratory value for c33")
    if {"c11", "c22"} <= set(free):
        raise InputError("only one of c11 and c22 can be determined from spin tones")
    if {"c12", "c21"} <= set(free):
        raise InputError("only one of c12 and c21 can be determined from spin tones")
    return [PARAM_NAMES.index(name) for name in free]


def prepare_harmonics(t_s, b, phase_rad, *, n_harmonics: int = 2, spins_per_block: int = 1,
                      max_gap_rad: float = np.pi / 4, min_spins: int = 10
                      ) -> tuple[np.ndarray, SpinBlocks]:
    """Block harmonics of the twelve signals of the ripple model (the O(n) part).

    Returns the coefficients (n_blocks, 2 H, 12) and the block assignment. Raises
    :class:`InputError` when there are too few spins or samples per spin.
    """
    t = np.asarray(t_s, dtype=float)
    bb = np.asarray(b, dtype=float)
    p = np.asarray(phase_rad, dtype=float)
    if bb.ndim != 2 or bb.shape[1] != 3 or bb.shape[0] != t.size or p.size != t.size:
        raise InputError("need times, phases and readings b1, b2, b3 of equal length")
    if not np.all(np.isfinite(bb)):
        raise InputError("readings contain missing values: drop or fill them first",
                         column="b1/b2/b3")
    if n_harmonics < 1:
        raise InputError("n_harmonics must be at least 1")
    k = 2 + 2 * n_harmonics
    blocks = spin_blocks(p, spins_per_block=spins_per_block, max_gap_rad=max_gap_rad,
                         min_samples=2 * k)
    span = (p[-1] - p[0]) / (2 * np.pi)
    per_spin = t.size / max(span, 1e-12)
    if per_spin < 2 * k:
        raise InputError(f"{per_spin:.1f} samples per spin are too few to resolve "
                         f"{n_harmonics} spin harmonics (need at least {2 * k})")
    if blocks.n_blocks * spins_per_block < min_spins:
        raise InputError(
            f"only {blocks.n_blocks * spins_per_block} complete spins usable "
            f"({span:.1f} spins in the data, {blocks.n_dropped_gap} blocks with gaps "
            f"inside a spin); need at least {min_spins} for the spin-ripple fit")
    coef = block_harmonics(t, p, _signals(bb, p), blocks, n_harmonics=n_harmonics)
    return coef, blocks


def _cosine_long_run(score: np.ndarray, n_terms: int) -> np.ndarray:
    """Equal-weighted cosine estimate of the long-run covariance of ``score.sum(0)``.

    ``score`` (n, p) is projected on the first ``n_terms`` non-constant cosines of a
    type-II DCT (Mueller 2007; Lazarus, Lewis, Stock and Watson 2018); their mean outer
    product times ``n`` is the covariance of the sum if the spectrum is flat over that
    low band. The constant is left out (the fitted scores sum to zero) and no tone
    above the band enters, however strong.
    """
    n = score.shape[0]
    lam = _cosine_basis(n, n_terms) @ score
    return lam.T @ lam * (n / n_terms)


def _cosine_basis(n: int, n_terms: int) -> np.ndarray:
    """The first ``n_terms`` non-constant type-II DCT cosines on ``n`` points, (n_terms, n),
    orthonormal."""
    t = (np.arange(n) + 0.5) / n
    return np.sqrt(2.0 / n) * np.cos(np.pi * np.outer(np.arange(1, n_terms + 1), t))


def lrv_dof(jac: np.ndarray, bread: np.ndarray, n_terms: int) -> np.ndarray:
    """Effective degrees of freedom of each parameter's long-run variance (Satterthwaite).

    A parameter's variance from the cosine estimate (:func:`_cosine_long_run`) is a sum
    of ``K = n_terms`` squared projections of its blocks' influences
    ``g J_b^T r_b`` (``g`` its row of ``bread``). Influences of equal variance make the
    projections independent and of equal variance, the estimate a scaled chi-squared on
    ``K`` degrees of freedom. Where their variance changes over the record the projections
    are correlated and unequal, and the estimate scatters as a chi-squared on fewer:
    Student's factor on ``K`` then makes the 95 % interval too short. That is the case of
    the parameters told apart only by the change of the spin-axis field over the record
    (``c13`` from ``O1``, ``c23`` from ``O2``): a block's influence on them grows with its
    field's distance from the record's mean, so it is concentrated where the field is
    furthest from it, often at the record's ends; on a short pass through a strongly
    changing field they have about half of ``K``.

    The variance of block ``b``'s influence is taken as ``g J_b^T J_b g^T``: that of
    residual harmonics that are white and of one variance, which sets its shape over the
    record (the variance's scale cancels). With ``A = Phi diag(v) Phi^T`` over the
    ``K`` cosines ``Phi``, the degrees of freedom are ``tr(A)**2 / tr(A A)`` (Satterthwaite
    1946): ``K`` for a constant ``v``, fewer otherwise.

    Parameters
    ----------
    jac : ndarray, shape (n_blocks, k, p)
        Jacobian of the residual harmonics, one block per row.
    bread : ndarray, shape (p, p)
        Inverse of the Gauss-Newton normal matrix.
    n_terms : int
        Cosine terms of the long-run variance (:func:`lrv_terms`).

    Returns
    -------
    ndarray, shape (p,)
        Degrees of freedom of each parameter, between 1 and ``n_terms`` (``n_terms`` for
        a parameter without influence).

    Examples
    --------
    Influences growing away from the record's middle (a linearly changing field) leave
    about half the terms:

    >>> import numpy as np
    >>> x = np.linspace(-1.0, 1.0, 200)
    >>> jac = np.stack([np.ones_like(x), x], axis=-1)[:, None, :]
    >>> bread = np.linalg.inv(np.einsum("bkp,bkq->pq", jac, jac))
    >>> lrv_dof(jac, bread, 40).round(1)
    array([40. , 22.8])
    """
    nb = jac.shape[0]
    infl = np.einsum("pq,bkq->bkp", bread, jac)
    v = np.einsum("bkp,bkp->bp", infl, infl)                 # (n_blocks, p)
    basis = _cosine_basis(nb, n_terms)
    tr = (basis * basis).sum(axis=0) @ v
    overlap = basis.T @ basis                                 # (n_blocks, n_blocks)
    tr2 = np.sum(((overlap * overlap) @ v) * v, axis=0)
    dof = np.full(v.shape[1], float(n_terms))
    ok = tr2 > 0
    dof[ok] = tr[ok] ** 2 / tr2[ok]
    return np.clip(dof, 1.0, float(n_terms))


def lrv_terms(n_blocks: int) -> int:
    """Cosine terms of the long-run variance for ``n_blocks`` blocks: its degrees of
    freedom (:data:`LRV_BLOCKS_PER_TERM`, :data:`LRV_MIN_TERMS`)."""
    return max(1, min(n_blocks - 1, max(n_blocks // LRV_BLOCKS_PER_TERM, LRV_MIN_TERMS)))


def _high_pass(harm: np.ndarray, n_slow: int) -> np.ndarray:
    """``harm`` (n, ...) minus its least-squares fit by the first ``n_slow`` DCT terms."""
    n = harm.shape[0]
    t = (np.arange(n) + 0.5) / n
    slow = np.cos(np.pi * np.outer(t, np.arange(n_slow)))
    flat = harm.reshape(n, -1)
    coef, *_ = np.linalg.lstsq(slow, flat, rcond=None)
    return (flat - slow @ coef).reshape(harm.shape)


def wave_tones(resid: np.ndarray, n_terms: int) -> tuple[np.ndarray, np.ndarray]:
    """Natural waves' tones in the residual spin harmonics of the blocks, fitted.

    A natural wave leaves in each block's residual harmonics a tone at its frequency
    (aliased to the blocks' rate). Its sum over the record does not cancel at the
    record's ends: through the slowly varying regressors it is an error of the fit,
    linear in the wave and changing with its phase (:func:`solve_ripple`), and it
    reaches the low cosines of the long-run variance.

    Tones are sought, one at a time, above :data:`TONE_BAND_FACTOR` times the band of
    the ``n_terms`` cosines: the peak of the periodogram (padded 8 times) of the
    whitened residual, less the constant, the band's cosines and the tones found, summed
    over the columns each normalised by its median, is kept when white residuals would
    exceed it with probability :data:`TONE_FALSE_ALARM` (a gamma law), its frequency
    refined, and at most :data:`TONE_MAX` are kept. All are then fitted by least squares
    together with the constant and the band's cosines.

    Parameters
    ----------
    resid : ndarray, shape (n, k)
        Residual harmonics, one row per block.
    n_terms : int
        Cosine terms of the long-run variance (:func:`lrv_terms`).

    Returns
    -------
    tones : ndarray, shape (n, k)
        The fitted tones.
    freqs : ndarray
        Their frequencies in cycles per block.

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(1)
    >>> b = np.arange(400)
    >>> wave = np.cos(2 * np.pi * 0.27 * b + 1.0)[:, None] * [2.0, -1.0]
    >>> tones, freqs = wave_tones(wave + rng.standard_normal((400, 2)), 80)
    >>> freqs.round(3), bool(np.abs(tones - wave).max() < 0.5)
    (array([0.27]), True)
    """
    n, k = resid.shape
    none = (np.zeros_like(resid), np.zeros(0))
    pad = 8 * n
    grid = np.arange(pad // 2 + 1) / pad
    band = grid >= TONE_BAND_FACTOR * n_terms / (2.0 * n)
    if n < 4 or not band.any():
        return none
    dev = resid - resid.mean(axis=0)
    val, vec = np.linalg.eigh(dev.T @ dev / n)
    keep = val > 1e-12 * max(val.max(), 1e-300)
    if not keep.any():
        return none
    white = resid @ (vec[:, keep] / np.sqrt(val[keep]))
    threshold = stats.gamma.isf(TONE_FALSE_ALARM / n, int(keep.sum()))
    b = np.arange(n)
    design = np.cos(np.pi * np.outer((b + 0.5) / n, np.arange(n_terms + 1)))
    freqs = []
    for _ in range(TONE_MAX):
        coef, *_ = np.linalg.lstsq(design, white, rcond=None)
        rest = white - design @ coef
        power = np.abs(np.fft.rfft(rest, pad, axis=0)[band]) ** 2
        scale = np.median(power, axis=0) / np.log(2.0)
        if not np.all(scale > 0):
            break
        total = (power / scale).sum(axis=1)
        j = int(np.argmax(total))
        if total[j] < threshold:
            break

        def minus_power(f, rest=rest):
            return -np.sum(np.abs(np.exp(-2j * np.pi * f * b) @ rest) ** 2)

        f0 = grid[band][j]
        f = optimize.minimize_scalar(minus_power, bounds=(f0 - 1.0 / pad, f0 + 1.0 / pad),
                                     method="bounded").x
        freqs.append(float(f))
        design = np.column_stack([design, np.cos(2 * np.pi * f * b),
                                  np.sin(2 * np.pi * f * b)])
    if not freqs:
        return none
    coef, *_ = np.linalg.lstsq(design, resid, rcond=None)
    m = n_terms + 1
    return design[:, m:] @ coef[m:], np.array(freqs)


def _error_terms(harm: np.ndarray, theta: np.ndarray, idx: list[int], leak: np.ndarray,
                 correct_leakage: bool = True
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, np.ndarray]:
    """Random covariance, estimated bias and waves' end leakage of the parameters ``idx``.

    See :func:`solve_ripple`. Each parameter's row and column of the covariance are
    scaled by :func:`magcal.stats.student_scale` for its long-run variance's degrees of
    freedom (:func:`lrv_dof`), which are returned last. The leakage (zero when
    ``correct_leakage`` is false or no tone is found) is to be added to ``theta``; the
    fourth value is the number of tones found.
    """
    nb = harm.shape[0]
    w, dw = _weights_and_jacobian(theta)
    dw = dw[:, :, idx]
    r = np.einsum("bhs,cs->bhc", harm, w).reshape(nb, -1) - leak
    jac = np.einsum("bhs,csp->bhcp", harm, dw).reshape(nb, -1, len(idx))
    bread = np.linalg.pinv(np.einsum("bkp,bkq->pq", jac, jac))
    score = np.einsum("bkp,bk->bp", jac, r)
    n_terms = lrv_terms(nb)
    n_slow = max(1, min(nb // 2, 1 + (2 * nb) // BIAS_SMOOTH_BLOCKS))
    shift = np.zeros(len(idx))
    freqs = np.zeros(0)
    if correct_leakage:
        tones, freqs = wave_tones(r, n_terms)
        if freqs.size:
            # Through the slow regressors only: the tones times the fast ones are the
            # errors-in-variables bias, estimated below.
            tone_score = np.einsum("bkp,bk->bp", jac - _high_pass(jac, n_slow), tones)
            score = score - tone_score
            shift = bread @ tone_score.sum(axis=0)
    # the cosine estimate of a parameter's variance is a scaled chi-squared on its dof (K
    # when its blocks' influences have one variance, fewer when it changes over the
    # record): error / std is Student's t on them, so each std is scaled for 1.96 std to
    # be its 95 % interval
    dof = lrv_dof(jac, bread, n_terms)
    scale = np.array([student_scale(d) for d in dof])
    cov = bread @ _cosine_long_run(score, n_terms) @ bread * np.outer(scale, scale)
    # Errors in variables: the fast part of the harmonics is in both J and r.
    fast = _high_pass(harm, n_slow)
    gram = np.einsum("bhs,bht->st", fast, fast)
    bias = -bread @ np.einsum("csp,st,ct->p", dw, gram, w)
    return cov, bias, shift, int(freqs.size), dof


def curvature_leakage(t_s, b, phase_rad, blocks: SpinBlocks, coupling0, offsets0, *,
                      n_harmonics: int = 2) -> np.ndarray:
    """Spin harmonics that the field's curvature within a spin puts in each block.

    The block fit (:func:`magcal.spin.harmonics.block_harmonics`) takes out a constant
    and a trend per spin; the field's curvature is left, and a parabola over one spin is
    almost a cosine of the spin phase (correlation 0.96), so it appears in the despun
    components' harmonics as if it were ripple. It is the same in neighbouring blocks,
    so it biases the fit: on ELFIN-like passes (a 2000-3000 nT field changing with
    periods of 900-1300 s, 2.9 s spins) the error of c31 spread 1.24 times its random
    std (c13, O1 1.1 times) with the slow field's phase, and its 95 % intervals held the
    truth in 83-87 % of records with 0.5 nT white noise.

    The field ``B`` is despun with the priors, its level per block taken
    (:func:`magcal.spin.harmonics.block_levels`), and a quadratic in time fitted to the
    levels of the :data:`CURVATURE_WINDOW_BLOCKS` blocks around each block (shifted
    inward at the record's ends) gives the curvature ``k`` there. The leakage is
    ``k`` times the block harmonics of ``(t - t_b)**2``. Calibration errors change the
    curvature in proportion (1e-3 for errors of 1e-3), so the priors suffice. A record
    of fewer than five blocks gets none.

    Returns
    -------
    ndarray, shape (n_blocks, 2 H, 3)
        Harmonics (``cos p, sin p, cos 2p, ...``) of ``BX, BY, BZ`` to subtract from the
        fit's residual.
    """
    nb = blocks.n_blocks
    out = np.zeros((nb, 2 * n_harmonics, 3))
    if nb < 5:
        return out
    t = np.asarray(t_s, dtype=float)
    p = np.asarray(phase_rad, dtype=float)
    c0 = np.asarray(coupling0, dtype=float).reshape(3, 3)
    o0 = np.asarray(offsets0, dtype=float).reshape(3)
    despun = despin((np.asarray(b, dtype=float) - o0) @ c0.T, p)
    levels, times = block_levels(t, p, despun, blocks, n_harmonics=n_harmonics)
    width = min(nb, CURVATURE_WINDOW_BLOCKS)
    first = np.clip(np.arange(nb) - width // 2, 0, nb - width)
    window = first[:, None] + np.arange(width)[None, :]
    x = times[window] - times[:, None]
    scale = np.max(np.abs(x), axis=1, keepdims=True)
    x = x / scale
    design = np.stack([np.ones_like(x), x, x * x], axis=-1)            # (nb, width, 3)
    coef = np.linalg.solve(np.einsum("bwi,bwj->bij", design, design),
                           np.einsum("bwi,bwc->bic", design, levels[window]))
    curvature = coef[:, 2, :] / scale ** 2                              # (nb, 3), nT/s^2
    used = blocks.used
    tau = np.zeros(t.size)
    tau[used] = t[used] - times[blocks.index[used]]
    shape = block_harmonics(t, p, (tau * tau)[:, None], blocks, n_harmonics=n_harmonics)
    return shape * curvature[:, None, :]


def solve_ripple(harm: np.ndarray, coupling0, offsets0, free=DETERMINABLE, *,
                 max_iter: int = 20, tol: float = 1e-12, correct_bias: bool = True,
                 leakage: np.ndarray | None = None, correct_leakage: bool = True
                 ) -> tuple[np.ndarray, np.ndarray, int, bool, np.ndarray, np.ndarray,
                            np.ndarray, np.ndarray]:
    """Gauss-Newton solution of the ripple problem on precomputed block harmonics.

    Returns ``theta`` (12 parameters, corrected for the waves' end leakage and bias,
    below), the error covariance of the free ones, the number of iterations, whether the
    step size fell below ``tol``, the estimated bias of the free parameters, the part of
    it subtracted (zero where the guard, below, or ``correct_bias=False`` left it in),
    the waves' end leakage added (zero with ``correct_leakage=False``), and the degrees
    of freedom of each free parameter's random std (:func:`lrv_dof`).
    ``leakage`` (n_blocks, 2 H, 3), when given, is subtracted from the despun
    components' harmonics before the fit and its error terms: the part of them that is
    not ripple (:func:`curvature_leakage`).

    Random part: a sandwich whose meat is the long-run covariance of the block scores,
    by the equal-weighted cosine estimate (:func:`_cosine_long_run`) with one term per
    :data:`LRV_BLOCKS_PER_TERM` blocks (at least :data:`LRV_MIN_TERMS`, at most all;
    :func:`lrv_terms`). The scores of the random natural field and noise are nearly
    white, but natural waves leave large oscillating residuals that cancel in the sum
    and would not in short clusters of spins; the low cosines keep the first and drop
    the second. The estimate with ``K`` terms has ``K`` degrees of freedom where the
    blocks' influences on a parameter have one variance, and fewer where that changes
    over the record (:func:`lrv_dof`; ``c13, c23, O1, O2``, told apart by the change of
    the spin-axis field, on short records). Each parameter's std is scaled by
    ``t_0.975(dof) / 1.96`` for its own degrees of freedom
    (:func:`magcal.stats.student_scale`), so 1.96 std is Student's 95 % interval.

    Bias: a natural-field tone enters both the residual and the regressors (the block
    harmonics of ``b``), so the score at the truth has a non-zero mean and the fit a bias
    that does not shrink with the record (errors in variables). It is estimated as
    ``-bread @ sum_b dJ_b^T dr_b``, with the parts of the block harmonics faster than
    :data:`BIAS_SMOOTH_BLOCKS` blocks as ``dJ, dr``, and subtracted from each parameter
    whose estimate exceeds :data:`BIAS_CORRECTION_MIN_RATIO` of its random std; the bias
    of the others stays in the covariance as the outer product (their std is a root mean
    square error). The estimate's own scatter is a few per cent of the random std, so a
    corrected parameter's covariance is the random part alone.

    End leakage: a natural wave leaves a tone in the residual harmonics, which the slowly
    varying regressors (the field's level) turn into a tone in the scores. A tone's sum
    does not cancel at the record's ends, so the fit has an error linear in the wave and
    changing with its phase (0.3-0.7 random std on 1-hour Galileo-like records), and
    the tone reaches the long-run variance's low cosines through the ends (the std of
    c22, c31, c32 came out 5-15 % too large). The tones are fitted to the residual
    harmonics (:func:`wave_tones`); their scores through the slow part of the
    regressors (the fast part times the tones is the bias, above) are taken out of the
    scores before the long-run variance, and their sum, mapped through the bread, is
    added to the parameters (``correct_leakage``).

    The guard: with the waves' tones found and their leakage taken out, a bias estimate
    larger than :data:`BIAS_CORRECTION_MIN_RATIO` of the random std is subtracted. With
    no tone found, or the leakage left in (``correct_leakage=False``), where it can
    cancel the bias, the guard is :data:`LEAKY_BIAS_CORRECTION_MIN_RATIO`.

    Coverage and error against the truth, with the variants measured and refused, are
    in the CHANGELOG (spin-ripple errors) and ``benchmarks/bench_ripple_phases.py``.
    """
    idx = _check_free(free)
    theta = np.concatenate([np.asarray(coupling0, float).ravel(), np.asarray(offsets0, float)])
    nb = harm.shape[0]
    leak = np.zeros((nb, harm.shape[1] * 3)) if leakage is None else \
        np.asarray(leakage, dtype=float).reshape(nb, -1)
    converged = False
    it = 0
    for it in range(1, max_iter + 1):
        w, dw = _weights_and_jacobian(theta)
        r = np.einsum("bhs,cs->bhc", harm, w).reshape(nb, -1) - leak
        jac = np.einsum("bhs,csp->bhcp", harm, dw[:, :, idx]).reshape(nb, -1, len(idx))
        jj = jac.reshape(-1, len(idx))
        step, *_ = np.linalg.lstsq(jj, -r.ravel(), rcond=None)
        theta[idx] += step
        if np.max(np.abs(step)) < tol * max(1.0, np.max(np.abs(theta[idx]))):
            converged = True
            break
    cov, bias, shift, n_tones, dof = _error_terms(harm, theta, idx, leak, correct_leakage)
    theta[idx] += shift
    applied = np.zeros_like(bias)
    if correct_bias:
        random_std = np.sqrt(np.clip(np.diag(cov), 0.0, None))
        ratio = BIAS_CORRECTION_MIN_RATIO if n_tones else LEAKY_BIAS_CORRECTION_MIN_RATIO
        use = np.abs(bias) > ratio * random_std
        applied[use] = bias[use]
        theta[idx] -= applied
    left = bias - applied
    return theta, cov + np.outer(left, left), it, converged, bias, applied, shift, dof


def fit_spin_ripple(t_s, b, phase_rad, *, coupling0=None, offsets0=None, free=DETERMINABLE,
                    n_harmonics: int = 2, spins_per_block: int = 1,
                    max_gap_rad: float = np.pi / 4, min_spins: int = 10,
                    max_iter: int = 20, correct_bias: bool = True,
                    correct_curvature: bool = True, correct_leakage: bool = True,
                    provenance: dict | None = None) -> SpinCalibration:
    """Find ``C`` and ``O`` that minimise the spin tones of the despun field.

    Parameters
    ----------
    t_s : array_like, shape (n,)
        Sample times in seconds (any epoch), increasing.
    b : array_like, shape (n, 3)
        Sensor readings ``b1, b2, b3`` (sensor 3 nominally along the spin axis).
    phase_rad : array_like, shape (n,)
        Spin phase, increasing (unwrapped).
    coupling0, offsets0 : array_like, optional
        Prior ``C`` (default identity) and ``O`` (default zero). Parameters not in
        ``free`` keep these values.
    free : sequence of str
        Parameters to estimate; default the 8 determinable ones
        (:data:`DETERMINABLE`).
    n_harmonics : int
        Spin harmonics minimised (the paper: 1 and 2).
    spins_per_block : int
        Whole spins per analysis block.
    max_gap_rad : float
        Largest allowed phase gap inside a block; blocks with larger gaps are dropped.
    min_spins : int
        Fewest usable spins accepted.
    max_iter : int
        Gauss-Newton iterations at most.
    correct_bias : bool
        Subtract the waves' estimated errors-in-variables bias where it is significant
        (:func:`solve_ripple`); ``False`` gives the plain least-squares values, with the
        whole bias in ``std``.
    correct_curvature : bool
        Take the field's curvature within each spin out of the fitted harmonics
        (:func:`curvature_leakage`); ``False`` fits them as they are.
    correct_leakage : bool
        Correct the parameters for the natural waves' tones summed over the record and
        take the tones out of the long-run variance (:func:`solve_ripple`).
    provenance : dict, optional
        Provenance record to attach.

    Returns
    -------
    SpinCalibration

    Raises
    ------
    InputError
        Too few spins or samples per spin, missing values, or a parameter set that spin
        tones cannot determine.

    Examples
    --------
    >>> import numpy as np
    >>> from magcal.simulate.spinning import SpinningConfig, simulate_spinning
    >>> sim = simulate_spinning(SpinningConfig.galileo_like(duration_s=1800.0),
    ...                         rng=np.random.default_rng(0))
    >>> d, tr = sim.data, sim.truth
    >>> c0 = np.eye(3); c0[0] = tr.coupling[0]; c0[2, 2] = tr.coupling[2, 2]
    >>> o0 = np.array([0, 0, tr.offsets_nT[2]])
    >>> cal = fit_spin_ripple(tr.t_s, d[["b1", "b2", "b3"]].to_numpy(), d["phase"].to_numpy(),
    ...                       coupling0=c0, offsets0=o0)
    >>> bool(np.allclose(cal.offsets_nT, tr.offsets_nT, atol=0.05))
    True
    """
    free = tuple(free)
    _check_free(free)
    c0 = np.eye(3) if coupling0 is None else np.asarray(coupling0, dtype=float).reshape(3, 3)
    o0 = np.zeros(3) if offsets0 is None else np.asarray(offsets0, dtype=float).reshape(3)
    harm, blocks = prepare_harmonics(t_s, b, phase_rad, n_harmonics=n_harmonics,
                                     spins_per_block=spins_per_block,
                                     max_gap_rad=max_gap_rad, min_spins=min_spins)
    leak = curvature_leakage(t_s, b, phase_rad, blocks, c0, o0, n_harmonics=n_harmonics) \
        if correct_curvature else None
    theta, cov, n_it, converged, bias, applied, shift, dof = solve_ripple(
        harm, c0, o0, free, max_iter=max_iter, correct_bias=correct_bias, leakage=leak,
        correct_leakage=correct_leakage)
    theta0 = np.concatenate([c0.ravel(), o0])
    before = _tone_from_coefs(np.einsum("bhs,cs->bhc", harm, _weights_and_jacobian(theta0)[0]))
    after = _tone_from_coefs(np.einsum("bhs,cs->bhc", harm, _weights_and_jacobian(theta)[0]))
    fixed = tuple(name for name in PARAM_NAMES if name not in free)
    std = {name: float(np.sqrt(max(cov[k, k], 0.0))) for k, name in enumerate(free)}
    notes = [f"held at prior values (not determinable from spin tones): {', '.join(fixed)}"]
    if blocks.n_dropped_gap:
        notes.append(f"{blocks.n_dropped_gap} spin block(s) dropped for gaps inside the spin")
    corrected = [name for name, a in zip(free, applied) if a != 0.0]
    if corrected:
        notes.append("corrected for the natural waves' errors-in-variables bias: "
                     + ", ".join(corrected))
    return SpinCalibration(
        coupling=theta[:9].reshape(3, 3).copy(), offsets_nT=theta[9:].copy(),
        determined=free, fixed=fixed, std=std, covariance=cov,
        spin_tone_before_nT=before.as_dict(), spin_tone_after_nT=after.as_dict(),
        spin_tone_noise_nT=after.as_dict("noise"), n_samples=int(blocks.used.sum()),
        n_blocks=blocks.n_blocks, n_blocks_dropped_gap=blocks.n_dropped_gap,
        n_blocks_dropped_partial=blocks.n_dropped_partial, n_iterations=n_it,
        converged=converged, notes=tuple(notes), provenance=dict(provenance or {}),
        bias_correction={name: float(a) for name, a in zip(free, applied)},
        bias_estimate={name: float(x) for name, x in zip(free, bias)},
        std_dof=lrv_terms(blocks.n_blocks),
        std_dof_by_parameter={name: float(x) for name, x in zip(free, dof)},
        leakage_correction={name: float(x) for name, x in zip(free, shift)})


class SpinRippleCalibrator:
    """Estimator wrapper around :func:`fit_spin_ripple`.

    Parameters are stored unchanged; :meth:`fit` sets ``result_``, ``coupling_`` and
    ``offsets_``; :meth:`transform` returns the calibrated spacecraft-frame field and
    :meth:`despun` the despun one.

    Examples
    --------
    >>> import numpy as np
    >>> from magcal.simulate.spinning import SpinningConfig, simulate_spinning
    >>> sim = simulate_spinning(SpinningConfig.galileo_like(duration_s=1200.0),
    ...                         rng=np.random.default_rng(3))
    >>> b = sim.data[["b1", "b2", "b3"]].to_numpy()
    >>> est = SpinRippleCalibrator().fit(sim.truth.t_s, b, sim.data["phase"].to_numpy())
    >>> est.transform(b).shape
    (5400, 3)
    """

    def __init__(self, *, coupling0=None, offsets0=None, free=DETERMINABLE, n_harmonics=2,
                 spins_per_block=1, max_gap_rad=np.pi / 4, min_spins=10, max_iter=20,
                 correct_bias=True, correct_curvature=True, correct_leakage=True):
        self.coupling0 = coupling0
        self.offsets0 = offsets0
        self.free = free
        self.n_harmonics = n_harmonics
        self.spins_per_block = spins_per_block
        self.max_gap_rad = max_gap_rad
        self.min_spins = min_spins
        self.max_iter = max_iter
        self.correct_bias = correct_bias
        self.correct_curvature = correct_curvature
        self.correct_leakage = correct_leakage

    def fit(self, t_s, b, phase_rad, provenance=None) -> "SpinRippleCalibrator":
        """Fit on readings ``b`` (n, 3) with times and spin phase; return ``self``."""
        self.result_ = fit_spin_ripple(
            t_s, b, phase_rad, coupling0=self.coupling0, offsets0=self.offsets0,
            free=self.free, n_harmonics=self.n_harmonics,
            spins_per_block=self.spins_per_block, max_gap_rad=self.max_gap_rad,
            min_spins=self.min_spins, max_iter=self.max_iter,
            correct_bias=self.correct_bias, correct_curvature=self.correct_curvature,
            correct_leakage=self.correct_leakage, provenance=provenance)
        self.coupling_ = self.result_.coupling
        self.offsets_ = self.result_.offsets_nT
        return self

    def transform(self, b) -> np.ndarray:
        """Calibrated spacecraft-frame field ``C (b - O)``."""
        return self.result_.calibrate(b)

    def despun(self, b, phase_rad) -> np.ndarray:
        """Calibrated and despun field ``(BX, BY, BZ)``."""
        return despin(self.transform(b), phase_rad)
