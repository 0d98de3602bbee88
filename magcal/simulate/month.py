"""A month (or a year) of 1-min Hpen data of a geostationary magnetometer, with known truth.

The measured field is the sum of separately kept parts::

    measured = model (T89 at the simulated Kp)
             + offset            slowly drifting DC offsets (the truth to recover)
             + local_time        a local-time field T89 lacks (SOSMAG paper Fig. 19:
                                 8 nT peak-to-peak in Hp, ~5 nT in He, 1-2 nT in Hn)
             + disturbed         substorm dips near local midnight and the storm-time
                                 depression (from a simulated Dst), only at high Kp
             + ulf               Pc5-like waves, stronger at high Kp
             + temperature       optional offset drift with sensor temperature (off by
                                 default)
             + noise             white noise of the 1-min averages

The Kp series is 3-hourly, in thirds, persistent (an AR(1) latent process), quiet most of
the time, with storm days added on top. Dst follows a Burton-type equation driven by
Kp. The sensor temperature follows a daily boom-shadow cycle (+30 C in sunlight, towards
-90 C during an 8.5-hour shadow ending at dawn). Every random part draws from its own
child generator of ``rng``, so switching one part on or off (e.g. disturbed days) leaves
the others unchanged.

The local-time field uses only odd harmonics of the day, so its values are symmetric
about zero over a day: its mean and its median over uniformly sampled local times are 0
and it does not bias a median offset estimate by construction.
"""

from __future__ import annotations

from dataclasses import dataclass, field as dc_field

import numpy as np

from magcal.errors import InputError

_DAY_S = 86_400.0
_STREAMS = ("kp", "storms", "substorms", "ulf", "noise")


@dataclass(frozen=True)
class MonthConfig:
    """Knobs of :func:`simulate_month` (defaults: GK-2A, November 2019-like).

    Attributes
    ----------
    start : str
        First sample (UTC, ISO).
    n_days : float
        Length; 30 by default, up to a year or more.
    cadence_s : float
        Sample spacing (60 s).
    lon_deg, lat_deg, r_re : float
        Geostationary position (128.2 E, 0, 6.6 RE).
    model : str
        Field model of the ambient part (``T89``: driven by the simulated Kp).
    offset_start_nT : tuple of 3 float
        DC offsets (Hp, He, Hn) at ``start`` (the paper's November 2019 values).
    offset_drift_nT_per_day : tuple of 3 float
        Linear drift.
    offset_wander_nT, offset_wander_days : tuple of 3 float, float
        Amplitude and period of a slow sinusoidal wander added to the drift.
    local_time_pp_nT : tuple of 3 float
        Peak-to-peak of the local-time field in Hp, He, Hn.
    kp_quiet_median, kp_spread, kp_persistence : float
        Latent AR(1) Kp: ``median + spread * x``, lag-one correlation per 3 h.
    n_disturbed_days : int
        Storm days added at random days; ``disturbed_days`` (day indices) overrides.
    storm_kp_range : tuple of 2 float
        Peak Kp of a storm, drawn uniformly and rounded to thirds.
    dst_tau_h, dst_per_kp_nT_per_h, dst_kp_threshold : float
        Burton-type Dst: ``dDst/dt = -q * max(Kp - threshold, 0)**1.5 - Dst / tau``.
    storm_coupling : tuple of 3 float
        Storm-time field = coupling * Dst (nT per nT of Dst) in Hp, He, Hn.
    substorm_depth_nT_per_kp : float
        Depth of a substorm dip in Hp per unit Kp above 2 (onsets only when Kp >= 3).
    ulf_base_nT, ulf_per_kp_nT : float
        RMS of the ULF waves: ``base + per_kp * Kp``.
    noise_nT : float
        White noise RMS per component.
    temperature_coeff_nT_per_C : tuple of 3 float
        Offset change per deg C of sensor temperature from +30 C (0 by default).
    shadow_start_lt_h, shadow_hours : float
        Boom shadow in local time.
    gaps : tuple of (str, float)
        Data gaps as (start ISO, hours): measured values are NaN there.
    n_jobs : int or None
        Worker processes for the model field.
    """

    start: str = "2019-11-01T00:00:00"
    n_days: float = 30.0
    cadence_s: float = 60.0
    lon_deg: float = 128.2
    lat_deg: float = 0.0
    r_re: float = 6.6
    model: str = "T89"
    offset_start_nT: tuple = (14.8, 38.4, -89.8)
    offset_drift_nT_per_day: tuple = (0.03, -0.02, 0.008)
    offset_wander_nT: tuple = (0.5, 0.3, 0.1)
    offset_wander_days: float = 120.0
    local_time_pp_nT: tuple = (8.0, 5.0, 1.5)
    kp_quiet_median: float = 0.7
    kp_spread: float = 0.9
    kp_persistence: float = 0.85
    n_disturbed_days: int = 3
    disturbed_days: tuple | None = None
    storm_kp_range: tuple = (5.0, 7.0)
    dst_tau_h: float = 6.0
    dst_per_kp_nT_per_h: float = 3.0
    dst_kp_threshold: float = 3.0
    storm_coupling: tuple = (0.7, 0.1, 0.05)
    substorm_depth_nT_per_kp: float = 12.0
    ulf_base_nT: float = 0.3
    ulf_per_kp_nT: float = 0.4
    noise_nT: float = 0.15
    temperature_coeff_nT_per_C: tuple = (0.0, 0.0, 0.0)
    shadow_start_lt_h: float = 21.5
    shadow_hours: float = 8.5
    gaps: tuple = ()
    n_jobs: int | None = None


