"""Quality control of one record: every check of :mod:`magcal.qc.checks` combined into
the per-sample ``quality`` flag (:mod:`magcal.qc.flags`).

:class:`QCSettings` holds the thresholds (CHAIN.toml ``[qc]``); :func:`flag_samples`
runs the checks on the sensors of one record and returns a :class:`QCResult`;
:func:`plausibility_flags` adds the check against the model field once it is known.
Flagged samples are kept in the products, with their flag, and left out of every fit,
average and statistic (:func:`masked`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields

import numpy as np

from magcal.errors import InputError
from magcal.qc import checks
from magcal.qc.flags import EXCLUDE, FILL, IMPLAUSIBLE, SPIKE, STUCK, TIME, counts


@dataclass(frozen=True)
class QCSettings:
    """Thresholds of the sample quality checks (CHAIN.toml ``[qc]``; README table).

    Attributes
    ----------
    enabled : bool
        False: no check (every quality is 0 but for the offset bit).
    spike_window : int
        Running-median length in samples (odd, >= 5): bursts of up to half of it are
        caught.
    spike_k : float
        Spike threshold in robust sigmas of the first differences.
    spike_scale_window : int
        Samples over which the robust sigma is taken.
    stuck_samples : int
        Identical readings in a row (every component) that make a stuck run...
    stuck_seconds : float
        ...and the least duration they must span (a 10 Hz quantised quiet second is not
        stuck; the run must be at least this long as well).
    range_nT : float or None
        Declared instrument range: ``abs(component) >= range_nT`` is saturated.
    saturation_samples : int
        A component repeating its record's extreme value this often in a row is at a
        detected range.
    time_tolerance : float
        Stamps further than this fraction of the cadence from the record's grid.
    max_model_deviation_nT, max_model_relative : float
        A magnitude further from the model's than ``max(deviation, relative * |model|)``
        is implausible.
    """

    enabled: bool = True
    spike_window: int = 11
    spike_k: float = 8.0
    spike_scale_window: int = 201
    stuck_samples: int = 10
    stuck_seconds: float = 60.0
    range_nT: float | None = None
    saturation_samples: int = 3
    time_tolerance: float = 0.25
    max_model_deviation_nT: float = 1000.0
    max_model_relative: float = 0.5

    def __post_init__(self):
        if self.spike_window < 5 or self.spike_window % 2 == 0:
            raise InputError("[qc] spike_window must be odd and at least 5",
                             column="qc.spike_window")
        for name in ("spike_k", "max_model_deviation_nT", "max_model_relative",
                     "time_tolerance"):
            if not float(getattr(self, name)) > 0:
                raise InputError(f"[qc] {name} must be positive", column=f"qc.{name}")
        if self.range_nT is not None and not 0 < float(self.range_nT) < np.inf:
            raise InputError(f"[qc] range_nT must be a positive finite number of nT, got "
                             f"{self.range_nT!r} (every sample would be flagged saturated)",
                             column="qc.range_nT")
        if self.stuck_samples < 2 or self.saturation_samples < 1:
            raise InputError("[qc] stuck_samples must be >= 2 and saturation_samples >= 1",
                             column="qc.stuck_samples")

    @classmethod
    def from_mapping(cls, values: dict | None) -> "QCSettings":
        """From the ``[qc]`` table; unknown keys are an error naming them."""
        values = dict(values or {})
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise InputError(f"unknown key {unknown[0]!r} in [qc]; known: "
                             + ", ".join(sorted(known)), column=f"qc.{unknown[0]}")
        return cls(**values)

    def to_json(self) -> dict:
        return asdict(self)

    @classmethod
    def schema(cls) -> dict:
        """``key -> (types, default)`` for the chain configuration's ``[qc]`` table."""
        kinds = {bool: bool, int: int, float: (int, float)}
        out = {}
        for f in fields(cls):
            default = f.default
            types = (int, float) if f.name == "range_nT" else kinds[type(default)]
            out[f.name] = (types, default)
        return out


@dataclass(frozen=True)
class QCResult:
    """The quality flags of one record.

    Attributes
    ----------
    flags : ndarray of uint16, shape (n,)
        Bitwise OR over the sensors checked.
    by_sensor : dict
        ``sensor -> {flag name: samples}``.
    """

    flags: np.ndarray
    by_sensor: dict = field(default_factory=dict)

    @property
    def excluded(self) -> np.ndarray:
        """Samples to leave out of fits and averages."""
        return (self.flags & EXCLUDE) != 0

    def counts(self) -> dict:
        return counts(self.flags)

    def to_json(self) -> dict:
        return {"n_samples": int(self.flags.size), "n_flagged": int(self.excluded.sum()),
                "counts": self.counts(), "by_sensor": self.by_sensor}


