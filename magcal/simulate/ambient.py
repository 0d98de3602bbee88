"""Ambient magnetic field at geostationary orbit for the simulators (Hpen frame, nT).

The quiet field comes from a magnetospheric model evaluated once a minute and
interpolated with a cubic spline to the sample times:

* ``"T89"``: :func:`magcal.models.irbem.field_geo` (IGRF + Tsyganenko 89 through
  IRBEM) driven by Kp;
* ``"dipole"``: a built-in placeholder - the IGRF-2020 centred tilted dipole plus a
  simple local-time dependent external field (dayside compression, nightside
  stretching, a Kp-dependent depression). It needs no compiled library and is fast.

On top come Pc5 ULF wave packets and substorm dips (growth-phase decrease of Hp,
sudden recovery with turbulence in He and Hn), both computed at the sample times.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from scipy.interpolate import CubicSpline

from magcal.errors import InputError
from magcal.frames.hpen import geo_to_hpen

#: Geostationary radius in Earth radii (42164.2 km / 6371.2 km).
GEO_RADIUS_RE = 42164.2 / 6371.2
#: IGRF-13 dipole Gauss coefficients for 2020.0 (nT): g10, g11, h11.
IGRF2020_DIPOLE_NT = (-29404.8, -1450.9, 4652.5)
KP_STEP = pd.Timedelta(hours=3)
AMBIENT_MODELS = ("T89", "dipole")


def utc_timestamp(value) -> pd.Timestamp:
    """A UTC :class:`pandas.Timestamp` from an ISO string or timestamp (naive = UTC)."""
    ts = pd.Timestamp(value)
    return ts.tz_localize("UTC") if ts.tz is None else ts.tz_convert("UTC")


def local_time_h(t_s, start: pd.Timestamp, longitude_deg: float) -> np.ndarray:
    """Local (solar-mean) time in hours: UT + longitude / 15, modulo 24."""
    start = utc_timestamp(start)
    ut0_h = (start - start.normalize()).total_seconds() / 3600.0
    return (ut0_h + np.asarray(t_s, dtype=float) / 3600.0 + longitude_deg / 15.0) % 24.0


# --------------------------------------------------------------------------- Kp

def quiet_kp_series(start, end, rng: np.random.Generator, mean_kp: float = 1.3) -> pd.Series:
    """A quiet-ish 3-hourly Kp series (decimal thirds: 1+ = 1.333) covering [start, end].

    An AR(1) walk around ``mean_kp`` rounded to thirds and clipped to [0, 4].

    Examples
    --------
    >>> kp = quiet_kp_series("2019-03-04", "2019-03-05", np.random.default_rng(1))
    >>> len(kp), float(kp.min()) >= 0.0, float(kp.max()) <= 4.0
    (9, True, True)
    """
    t0 = utc_timestamp(start).floor("3h")
    t1 = utc_timestamp(end)
    index = pd.date_range(t0, t1, freq="3h", inclusive="both")
    x = np.empty(len(index))
    level = mean_kp + rng.normal(0.0, 0.5)
    for k in range(len(index)):  # a handful of 3-hour bins, not samples
        level = mean_kp + 0.7 * (level - mean_kp) + rng.normal(0.0, 0.45)
        x[k] = level
    kp = np.clip(np.round(x * 3.0) / 3.0, 0.0, 4.0)
    return pd.Series(kp, index=index.rename("time"), name="kp")


def kp_series_for(kp, start, end, rng: np.random.Generator) -> pd.Series:
    """Normalise the ``kp`` knob of a config into a 3-hourly UTC series.

    Parameters
    ----------
    kp : None, float, array_like or pandas.Series
        None draws :func:`quiet_kp_series`; a number is held constant; an array gives
        one value per 3-hour bin starting at the bin containing ``start``; a Series is
        indexed by bin start times (naive = UTC) and must cover ``start``.
    start, end : timestamp-like
        The simulated interval.
    rng : numpy.random.Generator
        Used only when ``kp`` is None.
    """
    t0 = utc_timestamp(start).floor("3h")
    t1 = utc_timestamp(end)
    bins = pd.date_range(t0, t1, freq="3h", inclusive="both").rename("time")
    if kp is None:
        return quiet_kp_series(start, end, rng)
    if isinstance(kp, pd.Series):
        index = pd.DatetimeIndex(kp.index)
        index = index.tz_localize("UTC") if index.tz is None else index.tz_convert("UTC")
        series = pd.Series(np.asarray(kp.values, dtype=float), index=index.rename("time"),
                           name="kp").sort_index()
        if series.index[0] > utc_timestamp(start):
            raise InputError(f"kp series starts at {series.index[0]}, after the simulation "
                             f"start {utc_timestamp(start)}", column="kp")
    elif np.ndim(kp) == 0:
        series = pd.Series(np.full(len(bins), float(kp)), index=bins, name="kp")
    else:
        values = np.asarray(kp, dtype=float)
        if values.ndim != 1 or len(values) < len(bins):
            raise InputError(f"kp array needs one value per 3-hour bin from {t0}: "
                             f"{len(bins)} values, got {values.size}", column="kp")
        series = pd.Series(values[:len(bins)], index=bins, name="kp")
    if np.any(~np.isfinite(series.values)) or np.any((series.values < 0) | (series.values > 9)):
        raise InputError("kp values must be finite and within [0, 9]", column="kp")
    return series


def kp_at(times: pd.DatetimeIndex, kp: pd.Series) -> np.ndarray:
    """Kp of the 3-hour bin containing each time (last bin start at or before it)."""
    idx = np.searchsorted(pd.DatetimeIndex(kp.index).as_unit("ns").asi8,
                          pd.DatetimeIndex(times).as_unit("ns").asi8, side="right") - 1
    return np.asarray(kp.values, dtype=float)[np.clip(idx, 0, len(kp) - 1)]


# ----------------------------------------------------------------- quiet field

def dipole_geo(pos_geo_re, g10=IGRF2020_DIPOLE_NT[0], g11=IGRF2020_DIPOLE_NT[1],
               h11=IGRF2020_DIPOLE_NT[2]) -> np.ndarray:
    """Centred tilted dipole field in GEO cartesian components (nT).

    ``B = (a / r)^3 (3 (g . r_hat) r_hat - g)`` with ``g = (g11, h11, g10)``.

    Examples
    --------
    On the equator the field of an axial dipole points north (+z) with strength
    ``|g10| / r^3``:

    >>> dipole_geo([[5.0, 0.0, 0.0]], g10=-30000.0, g11=0.0, h11=0.0).round(6) + 0.0
    array([[  0.,   0., 240.]])
    """
    r = np.atleast_2d(np.asarray(pos_geo_re, dtype=float))
    dist = np.linalg.norm(r, axis=1)
    r_hat = r / dist[:, None]
    g = np.array([g11, h11, g10], dtype=float)
    return (3.0 * (r_hat @ g)[:, None] * r_hat - g[None, :]) / dist[:, None] ** 3


def placeholder_external_hpen(lt_h, kp) -> np.ndarray:
    """Simple external field at GEO in Hpen (nT): compression, stretching, depression."""
    phase = 2 * np.pi * (np.asarray(lt_h, dtype=float) - 12.0) / 24.0
    kp = np.asarray(kp, dtype=float)
    hp = 5.0 + 10.0 * np.cos(phase) - 3.0 * kp
    he = -6.0 * 0.5 * (1.0 - np.cos(phase)) * (1.0 + kp / 3.0)
    hn = 3.0 * np.sin(phase)
    return np.column_stack([hp, he, hn])


def geo_position_re(longitude_deg: float, n: int) -> np.ndarray:
    """GEO cartesian position (Earth radii) of a geostationary spacecraft, (n, 3)."""
    lon = np.deg2rad(longitude_deg)
    return np.tile([GEO_RADIUS_RE * np.cos(lon), GEO_RADIUS_RE * np.sin(lon), 0.0], (n, 1))


def quiet_field_hpen(times: pd.DatetimeIndex, longitude_deg: float, kp_values,
                     model: str) -> np.ndarray:
    """Quiet model field in Hpen at a geostationary position, one row per time.

    Parameters
    ----------
    times : pandas.DatetimeIndex
        UTC times (typically a 1-min grid).
    longitude_deg : float
        East longitude of the spacecraft.
    kp_values : array_like, shape (n,)
        Kp (decimal thirds) at each time.
    model : {"T89", "dipole"}
        See the module docstring.
    """
    n = len(times)
    pos = geo_position_re(longitude_deg, n)
    if model == "dipole":
        start = times[0]
        t_s = (times - start).total_seconds().to_numpy()
        internal = geo_to_hpen(dipole_geo(pos), longitude_deg, 0.0)
        return internal + placeholder_external_hpen(local_time_h(t_s, start, longitude_deg),
                                                    kp_values)
    if model == "T89":
        from magcal.models.irbem import field_geo

        # field_geo takes Kp in Kp units (1+ = 4/3) and converts it for IRBEM itself
        b_geo = field_geo(times, pos, model="T89",
                          inputs={"Kp": np.asarray(kp_values, dtype=float)})
        return geo_to_hpen(np.asarray(b_geo, dtype=float), longitude_deg, 0.0)
    raise InputError(f"unknown ambient model {model!r}; choose one of {AMBIENT_MODELS}")


def t89_available() -> bool:
    """True when the IRBEM-backed model interface and its library can be used."""
    try:
        from magcal.models.irbem import ctypes_available, field_geo  # noqa: F401
    except ImportError:
        return False
    try:
        import importlib.util

        return ctypes_available() or importlib.util.find_spec("spacepy") is not None
    except Exception:  # pragma: no cover - a broken install counts as unavailable
        return False


def smooth_model_field_hpen(times: pd.DatetimeIndex, longitude_deg: float, kp: pd.Series,
                            model: str, grid_s: float = 60.0) -> np.ndarray:
    """Model field evaluated every ``grid_s`` seconds, cubic-spline interpolated to ``times``.

    Kp steps at 3-hour boundaries are kept (the model itself jumps there).
    """
    times = pd.DatetimeIndex(times)
    t0 = times[0].floor(f"{int(grid_s)}s") - pd.Timedelta(seconds=2 * grid_s)
    t1 = times[-1].ceil(f"{int(grid_s)}s") + pd.Timedelta(seconds=2 * grid_s)
    grid = pd.date_range(t0, t1, freq=f"{int(grid_s)}s")
    b_grid = quiet_field_hpen(grid, longitude_deg, kp_at(grid, kp), model)
    x_grid = (grid - t0).total_seconds().to_numpy()
    x = (times - t0).total_seconds().to_numpy()
    return CubicSpline(x_grid, b_grid, axis=0)(x)


# ------------------------------------------------------------ variable parts

def ulf_waves_hpen(t_s, rng: np.random.Generator, amplitude_nT: float = 2.0,
                   packets_per_day: float = 6.0,
                   period_range_s: tuple[float, float] = (150.0, 600.0)) -> np.ndarray:
    """Pc5 ULF wave packets in Hpen (nT), shape (n, 3).

    Each packet has a Gaussian envelope (sigma 15-45 min), a period drawn uniformly in
    ``period_range_s`` (Pc5: 150-600 s), random phases per component and component
    amplitudes up to ``amplitude_nT`` (largest in He and Hn: poloidal and toroidal
    modes), so the polarisation is elliptical and changes from packet to packet.

    Examples
    --------
    >>> w = ulf_waves_hpen(np.arange(0, 86400.0, 10.0), np.random.default_rng(3))
    >>> w.shape, bool(np.abs(w).max() < 3 * 2.0)
    ((8640, 3), True)
    """
    t_s = np.asarray(t_s, dtype=float)
    if len(t_s) == 0 or amplitude_nT == 0:
        return np.zeros((len(t_s), 3))
    span = t_s[-1] - t_s[0]
    n_packets = max(1, int(rng.poisson(packets_per_day * max(span, 3600.0) / 86400.0)))
    centres = rng.uniform(t_s[0] - 3600.0, t_s[-1] + 3600.0, n_packets)
    sigmas = rng.uniform(900.0, 2700.0, n_packets)
    freqs = 1.0 / rng.uniform(*period_range_s, n_packets)
    weights = np.array([0.4, 1.0, 1.0])
    amps = amplitude_nT * weights * rng.uniform(0.3, 1.0, (n_packets, 3))
    phases = rng.uniform(0.0, 2 * np.pi, (n_packets, 3))
    out = np.zeros((len(t_s), 3))
    for p in range(n_packets):  # a few packets, each vectorised over samples
        env = np.exp(-0.5 * ((t_s - centres[p]) / sigmas[p]) ** 2)
        arg = 2 * np.pi * freqs[p] * t_s
        out += env[:, None] * amps[p] * np.sin(arg[:, None] + phases[p])
    return out


def substorm_hpen(t_s, onset_s, depth_nT: float, rng: np.random.Generator,
                  growth_s: float = 3600.0, recovery_s: float = 900.0,
                  turbulence_nT: float = 3.0, turbulence_s: float = 1800.0,
                  cadence_s: float = 1.0) -> np.ndarray:
    """Substorm dips in Hpen (nT), shape (n, 3).

    For each onset: Hp decreases smoothly by ``depth_nT`` over the growth phase (He by
    half as much: the field stretches tailward), then recovers exponentially with time
    constant ``recovery_s`` (dipolarisation), with band-limited turbulence (periods
    20 s - 10 min, rms ``turbulence_nT``) in He and Hn decaying over ``turbulence_s``
    (SOSMAG, 8 August 2019: Hp from 80 to 50 nT and back, "accompanied by turbulent
    disturbance in the earthward (He) and eastward (Hn) components").

    Examples
    --------
    >>> t = np.arange(0, 14400.0)
    >>> d = substorm_hpen(t, [7200.0], 30.0, np.random.default_rng(0))
    >>> round(float(d[:, 0].min()), 6)
    -30.0
    """
    t_s = np.asarray(t_s, dtype=float)
    n = len(t_s)
    out = np.zeros((n, 3))
    for onset in np.atleast_1d(np.asarray(onset_s, dtype=float)):
        x = np.clip((t_s - (onset - growth_s)) / growth_s, 0.0, 1.0)
        growth = x * x * (3.0 - 2.0 * x)  # smoothstep 0 -> 1
        after = t_s > onset
        shape = np.where(after, np.exp(-(t_s - onset) / recovery_s), growth)
        out[:, 0] -= depth_nT * shape
        out[:, 1] -= 0.5 * depth_nT * shape
        if turbulence_nT > 0 and n > 1:
            spectrum = np.fft.rfft(rng.standard_normal((2, n)), axis=1)
            f = np.fft.rfftfreq(n, cadence_s)
            band = ((f >= 1 / 600.0) & (f <= 1 / 20.0)).astype(float)
            noise = np.fft.irfft(spectrum * band, n, axis=1)
            rms = np.sqrt(np.mean(noise**2, axis=1, keepdims=True))
            noise = noise / np.where(rms > 0, rms, 1.0)
            env = np.where(after, np.exp(-(t_s - onset) / turbulence_s), 0.0)
            out[:, 1:] += turbulence_nT * (env[None, :] * noise).T
    return out