@dataclass(frozen=True)
class MonthResult:
    """Simulated data with every part of the truth kept separately (all (n, 3) in nT).

    ``measured_nT`` = ``model_nT + offset_nT + local_time_nT + disturbed_nT + ulf_nT +
    temperature_nT + noise_nT`` (NaN in gaps).
    """

    times: np.ndarray
    measured_nT: np.ndarray
    model_nT: np.ndarray
    offset_nT: np.ndarray
    local_time_nT: np.ndarray
    disturbed_nT: np.ndarray
    ulf_nT: np.ndarray
    temperature_nT: np.ndarray
    noise_nT: np.ndarray
    kp: np.ndarray
    kp_3h: object
    dst: np.ndarray
    temperature_C: np.ndarray
    lon_deg: np.ndarray
    local_time_h: np.ndarray
    disturbed_day_index: tuple
    config: MonthConfig = dc_field(default_factory=MonthConfig)

    def to_frame(self):
        """Measured data as a ``time,Hp,He,Hn`` DataFrame (UTC index named time)."""
        return self._frame(self.measured_nT)

    def model_frame(self):
        """Model field (T89 at the simulated Kp) as ``time,Hp,He,Hn``."""
        return self._frame(self.model_nT)

    def covariates_frame(self):
        """``time,temperature,kp,dst,lon_deg`` (CONTRACTS §5 covariate names)."""
        import pandas as pd

        return pd.DataFrame({"temperature": self.temperature_C, "kp": self.kp,
                             "dst": self.dst, "lon_deg": self.lon_deg},
                            index=self._index())

    def kp_frame(self):
        """3-hourly Kp as a ``time,kp`` DataFrame (interval starts)."""
        return self.kp_3h.to_frame("kp")

    def _index(self):
        import pandas as pd

        return pd.DatetimeIndex(self.times, name="time").tz_localize("UTC")

    def _frame(self, values):
        import pandas as pd

        return pd.DataFrame(values, index=self._index(), columns=["Hp", "He", "Hn"])


