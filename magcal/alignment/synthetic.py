"""Synthetic data with a known rotation for tests, benchmarks and demonstrations.

A geostationary-like reference field in Hpen (about 100 nT northward with daily and
half-daily variation) and data ``R(w) @ ref + offset + e`` with Ornstein-Uhlenbeck
errors of the size the SOSMAG paper reports for model-minus-data (6.7, 2.3, 2.0 nT).
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.spatial.transform import Rotation

from magcal.alignment.noise import simulate_ou

DAY_S = 86400.0


@dataclasses.dataclass(frozen=True)
class SyntheticPair:
    """Simulated data and reference with the injected truth."""

    times: np.ndarray
    data: np.ndarray
    ref: np.ndarray
    rotvec_deg: np.ndarray
    offset_nT: np.ndarray
    noise_std_nT: np.ndarray
    noise_tau_s: np.ndarray


def geostationary_reference(times_s, rng: np.random.Generator | None = None) -> np.ndarray:
    """Smooth geostationary-like Hpen field (nT) with daily and half-daily variation.

    With ``rng``, the daily amplitudes and phases vary from day to day (quiet/active
    days), otherwise the same day repeats.

    Examples
    --------
    >>> geostationary_reference(np.array([0.0])).round(1)
    array([[119. ,  18.8,   1.7]])
    """
    t = np.asarray(times_s, dtype=float)
    x = 2 * np.pi * t / DAY_S
    day = np.floor(t / DAY_S).astype(int)
    n_days = int(day.max()) + 1 if t.size else 1
    if rng is None:
        amp = np.ones((n_days, 3))
        ph = np.zeros((n_days, 3))
    else:
        amp = rng.uniform(0.6, 1.4, size=(n_days, 3))
        ph = rng.normal(0.0, 0.3, size=(n_days, 3))
    a, p = amp[day], ph[day]
    hp = 100.0 + 15.0 * a[:, 0] * np.cos(x + p[:, 0]) + 4.0 * np.cos(2 * x)
    he = 10.0 + 10.0 * a[:, 1] * np.cos(x + 0.5 + p[:, 1]) + 3.0 * np.sin(2 * x)
    hn = 6.0 * a[:, 2] * np.sin(x + p[:, 2]) + 2.0 * np.sin(2 * x + 1.0)
    return np.stack([hp, he, hn], axis=1)


def synthetic_pair(rng: np.random.Generator, n: int = 43200, cadence_s: float = 60.0,
                   rotvec_deg=(1.7, -0.5, -0.5), offset_nT=(0.0, 0.0, 0.0),
                   noise_std_nT=(6.7, 2.3, 2.0), noise_tau_s=(7200.0, 7200.0, 7200.0),
                   start: str = "2019-03-01T00:00:00") -> SyntheticPair:
    """Simulate ``n`` samples of data and reference with a known rotation.

    Parameters
    ----------
    rng : numpy.random.Generator
    n : int
        Number of samples (43,200 = a month of minutes).
    cadence_s : float
    rotvec_deg : 3 floats
        Injected rotation vector about (Hp, He, Hn), degrees.
    offset_nT : 3 floats
        Injected constant offset.
    noise_std_nT, noise_tau_s : 3 floats each
        OU noise standard deviation and correlation time per component.
    start : str
        ISO time of the first sample.

    Returns
    -------
    SyntheticPair

    Examples
    --------
    >>> case = synthetic_pair(np.random.default_rng(0), n=10)
    >>> case.data.shape, str(case.times[1])
    ((10, 3), '2019-03-01T00:01:00.000000000')
    """
    t_s = np.arange(n) * float(cadence_s)
    times = np.datetime64(start, "ns") + (t_s * 1e9).astype("int64").astype("timedelta64[ns]")
    ref = geostationary_reference(t_s, rng)
    std = np.broadcast_to(np.asarray(noise_std_nT, dtype=float), (3,))
    tau = np.broadcast_to(np.asarray(noise_tau_s, dtype=float), (3,))
    noise = np.stack([simulate_ou(rng, t_s, std[c], tau[c]) for c in range(3)], axis=1)
    rot = Rotation.from_rotvec(np.deg2rad(rotvec_deg))
    data = rot.apply(ref) + np.asarray(offset_nT, dtype=float) + noise
    return SyntheticPair(times=times, data=data, ref=ref,
                         rotvec_deg=np.asarray(rotvec_deg, dtype=float),
                         offset_nT=np.asarray(offset_nT, dtype=float),
                         noise_std_nT=std.copy(), noise_tau_s=tau.copy())
