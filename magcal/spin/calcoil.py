"""Reference direction in the spin plane from the calibration coil (MAG Cal Coil).

Spin tones cannot see a turn of the sensor triad about the spin axis nor a common gain
of the spin plane (Kivelson et al. 1992, App. 2). A coil fixed to the spacecraft and
driven with a known square wave (frequency, amplitude, switch-on time) gives a field of
known direction and size in the spacecraft frame. Its measured direction in the
calibrated frame gives the turn, its size the spin-plane gain; both are then removed
from the coupling matrix, which determines the remaining spin-plane parameters
(``c11, c12``).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from magcal.errors import InputError
from magcal.io.jsonio import product_dict
from magcal.spin.harmonics import block_harmonics, spin_blocks
from magcal.spin.ripple import SpinCalibration


def square_wave(t_s, frequency_hz: float, t_on_s: float, intervals_s=None) -> np.ndarray:
    """On/off square wave (1 during the first half of each period from ``t_on_s``).

    Examples
    --------
    >>> square_wave([0.0, 0.4, 0.6, 1.0, 1.2], 1.0, 0.0).tolist()
    [1.0, 1.0, 0.0, 1.0, 1.0]
    """
    t = np.asarray(t_s, dtype=float)
    s = ((((t - t_on_s) * frequency_hz) % 1.0) < 0.5).astype(float)
    if intervals_s is not None:
        inside = np.zeros(t.shape, dtype=bool)
        for a, b in intervals_s:
            inside |= (t >= a) & (t < b)
        s[~inside] = 0.0
    return s


@dataclass(frozen=True)
class CalCoilResult:
    """Coil field measured in the calibrated spacecraft frame.

    Attributes
    ----------
    vector_nT, vector_std_nT : ndarray, shape (3,)
        Measured coil field (amplitude of the on state) and its standard deviation.
    rotation_deg, rotation_std_deg : float
        Turn of the calibrated frame about the spin axis relative to the spacecraft
        frame (measured minus known azimuth of the coil).
    gain_ratio : float
        Measured over known spin-plane amplitude of the coil field.
    n_blocks : int
    provenance : dict
    """

    vector_nT: np.ndarray
    vector_std_nT: np.ndarray
    rotation_deg: float
    rotation_std_deg: float
    gain_ratio: float
    n_blocks: int
    provenance: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        """JSON payload with schema and magcal versions."""
        return product_dict(dataclasses.asdict(self))


def calcoil_rotation(t_s, b_sc, phase_rad, *, frequency_hz: float, t_on_s: float,
                     direction_sc, amplitude_nT: float, intervals_s=None,
                     max_gap_rad: float = np.pi / 4,
                     provenance: dict | None = None) -> CalCoilResult:
    """Measure the calibration-coil field and the turn about the spin axis.

    In each spin the calibrated components are fitted with a constant, a trend, the
    first two spin harmonics (the ambient field rotating past) and the known square
    wave; the square-wave coefficients are averaged over spins.

    Parameters
    ----------
    t_s, phase_rad : array_like, shape (n,)
        Times (s) and spin phase.
    b_sc : array_like, shape (n, 3)
        Field in the calibrated spacecraft frame, ``C (b - O)``.
    frequency_hz, t_on_s : float
        Square-wave frequency and a time (same epoch as ``t_s``) when it switches on.
    direction_sc : array_like, shape (3,)
        Known coil-field direction in the spacecraft frame.
    amplitude_nT : float
        Known coil-field amplitude (on state).
    intervals_s : sequence of (start, end), optional
        When the coil was driven (default: all of the record).

    Returns
    -------
    CalCoilResult

    Examples
    --------
    >>> import numpy as np
    >>> from magcal.simulate.spinning import SpinningConfig, simulate_spinning
    >>> sim = simulate_spinning(SpinningConfig.galileo_like(duration_s=600.0,
    ...     calcoil_amplitude_nT=4.5, calcoil_intervals_s=((0.0, 600.0),)),
    ...     rng=np.random.default_rng(4))
    >>> res = calcoil_rotation(sim.truth.t_s, sim.truth.b_sc @ np.diag([1, 1, 1.0]).T,
    ...                        sim.truth.phase_rad, frequency_hz=0.5, t_on_s=0.0,
    ...                        direction_sc=[0, 1, 0], amplitude_nT=4.5)
    >>> abs(res.rotation_deg) < 0.05
    True
    """
    t = np.asarray(t_s, dtype=float)
    b = np.asarray(b_sc, dtype=float)
    p = np.asarray(phase_rad, dtype=float)
    u = np.asarray(direction_sc, dtype=float)
    if not np.linalg.norm(u[:2]) > 0:
        raise InputError("the coil direction needs a spin-plane component to fix the turn")
    u = u / np.linalg.norm(u)
    s = square_wave(t, frequency_hz, t_on_s, intervals_s)
    if intervals_s is not None:
        inside = np.zeros(t.shape, dtype=bool)
        for a, bnd in intervals_s:
            inside |= (t >= a) & (t < bnd)
        t, b, p, s = t[inside], b[inside], p[inside], s[inside]
    if t.size == 0 or s.min() == s.max():
        raise InputError("no calibration-coil signal in the data (square wave never switches)")
    blocks = spin_blocks(p, max_gap_rad=max_gap_rad, min_samples=16)
    if blocks.n_blocks < 2:
        raise InputError(f"only {blocks.n_blocks} whole spins with the coil on; need 2 or more")
    coef = block_harmonics(t, p, b, blocks, n_harmonics=2, extra=s[:, None])[:, -1, :]
    vec = coef.mean(axis=0)
    vec_std = coef.std(axis=0, ddof=1) / np.sqrt(coef.shape[0])
    az_meas = np.arctan2(vec[1], vec[0])
    az_known = np.arctan2(u[1], u[0])
    rot = np.degrees(np.angle(np.exp(1j * (az_meas - az_known))))
    r_xy = np.hypot(vec[0], vec[1])
    rot_std = np.degrees(np.hypot(vec_std[0], vec_std[1]) / r_xy)
    gain = r_xy / (amplitude_nT * np.hypot(u[0], u[1]))
    return CalCoilResult(vector_nT=vec, vector_std_nT=vec_std, rotation_deg=float(rot),
                         rotation_std_deg=float(rot_std), gain_ratio=float(gain),
                         n_blocks=blocks.n_blocks, provenance=dict(provenance or {}))


def apply_calcoil(cal: SpinCalibration, coil: CalCoilResult, *, fix_gain: bool = True
                  ) -> SpinCalibration:
    """Turn (and optionally rescale) the spin plane of a calibration to the coil.

    ``C' = diag(g, g, 1) Rz(-rotation) C`` with ``g = 1 / gain_ratio`` when ``fix_gain``;
    ``c11, c12`` become determined.
    """
    a = np.radians(coil.rotation_deg)
    rz = np.array([[np.cos(a), np.sin(a), 0.0], [-np.sin(a), np.cos(a), 0.0], [0, 0, 1.0]])
    g = 1.0 / coil.gain_ratio if fix_gain else 1.0
    c = np.diag([g, g, 1.0]) @ rz @ cal.coupling
    newly = ("c12", "c11") if fix_gain else ("c12",)
    determined = tuple(cal.determined) + tuple(n for n in newly if n not in cal.determined)
    fixed = tuple(n for n in cal.fixed if n not in newly)
    std = dict(cal.std)
    std["c12"] = float(np.radians(coil.rotation_std_deg))
    note = (f"spin-plane turn {coil.rotation_deg:.4f} +- {coil.rotation_std_deg:.4f} deg"
            + (f" and gain {coil.gain_ratio:.5f}" if fix_gain else "")
            + " removed with the calibration coil")
    return dataclasses.replace(cal, coupling=c, determined=determined, fixed=fixed, std=std,
                               notes=tuple(cal.notes) + (note,))