# --------------------------------------------------------------------------- parts
def simulate_kp(n_intervals: int, config: MonthConfig, rng: np.random.Generator,
                storm_rng: np.random.Generator, n_days_total: int):
    """3-hourly Kp in thirds: persistent quiet background plus storm days."""
    rho = config.kp_persistence
    eps = rng.standard_normal(n_intervals)
    x = np.empty(n_intervals)
    x[0] = eps[0]
    for k in range(1, n_intervals):
        x[k] = rho * x[k - 1] + np.sqrt(1 - rho ** 2) * eps[k]
    kp = np.clip(config.kp_quiet_median + config.kp_spread * x, 0.0, 9.0)
    if config.disturbed_days is not None:
        days = np.asarray(config.disturbed_days, dtype=int)
    else:
        n = min(int(config.n_disturbed_days), max(n_days_total, 0))
        days = np.sort(storm_rng.choice(max(n_days_total, 1), size=n, replace=False))
    peaks = storm_rng.uniform(*config.storm_kp_range, size=days.size)
    onsets = storm_rng.integers(0, 4, size=days.size)
    # storm profile over 3-hour intervals after onset: sharp rise, slow decay (~1.5 days)
    profile = np.array([0.55, 0.9, 1.0, 0.9, 0.75, 0.6, 0.5, 0.4, 0.32, 0.25, 0.2, 0.15])
    for day, peak, onset in zip(days, peaks, onsets):
        k0 = day * 8 + onset
        for j, f in enumerate(profile):
            if 0 <= k0 + j < n_intervals:
                kp[k0 + j] = max(kp[k0 + j], peak * f + 0.4)
    kp = np.clip(np.round(kp * 3.0) / 3.0, 0.0, 9.0)
    return kp, tuple(int(d) for d in days)


def simulate_dst(kp: np.ndarray, dt_s: float, config: MonthConfig) -> np.ndarray:
    """Disturbance Dst (nT, <= 0) from a Burton-type equation driven by Kp."""
    decay = np.exp(-dt_s / (config.dst_tau_h * 3600.0))
    inj = (-config.dst_per_kp_nT_per_h * np.maximum(kp - config.dst_kp_threshold, 0.0) ** 1.5
           * dt_s / 3600.0)
    # acc[i] = decay * acc[i-1] + inj[i], in closed form per block (no Python loop per sample)
    out = np.empty_like(inj)
    block = 512
    powers = decay ** np.arange(block)
    acc = 0.0
    for a in range(0, inj.size, block):
        x = inj[a:a + block]
        p = powers[:x.size]
        out[a:a + x.size] = p * (acc * decay + np.cumsum(x / p))
        acc = out[a + x.size - 1]
    return out


def local_time_field(lt_h: np.ndarray, pp_nT) -> np.ndarray:
    """Local-time field: Hp min at midnight with a broad noon maximum, He max near 23 LT and
    min near 11 LT, Hn a weak odd-harmonic ripple; each scaled to its peak-to-peak.

    Examples
    --------
    >>> f = local_time_field(np.linspace(0, 24, 2400, endpoint=False), (8.0, 5.0, 1.5))
    >>> (f.max(axis=0) - f.min(axis=0)).round(3), f.mean(axis=0).round(3) + 0.0
    (array([8. , 5. , 1.5]), array([0., 0., 0.]))
    """
    phi = 2 * np.pi * np.asarray(lt_h, dtype=float) / 24.0
    shapes = np.stack([-np.cos(phi) + 0.15 * np.cos(3 * phi),
                       np.cos(phi - 2 * np.pi * 23 / 24),
                       np.sin(3 * phi + 0.7) + 0.5 * np.cos(phi)], axis=1)
    grid = 2 * np.pi * np.linspace(0, 1, 4001)
    ref = np.stack([-np.cos(grid) + 0.15 * np.cos(3 * grid),
                    np.cos(grid - 2 * np.pi * 23 / 24),
                    np.sin(3 * grid + 0.7) + 0.5 * np.cos(grid)], axis=1)
    scale = np.asarray(pp_nT, dtype=float) / (ref.max(axis=0) - ref.min(axis=0))
    return shapes * scale


