"""Spin-axis offset from the flipper (Kivelson et al. 1992).

With the flipper in position 1 the spin-axis sensor 3 is turned into the spin plane,
where the ambient field only modulates it at the spin frequency: with a steady field the
spin average of its reading is its offset ``O3`` (the paper's own caveat: "for steady
background fields or if averaged over long times"). Two things stand between that
average and ``O3``:

* a small tilt of sensor 3 out of the spin plane lets the spin-axis field ``Bz`` in.
  With the coupling matrix and ``O1`` from the ripple fit of position 0 that leak is
  ``k Bz`` with ``Bz`` measured by sensor 1, which the flip has turned onto the spin
  axis (``tilt_correction_nT``);
* a spin-plane field that changes during a spin does not average out: a despun
  component ``BY`` changing at ``dBY/dt`` adds ``-(S / 2 pi) dBY/dt`` to the average
  over a spin of period ``S``. On the Galileo-like simulation (20 s spin, 10 nT slow
  variations) that is -0.007 nT over a one-hour flip, 0.84 of the spin-average
  method's own standard deviation, and -2.2 nT on an ELFIN-like pass (2.9 s spin,
  2000 nT variations): the bias of the plain spin average. With ``BY`` held constant
  in the simulation it vanishes; the formula predicts it to 3 %.

The estimate therefore works in the despun frame, where the flipped triad is an ordinary
spinning magnetometer: sensors 3 and 2 span the spin plane, the ambient field is slow
and ``O3`` is a tone at the spin frequency (``O3 F^T C e3`` spun). In each spin the two
despun components are fitted with a constant, a trend and the second spin harmonic,
the tone amplitude is the spin's estimate, and the curvature of the field (from the
trends of the neighbouring spins) is taken off. The spins are combined with sine
multitapers (Riedel and Sidorenko 1995) at zero frequency: a smooth weighting that lets
a coherent wave's spin-to-spin oscillation average out, with the error from the same
tapers' residual spread (the spectral density of the spin series near zero frequency,
not the full scatter that the wave dominates). ``O3`` then completes the 12
parameters: ``O1, O2`` are moved so that ``C (b - O)`` stays the same in the spin plane.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from magcal.errors import InputError
from magcal.io.jsonio import product_dict
from magcal.spin.despin import TWO_PI, despin
from magcal.spin.harmonics import block_harmonics, spin_blocks
from magcal.spin.ripple import PARAM_NAMES, SpinCalibration
from magcal.stats import student_scale

#: Flipper position 1 turns the triad so that sensor readings are C^-1 F B_sc + O.
FLIP_MATRIX = np.array([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])

#: Half-width (cycles per spin) of the band about zero frequency whose spectral density
#: of the spin-by-spin estimates sets ``O3_std``: ``floor(2 W (n + 1))`` sine tapers for
#: ``n`` spins (18 for a one-hour Galileo flip). The simulated waves of 0.0137 and
#: 0.031 Hz sit at 0.27 and 0.38 cycles per 20 s spin, outside it. While choosing it
#: (100 records per case) a wider band (0.08) gave the same coverage; the plain scatter
#: of all spins (no band) gave 100 % coverage with z sd 0.25 on the Galileo-like
#: records (std 4 times too large).
TAPER_BANDWIDTH_CYCLES_PER_SPIN = 0.05

#: Fewest sine tapers per flip interval (dof of the error = tapers - 1 over all
#: intervals), so that a short flip still has an error: a 10-minute flip (30 spins)
#: gets 6 (0.09 cycles per spin); with 4, z sd was 1.22 and coverage 91 % there.
MIN_TAPERS = 6



@dataclass(frozen=True)
class FlipperResult:
    """Spin-axis offset from flipper data.

    Attributes
    ----------
    O3, O3_std : float
        Offset of sensor 3 (nT) and its standard deviation: the data's part scaled by
        ``t_0.975(O3_dof) / 1.96`` so that ``O3 -/+ 1.96 O3_std`` is the Student 95 %
        interval (1.08 for a one-hour Galileo flip, 1.31 for ten minutes), and the
        calibration's part in quadrature.
    O3_raw : float
        Plain spin average of sensor 3 in position 1 (before any correction).
    tilt_correction_nT : float
        ``k Bz`` subtracted from the raw average (0 without a coupling matrix).
    field_change_correction_nT : float
        ``O3_raw - tilt_correction_nT - O3``: what the spin-plane field's change within
        the spins (and the taper weighting) put into the plain average.
    n_spins_flipped, n_spins_unflipped : int
    O3_dof : int
        Degrees of freedom of ``O3_std_data`` (sine tapers over all flip intervals - 1).
    O3_std_data, O3_std_calibration : float
        The parts of ``O3_std``, in quadrature: the data's (the tapers', scaled as
        above) and the position-0 calibration's, propagated from its covariance
        (0 when none is given; :func:`flipper_offset`).
    provenance : dict
    """

    O3: float
    O3_std: float
    O3_raw: float
    tilt_correction_nT: float
    n_spins_flipped: int
    n_spins_unflipped: int
    field_change_correction_nT: float = 0.0
    O3_dof: int = 0
    O3_std_data: float = float("nan")
    O3_std_calibration: float = 0.0
    provenance: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        """FLIP.json payload (CONTRACTS §4)."""
        return product_dict(dataclasses.asdict(self))


def _spin_means(t, b3, p, max_gap_rad):
    blocks = spin_blocks(p, max_gap_rad=max_gap_rad, min_samples=8)
    if blocks.n_blocks == 0:
        return np.array([]), blocks
    used = blocks.used
    starts = blocks.starts
    # Per-spin constant of the least-squares fit [1, t, cos p, sin p, cos 2p, sin 2p]:
    # fit the harmonics, subtract them, then average (exact for the LS constant term
    # at the block-centred time).
    harm = block_harmonics(t, p, b3[:, None], blocks, n_harmonics=2)[:, :, 0]
    pu = p[used]
    model = (np.repeat(harm[:, 0], np.diff(np.r_[starts, pu.size])) * np.cos(pu)
             + np.repeat(harm[:, 1], np.diff(np.r_[starts, pu.size])) * np.sin(pu)
             + np.repeat(harm[:, 2], np.diff(np.r_[starts, pu.size])) * np.cos(2 * pu)
             + np.repeat(harm[:, 3], np.diff(np.r_[starts, pu.size])) * np.sin(2 * pu))
    rest = b3[used] - model
    counts = np.diff(np.r_[starts, pu.size])
    return np.add.reduceat(rest, starts) / counts, blocks


def _spin_tone(t, b, p, run, coupling, offsets, max_gap_rad):
    """Spin-by-spin estimates of ``O3`` from the despun flipped triad.

    Position 1 reads ``b = C^-1 F B_sc + O``, so ``F^T C (b - O') = B_sc + O3 v`` with
    ``O' = (O1, O2, 0)`` and ``v = F^T C e3`` (sensor 3 looks along +x). Despun, ``O3``
    is the tone ``O3 despin(v)`` at the spin frequency on a slow ambient field. In
    each spin both despun spin-plane components are fitted with a constant and a trend
    (the tone is orthogonal to the constant; the trend takes 30 % of its information)
    and the second spin harmonic, which a gain mismatch of sensors 2 and 3 in the
    calibration puts there and which the trend would otherwise pass to the tone: with
    the ripple-fitted calibration of the demo record (sensor gains 0.0012 and 0.0007
    off) ``O3`` was off by -0.0036 nT (5.5 std) without it, -0.0002 nT with it. The
    field's curvature, from the central difference of the neighbouring spins' trends
    within one flip interval, is removed from the tone's projection. Without it the
    0.1 nT s^-2 curvature of an ELFIN-like pass biased ``O3`` by -0.026 nT (z mean
    -0.89 over 100 records); with it +0.0013 nT (z mean +0.06). Fitting blocks of 2-3
    spins with a cubic instead removed that bias too but let the simulated waves into
    short flips (z mean +0.5 with two 10-minute flips).

    Returns
    -------
    x : ndarray
        ``O3`` of each usable spin.
    pos : ndarray
        Spin count at the middle of each spin (phase / 2 pi).
    run : ndarray
        Flip interval of each spin.
    """
    blocks = spin_blocks(p, max_gap_rad=max_gap_rad, min_samples=8)
    used, starts = blocks.used, blocks.starts
    c = np.eye(3) if coupling is None else np.asarray(coupling, dtype=float)
    o = np.zeros(3) if offsets is None else np.asarray(offsets, dtype=float).copy()
    o[2] = 0.0
    pu, tu = p[used], t[used]
    field_ = despin((b[used] - o) @ c.T @ FLIP_MATRIX, pu)[:, :2]
    v = FLIP_MATRIX.T @ c[:, 2]
    tone = despin(np.broadcast_to(v, (pu.size, 3)), pu)[:, :2]
    counts = np.diff(np.r_[starts, pu.size])
    tmid = np.add.reduceat(tu, starts) / counts
    u = tu - np.repeat(tmid, counts)
    half = np.maximum(np.maximum.reduceat(np.abs(u), starts), 1e-12)
    u = u / np.repeat(half, counts)
    design = np.column_stack([np.ones_like(u), u, np.cos(2 * pu), np.sin(2 * pu)])
    gram = np.add.reduceat(design[:, :, None] * design[:, None, :], starts, axis=0)

    def detrend(z):
        rhs = np.add.reduceat(design[:, :, None] * z[:, None, :], starts, axis=0)
        coef = np.linalg.solve(gram, rhs)                  # (nb, design column, comp)
        fit = np.einsum("nk,nkc->nc", design, np.repeat(coef, counts, axis=0))
        return z - fit, coef[:, 1, :]

    f_res, trend = detrend(field_)
    r_res, _ = detrend(tone)
    num = np.add.reduceat(np.sum(r_res * f_res, axis=1), starts)
    den = np.add.reduceat(np.sum(r_res * r_res, axis=1), starts)
    run_b = run[used][starts]
    slope = trend / half[:, None]                          # nT/s, per despun component
    curvature = np.zeros_like(slope)
    for r in np.unique(run_b):
        sel = np.flatnonzero(run_b == r)
        if sel.size >= 3:
            curvature[sel] = np.gradient(slope[sel], tmid[sel], axis=0)
    quad = 0.5 * curvature * half[:, None] ** 2            # coefficient of u^2
    num = num - np.sum(quad * np.add.reduceat(r_res * (u ** 2)[:, None], starts, axis=0),
                       axis=1)
    pos = np.add.reduceat(pu, starts) / counts / TWO_PI
    return num / den, pos, run_b


def _taper_mean(x, pos, run):
    """Mean of spin estimates and its error from sine multitapers at zero frequency.

    Per flip interval of ``n`` spins the ``K`` sine tapers
    ``sin(pi k (j + 1) / (n + 1))`` (orthonormalised over the spins present) project
    the series; the mean is the least-squares fit of the tapers' sums to the
    projections, and the residual spread of the projections estimates the spectral
    density near zero frequency with ``K - 1`` degrees of freedom over all intervals
    (Thomson's test for a line, here at frequency zero). A coherent wave off zero
    frequency enters neither, while a red field's power at low frequency enters both.

    Returns
    -------
    mean, std, dof
        ``std`` is already scaled by ``t_0.975(dof) / 1.96``.
    """
    proj, sums = [], []
    for r in np.unique(run):
        sel = run == r
        j = pos[sel] - pos[sel][0]
        length = j[-1] + 2.0
        k = min(max(MIN_TAPERS, int(np.floor(2 * TAPER_BANDWIDTH_CYCLES_PER_SPIN * length))),
                int(sel.sum()))
        tapers = np.sin(np.pi * np.outer(j + 1.0, np.arange(1, k + 1)) / length)
        q, _ = np.linalg.qr(tapers)
        proj.append(q.T @ x[sel])
        sums.append(q.sum(axis=0))
    y, s = np.concatenate(proj), np.concatenate(sums)
    mean = float(s @ y / (s @ s))
    dof = y.size - 1
    if dof < 1:
        return mean, float("nan"), 0
    se = np.sqrt(np.sum((y - mean * s) ** 2) / dof / (s @ s))
    # scaled by t_0.975(dof) / 1.96 (:func:`magcal.stats.student_scale`): unscaled,
    # coverage was 88 % on 10-minute flips and 92 % on a 2-minute ELFIN-like flip
    # (5 dof each, 100 records); scaled 96 % and 98 %
    return mean, float(se * student_scale(dof)), int(dof)


def flipper_offset(t_s, b, phase_rad, flip, *, coupling=None, offsets=None,
                   covariance=None, determined=(),
                   max_gap_rad: float = np.pi / 4, min_spins: int = 3,
                   provenance: dict | None = None) -> FlipperResult:
    """Estimate ``O3`` from intervals in both flipper positions.

    ``O3`` comes from the flipped spins as the spin-frequency tone of the despun
    sensors 3 and 2 (see the module notes), not from the plain spin average of sensor
    3, which a changing spin-plane field biases by ``-(S / 2 pi) dBY/dt``. z =
    (O3 - truth) / O3_std on 120 held-out seeded records per configuration (Galileo-like
    4 h record with the test's tilted coupling and a one-hour flip unless stated; the
    last two were looked at, on other seeds, while choosing the design):

    ===============================  ======================  ======================
    configuration                    plain average: z mean,  this estimate: z mean,
                                     z sd, 95 % coverage     z sd, 95 % coverage
    ===============================  ======================  ======================
    0.2 nT red turbulence, waves     -0.84, 0.07, 100 %      +0.04, 0.92, 98.3 %
    1 nT red turbulence, waves       -0.77, 0.31, 100 %      +0.10, 0.93, 97.5 %
    white noise only (0.1 nT)        -0.11, 0.94, 95.0 %     -0.07, 0.94, 94.2 %
    3 flips, 0.5 nT, drifting spin   -0.09, 0.17, 100 %      +0.14, 0.83, 99.2 %
    10-minute flip                   -0.19, 0.08, 100 %      -0.15, 0.96, 94.2 %
    ELFIN-like pass, 2-min flip      -17.2, 0.63, 0 %        -0.08, 0.98, 93.3 %
    ===============================  ======================  ======================

    Over 400 further records the three-flip case covers 93.5 % (z sd 1.04), and over
    2000 white-noise records 94.9 % (z sd 0.98). The price is noise: with white noise
    only the error is 1.25 times the plain average's (0.00098 against 0.00079 nT; the
    per-spin trend takes 30 % of the tone's information).

    Parameters
    ----------
    t_s, phase_rad : array_like, shape (n,)
        Times (s) and spin phase.
    b : array_like, shape (n, 3)
        Sensor readings.
    flip : array_like of int, shape (n,)
        Flipper position (0 or 1) of each sample; each run of 1s is one flip interval.
    coupling, offsets : array_like, optional
        Position-0 calibration (e.g. from :func:`~magcal.spin.ripple.fit_spin_ripple`).
        With them the leak of ``Bz`` into the flipped sensor is removed; without a
        coupling the triad is taken as ideal (identity; ``O1, O2`` zero unless given).
    covariance, determined : array_like, sequence of str, optional
        The calibration's error covariance and the names (:data:`PARAM_NAMES`) of the
        parameters it covers (``SpinCalibration.covariance``, ``.determined``). ``O3``
        depends on the coupling (the tone's direction, the ``Bz`` leak) and ``O1, O2``:
        their errors move it, and the data's error does not say so. The derivative of
        ``O3`` by each parameter (central difference over one standard deviation) and
        the covariance give ``O3_std_calibration``, added in quadrature. With a
        calibration fitted by the ripple fit on the same record (Galileo-like, 4 h, a
        one-hour flip; 40 seeded records each) the data's part alone held the truth in
        82 % (0.2 nT red turbulence) and 80 % (1 nT) of the 95 % intervals.
    min_spins : int
        Fewest whole spins needed in position 1.

    Returns
    -------
    FlipperResult

    Raises
    ------
    InputError
        No samples in one of the flip positions, or too few whole spins flipped.

    Examples
    --------
    >>> import numpy as np
    >>> from magcal.simulate.spinning import SpinningConfig, simulate_spinning
    >>> sim = simulate_spinning(SpinningConfig.galileo_like(
    ...     duration_s=1800.0, flip_intervals_s=((600.0, 1200.0),)), rng=np.random.default_rng(2))
    >>> d = sim.data
    >>> res = flipper_offset(sim.truth.t_s, d[["b1", "b2", "b3"]].to_numpy(), d["phase"].to_numpy(),
    ...                      d["flip"].to_numpy(), coupling=sim.truth.coupling,
    ...                      offsets=sim.truth.offsets_nT)
    >>> abs(res.O3 - 0.45) < 0.05
    True
    """
    t = np.asarray(t_s, dtype=float)
    bb = np.asarray(b, dtype=float)
    p = np.asarray(phase_rad, dtype=float)
    fl = np.asarray(flip)
    if fl.shape != t.shape:
        raise InputError("flip column has the wrong length", column="flip")
    if not np.all(np.isin(fl, (0, 1))):
        raise InputError("flip must be 0 or 1 in every row", column="flip")
    on = fl == 1
    if not on.any():
        raise InputError("no flipper intervals: no rows with flip = 1", column="flip")
    if on.all():
        raise InputError("no rows with flip = 0: the spin-axis field needs data in both "
                         "flipper positions", column="flip")
    t_on, b_on, p_on = t[on], bb[on], p[on]
    means, blocks = _spin_means(t_on, b_on[:, 2], p_on, max_gap_rad)
    if means.size < min_spins:
        raise InputError(f"only {means.size} whole spins with flip = 1 "
                         f"(need at least {min_spins})", column="flip")
    raw = float(means.mean())
    tilt = 0.0
    n_off = int(spin_blocks(p[~on], max_gap_rad=max_gap_rad, min_samples=8).n_blocks)
    if coupling is not None:
        # Position 1: b = C^-1 F B_sc + O, so the spin averages are
        # <b> = Bz g + O with g = C^-1 F e_z. Sensor 1 (now on the spin axis, offset O1
        # known from position 0) gives Bz spin by spin, g[2] Bz is sensor 3's share.
        c = np.asarray(coupling, dtype=float)
        o = np.zeros(3) if offsets is None else np.asarray(offsets, dtype=float)
        g = np.linalg.solve(c, FLIP_MATRIX @ np.array([0.0, 0.0, 1.0]))
        m1, _ = _spin_means(t_on, b_on[:, 0], p_on, max_gap_rad)
        tilt = float(np.mean(g[2] * (m1 - o[0]) / g[0]))
    run = np.cumsum(np.r_[True, on[1:] != on[:-1]])[on]

    def estimate(c_, o_):
        return _taper_mean(*_spin_tone(t_on, b_on, p_on, run, c_, o_, max_gap_rad))

    o3, o3_std, dof = estimate(coupling, offsets)
    std_cal = 0.0
    if covariance is not None and len(determined):
        std_cal = _calibration_std(lambda c_, o_: estimate(c_, o_)[0],
                                   coupling, offsets, covariance, determined)
    return FlipperResult(O3=o3, O3_std=float(np.hypot(o3_std, std_cal)), O3_raw=raw,
                         tilt_correction_nT=tilt,
                         n_spins_flipped=int(means.size), n_spins_unflipped=n_off,
                         field_change_correction_nT=raw - tilt - o3, O3_dof=dof,
                         O3_std_data=o3_std, O3_std_calibration=std_cal,
                         provenance=dict(provenance or {}))


def _calibration_std(estimate, coupling, offsets, covariance, determined) -> float:
    """Standard deviation that a calibration's errors give ``estimate(coupling, offsets)``:
    ``sqrt(g^T S g)`` with ``g`` its central differences over one standard deviation of
    each parameter in ``determined`` and ``S`` their ``covariance``."""
    cov = np.atleast_2d(np.asarray(covariance, dtype=float))
    names = list(determined)
    if cov.shape != (len(names), len(names)):
        raise InputError(f"calibration covariance of shape {cov.shape} for {len(names)} "
                         "determined parameters", column="covariance")
    theta = np.concatenate([np.eye(3).ravel() if coupling is None
                            else np.asarray(coupling, dtype=float).ravel(),
                            np.zeros(3) if offsets is None
                            else np.asarray(offsets, dtype=float)])
    grad = np.zeros(len(names))
    for k, name in enumerate(names):
        h = float(np.sqrt(max(cov[k, k], 0.0)))
        if name not in PARAM_NAMES or not np.isfinite(h) or h == 0.0:
            continue
        j = PARAM_NAMES.index(name)
        vals = []
        for sign in (1.0, -1.0):
            th = theta.copy()
            th[j] += sign * h
            vals.append(estimate(th[:9].reshape(3, 3), th[9:]))
        grad[k] = (vals[0] - vals[1]) / (2.0 * h)
    return float(np.sqrt(max(grad @ np.nan_to_num(cov) @ grad, 0.0)))


def offsets_with_o3(coupling, offsets, o3: float) -> np.ndarray:
    """``offsets`` with ``O3`` set to ``o3`` and ``O1, O2`` moved so that ``C (b - O)``
    stays the same in the spin plane (the ripple fit determined ``C O`` there, not
    ``O1, O2`` on their own).

    Examples
    --------
    >>> c = np.array([[1.0, 0.0, 0.01], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    >>> offsets_with_o3(c, [1.0, 2.0, 0.0], 5.0).tolist()
    [0.95, 2.0, 5.0]
    """
    c = np.asarray(coupling, dtype=float)
    o = np.array(offsets, dtype=float)
    o[:2] -= np.linalg.solve(c[:2, :2], c[:2, 2] * (o3 - o[2]))
    o[2] = o3
    return o


def complete_with_flipper(cal: SpinCalibration, flip: FlipperResult) -> SpinCalibration:
    """Put the flipper's ``O3`` into a ripple calibration (12th parameter).

    ``O1, O2`` move so that ``C (b - O)`` is unchanged in the spin plane (the ripple
    fit determined ``C O`` there, not ``O1, O2`` on their own); ``O3`` moves from
    ``fixed`` to ``determined``.

    Examples
    --------
    See ``workflows/spin_calibration.py``.
    """
    o = offsets_with_o3(cal.coupling, cal.offsets_nT, flip.O3)
    std = dict(cal.std)
    std["O3"] = flip.O3_std
    determined = tuple(cal.determined) + ("O3",)
    fixed = tuple(n for n in cal.fixed if n != "O3")
    notes = tuple(cal.notes) + (f"O3 from the flipper: {flip.O3:.4f} +- {flip.O3_std:.4f} nT; "
                                "O1, O2 adjusted to keep the spin-plane calibration",)
    return dataclasses.replace(cal, offsets_nT=o, determined=determined, fixed=fixed, std=std,
                               notes=notes)
