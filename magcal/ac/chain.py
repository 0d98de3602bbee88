"""Chains of PiCoG corrections and their collapse into upload matrices (§3.2, §4.3).

A plan is a list of stages:

- ``reference`` stage: each listed sensor is cleaned against one reference sensor
  (which is not changed), one order after the other: ``B_n = B_{n-1} + A (B_{n-1} - B_ref)``
  (Eq. 27 for the first order);
- ``pair`` stage: two sensors clean each other in parallel, order by order (Eqs. 23-26):
  ``B_{n,ij} = B_{n-1,ij} + A_{n-1,ij} (B_{n-1,ij} - B_{n-1,ji})`` and symmetrically;
- ``regression`` stage: the non-orthogonal multi-sensor extension
  (:mod:`magcal.ac.nonorthogonal`).

The corrected field of one stage replaces the raw field in the next. Every corrected
field stays a linear combination ``sum_k W[k] @ B0_k`` of the raw sensors; the chain
tracks these weight matrices alongside the data, so the constant upload matrices of
Eqs. 28-30 are the weights of the target and sum to the identity (Eq. 33).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping

import numpy as np

from magcal.ac.core import DIRECTION_METHODS, correction_matrix, fit_first_order
from magcal.ac.filters import bandpass, highpass, highpass_samples
from magcal.ac.scan import scan_first_order, summarize_scan
from magcal.errors import InputError

Weights = dict  # sensor -> (3, 3) ndarray


@dataclass(frozen=True)
class Order:
    """How one correction order is fitted.

    ``interval`` (start, end) in the time base of the data (seconds) restricts the fit;
    ``window_s`` selects the sliding-window scan; with neither the whole input is used.
    ``direction`` chooses how the disturbance direction at the cleaned sensor is found
    (``"variance"``: the paper; ``"coherent"``: from the part of the sensor that varies
    with the difference, where the ambient field cancels). ``highpass_s`` removes
    running means over that many seconds from both sensors before the fit, so slow
    ambient variations do not enter the variance analysis (the correction is linear,
    so it is fitted on the filtered and applied to the raw data).
    """

    window_s: float | None = None
    interval: tuple[float, float] | None = None
    cone_deg: float = 2.5
    detrend_s: float | None = None   #: regression stages: running-mean removal before fitting
    direction: str = "variance"
    highpass_s: float | None = None
    band_hz: tuple[float, float] | None = None   #: fit on an FFT band-pass of both sensors

    def __post_init__(self):
        if self.band_hz is not None and not 0 <= self.band_hz[0] < self.band_hz[1]:
            raise InputError(f"band_hz must be [low, high] with 0 <= low < high, "
                             f"got {self.band_hz}")
        if self.direction not in DIRECTION_METHODS:
            raise InputError(f"direction must be one of {DIRECTION_METHODS}, "
                             f"got {self.direction!r}")
        if self.highpass_s is not None and not self.highpass_s >= 0:
            raise InputError(f"highpass_s must be positive, got {self.highpass_s}")


@dataclass(frozen=True)
class Stage:
    """One stage of a plan (see the module docstring for the kinds)."""

    kind: str
    sensors: tuple[str, ...]
    reference: str | None = None
    references: tuple[str, ...] = ()
    orders: tuple[Order, ...] = (Order(),)
    #: pair stages: fit one constant 3x3 per sensor jointly over the selections of all
    #: orders plus event intervals (:mod:`magcal.ac.joint`) instead of order by order
    joint: bool = False
    event_half_s: float | None = 120.0   #: joint: half-width of the event intervals
    min_snr: float = 5.0                 #: joint: drop selections below this
    #: joint: event selections, ``"pulse"`` (matched filter on the pulse shape of every
    #: event, other spikes masked, ambient waves removed, pooled) or ``"interval"``
    #: (whole intervals free of other events), see :func:`magcal.ac.joint.selections`
    events: str = "pulse"
    pulse_min_snr: float = 2.5           #: joint: drop the pooled pulse selection below this

    def __post_init__(self):
        if self.joint and self.kind != "pair":
            raise InputError("joint = true is only for a pair stage")
        if self.events not in ("pulse", "interval"):
            raise InputError(f"events must be \"pulse\" or \"interval\", got {self.events!r}")
        for key in ("min_snr", "pulse_min_snr"):
            if not getattr(self, key) >= 0:
                raise InputError(f"{key} must be >= 0, got {getattr(self, key)}")
        if self.kind not in ("reference", "pair", "regression"):
            raise InputError(f"unknown stage kind {self.kind!r}")
        if self.kind == "pair" and len(self.sensors) != 2:
            raise InputError(f"a pair stage needs exactly two sensors, got {list(self.sensors)}")
        if self.kind == "reference" and (self.reference is None or not self.sensors):
            raise InputError("a reference stage needs a reference and at least one sensor")
        if self.kind == "reference" and self.reference in self.sensors:
            raise InputError(f"sensor {self.reference!r} cannot be cleaned against itself")
        if self.kind == "regression" and (not self.references or not self.sensors):
            raise InputError("a regression stage needs sensors and references")
        if not self.orders:
            raise InputError("a stage needs at least one order")

    @property
    def involved(self) -> tuple[str, ...]:
        extra = (self.reference,) if self.reference else ()
        return tuple(self.sensors) + extra + tuple(self.references)


@dataclass(frozen=True)
class Plan:
    """Target sensor and the stages that clean it."""

    target: str
    stages: tuple[Stage, ...]

    @property
    def sensors(self) -> list[str]:
        out = [self.target]
        for st in self.stages:
            for s in st.involved:
                if s not in out:
                    out.append(s)
        return out


def _nan3() -> np.ndarray:
    return np.full(3, np.nan)


@dataclass(frozen=True, kw_only=True)
class Step:
    """One fitted correction (one row of PARAMS.json ``steps``); keyword construction
    only. Regression, joint and fixed steps have a full matrix ``A`` and no rank-one
    parts (``alpha`` and the directions stay NaN)."""

    stage: int
    order: int
    i: str
    j: str
    A: np.ndarray
    alpha: float = float("nan")
    direction_i: np.ndarray = field(default_factory=_nan3)
    direction_ij: np.ndarray = field(default_factory=_nan3)
    window_s: float | None = None
    alpha_variance: float = float("nan")
    correlation: float = float("nan")
    n_used: int = 0
    interval: tuple | None = None
    scan: dict | None = None
    kind: str = "picog"
    direction_method: str = "variance"
    highpass_s: float | None = None
    band_hz: tuple | None = None

    def to_dict(self) -> dict:
        d = {"stage": self.stage, "order": self.order, "i": self.i, "j": self.j,
             "alpha": self.alpha, "direction_i": np.asarray(self.direction_i).tolist(),
             "direction_ij": np.asarray(self.direction_ij).tolist(), "window_s": self.window_s,
             "A": np.asarray(self.A).tolist(), "alpha_variance": self.alpha_variance,
             "correlation": self.correlation, "n_used": self.n_used, "kind": self.kind,
             "direction_method": self.direction_method, "highpass_s": self.highpass_s,
             "band_hz": list(self.band_hz) if self.band_hz else None}
        if self.interval is not None:
            d["interval"] = list(self.interval)
        if self.scan is not None:
            d["scan"] = self.scan
        return d


@dataclass(frozen=True)
class ChainResult:
    """Outcome of running a plan on data."""

    target: str
    M: dict                   #: raw sensor -> (3, 3) upload matrix (Eq. 28)
    G: np.ndarray             #: DC offset of the correction (Eq. 31), nT
    steps: tuple[Step, ...]
    corrected: np.ndarray     #: iteratively corrected target, (n, 3)
    weights: dict = field(default_factory=dict)   #: every cleaned sensor -> Weights
    scans: dict = field(default_factory=dict)     #: (stage, order, i) -> (ScanResult, ScanSummary)

    @property
    def identity_error(self) -> float:
        """max |sum_k M_k - I| (Eq. 33; zero up to rounding)."""
        return float(np.max(np.abs(sum(self.M.values()) - np.eye(3))))


def _wcombine(w_i: Weights, w_j: Weights, A: np.ndarray) -> Weights:
    keys = list(dict.fromkeys([*w_i, *w_j]))
    z = np.zeros((3, 3))
    return {k: w_i.get(k, z) + A @ (w_i.get(k, z) - w_j.get(k, z)) for k in keys}


def rank_one_parts(A: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """``(alpha, e_i, e_ij)`` with ``A = -alpha e_i e_ij^T`` (Eq. 17) for a rank-one ``A``.

    Examples
    --------
    >>> a, ei, eij = rank_one_parts(correction_matrix(0.7, [0, 1, 0], [0, 0, 1]))
    >>> round(a, 12), ei.tolist(), eij.tolist()
    (0.7, [0.0, 1.0, 0.0], [0.0, 0.0, 1.0])
    """
    from magcal.ac.core import canonical_sign

    u, sv, vt = np.linalg.svd(np.asarray(A, dtype=float))
    e_i, e_ij = canonical_sign(u[:, 0]), canonical_sign(vt[0])
    return float(-(e_i @ A @ e_ij)), e_i, e_ij


def apply_weights(data: Mapping[str, np.ndarray], weights: Mapping[str, np.ndarray]) -> np.ndarray:
    """One-step linear combination ``sum_k W[k] @ B_k`` (Eq. 28); NaN where a needed
    sensor is NaN.

    Examples
    --------
    >>> b = {"a": np.ones((2, 3)), "b": np.zeros((2, 3))}
    >>> apply_weights(b, {"a": 0.5 * np.eye(3), "b": 0.5 * np.eye(3)}).tolist()
    [[0.5, 0.5, 0.5], [0.5, 0.5, 0.5]]
    """
    out = None
    for k, m in weights.items():
        if k not in data:
            raise InputError(f"sensor {k!r} needed by the correction is missing", column=f"{k}_x")
        term = np.asarray(data[k], dtype=float) @ np.asarray(m, dtype=float).T
        out = term if out is None else out + term
    return out


def dc_offset(data: Mapping[str, np.ndarray], target: str, M: Mapping[str, np.ndarray],
              mask: np.ndarray | None = None) -> np.ndarray:
    """DC offset of the correction, Eq. 31: ``<B0_target> - <sum_k M_k B0_k>``."""
    corrected = apply_weights(data, M)
    raw = np.asarray(data[target], dtype=float)
    ok = np.all(np.isfinite(corrected), axis=1) & np.all(np.isfinite(raw), axis=1)
    if mask is not None:
        ok &= mask
    if not ok.any():
        raise InputError("no sample where all sensors of the correction are valid")
    return raw[ok].mean(axis=0) - corrected[ok].mean(axis=0)


def sample_period_s(t_s: np.ndarray) -> float:
    """Median sample spacing (s)."""
    t_s = np.asarray(t_s, dtype=float)
    if t_s.size < 2:
        raise InputError("need at least two samples")
    dt = float(np.median(np.diff(t_s)))
    if not dt > 0:
        raise InputError("times must be strictly increasing")
    return dt


def fit_order(b_i: np.ndarray, b_j: np.ndarray, t_s: np.ndarray, order: Order, *,
              dt_s: float | None = None, alpha_method: str = "decorrelate",
              keep_scan: bool = False, scan_step: int = 1):
    """Fit one correction order of ``b_i`` with ``b_j``.

    Returns
    -------
    (alpha, direction_i, direction_ij, info) where ``info`` holds ``alpha_variance``,
    ``correlation``, ``n_used`` and, for scans, ``scan`` (summary numbers) and
    ``scan_objects`` (ScanResult, ScanSummary) when ``keep_scan``.
    """
    t_s = np.asarray(t_s, dtype=float)
    mask = None
    if order.interval is not None:
        t0, t1 = order.interval
        mask = (t_s >= t0) & (t_s < t1)
        if not mask.any():
            raise InputError(f"interval {order.interval} contains no sample")
    dt = sample_period_s(t_s) if dt_s is None else dt_s
    hp_n = highpass_samples(order.highpass_s, dt)
    if hp_n is not None:
        b_i, b_j = highpass(b_i, hp_n), highpass(b_j, hp_n)
    if order.band_hz is not None:
        b_i, b_j = bandpass(b_i, order.band_hz, dt), bandpass(b_j, order.band_hz, dt)
    if order.window_s is None:
        fit = fit_first_order(b_i, b_j, mask=mask, alpha_method=alpha_method,
                              direction=order.direction)
        return fit.alpha, fit.direction_i, fit.direction_ij, {
            "alpha_variance": fit.alpha_variance, "correlation": fit.correlation,
            "n_used": fit.n_used}
    window_n = int(round(order.window_s / dt))
    bi, bj = (b_i, b_j) if mask is None else (b_i[mask], b_j[mask])
    if window_n > bi.shape[0]:
        raise InputError(f"window_s = {order.window_s} s ({window_n} samples) is longer "
                         f"than the data ({bi.shape[0]} samples)")
    scan = scan_first_order(bi, bj, window_n, step=scan_step, direction=order.direction)
    summ = summarize_scan(scan, cone_deg=order.cone_deg,
                          alpha_kind="alpha" if alpha_method == "decorrelate" else "alpha_variance")
    sel = summ.selected
    info = {"alpha_variance": float(np.mean(scan.alpha_variance[sel])),
            "correlation": float(np.mean(scan.correlation[sel])),
            "n_used": int(np.all(np.isfinite(bi - bj), axis=1).sum()),
            "scan": {"window_n": window_n, "n_windows": summ.n_windows,
                     "n_selected": summ.n_selected, "alpha_std": summ.alpha_std,
                     "cone_deg": summ.cone_deg,
                     "n_ill_defined": summ.n_ill_defined,
                     "min_eigen_ratio": summ.min_eigen_ratio,
                     "direction_i_mode": summ.direction_i_mode.tolist(),
                     "direction_ij_mode": summ.direction_ij_mode.tolist()}}
    if keep_scan:
        info["scan_objects"] = (scan, summ)
    return summ.alpha, summ.direction_i, summ.direction_ij, info


def _joint_steps(stage_no, stage, b_i, b_j, t_s, dt, fixed, raw_diff) -> list:
    """The two steps of a joint pair stage (``A_ij`` and ``A_ji`` in the chain's
    convention ``B_j' = B_j - A_ji (B_i - B_j)``)."""
    from magcal.ac.joint import fit_joint, selections, swap

    i, j = stage.sensors
    key_i, key_j = (stage_no, 1, i), (stage_no, 1, j)
    if key_i in fixed and key_j in fixed:
        return [Step(stage=stage_no, order=1, i=a, j=b, A=np.asarray(fixed[key], dtype=float),
                     kind="fixed")
                for a, b, key in ((i, j, key_i), (j, i, key_j))]
    sels = selections(b_i, b_j, t_s, stage.orders, dt, event_half_s=stage.event_half_s,
                      event_difference=raw_diff, events=stage.events)
    out = []
    for a, b, ss in ((i, j, sels), (j, i, swap(sels))):
        fit = fit_joint(ss, dt, min_snr=stage.min_snr, pulse_min_snr=stage.pulse_min_snr)
        # the partner: B_j + K_ji (B_j - B_i), which is the chain's A_ji = K_ji
        out.append(Step(stage=stage_no, order=1, i=a, j=b, A=fit.K, kind="joint",
                        n_used=int(sum(s.mask.sum() for s in ss)), scan=fit.to_dict(),
                        direction_method=stage.orders[0].direction,
                        highpass_s=stage.orders[0].highpass_s))
    return out


class _ChainState:
    """Working state of :func:`run_chain`: current fields, weights, steps, scans."""

    def __init__(self, *, data, t_s, dt, alpha_method, keep_scans, fixed):
        self.data, self.t_s, self.dt = data, t_s, dt
        self.alpha_method, self.keep_scans, self.fixed = alpha_method, keep_scans, fixed
        self.cur = {s: b.copy() for s, b in data.items()}
        self.w = {s: {s: np.eye(3)} for s in data}
        self.steps: list[Step] = []
        self.scans: dict = {}

    def fit_step(self, stage_no, order_no, order, i, j):
        """(A, Step) of one order of ``i`` cleaned with ``j`` (or the fixed one)."""
        key = (stage_no, order_no, i)
        if key in self.fixed:
            A = np.asarray(self.fixed[key], dtype=float)
            return A, Step(stage=stage_no, order=order_no, i=i, j=j, A=A,
                           window_s=order.window_s, kind="fixed")
        alpha, e_i, e_ij, info = fit_order(self.cur[i], self.cur[j], self.t_s, order,
                                           dt_s=self.dt, alpha_method=self.alpha_method,
                                           keep_scan=self.keep_scans)
        if "scan_objects" in info:
            self.scans[key] = info.pop("scan_objects")
        A = correction_matrix(alpha, e_i, e_ij)
        return A, Step(stage=stage_no, order=order_no, i=i, j=j, A=A, alpha=float(alpha),
                       direction_i=np.asarray(e_i), direction_ij=np.asarray(e_ij),
                       window_s=order.window_s, alpha_variance=info["alpha_variance"],
                       correlation=info["correlation"], n_used=info["n_used"],
                       interval=order.interval, scan=info.get("scan"),
                       direction_method=order.direction, highpass_s=order.highpass_s,
                       band_hz=order.band_hz)

    def pair_update(self, i, j, A_ij, A_ji):
        """Apply one pair order to both sensors and their weights (Eqs. 23-26)."""
        cur, w = self.cur, self.w
        d = cur[i] - cur[j]
        cur[i], cur[j] = cur[i] + d @ A_ij.T, cur[j] - d @ A_ji.T
        w[i], w[j] = _wcombine(w[i], w[j], A_ij), _wcombine(w[j], w[i], A_ji)


def _partner_step(stage_no, order_no, order, j, i, A_ij, st_ij):
    """The partner's correction of a coherent pair order: Eqs. 20-21 generalised, so the
    corrected pair agrees along ``e_ij`` and the order removes exactly that direction
    from the difference."""
    e = np.asarray(st_ij.direction_ij, dtype=float)
    A = -A_ij - np.outer(e, e)
    alpha, e_j, e_ji = rank_one_parts(A)
    return A, Step(stage=stage_no, order=order_no, i=j, j=i, A=A, alpha=alpha,
                   direction_i=e_j, direction_ij=e_ji, window_s=order.window_s,
                   n_used=st_ij.n_used, interval=order.interval, kind="partner",
                   direction_method=order.direction, highpass_s=order.highpass_s,
                   band_hz=order.band_hz)


def _reference_stage(st: _ChainState, k: int, stage: Stage) -> None:
    ref = stage.reference
    for n_o, order in enumerate(stage.orders, start=1):
        for s in stage.sensors:
            A, step = st.fit_step(k, n_o, order, s, ref)
            st.cur[s] = st.cur[s] + (st.cur[s] - st.cur[ref]) @ A.T
            st.w[s] = _wcombine(st.w[s], st.w[ref], A)
            st.steps.append(step)


def _joint_stage(st: _ChainState, k: int, stage: Stage) -> None:
    i, j = stage.sensors
    raw_diff = st.data[i] - st.data[j]
    pair_steps = _joint_steps(k, stage, st.cur[i], st.cur[j], st.t_s, st.dt, st.fixed,
                              raw_diff)
    st.pair_update(i, j, pair_steps[0].A, pair_steps[1].A)
    st.steps += pair_steps


def _pair_stage(st: _ChainState, k: int, stage: Stage) -> None:
    i, j = stage.sensors
    for n_o, order in enumerate(stage.orders, start=1):
        A_ij, st_ij = st.fit_step(k, n_o, order, i, j)
        if order.direction == "coherent" and (k, n_o, j) not in st.fixed:
            A_ji, st_ji = _partner_step(k, n_o, order, j, i, A_ij, st_ij)
        else:
            A_ji, st_ji = st.fit_step(k, n_o, order, j, i)
        st.pair_update(i, j, A_ij, A_ji)
        st.steps += [st_ij, st_ji]


def _regression_stage(st: _ChainState, k: int, stage: Stage) -> None:
    from magcal.ac.nonorthogonal import fit_regression_stage

    cur, w = st.cur, st.w
    refs = list(stage.references)
    z = np.zeros((3, 3))
    for n_o, order in enumerate(stage.orders, start=1):
        for s in stage.sensors:
            mats, info = fit_regression_stage(cur[s], [cur[r] for r in refs], st.t_s,
                                              interval=order.interval,
                                              detrend_s=order.detrend_s)
            cur[s] = cur[s] + sum((cur[s] - cur[r]) @ m.T for r, m in zip(refs, mats))
            new = {key: val.copy() for key, val in w[s].items()}
            for r, m in zip(refs, mats):
                for key in set(w[s]) | set(w[r]):
                    new[key] = new.get(key, z) + m @ (w[s].get(key, z) - w[r].get(key, z))
            w[s] = new
            st.steps += [Step(stage=k, order=n_o, i=s, j=r, A=m, n_used=info["n_used"],
                              interval=order.interval, kind="regression")
                         for r, m in zip(refs, mats)]


def run_chain(data: Mapping[str, np.ndarray], t_s: np.ndarray, plan: Plan, *,
              alpha_method: str = "decorrelate", keep_scans: bool = False,
              fixed_steps: Mapping | None = None) -> ChainResult:
    """Fit and apply a plan iteratively; collapse it into upload matrices.

    Parameters
    ----------
    data : mapping sensor -> ndarray (n, 3)
        Raw fields of all sensors in one frame (nT), NaN for missing samples.
    t_s : ndarray (n,)
        Sample times in seconds (any origin; intervals use the same origin).
    plan : Plan
    alpha_method : {"decorrelate", "variance"}
    keep_scans : bool
        Keep per-window scan results (for Fig.-3-style plots).
    fixed_steps : mapping, optional
        ``(stage, order, i) -> A`` to reuse instead of fitting (used to re-run a fitted
        chain on new data, e.g. for stability checks).

    Returns
    -------
    ChainResult

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> s = rng.normal(size=(1000, 1)); amb = np.array([100.0, -20.0, 40.0])
    >>> u = np.array([0.0, 0.6, 0.8])
    >>> data = {"o": amb + 2 * s * u, "a": amb + 40 * s * u}
    >>> plan = Plan("o", (Stage("reference", ("o",), reference="a"),))
    >>> res = run_chain(data, np.arange(1000.0), plan)
    >>> bool(np.allclose(res.corrected, amb, atol=1e-9)), res.identity_error < 1e-12
    (True, True)
    """
    t_s = np.asarray(t_s, dtype=float)
    names = plan.sensors
    for s in names:
        if s not in data:
            raise InputError(f"sensor {s!r} from the plan is missing from the data",
                             column=f"{s}_x")
    n = np.asarray(data[names[0]]).shape[0]
    for s in names:
        if np.asarray(data[s]).shape != (n, 3):
            raise InputError(f"sensor {s!r} must be an (n, 3) array, got "
                             f"{np.asarray(data[s]).shape}")
    st = _ChainState(data={s: np.asarray(data[s], dtype=float) for s in names}, t_s=t_s,
                     dt=sample_period_s(t_s), alpha_method=alpha_method,
                     keep_scans=keep_scans, fixed=dict(fixed_steps or {}))
    for k, stage in enumerate(plan.stages, start=1):
        if stage.kind == "reference":
            _reference_stage(st, k, stage)
        elif stage.kind == "pair" and stage.joint:
            _joint_stage(st, k, stage)
        elif stage.kind == "pair":
            _pair_stage(st, k, stage)
        else:
            _regression_stage(st, k, stage)
    cur, w, steps, scans = st.cur, st.w, st.steps, st.scans
    target = plan.target
    M = {key: val for key, val in w[target].items()}
    G = dc_offset({s: np.asarray(data[s], dtype=float) for s in M}, target, M)
    return ChainResult(target=target, M=M, G=G, steps=tuple(steps), corrected=cur[target],
                       weights=w, scans=scans)