def flag_samples(times_ns, vectors: dict, cadence_s: float,
                 settings: QCSettings | None = None, independent=()) -> QCResult:
    """Run every check but the model's on one record.

    Parameters
    ----------
    times_ns : array_like of int, shape (n,)
        Sample times (ns), increasing.
    vectors : dict
        ``sensor -> (n, 3)`` readings in nT as read (before any rotation or cleaning).
    cadence_s : float
        The record's nominal cadence.
    settings : QCSettings, optional
    independent : sequence of str
        Physically distinct sensors among ``vectors`` (the chain's PiCoG sensors): a
        spike that two of them show at the same samples, under
        ``max_model_deviation_nT``, is a field (a spacecraft pulse PiCoG must see, or a
        natural one), not flagged (:func:`~magcal.qc.checks.coincident_field_mask`).

    Returns
    -------
    QCResult

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> t = np.arange(2880) * 30 * 10**9
    >>> b = 100 + rng.normal(0, 0.3, (2880, 3)).cumsum(axis=0) * 0.1
    >>> b[500, 1] = 1e6
    >>> b[1000:1400] = 65535.0
    >>> res = flag_samples(t, {"fgmo": b}, 30.0)
    >>> res.counts()
    {'spike': 1, 'saturated_or_stuck': 400}
    """
    s = settings or QCSettings()
    t = np.asarray(times_ns, dtype=np.int64)
    flags = np.zeros(t.size, dtype=np.uint16)
    by_sensor = {}
    if not s.enabled:
        return QCResult(flags, {})
    if not np.isfinite(cadence_s) or cadence_s <= 0:  # one sample: no cadence, no run
        cadence_s = s.stuck_seconds
    stuck_run = max(s.stuck_samples, int(np.ceil(s.stuck_seconds / max(cadence_s, 1e-9))))
    owns = {}
    for name, b in vectors.items():
        b = np.asarray(b, dtype=float)
        own = np.zeros(t.size, dtype=np.uint16)
        own[checks.nonfinite_mask(b)] |= FILL
        own[checks.stuck_mask(b, min_run=stuck_run)] |= STUCK
        own[checks.saturation_mask(b, range_nT=s.range_nT,
                                   min_run=s.saturation_samples)] |= STUCK
        # spikes among the samples not already bad: a stuck block or a fill run is
        # bridged (not a jump that confirms its neighbours as spikes)
        spikes = checks.spike_mask(np.where(own[:, None] != 0, np.nan, b),
                                   window=s.spike_window, k=s.spike_k,
                                   scale_window=s.spike_scale_window)
        own[spikes & ((own & STUCK) == 0)] |= SPIKE  # a stuck run's edge is not a spike
        owns[name] = own
    field = checks.coincident_field_mask(
        {n: (owns[n] & SPIKE) != 0 for n in independent if n in owns},
        {n: vectors[n] for n in independent if n in owns}, window=s.spike_window,
        max_deviation_nT=s.max_model_deviation_nT)
    for name, own in owns.items():
        if field.any():
            own[field] &= np.uint16(~int(SPIKE) & 0xFFFF)
        by_sensor[name] = counts(own)
        flags |= own
    flags[checks.time_mask(t, cadence_s, tolerance=s.time_tolerance)] |= TIME
    return QCResult(flags, by_sensor)


def plausibility_flags(b_nT, model_nT, settings: QCSettings | None = None) -> np.ndarray:
    """The ``implausible_vs_model`` bit for field samples against the model on the same
    times (zeros where QC is disabled)."""
    s = settings or QCSettings()
    out = np.zeros(len(b_nT), dtype=np.uint16)
    if s.enabled:
        out[checks.implausible_mask(b_nT, model_nT, max_deviation_nT=s.max_model_deviation_nT,
                                    max_relative=s.max_model_relative)] = IMPLAUSIBLE
    return out


def masked(values, flags) -> np.ndarray:
    """``values`` (n, ...) with the samples QC excludes set to NaN (a copy)."""
    out = np.array(values, dtype=float, copy=True)
    out[(np.asarray(flags, dtype=np.uint16) & EXCLUDE) != 0] = np.nan
    return out
