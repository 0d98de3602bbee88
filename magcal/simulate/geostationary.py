"""Geostationary multi-sensor spacecraft simulator with known truth (GK-2A / SOSMAG-like).

What a sensor ``s`` reports, in the common frame (the outboard sensor frame, OSRF):

    B_s(t) = R_s @ (B_ambient(t) + sum_d b_{d,s}(t)) + O_s(t) + n_s(t)

* ``B_ambient``: model field (T89 through IRBEM, or the built-in dipole placeholder)
  every minute, spline-interpolated to the cadence, plus Pc5 ULF wave packets and a
  substorm dip per day, in Hpen, then mapped to the OSRF with GK-2A's nominal attitude
  (Hp = By, He = Bx, Hn = Bz);
* ``b_{d,s}``: field of disturber ``d`` at sensor ``s``: fixed spatial pattern (dipole,
  dipole-pair quadrupole, or a rotating dipole) times a time profile;
* ``R_s``: small true misalignment; ``O_s``: constant offset plus temperature-driven
  drift and oscillations during the daily boom shadow; ``n_s``: white noise.

The truth carries every term, so a test can check a cleaned series against exactly
what a perfect AC cleaning should return, ``truth.clean(s) = R_s @ B_ambient + O_s``.

Examples
--------
>>> import numpy as np
>>> from magcal.simulate.geostationary import GeostationaryConfig, simulate_geostationary
>>> cfg = GeostationaryConfig(duration_s=600, ambient_model="dipole")
>>> res = simulate_geostationary(cfg, rng=np.random.default_rng(0))
>>> res.measurements.shape
(600, 12)
>>> list(res.measurements.columns[:3])
['fgmo_x', 'fgmo_y', 'fgmo_z']
>>> parts = res.truth.clean("fgmo") + res.truth.disturbance("fgmo") + res.truth.noise["fgmo"]
>>> bool(np.allclose(res.sensor("fgmo"), parts, rtol=0, atol=1e-9))
True
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from magcal.errors import InputError
from magcal.io.jsonio import product_dict
from magcal.provenance import make_provenance
from magcal.simulate import ambient as _ambient
from magcal.simulate.disturbers import Disturber, disturber_fields, disturber_patterns
from magcal.simulate.gk2a import GK2A_BODY_TO_OSRF, gk2a_disturbers, gk2a_sensors
from magcal.simulate.profiles import ProfileContext
from magcal.simulate.sensors import Sensor, ShadowPhase, temperature_offsets

__all__ = ["GeostationaryConfig", "GeostationaryTruth", "GeostationaryResult",
           "simulate_geostationary", "hpen_to_osrf", "Sensor", "Disturber", "ShadowPhase"]


def hpen_to_osrf(b_hpen) -> np.ndarray:
    """Inverse of :func:`magcal.frames.hpen.osrf_to_hpen`: Bx = He, By = Hp, Bz = Hn.

    Examples
    --------
    >>> hpen_to_osrf([[2.0, 1.0, 3.0]])
    array([[1., 2., 3.]])
    """
    b = np.atleast_2d(np.asarray(b_hpen, dtype=float))
    return b[:, [1, 0, 2]].copy()


@dataclass(frozen=True, eq=False)
class GeostationaryConfig:
    """Knobs of :func:`simulate_geostationary`; the defaults are the GK-2A-like case.

    Parameters
    ----------
    start : str
        ISO UTC time of the first sample.
    duration_s, cadence_s : float
        Length of the simulation and sample spacing (``round(duration_s / cadence_s)``
        samples).
    longitude_deg : float
        East longitude of the geostationary slot (GK-2A: 128.2).
    kp : None, float, array_like or pandas.Series
        Kp driving the model field (see :func:`magcal.simulate.ambient.kp_series_for`);
        None draws a quiet-ish 3-hourly series.
    sensors : tuple of Sensor
        Sensor specs; positions in the body frame. Default: :func:`gk2a_sensors`.
    disturbers : tuple of Disturber
        Disturber specs; positions and moments in the body frame. Default:
        :func:`gk2a_disturbers`.
    body_to_common : 3x3 nested tuple
        Rotation taking body-frame vectors to the common measurement frame (OSRF).
    ambient_model : {"auto", "T89", "dipole"}
        Quiet model field; "auto" uses T89 when :mod:`magcal.models.irbem` is
        available and the dipole placeholder otherwise (the choice is recorded in
        ``truth.ambient_model``).
    ulf : bool
        Add Pc5 ULF wave packets of up to ``ulf_amplitude_nT``,
        ``ulf_packets_per_day`` on average.
    substorm : bool
        Add one substorm dip per day of depth ``substorm_depth_nT`` (in Hp) with onset
        at local time ``substorm_onset_lt_h`` (+- up to 30 min).
    shadow : ShadowPhase or None
        Daily boom shadow driving temperature offsets; None switches them off.

    Notes
    -----
    The substorm dip is a disturbed-ambient case: its 25 nT Hp variation dominates
    the variance in long windows (the paper's 16,000 s third order), which is where
    PiCoG is "susceptible to the influence of the ambient magnetic field" (Constantinescu
    et al. 2020 §4.2). ``replace(substorm=False)`` gives the quiet day of the paper.

    Examples
    --------
    >>> cfg = GeostationaryConfig.gk2a_like(duration_s=3600.0, ulf=False)
    >>> [s.name for s in cfg.sensors], len(cfg.disturbers)
    (['fgmo', 'fgmi', 'amr1', 'amr2'], 7)
    """

    start: str = "2019-03-04T00:00:00"
    duration_s: float = 86400.0
    cadence_s: float = 1.0
    longitude_deg: float = 128.2
    kp: Any = None
    sensors: tuple = field(default_factory=gk2a_sensors)
    disturbers: tuple = field(default_factory=gk2a_disturbers)
    body_to_common: tuple = GK2A_BODY_TO_OSRF
    ambient_model: str = "auto"
    ulf: bool = True
    ulf_amplitude_nT: float = 2.0
    ulf_packets_per_day: float = 6.0
    substorm: bool = True
    substorm_depth_nT: float = 25.0
    substorm_onset_lt_h: float = 22.5
    shadow: ShadowPhase | None = ShadowPhase()

    @classmethod
    def gk2a_like(cls, **overrides) -> "GeostationaryConfig":
        """The GK-2A/SOSMAG-like default case, with any field overridden."""
        return cls(**overrides)

    def replace(self, **changes) -> "GeostationaryConfig":
        """A copy with some fields changed (:func:`dataclasses.replace`)."""
        return dataclasses.replace(self, **changes)

    def n_samples(self) -> int:
        """Number of samples, ``round(duration_s / cadence_s)``."""
        return int(round(self.duration_s / self.cadence_s))

    def validate(self) -> None:
        """Raise :class:`~magcal.errors.InputError` if the knobs are inconsistent."""
        if not (self.cadence_s > 0 and self.duration_s > 0):
            raise InputError("cadence_s and duration_s must be positive")
        if self.n_samples() < 2:
            raise InputError("duration_s must cover at least two samples")
        names = [s.name for s in self.sensors]
        if not names:
            raise InputError("at least one sensor is needed")
        if len(set(names)) != len(names):
            raise InputError(f"sensor names must be unique: {names}")
        dnames = [d.name for d in self.disturbers]
        if len(set(dnames)) != len(dnames):
            raise InputError(f"disturber names must be unique: {dnames}")
        m = np.asarray(self.body_to_common, dtype=float)
        if m.shape != (3, 3) or not np.allclose(m @ m.T, np.eye(3), atol=1e-9) \
                or np.linalg.det(m) < 0:
            raise InputError("body_to_common must be a 3x3 rotation matrix")
        if self.ambient_model not in ("auto",) + _ambient.AMBIENT_MODELS:
            raise InputError(f"ambient_model must be 'auto' or one of {_ambient.AMBIENT_MODELS}")
        _ambient.utc_timestamp(self.start)

    def summary(self) -> dict:
        """JSON-ready description of the configuration (profiles by class name)."""
        kp = self.kp
        if isinstance(kp, pd.Series):
            kp = {"index": [t.isoformat() for t in kp.index], "values": kp.to_numpy()}
        elif kp is not None and np.ndim(kp) > 0:
            kp = np.asarray(kp, dtype=float)
        out = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)
               if f.name not in ("sensors", "disturbers", "kp")}
        out["kp"] = kp
        out["sensors"] = [dataclasses.asdict(s) for s in self.sensors]
        out["disturbers"] = [{"name": d.name, "kind": d.kind, "position_m": d.position_m,
                              "moment_Am2": d.moment_Am2, "separation_m": d.separation_m,
                              "rotation_axis": d.rotation_axis,
                              "profile": type(d.profile).__name__} for d in self.disturbers]
        return out


@dataclass(frozen=True, eq=False)
class GeostationaryTruth:
    """Every term of the simulated measurements.

    Attributes
    ----------
    times : pandas.DatetimeIndex
        Sample times (UTC).
    ambient : ndarray, shape (n, 3)
        Ambient field in the common frame (no misalignment), nT.
    ambient_hpen : ndarray, shape (n, 3)
        The same in Hpen (Hp, He, Hn).
    disturbances : dict
        ``disturbances[disturber][sensor]``: that disturber's contribution to that
        sensor's measurement, shape (n, 3), i.e. its field at the sensor with the
        sensor's misalignment applied (``R_s @ b_{d,s}``).
    patterns : dict
        ``patterns[disturber][sensor]``: the disturber's field per unit profile value at
        the sensor in the common frame without misalignment, shape (k, 3) (k = 2 for a
        rotating disturber).
    profiles : dict
        ``profiles[disturber]``: the profile coefficients, shape (n, k).
    offsets : dict
        ``offsets[sensor]``: constant plus temperature-driven offset, (n, 3).
    noise : dict
        ``noise[sensor]``: the noise added, (n, 3).
    misalignment : dict
        ``misalignment[sensor]``: the 3x3 rotation ``R_s``.
    temperature_C : dict
        ``temperature_C[sensor]``: sensor temperature, (n,).
    kp : pandas.Series
        3-hourly Kp used for the model field.
    events : dict
        Event times (UTC DatetimeIndex) per disturber (spike peaks, step ramps, ...) and
        ``"substorm"`` onsets.
    ambient_model : str
        ``"T89"`` or ``"dipole"``.
    config : GeostationaryConfig
    """

    times: pd.DatetimeIndex
    ambient: np.ndarray
    ambient_hpen: np.ndarray
    disturbances: dict
    patterns: dict
    profiles: dict
    offsets: dict
    noise: dict
    misalignment: dict
    temperature_C: dict
    kp: pd.Series
    events: dict
    ambient_model: str
    config: GeostationaryConfig

    @property
    def sensor_names(self) -> list[str]:
        return list(self.offsets)

    def _check(self, sensor: str) -> None:
        if sensor not in self.offsets:
            raise InputError(f"unknown sensor {sensor!r}; have {self.sensor_names}")

    def ambient_seen(self, sensor: str) -> np.ndarray:
        """Ambient field as measured by ``sensor`` (its misalignment applied), (n, 3)."""
        self._check(sensor)
        return self.ambient @ self.misalignment[sensor].T

    def clean(self, sensor: str) -> np.ndarray:
        """What a perfect AC cleaning of ``sensor`` returns: ``R_s @ ambient + O_s``."""
        return self.ambient_seen(sensor) + self.offsets[sensor]

    def disturbance(self, sensor: str) -> np.ndarray:
        """Total disturbance in ``sensor``'s measurement (sum over disturbers), (n, 3)."""
        self._check(sensor)
        total = np.zeros_like(self.ambient)
        for per_sensor in self.disturbances.values():
            total += per_sensor[sensor]
        return total


@dataclass(frozen=True, eq=False)
class GeostationaryResult:
    """Output of :func:`simulate_geostationary`.

    Attributes
    ----------
    times : pandas.DatetimeIndex
        UTC sample times.
    measurements : pandas.DataFrame
        Index ``time``, columns ``<sensor>_x, <sensor>_y, <sensor>_z`` in nT, all
        sensors in the common frame (CONTRACTS §0 multi-sensor layout).
    truth : GeostationaryTruth
    provenance : dict
    """

    times: pd.DatetimeIndex
    measurements: pd.DataFrame
    truth: GeostationaryTruth
    provenance: dict

    def sensor(self, name: str) -> np.ndarray:
        """Measurements of one sensor as an (n, 3) array."""
        self.truth._check(name)
        return self.measurements[[f"{name}_x", f"{name}_y", f"{name}_z"]].to_numpy()

    def to_json(self) -> dict:
        """JSON-ready summary of the truth (no time series): the scalar parameters."""
        t = self.truth
        payload = {
            "kind": "geostationary simulation",
            "n_samples": len(self.times),
            "start": self.times[0].isoformat(),
            "end": self.times[-1].isoformat(),
            "ambient_model": t.ambient_model,
            "misalignment": t.misalignment,
            "offset_mean_nT": {s: v.mean(axis=0) for s, v in t.offsets.items()},
            "noise_rms_nT": {s: np.sqrt((v**2).mean(axis=0)) for s, v in t.noise.items()},
            "patterns_nT": {d: {s: p for s, p in per.items()} for d, per in t.patterns.items()},
            "kp": {"index": [x.isoformat() for x in t.kp.index], "values": t.kp.to_numpy()},
            "events": {k: [x.isoformat() for x in v] for k, v in t.events.items()},
            "config": t.config.summary(),
            "provenance": self.provenance,
        }
        return product_dict(payload)


def _times(config: GeostationaryConfig) -> tuple[pd.DatetimeIndex, np.ndarray]:
    start = _ambient.utc_timestamp(config.start)
    t_s = np.arange(config.n_samples()) * float(config.cadence_s)
    ns = np.rint(t_s * 1e9).astype(np.int64)
    times = pd.DatetimeIndex(start.as_unit("ns") + pd.to_timedelta(ns, unit="ns"), name="time")
    return times, t_s


def _to_events(start: pd.Timestamp, events_s) -> pd.DatetimeIndex:
    ns = np.rint(np.asarray(events_s, dtype=float) * 1e9).astype(np.int64)
    return pd.DatetimeIndex(start.as_unit("ns") + pd.to_timedelta(ns, unit="ns"), name="time")


def simulate_geostationary(config: GeostationaryConfig | None = None, *,
                           rng: np.random.Generator) -> GeostationaryResult:
    """Simulate multi-sensor magnetometer data on a geostationary spacecraft.

    Parameters
    ----------
    config : GeostationaryConfig, optional
        Default :meth:`GeostationaryConfig.gk2a_like`.
    rng : numpy.random.Generator
        Source of all randomness. The generator is split with ``spawn`` into
        independent streams (Kp, ULF, substorm, one per disturber, one per sensor), so
        adding a sensor does not change the other sensors' noise.

    Returns
    -------
    GeostationaryResult

    Raises
    ------
    InputError
        If the configuration is inconsistent (see :meth:`GeostationaryConfig.validate`)
        or a sensor sits on a disturber.

    Examples
    --------
    >>> cfg = GeostationaryConfig(duration_s=120, cadence_s=0.5, ambient_model="dipole")
    >>> r = simulate_geostationary(cfg, rng=np.random.default_rng(1))
    >>> len(r.times), float((r.times[1] - r.times[0]).total_seconds())
    (240, 0.5)
    """
    config = GeostationaryConfig() if config is None else config
    if not isinstance(rng, np.random.Generator):
        raise InputError("rng must be a numpy.random.Generator")
    config.validate()
    kp_rng, ulf_rng, sub_rng, dist_parent, sens_parent = rng.spawn(5)
    dist_rngs = dist_parent.spawn(max(1, len(config.disturbers)))
    sens_rngs = sens_parent.spawn(len(config.sensors))

    times, t_s = _times(config)
    n = len(times)
    start = times[0]
    context = ProfileContext(start, float(config.longitude_deg), float(config.cadence_s))
    model = config.ambient_model
    if model == "auto":
        model = "T89" if _ambient.t89_available() else "dipole"

    # Ambient field (Hpen, then common frame)
    kp = _ambient.kp_series_for(config.kp, start, times[-1], kp_rng)
    amb_hpen = _ambient.smooth_model_field_hpen(times, config.longitude_deg, kp, model)
    events: dict[str, pd.DatetimeIndex] = {}
    if config.ulf:
        amb_hpen += _ambient.ulf_waves_hpen(t_s, ulf_rng, config.ulf_amplitude_nT,
                                            config.ulf_packets_per_day)
    if config.substorm:
        onsets = context.local_time_events_s(config.substorm_onset_lt_h, t_s[0], t_s[-1])
        onsets = onsets + sub_rng.uniform(-1800.0, 1800.0, len(onsets))
        onsets = onsets[(onsets >= t_s[0]) & (onsets <= t_s[-1])]
        amb_hpen += _ambient.substorm_hpen(t_s, onsets, config.substorm_depth_nT, sub_rng,
                                           cadence_s=config.cadence_s)
        events["substorm"] = _to_events(start, onsets)
    ambient = hpen_to_osrf(amb_hpen)

    # Disturbers: patterns at all sensors in the common frame, times profiles
    body_to_common = np.asarray(config.body_to_common, dtype=float)
    positions = np.array([s.position_m for s in config.sensors], dtype=float)
    names = [s.name for s in config.sensors]
    rotations = {s.name: s.rotation() for s in config.sensors}
    disturbances: dict[str, dict[str, np.ndarray]] = {}
    patterns: dict[str, dict[str, np.ndarray]] = {}
    profiles: dict[str, np.ndarray] = {}
    total = np.zeros((len(names), n, 3))
    for d, d_rng in zip(config.disturbers, dist_rngs):
        try:
            pat_body = disturber_patterns(d, positions)
        except ValueError as exc:
            raise InputError(f"disturber {d.name!r}: {exc}") from None
        pat = pat_body @ body_to_common.T  # (k, p, 3)
        sample = d.profile.evaluate(t_s, rng=d_rng, context=context)
        fields = disturber_fields(pat, sample.values)  # (p, n, 3)
        total += fields
        patterns[d.name] = {name: pat[:, j, :].copy() for j, name in enumerate(names)}
        disturbances[d.name] = {name: fields[j] @ rotations[name].T
                                for j, name in enumerate(names)}
        profiles[d.name] = sample.values
        events[d.name] = _to_events(start, sample.events_s)

    # Sensors: misalignment, offsets, noise
    columns: dict[str, np.ndarray] = {}
    offsets, noise, temperature = {}, {}, {}
    for j, (sensor, s_rng) in enumerate(zip(config.sensors, sens_rngs)):
        noise_rng, temp_rng = s_rng.spawn(2)
        temp, temp_offset = temperature_offsets(sensor, t_s, config.shadow, context, temp_rng)
        offsets[sensor.name] = np.asarray(sensor.offset_nT, dtype=float)[None, :] + temp_offset
        noise[sensor.name] = sensor.noise_nT * noise_rng.standard_normal((n, 3))
        temperature[sensor.name] = temp
        measured = ((ambient + total[j]) @ rotations[sensor.name].T
                    + offsets[sensor.name] + noise[sensor.name])
        for c, axis in enumerate("xyz"):
            columns[f"{sensor.name}_{axis}"] = measured[:, c]
    del total
    measurements = pd.DataFrame(columns, index=times)

    truth = GeostationaryTruth(
        times=times, ambient=ambient, ambient_hpen=amb_hpen, disturbances=disturbances,
        patterns=patterns, profiles=profiles, offsets=offsets, noise=noise,
        misalignment=rotations, temperature_C=temperature, kp=kp, events=events,
        ambient_model=model, config=config)
    provenance = make_provenance("simulate geostationary", {
        "start": start.isoformat(), "duration_s": config.duration_s,
        "cadence_s": config.cadence_s, "longitude_deg": config.longitude_deg,
        "ambient_model": model, "sensors": names,
        "disturbers": [d.name for d in config.disturbers]})
    return GeostationaryResult(times=times, measurements=measurements, truth=truth,
                               provenance=provenance)
