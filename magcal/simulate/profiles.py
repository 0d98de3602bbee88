"""Time profiles of spacecraft disturbers (the disturbance classes of GK-2A).

A profile turns sample times into the coefficients that multiply a disturber's fixed
spatial field pattern. A linearly polarised disturber (PiCoG's assumption) has one
coefficient per sample; a rotating one (a reaction wheel) has two, ``cos`` and ``sin``
of its rotation phase. The classes follow the disturbances seen on GK-2A on
4 March 2019 (Constantinescu et al. 2020 §4; Magnes et al. 2020 §5.2):

* :class:`DailyStepProfile` - the midnight disturbance: a step up near local midnight,
  a drop about 45 min later that overshoots below the baseline, and the end of the
  overshoot about 4 h later;
* :class:`EdgePulseProfile` - the triangular pulses centred on those ramps;
* :class:`SpikeTrainProfile` - spikes every 10 min;
* :class:`ToggleStepProfile` - steps up and down at irregular 80-90 min intervals;
* :class:`BroadbandNoiseProfile` - irregular noise with periods under 1 min, a DC level
  while on, and short off intervals;
* :class:`ToneProfile` - a sinusoidal tone (6 s on GK-2A);
* :class:`SquareWaveProfile` - a regular on/off cycle (heaters, generic tests);
* :class:`RotatingProfile` - the phase of a rotating moment (two coefficients);
* :class:`ArrayProfile` - explicit coefficients.

Every ``evaluate`` is vectorised over samples and takes its randomness from the
generator it is given. Profiles are scaled so that their "on" level is 1: the
disturber's moment is the moment at profile value 1.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np
import pandas as pd

from magcal.errors import InputError

DAY_S = 86400.0


@dataclass(frozen=True)
class ProfileContext:
    """What a profile needs to know about the simulated interval.

    Parameters
    ----------
    start : pandas.Timestamp
        UTC time of the first sample (``t_s = 0``).
    longitude_deg : float
        Spacecraft longitude (east), for local-time schedules.
    cadence_s : float
        Sample spacing in seconds.
    """

    start: pd.Timestamp
    longitude_deg: float
    cadence_s: float

    def local_time_events_s(self, lt_h: float, t_first_s: float, t_last_s: float) -> np.ndarray:
        """Times (s since start) at which local time equals ``lt_h``, one per day.

        Every such time in ``[t_first_s - 1 day, t_last_s + 1 day]`` is returned, so
        events whose effects reach into the interval are not missed.
        """
        start = pd.Timestamp(self.start)
        ut0_s = (start - start.normalize()).total_seconds()
        ut_event_s = ((lt_h - self.longitude_deg / 15.0) % 24.0) * 3600.0
        first = ut_event_s - ut0_s  # the event on the start day
        k0 = int(np.floor((t_first_s - DAY_S - first) / DAY_S))
        k1 = int(np.ceil((t_last_s + DAY_S - first) / DAY_S))
        return first + DAY_S * np.arange(k0, k1 + 1)


@dataclass(frozen=True)
class ProfileSample:
    """Coefficients of a profile and the times of its discrete events.

    ``values`` has shape (n, k) with ``k`` the profile's number of components;
    ``events_s`` are event times (s since start, e.g. spike peaks or step ramps) inside
    the sampled interval.
    """

    values: np.ndarray
    events_s: np.ndarray


class Profile(Protocol):
    """Interface of a time profile."""

    n_components: int

    def evaluate(self, t_s: np.ndarray, *, rng: np.random.Generator,
                 context: ProfileContext) -> ProfileSample:
        ...


def _inside(events: np.ndarray, t_s: np.ndarray) -> np.ndarray:
    if len(t_s) == 0:
        return events[:0]
    return events[(events >= t_s[0]) & (events <= t_s[-1])]


def _piecewise(t_s, knots_t, knots_v) -> np.ndarray:
    order = np.argsort(knots_t, kind="stable")
    return np.interp(t_s, np.asarray(knots_t)[order], np.asarray(knots_v)[order],
                     left=0.0, right=0.0)


def _ramp_knots(times, levels_before, levels_after, ramp_s):
    """Knots of linear ramps centred on ``times`` between the given levels."""
    times = np.asarray(times, dtype=float)
    half = 0.5 * max(float(ramp_s), 1e-9)
    knots_t = np.column_stack([times - half, times + half]).ravel()
    knots_v = np.column_stack([levels_before, levels_after]).ravel()
    return knots_t, knots_v


@dataclass(frozen=True)
class DailyStepProfile:
    """Daily midnight disturbance: step to 1, overshoot below 0, return to 0.

    Parameters
    ----------
    onset_lt_h : float
        Local time of the step up (default 23.8 h, i.e. about 15:15 UT at 128.2 E).
    high_s : float
        Duration of the high level (default 2700 s, about 45 min).
    overshoot : float
        Level after the drop, as a fraction of the step (default -0.15, "overshooting
        by about 5 nT" of a 34 nT step).
    low_s : float
        Duration of the overshoot level (default 14400 s, 4 h).
    ramp_s : float
        Duration of each ramp (default 30 s).

    Examples
    --------
    >>> ctx = ProfileContext(pd.Timestamp("2019-03-04", tz="UTC"), 128.2, 60.0)
    >>> t = np.arange(0, 86400, 60.0)
    >>> s = DailyStepProfile().evaluate(t, rng=np.random.default_rng(0), context=ctx)
    >>> float(s.values.max()), float(s.values.min())
    (1.0, -0.15)
    """

    onset_lt_h: float = 23.8
    high_s: float = 2700.0
    overshoot: float = -0.15
    low_s: float = 14400.0
    ramp_s: float = 30.0
    n_components: int = 1

    def ramp_times_s(self, t_s, context) -> np.ndarray:
        """(days, 3) times of the up, down and end ramps."""
        t_s = np.asarray(t_s, dtype=float)
        lo, hi = (t_s[0], t_s[-1]) if len(t_s) else (0.0, 0.0)
        onsets = context.local_time_events_s(self.onset_lt_h, lo, hi)
        return np.column_stack([onsets, onsets + self.high_s,
                                onsets + self.high_s + self.low_s])

    def evaluate(self, t_s, *, rng, context) -> ProfileSample:
        t_s = np.asarray(t_s, dtype=float)
        ramps = self.ramp_times_s(t_s, context)
        knots_t, knots_v = [], []
        for before, after, col in ((0.0, 1.0, 0), (1.0, self.overshoot, 1),
                                   (self.overshoot, 0.0, 2)):
            kt, kv = _ramp_knots(ramps[:, col], np.full(len(ramps), before),
                                 np.full(len(ramps), after), self.ramp_s)
            knots_t.append(kt)
            knots_v.append(kv)
        values = _piecewise(t_s, np.concatenate(knots_t), np.concatenate(knots_v))
        return ProfileSample(values[:, None], _inside(np.sort(ramps.ravel()), t_s))


@dataclass(frozen=True)
class EdgePulseProfile:
    """Triangular pulses of height 1 centred on the ramps of a :class:`DailyStepProfile`.

    Parameters
    ----------
    step : DailyStepProfile
        The midnight disturbance whose up and down ramps carry the pulses.
    width_s : float
        Full base width of each triangle (default 180 s, "lasting about three minutes").
    """

    step: DailyStepProfile = DailyStepProfile()
    width_s: float = 180.0
    n_components: int = 1

    def evaluate(self, t_s, *, rng, context) -> ProfileSample:
        t_s = np.asarray(t_s, dtype=float)
        centres = np.sort(self.step.ramp_times_s(t_s, context)[:, :2].ravel())
        half = 0.5 * self.width_s
        knots_t = np.column_stack([centres - half, centres, centres + half]).ravel()
        knots_v = np.tile([0.0, 1.0, 0.0], len(centres))
        values = _piecewise(t_s, knots_t, knots_v)
        return ProfileSample(values[:, None], _inside(centres, t_s))


@dataclass(frozen=True)
class SpikeTrainProfile:
    """Gaussian spikes of height about 1 at a fixed period.

    Parameters
    ----------
    period_s : float
        Spike period (default 600 s).
    width_s : float
        Full width at half maximum of each spike (default 6 s).
    phase_s : float or None
        Time of the first spike after the start; None draws it uniformly.
    jitter_s : float
        Standard deviation of each spike's timing error (default 0.5 s).
    height_spread : float
        Relative standard deviation of the spike heights (default 0.05).
    """

    period_s: float = 600.0
    width_s: float = 6.0
    phase_s: float | None = None
    jitter_s: float = 0.5
    height_spread: float = 0.05
    n_components: int = 1

    def evaluate(self, t_s, *, rng, context) -> ProfileSample:
        t_s = np.asarray(t_s, dtype=float)
        if self.period_s <= 0 or self.width_s <= 0:
            raise InputError("spike period_s and width_s must be positive")
        phase = rng.uniform(0.0, self.period_s) if self.phase_s is None else self.phase_s
        lo, hi = (t_s[0], t_s[-1]) if len(t_s) else (0.0, 0.0)
        k0 = int(np.floor((lo - phase) / self.period_s)) - 1
        k1 = int(np.ceil((hi - phase) / self.period_s)) + 1
        ks = np.arange(k0, k1 + 1)
        centres = phase + ks * self.period_s + rng.normal(0.0, self.jitter_s, len(ks))
        heights = 1.0 + rng.normal(0.0, self.height_spread, len(ks))
        nearest = np.clip(np.rint((t_s - phase) / self.period_s).astype(np.int64) - k0,
                          0, len(ks) - 1)
        sigma = self.width_s / (2.0 * np.sqrt(2.0 * np.log(2.0)))
        values = heights[nearest] * np.exp(-0.5 * ((t_s - centres[nearest]) / sigma) ** 2)
        return ProfileSample(values[:, None], _inside(centres, t_s))


@dataclass(frozen=True)
class ToggleStepProfile:
    """A level toggling between 0 and 1 at irregular intervals.

    Parameters
    ----------
    min_interval_s, max_interval_s : float
        Each interval between toggles is uniform in this range (default 80-90 min).
    ramp_s : float
        Duration of each ramp (default 20 s).
    start_level : int or None
        Level at the start (0 or 1); None draws it.
    """

    min_interval_s: float = 4800.0
    max_interval_s: float = 5400.0
    ramp_s: float = 20.0
    start_level: int | None = None
    n_components: int = 1

    def evaluate(self, t_s, *, rng, context) -> ProfileSample:
        t_s = np.asarray(t_s, dtype=float)
        if not 0 < self.min_interval_s <= self.max_interval_s:
            raise InputError("toggle intervals must satisfy 0 < min_interval_s <= max_interval_s")
        lo, hi = (t_s[0], t_s[-1]) if len(t_s) else (0.0, 0.0)
        level0 = int(rng.integers(0, 2)) if self.start_level is None else int(self.start_level)
        n_max = int(np.ceil((hi - lo) / self.min_interval_s)) + 2
        first = lo + rng.uniform(0.0, self.max_interval_s)
        toggles = first + np.concatenate(
            [[0.0], np.cumsum(rng.uniform(self.min_interval_s, self.max_interval_s, n_max))])
        toggles = toggles[toggles <= hi + self.max_interval_s]
        before = (level0 + np.arange(len(toggles))) % 2
        after = 1 - before
        knots_t, knots_v = _ramp_knots(toggles, before, after, self.ramp_s)
        pad = self.ramp_s + 1.0
        knots_t = np.concatenate([[lo - pad], knots_t, [hi + self.max_interval_s + pad]])
        knots_v = np.concatenate([[level0], knots_v, [knots_v[-1] if len(knots_v) else level0]])
        values = np.interp(t_s, knots_t, knots_v)
        return ProfileSample(values[:, None], _inside(toggles, t_s))


@dataclass(frozen=True)
class BroadbandNoiseProfile:
    """Irregular noise with periods under ``max_period_s``, a DC level while on.

    The noise is white noise shaped in the frequency domain: zero below
    ``1 / max_period_s``, flat above, with a Gaussian enhancement around
    ``peak_hz`` (GK-2A: "enhanced around 0.3 Hz"), scaled to unit rms while on. The
    profile is ``on(t) * (level + noise(t))``; ``on`` drops to 0 during ``n_off``
    intervals of ``off_s`` seconds per day ("between 00:40 and 00:50 UTC the
    high-frequency disturbance was switched off").

    Parameters
    ----------
    level : float
        DC level while on, in units of the noise rms (default 7: a 5 nT offset under
        0.7 nT rms noise at the inboard sensor).
    max_period_s : float
        Longest period in the noise (default 60 s).
    peak_hz, peak_width_hz, peak_gain : float
        Centre, width and power gain of the spectral enhancement (0.3 Hz, 0.05 Hz, 4).
    n_off : int
        Off intervals per day (default 2).
    off_s : float
        Length of each off interval (default 600 s).
    """

    level: float = 7.0
    max_period_s: float = 60.0
    peak_hz: float = 0.3
    peak_width_hz: float = 0.05
    peak_gain: float = 4.0
    n_off: int = 2
    off_s: float = 600.0
    n_components: int = 1

    def evaluate(self, t_s, *, rng, context) -> ProfileSample:
        t_s = np.asarray(t_s, dtype=float)
        n = len(t_s)
        if n == 0:
            return ProfileSample(np.zeros((0, 1)), np.zeros(0))
        dt = float(context.cadence_s)
        spectrum = np.fft.rfft(rng.standard_normal(n))
        f = np.fft.rfftfreq(n, dt)
        gain = (f >= 1.0 / self.max_period_s).astype(float)
        gain *= np.sqrt(1.0 + self.peak_gain * np.exp(
            -0.5 * ((f - self.peak_hz) / self.peak_width_hz) ** 2))
        noise = np.fft.irfft(spectrum * gain, n)
        rms = np.sqrt(np.mean(noise**2))
        noise = noise / rms if rms > 0 else noise
        days = max(1, int(np.ceil((t_s[-1] - t_s[0] + dt) / DAY_S)))
        n_off = self.n_off * days
        off_start = np.sort(rng.uniform(t_s[0], t_s[-1], n_off))
        on = np.ones(n)
        if n_off:
            idx = np.searchsorted(off_start, t_s, side="right") - 1
            valid = idx >= 0
            in_off = np.zeros(n, dtype=bool)
            in_off[valid] = t_s[valid] < off_start[idx[valid]] + self.off_s
            on[in_off] = 0.0
        values = on * (self.level + noise)
        events = np.sort(np.concatenate([off_start, off_start + self.off_s]))
        return ProfileSample(values[:, None], _inside(events, t_s))


@dataclass(frozen=True)
class ToneProfile:
    """A sinusoid of unit amplitude.

    Parameters
    ----------
    period_s : float
        Period (default 6 s, the GK-2A 0.166 Hz tone).
    phase_rad : float or None
        Phase at the start; None draws it.
    """

    period_s: float = 6.0
    phase_rad: float | None = None
    n_components: int = 1

    def evaluate(self, t_s, *, rng, context) -> ProfileSample:
        t_s = np.asarray(t_s, dtype=float)
        phase = rng.uniform(0.0, 2 * np.pi) if self.phase_rad is None else self.phase_rad
        values = np.sin(2 * np.pi * t_s / self.period_s + phase)
        return ProfileSample(values[:, None], np.zeros(0))


@dataclass(frozen=True)
class SquareWaveProfile:
    """A regular on/off cycle between 0 and 1 with linear ramps.

    Parameters
    ----------
    period_s : float
        Cycle period.
    duty : float
        Fraction of the period at level 1 (0 < duty < 1).
    ramp_s : float
        Duration of each ramp (default 10 s).
    phase_s : float or None
        Time of the first rise after the start; None draws it.
    """

    period_s: float = 3600.0
    duty: float = 0.5
    ramp_s: float = 10.0
    phase_s: float | None = None
    n_components: int = 1

    def evaluate(self, t_s, *, rng, context) -> ProfileSample:
        t_s = np.asarray(t_s, dtype=float)
        if not 0.0 < self.duty < 1.0 or self.period_s <= 0:
            raise InputError("square wave needs period_s > 0 and 0 < duty < 1")
        phase = rng.uniform(0.0, self.period_s) if self.phase_s is None else self.phase_s
        lo, hi = (t_s[0], t_s[-1]) if len(t_s) else (0.0, 0.0)
        ks = np.arange(int(np.floor((lo - phase) / self.period_s)) - 1,
                       int(np.ceil((hi - phase) / self.period_s)) + 2)
        rises = phase + ks * self.period_s
        falls = rises + self.duty * self.period_s
        kt1, kv1 = _ramp_knots(rises, np.zeros(len(ks)), np.ones(len(ks)), self.ramp_s)
        kt2, kv2 = _ramp_knots(falls, np.ones(len(ks)), np.zeros(len(ks)), self.ramp_s)
        values = _piecewise(t_s, np.concatenate([kt1, kt2]), np.concatenate([kv1, kv2]))
        return ProfileSample(values[:, None], _inside(np.sort(np.concatenate([rises, falls])), t_s))


@dataclass(frozen=True)
class RotatingProfile:
    """Phase of a rotating moment: coefficients ``cos(phi), sin(phi)``.

    The rotation frequency drifts slowly, ``f(t) = f0 + df sin(2 pi t / drift_period +
    psi)``, like a reaction wheel changing speed. Real wheels spin at tens of Hz; at a
    1 s cadence what survives the on-board boxcar averaging is an aliased, much slower
    rotation, which is what ``f0`` stands for.

    Parameters
    ----------
    frequency_hz : float
        Mean rotation frequency f0 (default 0.11 Hz).
    drift_hz : float
        Amplitude df of the slow frequency drift (default 0.04 Hz).
    drift_period_s : float
        Period of the drift (default one day).
    """

    frequency_hz: float = 0.11
    drift_hz: float = 0.04
    drift_period_s: float = DAY_S
    n_components: int = 2

    def evaluate(self, t_s, *, rng, context) -> ProfileSample:
        t_s = np.asarray(t_s, dtype=float)
        phi0, psi = rng.uniform(0.0, 2 * np.pi, 2)
        w = 2 * np.pi / self.drift_period_s
        # phase = 2 pi * integral of f(t) dt, in closed form
        phase = phi0 + 2 * np.pi * (self.frequency_hz * t_s
                                    - self.drift_hz / w * (np.cos(w * t_s + psi) - np.cos(psi)))
        return ProfileSample(np.column_stack([np.cos(phase), np.sin(phase)]), np.zeros(0))


@dataclass(frozen=True, eq=False)
class ArrayProfile:
    """Explicit coefficients, one row per sample.

    Parameters
    ----------
    values : array_like, shape (n,) or (n, k)
        Coefficients at the simulated samples (``k`` = 2 for a rotating disturber).

    Examples
    --------
    >>> ctx = ProfileContext(pd.Timestamp("2019-03-04", tz="UTC"), 128.2, 1.0)
    >>> ArrayProfile([0.0, 1.0, 0.5]).evaluate(np.arange(3.0), rng=None, context=ctx).values[:, 0]
    array([0. , 1. , 0.5])
    """

    values: np.ndarray

    @property
    def n_components(self) -> int:
        v = np.asarray(self.values)
        return 1 if v.ndim == 1 else int(v.shape[1])

    def evaluate(self, t_s, *, rng, context) -> ProfileSample:
        v = np.asarray(self.values, dtype=float)
        v = v[:, None] if v.ndim == 1 else v
        if v.shape[0] != len(t_s):
            raise InputError(f"ArrayProfile has {v.shape[0]} rows for {len(t_s)} samples")
        return ProfileSample(v.copy(), np.zeros(0))
