"""Spinning-spacecraft magnetometer simulator with known truth (Galileo- and ELFIN-like).

The ambient field is built in the despun (inertial) frame: a constant background, a
power-law turbulence of given RMS, discrete waves, all sampled at the instrument's
(possibly non-equispaced) times. It is spun into the spacecraft frame with the spin
phase ``p`` (inverse of CONTRACTS §4 despin), a spacecraft-fixed calibration-coil
square wave is added, and the sensors read

    b = C^-1 (F B_sc) + O + noise,

where ``C`` and ``O`` are the true coupling matrix and offsets (so that
``B = C (b - O)`` recovers the field) and ``F`` is the identity, or, while the flipper
is in position 1, the 90-degree turn of the triad about sensor 2 that brings sensor 3
into the spin plane (sensor 3 then looks along +x, sensor 1 along -z).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from magcal.frames.spinning import TWO_PI, spin

#: Galileo low-rate science sampling: 3 vectors per 2/3 s frame, spaced 7/30, 7/30, 6/30 s.
GALILEO_FRAME_S = 2.0 / 3.0
GALILEO_OFFSETS_S = (0.0, 7.0 / 30.0, 14.0 / 30.0)

#: Flipper position 1: sensor readings are C^-1 @ FLIP_MATRIX @ B_sc + O.
FLIP_MATRIX = np.array([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])


def rotation_z(angle_deg: float) -> np.ndarray:
    """Rotation matrix about the spin axis (z) by ``angle_deg``."""
    a = np.radians(angle_deg)
    return np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0, 0, 1.0]])


def _galileo_coupling() -> np.ndarray:
    inner = np.array([[1.0012, 0.0, 0.0021],
                      [0.0017, 0.9981, -0.0013],
                      [0.0009, -0.0024, 0.9993]])
    return rotation_z(0.5) @ inner


@dataclass(frozen=True)
class SpinningConfig:
    """Knobs of :func:`simulate_spinning` (defaults: Galileo-like, see :meth:`galileo_like`).

    Times are seconds from ``start``; fields in nT; the despun frame is ``(X, Y, Z)``.

    Attributes
    ----------
    start : str
        UTC start time (ISO-8601).
    duration_s : float
        Length of the record.
    frame_s, sample_offsets_s : float, tuple of float
        Samples are taken at ``k * frame_s + offset`` for every offset (Galileo: three
        vectors per 2/3 s at 0, 7/30, 14/30 s; equispaced data: one offset 0).
    spin_period_s : float
        Spin period at the start.
    spin_period_drift_s_per_h : float
        Linear change of the spin period per hour (0 = constant).
    phase0_rad : float
        Spin phase at the first sample.
    coupling, offsets_nT : array_like
        True ``C`` (3x3) and ``O`` (3,) with ``B = C (b - O)``.
    background_nT : tuple
        Constant ambient field in the despun frame.
    slow_amplitude_nT, slow_period_s : tuple
        Large-scale variation: component ``k`` adds ``A_k sin(2 pi t / P_k)`` (the
        spin-axis field must change over the record to separate spin-plane sensor tilts
        from offsets; with ``random_phases``, ``A_k sin(2 pi t / P_k + phi_k)``).
    turbulence_rms_nT, turbulence_index, turbulence_fmin_hz : float
        Power-law (``f^-index``) ambient fluctuation per component, above ``fmin``.
    waves : tuple of (amplitude_nT, frequency_hz, (dx, dy, dz)[, phase_rad])
        Discrete linearly polarised waves in the despun frame,
        ``amplitude sin(2 pi frequency t + phase)`` along ``d``; the phase is 0.3 rad
        when not given.
    noise_nT : float
        White instrument noise per sensor (standard deviation).
    flip_intervals_s : tuple of (start, end)
        Intervals with the flipper in position 1.
    calcoil_amplitude_nT, calcoil_frequency_hz, calcoil_direction_sc, calcoil_intervals_s
        Spacecraft-fixed calibration coil: an on/off square wave (0 or amplitude) of the
        given frequency along a unit vector in the spacecraft frame, during the intervals
        (the square wave is on during the first half of each period, counted from the
        interval start).
    gaps_s : tuple of (start, end)
        Intervals with no samples.
    random_phases : bool
        Add to each wave's phase, each slow-field component's phase and the spin phase
        at the first sample an independent uniform draw on ``[0, 2 pi)`` from the
        ``rng`` (drawn before the turbulence and the noise). Off by default, when every
        record has the same waves and slow field and only the turbulence and noise
        change with the seed; a real record's phases are arbitrary, and the waves'
        errors-in-variables bias in a calibration depends on them, so statements about
        errors over many records need them drawn.
    """

    start: str = "1989-10-31T00:00:00"
    duration_s: float = 5 * 3600.0
    frame_s: float = GALILEO_FRAME_S
    sample_offsets_s: tuple = GALILEO_OFFSETS_S
    spin_period_s: float = 20.0
    spin_period_drift_s_per_h: float = 0.0
    phase0_rad: float = 0.0
    coupling: tuple = field(default_factory=lambda: tuple(map(tuple, _galileo_coupling())))
    offsets_nT: tuple = (0.8, -1.3, 0.45)
    background_nT: tuple = (25.0, -15.0, 35.0)
    slow_amplitude_nT: tuple = (10.0, 10.0, 20.0)
    slow_period_s: tuple = (21600.0, 15000.0, 12000.0)
    turbulence_rms_nT: float = 0.2
    turbulence_index: float = 2.0
    turbulence_fmin_hz: float = 1e-4
    waves: tuple = ((0.6, 0.0137, (0.6, 0.8, 0.0)), (0.3, 0.031, (0.0, 0.6, 0.8)))
    noise_nT: float = 0.02
    flip_intervals_s: tuple = ()
    calcoil_amplitude_nT: float = 0.0
    calcoil_frequency_hz: float = 0.5
    calcoil_direction_sc: tuple = (0.0, 1.0, 0.0)
    calcoil_intervals_s: tuple = ()
    gaps_s: tuple = ()
    random_phases: bool = False

    @classmethod
    def galileo_like(cls, **changes) -> "SpinningConfig":
        """Galileo low-rate science: 20 s spin, 4.5 non-equispaced vectors/s, 5 h."""
        return dataclasses.replace(cls(), **changes)

    @classmethod
    def elfin_like(cls, **changes) -> "SpinningConfig":
        """ELFIN-like CubeSat: 2.9 s spin, 10 Hz equispaced, a 6-min pass in a strong field."""
        base = cls(start="2022-01-12T00:00:00", duration_s=360.0, frame_s=0.1,
                   sample_offsets_s=(0.0,), spin_period_s=2.9,
                   coupling=tuple(map(tuple, rotation_z(-1.5) @ np.array(
                       [[1.003, 0.0, 0.004], [0.006, 0.996, -0.003], [0.002, 0.005, 1.001]]))),
                   offsets_nT=(35.0, -20.0, 12.0), background_nT=(18000.0, -9000.0, 30000.0),
                   slow_amplitude_nT=(2000.0, 1500.0, 3000.0),
                   slow_period_s=(900.0, 1100.0, 1300.0),
                   turbulence_rms_nT=2.0, waves=(), noise_nT=0.5)
        return dataclasses.replace(base, **changes)


@dataclass(frozen=True)
class SpinningTruth:
    """What the simulator put in.

    Attributes
    ----------
    coupling, offsets_nT : ndarray
        True ``C`` and ``O``.
    b_despun : ndarray, shape (n, 3)
        Ambient field in the despun frame at the samples (without the coil).
    b_sc : ndarray, shape (n, 3)
        Field in the spacecraft frame including the coil, before the sensors.
    calcoil_nT : ndarray, shape (n, 3)
        Coil field in the spacecraft frame.
    phase_rad, t_s : ndarray
        Spin phase and seconds from the start.
    spin_period_s : ndarray
        Instantaneous spin period at the samples.
    """

    coupling: np.ndarray
    offsets_nT: np.ndarray
    b_despun: np.ndarray
    b_sc: np.ndarray
    calcoil_nT: np.ndarray
    phase_rad: np.ndarray
    t_s: np.ndarray
    spin_period_s: np.ndarray


@dataclass(frozen=True)
class SpinningResult:
    """Simulated record: ``data`` (DataFrame ``b1,b2,b3,phase,flip`` indexed by UTC
    ``time``), ``truth`` (:class:`SpinningTruth`) and the ``config`` used."""

    data: pd.DataFrame
    truth: SpinningTruth
    config: SpinningConfig


def _in_intervals(t, intervals) -> np.ndarray:
    mask = np.zeros(t.shape, dtype=bool)
    for a, b in intervals:
        mask |= (t >= a) & (t < b)
    return mask


def _turbulence(t, rms, index, fmin, rng) -> np.ndarray:
    """Three independent power-law series with the given RMS, sampled at ``t``."""
    if rms <= 0:
        return np.zeros((t.size, 3))
    dt = 0.1
    n = int(np.ceil((t[-1] - t[0]) / dt)) + 2
    nfft = 1 << int(np.ceil(np.log2(max(n, 16))))
    f = np.fft.rfftfreq(nfft, dt)
    amp = np.zeros_like(f)
    sel = f >= fmin
    amp[sel] = f[sel] ** (-index / 2.0)
    spec = amp[:, None] * (rng.standard_normal((f.size, 3)) + 1j * rng.standard_normal((f.size, 3)))
    series = np.fft.irfft(spec, n=nfft, axis=0)[:n]
    series -= series.mean(axis=0)
    series *= rms / series.std(axis=0)
    grid = t[0] + dt * np.arange(n)
    return np.column_stack([np.interp(t, grid, series[:, k]) for k in range(3)])


def simulate_spinning(config: SpinningConfig | None = None, *,
                      rng: np.random.Generator) -> SpinningResult:
    """Simulate a spinning-spacecraft magnetometer record with known calibration.

    Parameters
    ----------
    config : SpinningConfig, optional
        Knobs; default :meth:`SpinningConfig.galileo_like`.
    rng : numpy.random.Generator
        Source of all randomness (turbulence and noise, and with
        ``config.random_phases`` the phases, drawn first: one per wave, then one per
        slow-field component, then the spin phase).

    Returns
    -------
    SpinningResult
        ``data`` with columns ``b1, b2, b3`` (sensor readings, nT), ``phase`` (rad) and
        ``flip`` (0/1), and the ``truth``.

    Examples
    --------
    >>> import numpy as np
    >>> cfg = SpinningConfig.galileo_like(duration_s=60.0)
    >>> res = simulate_spinning(cfg, rng=np.random.default_rng(1))
    >>> len(res.data), list(res.data.columns)
    (270, ['b1', 'b2', 'b3', 'phase', 'flip'])
    """
    cfg = SpinningConfig.galileo_like() if config is None else config
    n_waves = len(cfg.waves)
    n_slow = len(cfg.slow_amplitude_nT)
    if cfg.random_phases:
        drawn = rng.uniform(0.0, TWO_PI, n_waves + n_slow + 1)
    else:
        drawn = np.zeros(n_waves + n_slow + 1)
    wave_phase, slow_phase, spin_phase = drawn[:n_waves], drawn[n_waves:-1], drawn[-1]
    n_frames = int(np.floor(cfg.duration_s / cfg.frame_s + 1e-9))
    offsets = np.asarray(cfg.sample_offsets_s, dtype=float)
    t = (np.arange(n_frames)[:, None] * cfg.frame_s + offsets[None, :]).ravel()
    t = t[t < cfg.duration_s]
    t = t[~_in_intervals(t, cfg.gaps_s)]

    # Spin phase with a linearly drifting period P(t) = P0 + r t.
    p0 = float(cfg.spin_period_s)
    rate = float(cfg.spin_period_drift_s_per_h) / 3600.0
    if rate == 0.0:
        phase = TWO_PI * t / p0
    else:
        phase = TWO_PI / rate * np.log1p(rate * t / p0)
    phase = phase + (cfg.phase0_rad + spin_phase)
    period = p0 + rate * t

    # Ambient field in the despun frame.
    b_i = np.tile(np.asarray(cfg.background_nT, dtype=float), (t.size, 1))
    for k, (amp, per) in enumerate(zip(cfg.slow_amplitude_nT, cfg.slow_period_s)):
        if amp:
            b_i[:, k] += amp * np.sin(TWO_PI * t / per + slow_phase[k])
    b_i += _turbulence(t, cfg.turbulence_rms_nT, cfg.turbulence_index,
                       cfg.turbulence_fmin_hz, rng)
    for wave, extra in zip(cfg.waves, wave_phase):
        amp, freq, direction = wave[:3]
        phi = (float(wave[3]) if len(wave) > 3 else 0.3) + extra
        d = np.asarray(direction, dtype=float)
        d = d / np.linalg.norm(d)
        b_i += amp * np.sin(TWO_PI * freq * t + phi)[:, None] * d[None, :]

    b_sc = spin(b_i, phase)
    coil = np.zeros_like(b_sc)
    if cfg.calcoil_amplitude_nT and cfg.calcoil_intervals_s:
        u = np.asarray(cfg.calcoil_direction_sc, dtype=float)
        u = u / np.linalg.norm(u)
        for a, b in cfg.calcoil_intervals_s:
            sel = (t >= a) & (t < b)
            on = (((t[sel] - a) * cfg.calcoil_frequency_hz) % 1.0) < 0.5
            coil[sel] = cfg.calcoil_amplitude_nT * on[:, None] * u[None, :]
    b_sc = b_sc + coil

    flip = _in_intervals(t, cfg.flip_intervals_s)
    seen = b_sc.copy()
    seen[flip] = b_sc[flip] @ FLIP_MATRIX.T
    c = np.asarray(cfg.coupling, dtype=float)
    o = np.asarray(cfg.offsets_nT, dtype=float)
    b = seen @ np.linalg.inv(c).T + o
    if cfg.noise_nT > 0:
        b = b + cfg.noise_nT * rng.standard_normal(b.shape)

    start = pd.Timestamp(cfg.start, tz="UTC") if pd.Timestamp(cfg.start).tzinfo is None \
        else pd.Timestamp(cfg.start).tz_convert("UTC")
    index = pd.DatetimeIndex(start + pd.to_timedelta(np.round(t * 1e9).astype(np.int64), unit="ns"),
                             name="time")
    data = pd.DataFrame({"b1": b[:, 0], "b2": b[:, 1], "b3": b[:, 2],
                         "phase": phase, "flip": flip.astype(int)}, index=index)
    truth = SpinningTruth(coupling=c, offsets_nT=o, b_despun=b_i, b_sc=b_sc, calcoil_nT=coil,
                          phase_rad=phase, t_s=t, spin_period_s=period)
    return SpinningResult(data=data, truth=truth, config=cfg)
