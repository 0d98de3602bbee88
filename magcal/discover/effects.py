"""The vocabulary of model-gap effects (CONTRACTS §5) and their regressors.

Every effect is a parametric term that is *linear in its parameters*: given the inputs
(times, model field, covariates, local time) it builds a set of columns, each an
``(n, m)`` array over samples and components, and its contribution to the residual
``measured - model`` is ``sum_j beta_j * column_j``. Non-linear hyper-parameters (the
time of a step, the period of a periodic term, the number of diurnal harmonics) are
fixed when the candidate is made, so every fit is linear least squares.

=============  ===============================================  ==================
name           regressor per component                          parameters
=============  ===============================================  ==================
offset         1                                                nT
drift          (t - t_ref) / 1 day                              nT/day
diurnal        cos, sin(k 2 pi LT / 24 h), k = 1..K             nT
temperature    T - T_ref                                        nT/degC
scale          B_model,i (own component only)                   dimensionless
rotation       e_j x B_model (couples components)               rad (reported deg)
activity       kp - kp_ref, dst - dst_ref                       nT/Kp, nT/nT
spin_tone      cos, sin(k phase), k = 1..K                      nT
step           H(t - t_step)                                    nT
periodic       cos, sin(2 pi t / P)                             nT
=============  ===============================================  ==================

Rotation follows CONTRACTS §3 to first order: ``R(w) @ B ~= B + w x B`` with ``w`` about
the stored component axes (as :mod:`magcal.alignment`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar, Mapping

import numpy as np

from magcal.frames.localtime import harmonic_basis, local_time_hours
from magcal.stats import student_interval

DAY_S = 86400.0

#: Effect names of CONTRACTS §5, in the order of the vocabulary.
EFFECT_NAMES = ("offset", "drift", "diurnal", "temperature", "scale", "rotation",
                "activity", "spin_tone", "step", "periodic")


def local_time_h(times_s, longitude_deg) -> np.ndarray:
    """Local (solar mean) time in hours at a longitude, from UT.

    Parameters
    ----------
    times_s : array_like
        Seconds since 1970-01-01 UTC.
    longitude_deg : float or array_like
        East longitude in degrees (scalar or one per sample).

    Returns
    -------
    ndarray
        ``(UT_h + lon / 15) mod 24``.

    Examples
    --------
    >>> float(local_time_h(np.array([12 * 3600.0]), 128.2)[0])  # doctest: +ELLIPSIS
    20.54666...
    """
    return local_time_hours(np.asarray(times_s, dtype=float), longitude_deg)


@dataclass(frozen=True)
class EffectInputs:
    """Everything an effect's regressors may depend on, on one set of samples.

    Parameters
    ----------
    times_s : ndarray, shape (n,)
        Seconds since 1970-01-01 UTC.
    model : ndarray, shape (n, m)
        Model field in nT.
    components : tuple of str
        Component names (e.g. ``("Hp", "He", "Hn")``).
    covariates : mapping of str to ndarray (n,)
        Any of ``temperature`` (deg C), ``kp``, ``dst`` (nT), ``phase`` (rad).
    local_time_h : ndarray (n,) or None
        Local time at the spacecraft, when a longitude is known.
    """

    times_s: np.ndarray
    model: np.ndarray
    components: tuple[str, ...]
    covariates: Mapping[str, np.ndarray] = field(default_factory=dict)
    local_time_h: np.ndarray | None = None

    @property
    def n(self) -> int:
        return len(self.times_s)

    @property
    def m(self) -> int:
        return len(self.components)

    def has(self, name: str) -> bool:
        """True when a covariate (or ``local_time``) is available."""
        if name == "local_time":
            return self.local_time_h is not None
        return name in self.covariates


@dataclass(frozen=True)
class Effect:
    """Base class: one parametric term on a subset of components.

    Subclasses set ``name``, ``requires`` and implement :meth:`columns` and
    :meth:`labels`. ``components`` lists the components the term acts on.
    """

    name: ClassVar[str] = "effect"
    requires: ClassVar[tuple[str, ...]] = ()
    coupled: ClassVar[bool] = False  # True: one parameter set acts on all components
    components: tuple[str, ...] = ()

    # -- to implement -------------------------------------------------------------
    def basis(self, inputs: EffectInputs) -> np.ndarray:  # pragma: no cover - abstract
        """Regressors shared by every component, shape (n, k)."""
        raise NotImplementedError

    def basis_labels(self) -> tuple[str, ...]:  # pragma: no cover - abstract
        raise NotImplementedError

    def hyper(self) -> dict:
        """Fixed hyper-parameters (reported with the fitted values)."""
        return {}

    # -- generic per-component machinery -------------------------------------------
    def with_components(self, components) -> "Effect":
        import dataclasses

        return dataclasses.replace(self, components=tuple(components))

    def labels(self) -> tuple[tuple[str, str], ...]:
        """One ``(component, parameter)`` label per column."""
        return tuple((c, lab) for c in self.components for lab in self.basis_labels())

    def columns(self, inputs: EffectInputs) -> np.ndarray:
        """Columns of the term, shape (q, n, m); column j in component c only."""
        b = np.asarray(self.basis(inputs), dtype=float)
        if b.ndim == 1:
            b = b[:, None]
        k = b.shape[1]
        out = np.zeros((len(self.components) * k, inputs.n, inputs.m))
        for ci, comp in enumerate(self.components):
            idx = inputs.components.index(comp)
            out[ci * k:(ci + 1) * k, :, idx] = b.T
        return out

    def evaluate(self, inputs: EffectInputs, beta) -> np.ndarray:
        """Contribution of the term with parameters ``beta``, shape (n, m)."""
        cols = self.columns(inputs)
        return np.tensordot(np.asarray(beta, dtype=float), cols, axes=(0, 0))

    def describe(self, beta, std, dof=None) -> dict:
        """Parameters as a JSON-ready dict: hyper-parameters, ``values``, ``std``.

        With ``dof`` (the degrees of freedom of each standard error) also ``dof`` and
        ``ci95``: ``[lo, hi]`` per parameter, ``value -/+ t_0.975(dof) * std``.
        """
        values: dict = {}
        stds: dict = {}
        for (comp, lab), b, s in zip(self.labels(), beta, std):
            values.setdefault(comp, {})[lab] = float(b)
            stds.setdefault(comp, {})[lab] = float(s)
        out = dict(self.hyper())
        out["values"] = values
        out["std"] = stds
        if dof is not None:
            lo, hi = student_interval(beta, std, dof)
            dofs: dict = {}
            ci: dict = {}
            for (comp, lab), v, a, b in zip(self.labels(), dof, lo, hi):
                dofs.setdefault(comp, {})[lab] = float(v)
                ci.setdefault(comp, {})[lab] = [float(a), float(b)]
            out["dof"] = dofs
            out["ci95"] = ci
        return out

    def n_params(self) -> int:
        return len(self.labels())

    def tested(self) -> tuple[bool, ...]:
        """Which columns the significance test is about (all, unless a term carries
        columns that only condition the test, like the rate beside a drift change)."""
        return (True,) * len(self.labels())


@dataclass(frozen=True)
class Offset(Effect):
    """Constant offset per component (nT)."""

    name: ClassVar[str] = "offset"

    def basis(self, inputs):
        return np.ones((inputs.n, 1))

    def basis_labels(self):
        return ("offset_nT",)


@dataclass(frozen=True)
class Drift(Effect):
    """Linear drift per component about ``t_ref_s`` (nT/day).

    With ``t_break_s`` set, the term holds a change of drift rate at that time (a hinge,
    zero before the break and rising at ``rate_change_nT_per_day`` after it), beside
    the linear drift itself when ``with_rate`` (a component without a drift yet); only
    the hinge is then tested (:meth:`tested`).
    """

    name: ClassVar[str] = "drift"
    t_ref_s: float = 0.0
    t_break_s: float | None = None
    with_rate: bool = False

    def basis(self, inputs):
        linear = (inputs.times_s - self.t_ref_s) / DAY_S
        if self.t_break_s is None:
            return linear[:, None]
        hinge = np.maximum(inputs.times_s - self.t_break_s, 0.0) / DAY_S
        return np.column_stack([linear, hinge]) if self.with_rate else hinge[:, None]

    def basis_labels(self):
        if self.t_break_s is None:
            return ("rate_nT_per_day",)
        return ("rate_nT_per_day", "rate_change_nT_per_day") if self.with_rate else \
            ("rate_change_nT_per_day",)

    def tested(self) -> tuple[bool, ...]:
        if self.t_break_s is not None and self.with_rate:
            return tuple(lab == "rate_change_nT_per_day" for _, lab in self.labels())
        return super().tested()

    def hyper(self):
        if self.t_break_s is None:
            return {"t_ref_s": self.t_ref_s}
        import pandas as pd

        return {"t_ref_s": self.t_ref_s, "t_break_s": self.t_break_s,
                "break_time": pd.Timestamp(self.t_break_s, unit="s", tz="UTC").isoformat()}


@dataclass(frozen=True)
class Diurnal(Effect):
    """Fourier series in local time with ``harmonics`` harmonics (nT)."""

    name: ClassVar[str] = "diurnal"
    requires: ClassVar[tuple[str, ...]] = ("local_time",)
    harmonics: int = 2

    def basis(self, inputs):
        return harmonic_basis(inputs.local_time_h, self.harmonics)

    def basis_labels(self):
        return tuple(lab for k in range(1, self.harmonics + 1)
                     for lab in (f"cos{k}_nT", f"sin{k}_nT"))

    def hyper(self):
        return {"harmonics": self.harmonics}

    def curve(self, beta_component, lt_h) -> np.ndarray:
        """The fitted variation of one component on local times ``lt_h``."""
        x = 2 * np.pi * np.asarray(lt_h, dtype=float) / 24.0
        out = np.zeros_like(x)
        for k in range(1, self.harmonics + 1):
            out += (beta_component[2 * k - 2] * np.cos(k * x)
                    + beta_component[2 * k - 1] * np.sin(k * x))
        return out

    def describe(self, beta, std, dof=None):
        out = super().describe(beta, std, dof)
        lt = np.arange(0, 24, 0.05)
        k2 = 2 * self.harmonics
        derived = {}
        for ci, comp in enumerate(self.components):
            c = self.curve(np.asarray(beta[ci * k2:(ci + 1) * k2]), lt)
            derived[comp] = {"peak_to_peak_nT": float(c.max() - c.min()),
                             "peak_lt_h": float(lt[np.argmax(c)]),
                             "trough_lt_h": float(lt[np.argmin(c)])}
        out["derived"] = derived
        return out


@dataclass(frozen=True)
class Temperature(Effect):
    """Linear temperature coefficient per component about ``t_ref_degC`` (nT/degC)."""

    name: ClassVar[str] = "temperature"
    requires: ClassVar[tuple[str, ...]] = ("temperature",)
    t_ref_degC: float = 0.0

    def basis(self, inputs):
        return (inputs.covariates["temperature"] - self.t_ref_degC)[:, None]

    def basis_labels(self):
        return ("coefficient_nT_per_degC",)

    def hyper(self):
        return {"t_ref_degC": self.t_ref_degC}


@dataclass(frozen=True)
class Scale(Effect):
    """Scale-factor error per component: residual_i = s_i * B_model,i."""

    name: ClassVar[str] = "scale"

    def basis_labels(self):
        return ("scale",)

    def columns(self, inputs):
        out = np.zeros((len(self.components), inputs.n, inputs.m))
        for ci, comp in enumerate(self.components):
            idx = inputs.components.index(comp)
            out[ci, :, idx] = inputs.model[:, idx]
        return out


@dataclass(frozen=True)
class Rotation(Effect):
    """Small rotation w of the measured frame: residual = w x B_model (3 components).

    ``axes`` lists the rotation axes fitted (default: all three); the signature of a
    rotation about one axis is proportional to the model field's components across it,
    so each axis is tested against the field's own variation.
    """

    name: ClassVar[str] = "rotation"
    coupled: ClassVar[bool] = True
    axes: tuple[str, ...] = ()

    def fitted_axes(self) -> tuple[str, ...]:
        return self.axes or self.components

    def labels(self):
        return tuple(("all", f"w_{c}_rad") for c in self.fitted_axes())

    def columns(self, inputs):
        if inputs.m != 3:
            raise ValueError("rotation needs three components")
        b = inputs.model
        idx = [inputs.components.index(a) for a in self.fitted_axes()]
        return np.stack([np.cross(np.eye(3)[j], b) for j in idx])

    def hyper(self):
        return {"axes": list(self.fitted_axes())}

    def describe(self, beta, std, dof=None):
        axes = self.fitted_axes()
        out = {"axes": list(axes),
               "angles_deg": {c: float(np.rad2deg(b)) for c, b in zip(axes, beta)},
               "std_deg": {c: float(np.rad2deg(s)) for c, s in zip(axes, std)},
               "values": {c: float(b) for c, b in zip(axes, beta)},
               "convention": "measured ~= R(w) @ model, w about the component axes"}
        if dof is not None:
            lo, hi = student_interval(np.rad2deg(beta), np.rad2deg(std), dof)
            out["dof"] = {c: float(v) for c, v in zip(axes, dof)}
            out["ci95_deg"] = {c: [float(a), float(b)] for c, a, b in zip(axes, lo, hi)}
        return out


@dataclass(frozen=True)
class Activity(Effect):
    """Linear response to geomagnetic indices (kp and/or dst) per component."""

    name: ClassVar[str] = "activity"
    indices: tuple[str, ...] = ("kp", "dst")
    refs: tuple[float, ...] = (0.0, 0.0)

    def basis(self, inputs):
        return np.column_stack([inputs.covariates[k] - r for k, r in zip(self.indices, self.refs)])

    def basis_labels(self):
        units = {"kp": "coefficient_nT_per_kp", "dst": "coefficient_nT_per_nT_dst"}
        return tuple(units[k] for k in self.indices)

    def hyper(self):
        return {"indices": list(self.indices), "refs": list(self.refs)}


@dataclass(frozen=True)
class SpinTone(Effect):
    """Residual tone at the spin frequency and its harmonics (needs ``phase``)."""

    name: ClassVar[str] = "spin_tone"
    requires: ClassVar[tuple[str, ...]] = ("phase",)
    harmonics: int = 2

    def basis(self, inputs):
        p = inputs.covariates["phase"]
        cols = []
        for k in range(1, self.harmonics + 1):
            cols += [np.cos(k * p), np.sin(k * p)]
        return np.column_stack(cols)

    def basis_labels(self):
        return tuple(lab for k in range(1, self.harmonics + 1)
                     for lab in (f"cos{k}_nT", f"sin{k}_nT"))

    def hyper(self):
        return {"harmonics": self.harmonics}

    def describe(self, beta, std, dof=None):
        out = super().describe(beta, std, dof)
        k2 = 2 * self.harmonics
        out["derived"] = {
            comp: {f"amplitude{k}_nT": float(np.hypot(beta[ci * k2 + 2 * k - 2],
                                                       beta[ci * k2 + 2 * k - 1]))
                   for k in range(1, self.harmonics + 1)}
            for ci, comp in enumerate(self.components)}
        return out


@dataclass(frozen=True)
class Step(Effect):
    """A jump at ``t_step_s`` (seconds since 1970): residual = size * H(t - t_step)."""

    name: ClassVar[str] = "step"
    t_step_s: float = 0.0

    def basis(self, inputs):
        return (inputs.times_s >= self.t_step_s).astype(float)[:, None]

    def basis_labels(self):
        return ("size_nT",)

    def hyper(self):
        import pandas as pd

        return {"t_step_s": self.t_step_s,
                "time": pd.Timestamp(self.t_step_s, unit="s", tz="UTC").isoformat()}


@dataclass(frozen=True)
class Periodic(Effect):
    """A sinusoid of period ``period_s`` (phase referred to 1970-01-01)."""

    name: ClassVar[str] = "periodic"
    period_s: float = DAY_S

    def basis(self, inputs):
        x = 2 * np.pi * np.mod(inputs.times_s, self.period_s) / self.period_s
        return np.column_stack([np.cos(x), np.sin(x)])

    def basis_labels(self):
        return ("cos_nT", "sin_nT")

    def hyper(self):
        return {"period_s": self.period_s, "period_h": self.period_s / 3600.0}

    def describe(self, beta, std, dof=None):
        out = super().describe(beta, std, dof)
        out["derived"] = {comp: {"amplitude_nT": float(np.hypot(beta[2 * ci], beta[2 * ci + 1]))}
                          for ci, comp in enumerate(self.components)}
        return out


EFFECT_TYPES: dict[str, type[Effect]] = {
    cls.name: cls for cls in (Offset, Drift, Diurnal, Temperature, Scale, Rotation, Activity,
                              SpinTone, Step, Periodic)}


def available(effect_cls: type[Effect], inputs: EffectInputs) -> bool:
    """True when the inputs carry what the effect needs."""
    if effect_cls is Rotation and inputs.m != 3:
        return False
    if effect_cls is Activity:
        return bool(_varying_indices(inputs))
    return all(inputs.has(r) for r in effect_cls.requires)


def _varying_indices(inputs: EffectInputs) -> tuple[str, ...]:
    """The activity indices present that vary over the samples. A constant index (a
    quiet stretch with one Kp, a Kp file of one value) is a column of zeros once
    referred to its mean: it made the whole activity term singular, and a Dst response
    of 0.3 nT/nT beside a constant Kp was never named."""
    out = []
    for k in ("kp", "dst"):
        if inputs.has(k):
            v = np.asarray(inputs.covariates[k], dtype=float)
            if np.isfinite(v).any() and np.nanmax(v) > np.nanmin(v):
                out.append(k)
    return tuple(out)


def make_activity(inputs: EffectInputs, components) -> Activity:
    """An :class:`Activity` term on the indices present that vary, referred to their
    means."""
    idx = _varying_indices(inputs)
    refs = tuple(float(np.nanmean(inputs.covariates[k])) for k in idx)
    return Activity(components=tuple(components), indices=idx, refs=refs)