def _band_noise(n: int, dt_s: float, f_lo: float, f_hi: float,
                rng: np.random.Generator) -> np.ndarray:
    """Unit-RMS band-limited Gaussian noise, (n, 3)."""
    white = rng.standard_normal((n, 3))
    spec = np.fft.rfft(white, axis=0)
    f = np.fft.rfftfreq(n, dt_s)
    spec[(f < f_lo) | (f > f_hi)] = 0.0
    out = np.fft.irfft(spec, n=n, axis=0)
    rms = np.sqrt(np.mean(out ** 2, axis=0))
    return out / np.where(rms > 0, rms, 1.0)


def _substorms(t_s: np.ndarray, kp: np.ndarray, lt_h: np.ndarray, config: MonthConfig,
               rng: np.random.Generator) -> np.ndarray:
    """Substorm dips in Hp (and turbulence in He, Hn) near local midnight when Kp >= 3."""
    n = t_s.size
    out = np.zeros((n, 3))
    dt = float(np.median(np.diff(t_s))) if n > 1 else 60.0
    night = (lt_h >= 20.0) | (lt_h < 4.0)
    # candidate onsets: one per hour of active night-side time, with probability 0.35
    hour = (t_s // 3600).astype(np.int64)
    first = np.r_[True, hour[1:] != hour[:-1]]
    cand = np.flatnonzero(first & night & (kp >= 3.0))
    onsets = cand[rng.random(cand.size) < 0.35]
    for i0 in onsets:
        depth = config.substorm_depth_nT_per_kp * (kp[i0] - 2.0) * rng.uniform(0.6, 1.4)
        span = int(4 * 3600 / dt)
        seg = slice(i0, min(n, i0 + span))
        tau = (t_s[seg] - t_s[i0]) / 60.0  # minutes
        shape = (1 - np.exp(-tau / 8.0)) * np.exp(-tau / 45.0)
        out[seg, 0] -= depth * shape / 0.72
        wiggle = rng.standard_normal((tau.size, 2)) * (0.15 * depth) * shape[:, None]
        out[seg, 1:] += wiggle
    return out


def boom_temperature(lt_h: np.ndarray, dt_s: float, config: MonthConfig) -> np.ndarray:
    """Sensor temperature (deg C): +30 in sunlight, relaxing towards -90 in the boom shadow."""
    in_shadow = np.mod(lt_h - config.shadow_start_lt_h, 24.0) < config.shadow_hours
    n = lt_h.size
    temp = np.empty(n)
    if n == 0:
        return temp
    # piecewise exponential relaxation, closed form per sunlit/shadow segment
    edges = np.r_[0, np.flatnonzero(in_shadow[1:] != in_shadow[:-1]) + 1, n]
    cur = 30.0  # the run starts from the sunlit equilibrium
    for a, b in zip(edges[:-1], edges[1:]):
        shadow = bool(in_shadow[a])
        target, tau = (-90.0, 1.5 * 3600.0) if shadow else (30.0, 3600.0)
        k = np.arange(1, b - a + 1)
        temp[a:b] = target + (cur - target) * np.exp(-k * dt_s / tau)
        cur = temp[b - 1]
    return temp


# --------------------------------------------------------------------------- main
def simulate_month(config: MonthConfig | None = None, *, rng: np.random.Generator) -> MonthResult:
    """Simulate 1-min Hpen data of a geostationary spacecraft with known truth.

    Parameters
    ----------
    config : MonthConfig, optional
        Knobs (defaults: 30 days from 2019-11-01 at 128.2 E).
    rng : numpy.random.Generator
        Source of all randomness (split into independent child streams).

    Returns
    -------
    MonthResult

    Examples
    --------
    >>> import numpy as np
    >>> res = simulate_month(MonthConfig(n_days=2, n_disturbed_days=0, n_jobs=1),
    ...                      rng=np.random.default_rng(1))
    >>> res.measured_nT.shape, res.to_frame().columns.tolist()
    ((2880, 3), ['Hp', 'He', 'Hn'])
    """
    import pandas as pd

    from magcal.models.field import model_field_hpen
    from magcal.frames.localtime import local_time_hours

    cfg = config or MonthConfig()
    if cfg.n_days <= 0 or cfg.cadence_s <= 0:
        raise InputError("n_days and cadence_s must be positive")
    if not isinstance(rng, np.random.Generator):
        raise InputError("rng must be a numpy.random.Generator")
    streams = dict(zip(_STREAMS, rng.spawn(len(_STREAMS))))
    dt = float(cfg.cadence_s)
    n = int(round(cfg.n_days * _DAY_S / dt))
    t0 = np.datetime64(cfg.start, "ns")
    times = t0 + (np.arange(n) * dt * 1e9).astype("timedelta64[ns]")
    t_s = np.arange(n) * dt
    lt = local_time_hours(times, cfg.lon_deg)

    # Kp: 3-hour intervals aligned to 00, 03, ... UTC
    first_interval = t0.astype("datetime64[D]").astype("datetime64[ns]")
    offset_ns = int((t0 - first_interval).astype(np.int64))
    k_idx = (offset_ns + t_s * 1e9).astype(np.int64) // (3 * 3600 * 10**9)
    n_int = int(k_idx[-1]) + 1 if n else 0
    n_days_total = int(np.ceil(n_int / 8))
    kp3, storm_days = simulate_kp(n_int, cfg, streams["kp"], streams["storms"], n_days_total)
    kp = kp3[k_idx]
    kp_series = pd.Series(kp3, name="kp", index=pd.DatetimeIndex(
        first_interval + np.arange(n_int) * np.timedelta64(3, "h"), name="time"
    ).tz_localize("UTC"))

    dst = simulate_dst(kp, dt, cfg)
    model = model_field_hpen(times, cfg.lon_deg, cfg.lat_deg, cfg.r_re, cfg.model, kp=kp,
                             cadence_s=None, n_jobs=cfg.n_jobs).b_hpen_nT
    days = t_s / _DAY_S
    wander = np.sin(2 * np.pi * days / cfg.offset_wander_days)
    offset = (np.asarray(cfg.offset_start_nT)[None, :]
              + np.asarray(cfg.offset_drift_nT_per_day)[None, :] * days[:, None]
              + np.asarray(cfg.offset_wander_nT)[None, :] * wander[:, None])
    lt_field = local_time_field(lt, cfg.local_time_pp_nT)
    storm = dst[:, None] * np.asarray(cfg.storm_coupling)[None, :]
    disturbed = storm + _substorms(t_s, kp, lt, cfg, streams["substorms"])
    ulf = (_band_noise(n, dt, 1.0 / 1200.0, 1.0 / 150.0, streams["ulf"])
           * (cfg.ulf_base_nT + cfg.ulf_per_kp_nT * kp)[:, None])
    temp = boom_temperature(lt, dt, cfg)
    temp_field = (temp - 30.0)[:, None] * np.asarray(cfg.temperature_coeff_nT_per_C)[None, :]
    noise = streams["noise"].standard_normal((n, 3)) * cfg.noise_nT
    measured = model + offset + lt_field + disturbed + ulf + temp_field + noise
    for start, hours in cfg.gaps:
        g0 = np.datetime64(start, "ns")
        g1 = g0 + np.timedelta64(int(round(hours * 3.6e12)), "ns")
        measured[(times >= g0) & (times < g1)] = np.nan
    return MonthResult(times=times, measured_nT=measured, model_nT=model, offset_nT=offset,
                       local_time_nT=lt_field, disturbed_nT=disturbed, ulf_nT=ulf,
                       temperature_nT=temp_field, noise_nT=noise, kp=kp, kp_3h=kp_series,
                       dst=dst, temperature_C=temp, lon_deg=np.full(n, cfg.lon_deg),
                       local_time_h=lt, disturbed_day_index=storm_days, config=cfg)
