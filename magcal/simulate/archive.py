"""A quarter of raw two-sensor data as daily files: the input of the demo chain.

The ambient field comes from :func:`magcal.simulate.month.simulate_month` (T89 at a
simulated Kp, the local-time field T89 lacks, storms, ULF waves, noise) at the
outboard sensor. The outboard DC offset drifts slowly and steps once; both sensors see
two linearly polarised spacecraft disturbers (a heater toggling on and off and a
reaction-wheel tone), four times stronger at the inboard sensor. The sensors are in
the Hpen frame (a geostationary spacecraft in fixed attitude), so the chain's common
frame is ``hpen``.

The truth kept per sample: the outboard offset (what the offset product must follow)
and the clean outboard field (what AC cleaning must return, offset included).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from magcal.errors import InputError

_DAY_NS = 86_400 * 10**9


@dataclass(frozen=True)
class ArchiveConfig:
    """Knobs of :func:`simulate_archive` (the demo's defaults).

    Attributes
    ----------
    start : str
        First sample (UTC).
    n_days : float
        Length (91: a quarter, enough for 10 offset windows of 28 days stepped by 7).
    cadence_s : float
        Sample spacing of the raw files.
    lon_deg : float
        Geostationary longitude.
    offset_start_nT, drift_nT_per_day : tuple of 3 float
        Outboard offset (Hp, He, Hn) at ``start`` and its linear drift.
    step_time : str
        When the outboard offset steps.
    step_nT : tuple of 3 float
        The step.
    inboard_offset_delta_nT : tuple of 3 float
        Inboard offset minus outboard offset (constant).
    heater_nT, tone_nT : float
        Amplitude of the two disturbers at the outboard sensor (4x at the inboard).
    heater_direction, tone_direction : tuple of 3 float
        Their (linear) polarisation, normalised.
    tone_period_s : float
    inboard_noise_nT : float
        Extra white noise of the inboard sensor.
    """

    start: str = "2019-11-01T00:00:00"
    n_days: float = 91.0
    cadence_s: float = 10.0
    lon_deg: float = 128.2
    offset_start_nT: tuple = (14.8, 38.4, -89.8)
    drift_nT_per_day: tuple = (0.04, -0.03, 0.02)
    step_time: str = "2019-12-12T00:00:00"
    step_nT: tuple = (3.0, -2.0, 1.5)
    inboard_offset_delta_nT: tuple = (-6.0, 4.0, 10.0)
    heater_nT: float = 2.0
    heater_direction: tuple = (0.3, 0.8, -0.5)
    tone_nT: float = 1.0
    tone_direction: tuple = (-0.6, 0.2, 0.77)
    tone_period_s: float = 120.0
    inboard_gain: float = 4.0
    inboard_noise_nT: float = 0.05


@dataclass(frozen=True)
class ArchiveResult:
    """Raw sensors, Kp and truth (all (n, 3) arrays in nT on ``times``)."""

    times: np.ndarray
    outboard: np.ndarray
    inboard: np.ndarray
    offset_nT: np.ndarray
    clean_outboard: np.ndarray
    kp_3h: pd.Series
    dst_nT: np.ndarray
    config: ArchiveConfig


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


def _heater(t_s: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """On/off square wave with on and off times drawn between 15 and 45 min."""
    edges = np.cumsum(rng.uniform(900.0, 2700.0, size=int(t_s[-1] / 900.0) + 2))
    return (np.searchsorted(edges, t_s) % 2).astype(float) - 0.5


def simulate_archive(config: ArchiveConfig | None = None, *,
                     rng: np.random.Generator) -> ArchiveResult:
    """Simulate the raw two-sensor archive (see the module docstring).

    Examples
    --------
    >>> res = simulate_archive(ArchiveConfig(n_days=1, cadence_s=60), rng=np.random.default_rng(1))
    >>> res.outboard.shape, bool(np.all(np.diff(res.times) > np.timedelta64(0)))
    ((1440, 3), True)
    """
    from magcal.simulate.month import MonthConfig, simulate_month

    cfg = config or ArchiveConfig()
    if not isinstance(rng, np.random.Generator):
        raise InputError("rng must be a numpy.random.Generator")
    month_rng, dist_rng, noise_rng = rng.spawn(3)
    month = simulate_month(MonthConfig(start=cfg.start, n_days=cfg.n_days,
                                       cadence_s=cfg.cadence_s, lon_deg=cfg.lon_deg,
                                       offset_start_nT=cfg.offset_start_nT,
                                       offset_drift_nT_per_day=cfg.drift_nT_per_day,
                                       offset_wander_nT=(0.0, 0.0, 0.0)), rng=month_rng)
    t = month.times
    t_s = (t - t[0]) / np.timedelta64(1, "s")
    step = (t >= np.datetime64(cfg.step_time, "ns"))[:, None] * np.asarray(cfg.step_nT)
    offset = month.offset_nT + step
    clean = month.measured_nT + step
    disturbance = (cfg.heater_nT * _heater(t_s, dist_rng)[:, None] * _unit(cfg.heater_direction)
                   + cfg.tone_nT * np.sin(2 * np.pi * t_s / cfg.tone_period_s)[:, None]
                   * _unit(cfg.tone_direction))
    outboard = clean + disturbance
    inboard = (clean + np.asarray(cfg.inboard_offset_delta_nT)
               + cfg.inboard_gain * disturbance
               + noise_rng.standard_normal(clean.shape) * cfg.inboard_noise_nT)
    return ArchiveResult(times=t, outboard=outboard, inboard=inboard, offset_nT=offset,
                         clean_outboard=clean, kp_3h=month.kp_3h, dst_nT=month.dst,
                         config=cfg)


def write_archive_files(result: ArchiveResult, folder: str | Path) -> dict:
    """Write one ``raw/day_YYYYMMDD.csv`` per UTC day (``time,fgmo_x..,fgmi_x..``), the
    Kp file ``raw/kp.csv``, the hourly Dst file ``raw/dst.csv`` (``time,dst`` in nT,
    hourly means stamped at the start of the hour, as the Kyoto WDC publishes it: the
    storm-time field in the simulated ambient follows it) and the truth
    ``raw/truth.csv`` (offsets and clean outboard).

    Returns
    -------
    dict
        ``{"files": [...], "kp": path, "dst": path, "truth": path}``.
    """
    from magcal.indices.kp import write_kp_csv
    from magcal.io.csv import write_csv_frame

    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    index = pd.DatetimeIndex(result.times, name="time").tz_localize("UTC")
    raw = pd.DataFrame(np.hstack([result.outboard, result.inboard]), index=index,
                       columns=[f"{s}_{c}" for s in ("fgmo", "fgmi") for c in "xyz"])
    files = []
    for day, part in raw.groupby(index.floor("D")):
        files.append(write_csv_frame(out / f"day_{day:%Y%m%d}.csv", part, float_format="%.3f"))
    truth = pd.DataFrame(np.hstack([result.offset_nT, result.clean_outboard]), index=index,
                         columns=[f"offset_{c}" for c in ("Hp", "He", "Hn")]
                         + [f"clean_{c}" for c in ("Hp", "He", "Hn")])
    truth_path = write_csv_frame(out / "truth.csv", truth.iloc[::6], float_format="%.4f")
    kp_path = write_kp_csv(out / "kp.csv", result.kp_3h)
    dst = pd.Series(result.dst_nT, index=index, name="dst").resample("1h").mean()
    dst_path = write_csv_frame(out / "dst.csv", dst.to_frame(), float_format="%.2f")
    return {"files": [str(f) for f in files], "kp": str(kp_path), "dst": str(dst_path),
            "truth": str(truth_path),
            "config": asdict(result.config)}
