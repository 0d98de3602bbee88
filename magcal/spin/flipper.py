"""Spin-axis offset from the flipper (Kivelson et al. 1992).

With the flipper in position 1 the spin-axis sensor 3 is turned into the spin plane,
where the ambient field only modulates it at the spin frequency: the spin average of
its reading is its offset ``O3``. A small tilt of sensor 3 out of the spin plane lets
the spin-axis field ``Bz`` into that average; with the coupling matrix and ``O1`` from
the ripple fit of position 0 the leak is removed spin by spin, with ``Bz`` measured by
sensor 1, which the flip has turned onto the spin axis. ``O3`` then completes the 12
parameters: ``O1, O2`` are moved so that ``C (b - O)`` stays the same in the spin plane.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from magcal.errors import InputError
from magcal.io.jsonio import product_dict
from magcal.spin.harmonics import block_harmonics, spin_blocks
from magcal.spin.ripple import SpinCalibration

#: Flipper position 1 turns the triad so that sensor readings are C^-1 F B_sc + O.
FLIP_MATRIX = np.array([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])


@dataclass(frozen=True)
class FlipperResult:
    """Spin-axis offset from flipper data.

    Attributes
    ----------
    O3, O3_std : float
        Offset of sensor 3 (nT) and its standard deviation.
    O3_raw : float
        Plain spin average of sensor 3 in position 1 (before the tilt correction).
    tilt_correction_nT : float
        ``k Bz`` subtracted from the raw average (0 without a coupling matrix).
    n_spins_flipped, n_spins_unflipped : int
    provenance : dict
    """

    O3: float
    O3_std: float
    O3_raw: float
    tilt_correction_nT: float
    n_spins_flipped: int
    n_spins_unflipped: int
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


def flipper_offset(t_s, b, phase_rad, flip, *, coupling=None, offsets=None,
                   max_gap_rad: float = np.pi / 4, min_spins: int = 3,
                   provenance: dict | None = None) -> FlipperResult:
    """Estimate ``O3`` from intervals in both flipper positions.

    Parameters
    ----------
    t_s, phase_rad : array_like, shape (n,)
        Times (s) and spin phase.
    b : array_like, shape (n, 3)
        Sensor readings.
    flip : array_like of int, shape (n,)
        Flipper position (0 or 1) of each sample.
    coupling, offsets : array_like, optional
        Position-0 calibration (e.g. from :func:`~magcal.spin.ripple.fit_spin_ripple`).
        With them the leak of ``Bz`` into the flipped sensor is removed.
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
    means, blocks = _spin_means(t[on], bb[on, 2], p[on], max_gap_rad)
    if means.size < min_spins:
        raise InputError(f"only {means.size} whole spins with flip = 1 "
                         f"(need at least {min_spins})", column="flip")
    raw = float(means.mean())
    per_spin = means
    n_off = int(spin_blocks(p[~on], max_gap_rad=max_gap_rad, min_samples=8).n_blocks)
    if coupling is not None:
        # Position 1: b = C^-1 F B_sc + O, so the spin averages are
        # <b> = Bz g + O with g = C^-1 F e_z. Sensor 1 (now on the spin axis, offset O1
        # known from position 0) gives Bz spin by spin; sensor 3 then gives O3.
        c = np.asarray(coupling, dtype=float)
        o = np.zeros(3) if offsets is None else np.asarray(offsets, dtype=float)
        g = np.linalg.solve(c, FLIP_MATRIX @ np.array([0.0, 0.0, 1.0]))
        m1, _ = _spin_means(t[on], bb[on, 0], p[on], max_gap_rad)
        bz = (m1 - o[0]) / g[0]
        per_spin = means - g[2] * bz
    o3 = float(per_spin.mean())
    correction = raw - o3
    o3_std = float(per_spin.std(ddof=1) / np.sqrt(per_spin.size)) if per_spin.size > 1 else np.nan
    return FlipperResult(O3=o3, O3_std=o3_std, O3_raw=raw,
                         tilt_correction_nT=float(correction), n_spins_flipped=int(means.size),
                         n_spins_unflipped=n_off, provenance=dict(provenance or {}))


def complete_with_flipper(cal: SpinCalibration, flip: FlipperResult) -> SpinCalibration:
    """Put the flipper's ``O3`` into a ripple calibration (12th parameter).

    ``O1, O2`` move so that ``C (b - O)`` is unchanged in the spin plane (the ripple
    fit determined ``C O`` there, not ``O1, O2`` on their own); ``O3`` moves from
    ``fixed`` to ``determined``.

    Examples
    --------
    See ``workflows/spin_calibration.py``.
    """
    c = cal.coupling
    o = cal.offsets_nT.copy()
    d_o3 = flip.O3 - o[2]
    o[:2] -= np.linalg.solve(c[:2, :2], c[:2, 2] * d_o3)
    o[2] = flip.O3
    std = dict(cal.std)
    std["O3"] = flip.O3_std
    determined = tuple(cal.determined) + ("O3",)
    fixed = tuple(n for n in cal.fixed if n != "O3")
    notes = tuple(cal.notes) + (f"O3 from the flipper: {flip.O3:.4f} +- {flip.O3_std:.4f} nT; "
                                "O1, O2 adjusted to keep the spin-plane calibration",)
    return dataclasses.replace(cal, offsets_nT=o, determined=determined, fixed=fixed, std=std,
                               notes=notes)
