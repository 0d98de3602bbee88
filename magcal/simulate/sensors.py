"""Simulated magnetometer sensors: placement, misalignment, offsets, noise, temperature.

A sensor ``s`` reports, in the common measurement frame,

    B_s(t) = R_s @ (B_ambient(t) + sum_d b_{d,s}(t)) + O_s(t) + n_s(t),

with ``R_s`` the small true misalignment rotation (rotation vector
``misalignment_deg`` about the common-frame x, y, z axes), ``O_s`` the constant offset
plus the temperature-driven part, and ``n_s`` white Gaussian noise of rms
``noise_nT`` per component.

Boom sensors (``on_boom=True``) go through a daily shadow phase (Magnes et al. 2020
§5.2: the boom is shadowed every day and the outboard sensor cools from +30 C to
-90 C): their temperature relaxes exponentially towards the shadow temperature and
back, the offset drifts with ``temp_coeff_nT_per_K`` and oscillates ("sensor offset
oscillations", SOO, up to 4 nT peak to peak) with an envelope proportional to the
rate of temperature change.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from magcal.errors import InputError
from magcal.simulate.profiles import ProfileContext


@dataclass(frozen=True)
class Sensor:
    """One three-axis magnetometer.

    Parameters
    ----------
    name : str
        Lowercase letters, digits and ``_`` (CONTRACTS §0); columns are
        ``<name>_x, <name>_y, <name>_z``.
    position_m : tuple of 3 floats
        Position in the spacecraft body frame (metres).
    noise_nT : float
        White noise rms per component at the simulated cadence.
    offset_nT : tuple of 3 floats
        Constant offset in the common frame.
    misalignment_deg : tuple of 3 floats
        Rotation vector (degrees) of the true misalignment about the common x, y, z axes.
    on_boom : bool
        Whether the daily boom-shadow phase changes its temperature.
    temp_coeff_nT_per_K : tuple of 3 floats
        Offset drift per kelvin below the sunlit temperature (boom sensors).
    soo_amplitude_nT : float
        Amplitude (half peak to peak) of the sensor offset oscillations at the fastest
        temperature change.
    soo_period_s : float
        Period of those oscillations.

    Examples
    --------
    >>> Sensor("fgmo", (2.55, -0.8, -1.6), noise_nT=0.03).name
    'fgmo'
    """

    name: str
    position_m: tuple
    noise_nT: float = 0.03
    offset_nT: tuple = (0.0, 0.0, 0.0)
    misalignment_deg: tuple = (0.0, 0.0, 0.0)
    on_boom: bool = False
    temp_coeff_nT_per_K: tuple = (0.0, 0.0, 0.0)
    soo_amplitude_nT: float = 0.0
    soo_period_s: float = 150.0

    def __post_init__(self):
        import re

        if not re.fullmatch(r"[a-z0-9_]+", self.name):
            raise InputError(f"sensor name {self.name!r}: use lowercase letters, digits and _")
        for label in ("position_m", "offset_nT", "misalignment_deg", "temp_coeff_nT_per_K"):
            if np.shape(getattr(self, label)) != (3,):
                raise InputError(f"sensor {self.name!r}: {label} must have 3 elements")
        if self.noise_nT < 0 or self.soo_amplitude_nT < 0 or self.soo_period_s <= 0:
            raise InputError(f"sensor {self.name!r}: noise_nT and soo_amplitude_nT must be "
                             ">= 0 and soo_period_s > 0")

    def rotation(self) -> np.ndarray:
        """The 3x3 misalignment rotation ``R_s``."""
        return rotation_from_vector(np.deg2rad(np.asarray(self.misalignment_deg, dtype=float)))


def rotation_from_vector(w_rad) -> np.ndarray:
    """Rotation matrix of a rotation vector (radians; scipy's ``Rotation.from_rotvec``).

    Examples
    --------
    >>> rotation_from_vector([0.0, 0.0, np.pi / 2]).round(12) + 0.0
    array([[ 0., -1.,  0.],
           [ 1.,  0.,  0.],
           [ 0.,  0.,  1.]])
    """
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(np.asarray(w_rad, dtype=float)).as_matrix()


@dataclass(frozen=True)
class ShadowPhase:
    """Daily shadowing of the boom.

    Parameters
    ----------
    start_lt_h : float
        Local time at which the boom enters the shadow (default 5.0 h, around dawn).
    duration_s : float
        Length of the shadow (default 3600 s).
    sunlit_C, shadow_C : float
        Temperatures the boom sensors relax towards in sunlight and in shadow.
    cool_tau_s, warm_tau_s : float
        Relaxation time constants.
    body_C : float
        Temperature of the sensors inside the body (constant).
    """

    start_lt_h: float = 5.0
    duration_s: float = 3600.0
    sunlit_C: float = 30.0
    shadow_C: float = -90.0
    cool_tau_s: float = 1800.0
    warm_tau_s: float = 1200.0
    body_C: float = 20.0

    def boom_temperature(self, t_s, context: ProfileContext) -> tuple[np.ndarray, np.ndarray]:
        """Temperature (C) and its rate (K/s) of a boom sensor at times ``t_s``."""
        t_s = np.asarray(t_s, dtype=float)
        lo, hi = (t_s[0], t_s[-1]) if len(t_s) else (0.0, 0.0)
        starts = context.local_time_events_s(self.start_lt_h, lo, hi)
        temp = np.full(len(t_s), self.sunlit_C)
        rate = np.zeros(len(t_s))
        idx = np.searchsorted(starts, t_s, side="right") - 1
        ok = idx >= 0
        since = np.where(ok, t_s - starts[np.clip(idx, 0, None)], np.inf)
        drop = self.shadow_C - self.sunlit_C
        cooling = since <= self.duration_s
        e_c = np.exp(-since[cooling] / self.cool_tau_s)
        temp[cooling] = self.sunlit_C + drop * (1.0 - e_c)
        rate[cooling] = drop / self.cool_tau_s * e_c
        end_temp = self.sunlit_C + drop * (1.0 - np.exp(-self.duration_s / self.cool_tau_s))
        warming = ~cooling & np.isfinite(since)
        e_w = np.exp(-(since[warming] - self.duration_s) / self.warm_tau_s)
        temp[warming] = self.sunlit_C + (end_temp - self.sunlit_C) * e_w
        rate[warming] = -(end_temp - self.sunlit_C) / self.warm_tau_s * e_w
        return temp, rate

    def max_rate(self) -> float:
        """Largest absolute cooling or warming rate (K/s)."""
        drop = abs(self.shadow_C - self.sunlit_C)
        end_drop = drop * (1.0 - np.exp(-self.duration_s / self.cool_tau_s))
        return max(drop / self.cool_tau_s, end_drop / self.warm_tau_s)


def temperature_offsets(sensor: Sensor, t_s, shadow: ShadowPhase | None,
                        context: ProfileContext,
                        rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Temperature (C, shape (n,)) and temperature-driven offset (nT, (n, 3)) of a sensor.

    Sensors inside the body, or every sensor when ``shadow`` is None, keep a constant
    temperature and get no temperature-driven offset. The oscillation direction and
    phase are drawn from ``rng``.
    """
    t_s = np.asarray(t_s, dtype=float)
    n = len(t_s)
    direction = rng.standard_normal(3)
    direction /= np.linalg.norm(direction)
    phase = rng.uniform(0.0, 2 * np.pi)
    if shadow is None:
        return np.full(n, 20.0), np.zeros((n, 3))
    if not sensor.on_boom:
        return np.full(n, shadow.body_C), np.zeros((n, 3))
    temp, rate = shadow.boom_temperature(t_s, context)
    drift = np.outer(shadow.sunlit_C - temp, np.asarray(sensor.temp_coeff_nT_per_K, dtype=float))
    envelope = np.abs(rate) / shadow.max_rate()
    soo = (sensor.soo_amplitude_nT * envelope
           * np.sin(2 * np.pi * t_s / sensor.soo_period_s + phase))
    return temp, drift + np.outer(soo, direction)
