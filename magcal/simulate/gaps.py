"""Months with hidden model-gap effects of random type and size, for testing discovery.

A *background* is what no effect of the discovery vocabulary should explain: the
ambient field T89 lacks nothing here except what is injected, and the residual
``measured - model - offset`` is ULF waves and white noise (from
:func:`magcal.simulate.month.simulate_month`), zero-mean bipolar substorm signatures on
the night side at high Kp (or the simulator's own one-sided dips) and a slowly varying
red "model error" (Ornstein-Uhlenbeck). :func:`draw_hidden` adds one effect of the
CONTRACTS §5 vocabulary with random component, onset, period and an amplitude drawn
above its *detectability threshold*: the amplitude at which the effect's coefficient
stands :func:`z_detect` standard errors above zero (the loop's significance level for
that kind, look-elsewhere included, plus a power margin), the standard error being
computed from the background's own autocorrelation with the offset free.

Every random choice comes from the generator passed in.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import pandas as pd

COMPONENTS = ("Hp", "He", "Hn")
LON_DEG = 128.2
_DAY_S = 86_400.0

#: Kinds of hidden effect :func:`draw_hidden` draws, and the effect name discovery must give.
KINDS = {"drift": "drift", "drift_change": "drift", "diurnal": "diurnal",
         "temperature": "temperature", "scale": "scale", "rotation": "rotation",
         "activity": "activity", "step": "step", "periodic": "periodic",
         "spin_tone": "spin_tone"}

#: Margin (in standard errors) of the detectability threshold above the significance the
#: discovery loop requires: 2 standard errors give ~98% power at the loop's level with the
#: standard errors computed here; the loop's own run up to ~20% larger (its jackknife
#: floor), and the extra half covers that.
Z_POWER = 2.5
#: Standard errors by which an effect's part that its nearest competitor cannot mimic
#: must stand out for the effect to be named right rather than the competitor.
Z_SEPARATE = 3.0
#: Coefficients per component (or axis) of each kind as the loop fits it.
_N_PARAMS = {"drift": 1, "drift_change": 1, "diurnal": 2, "temperature": 1, "scale": 1,
             "rotation": 1, "activity": 2, "step": 1, "periodic": 2, "spin_tone": 2}


@lru_cache(maxsize=16)
def base_month(seed: int = 7, n_days: float = 30.0, cadence_s: float = 60.0):
    """A quiet-model month (no local-time field, no storm coupling), cached per seed.

    Examples
    --------
    >>> m = base_month(7, 2.0, 600.0)
    >>> m.model_nT.shape
    (288, 3)
    """
    from magcal.simulate.month import MonthConfig, simulate_month

    cfg = MonthConfig(n_days=n_days, cadence_s=cadence_s, n_disturbed_days=3,
                      storm_coupling=(0.0, 0.0, 0.0), local_time_pp_nT=(0.0, 0.0, 0.0),
                      n_jobs=1)
    return simulate_month(cfg, rng=np.random.default_rng(seed))


def ou_noise(rng: np.random.Generator, n: int, dt_s: float, tau_s: float, std: float):
    """Three independent Ornstein-Uhlenbeck series (correlation time ``tau_s``), (n, 3).

    Examples
    --------
    >>> x = ou_noise(np.random.default_rng(0), 200000, 60.0, 600.0, 2.0)
    >>> bool(abs(x.std() - 2.0) < 0.15)
    True
    """
    from scipy.signal import lfilter

    a = np.exp(-dt_s / tau_s)
    e = rng.standard_normal((n, 3)) * std * np.sqrt(1 - a * a)
    first = rng.standard_normal(3) * std
    zi = (a * first)[None, :]
    return lfilter([1.0], [1.0, -a], e, axis=0, zi=zi)[0]


def bipolar_substorms(rng: np.random.Generator, t_s, kp, lt_h, dt_s: float = 60.0):
    """Zero-mean substorm signatures (growth-phase dip, then overshoot) at night, Kp >= 3."""
    n = t_s.size
    out = np.zeros((n, 3))
    hour = (t_s // 3600).astype(np.int64)
    first = np.r_[True, hour[1:] != hour[:-1]]
    night = (lt_h >= 20) | (lt_h < 4)
    cand = np.flatnonzero(first & night & (kp >= 3.0))
    onsets = cand[rng.random(cand.size) < 0.35]
    tau = np.arange(0, 240.0, dt_s / 60.0)  # minutes
    shape = -np.exp(-0.5 * ((tau - 30) / 12) ** 2) + 0.5 * np.exp(-0.5 * ((tau - 75) / 24) ** 2)
    shape -= shape.mean()
    for i0 in onsets:
        depth = 6.0 * (kp[i0] - 2.0) * rng.uniform(0.6, 1.4)
        seg = slice(i0, min(n, i0 + tau.size))
        k = seg.stop - seg.start
        out[seg, 0] += depth * shape[:k]
        out[seg, 1:] += rng.standard_normal((k, 2)) * 0.2 * depth * np.abs(shape[:k, None])
    return out


@dataclass(frozen=True)
class Background:
    """A month without hidden effects: model field, covariates and the benign residual.

    Attributes
    ----------
    month : MonthResult
        The simulated month (model field, Kp, Dst, temperature, local time).
    benign : ndarray (n, 3)
        What no effect should explain, nT.
    t_s : ndarray (n,)
        Seconds since the first sample.
    """

    month: object
    benign: np.ndarray
    t_s: np.ndarray

    @property
    def n(self) -> int:
        return self.t_s.size

    @property
    def day(self) -> np.ndarray:
        return self.t_s / _DAY_S

    @property
    def noise_floor_nT(self) -> float:
        return float(np.sqrt(np.mean(self.benign ** 2)))


def make_background(seed: int = 7, *, n_days: float = 30.0, cadence_s: float = 60.0,
                    red_std_nT: float = 2.0, red_tau_s: float = 7200.0,
                    simulator_substorms: bool = False, noise_seed: int | None = None
                    ) -> Background:
    """Benign background on the month ``base_month(seed, n_days, cadence_s)``.

    ``noise_seed`` (default ``seed + 1000``) seeds the substorms and the red model error,
    so one month can carry many independent backgrounds.
    """
    m = base_month(seed, n_days, cadence_s)
    rng = np.random.default_rng(seed + 1000 if noise_seed is None else noise_seed)
    t_s = (m.times - m.times[0]).astype("timedelta64[ns]").astype(np.int64) / 1e9
    substorms = (m.disturbed_nT if simulator_substorms
                 else bipolar_substorms(rng, t_s, m.kp, m.local_time_h, cadence_s))
    benign = m.ulf_nT + m.noise_nT + substorms + ou_noise(rng, t_s.size, cadence_s,
                                                          red_tau_s, red_std_nT)
    return Background(month=m, benign=benign, t_s=t_s)


def spin_phase(t_s, period_s: float = 6.283):
    """Spin phase (rad) of a slowly spinning body (not commensurate with the cadence)."""
    return np.mod(2 * np.pi * np.asarray(t_s) / period_s, 2 * np.pi)


def wandering_temperature(bg: Background, rng: np.random.Generator) -> np.ndarray:
    """Sensor temperature that follows the day and also wanders from day to day (deg C)."""
    period = rng.uniform(6.0, 14.0)
    return bg.month.temperature_C + 20 * np.sin(2 * np.pi * bg.day / period
                                                + rng.uniform(0, 2 * np.pi))


# ------------------------------------------------------------------ effect signatures
def _unit(kind: str, comp: int, bg: Background, rng: np.random.Generator, cov: dict):
    """Signature of amplitude 1 (natural unit) and its parameters."""
    n = bg.n
    day = bg.day
    span = day[-1] - day[0]
    out = np.zeros((n, 3))
    m = bg.month
    if kind == "drift":
        out[:, comp] = day - day.mean()
        return out, {"unit": "nT/day"}
    if kind == "drift_change":
        t0 = rng.uniform(0.3, 0.7) * span
        out[:, comp] = np.maximum(day - t0, 0.0)
        return out, {"unit": "nT/day", "t_break_day": float(t0)}
    if kind == "step":
        t0 = rng.uniform(0.15, 0.85) * span
        out[:, comp] = (day >= t0).astype(float)
        return out, {"unit": "nT", "t_step_day": float(t0)}
    if kind == "diurnal":
        peak = rng.uniform(0, 24)
        out[:, comp] = np.cos(2 * np.pi * (m.local_time_h - peak) / 24.0)
        return out, {"unit": "nT", "peak_lt_h": float(peak)}
    if kind == "temperature":
        temp = cov["temperature"]
        out[:, comp] = temp - temp.mean()
        return out, {"unit": "nT/degC"}
    if kind == "scale":
        out[:, comp] = m.model_nT[:, comp]
        return out, {"unit": "1"}
    if kind == "rotation":
        out[:] = np.cross(np.eye(3)[comp], m.model_nT)
        return out, {"unit": "rad", "axis": COMPONENTS[comp]}
    if kind == "activity":
        out[:, comp] = m.dst - m.dst.mean()
        return out, {"unit": "nT/nT_dst"}
    if kind == "periodic":
        while True:
            period_h = rng.uniform(2.5, 60.0)
            if min(abs(period_h - 24.0 / k) / (24.0 / k) for k in range(1, 9)) > 0.08:
                break
        out[:, comp] = np.cos(2 * np.pi * bg.t_s / (period_h * 3600) + rng.uniform(0, 2 * np.pi))
        return out, {"unit": "nT", "period_h": float(period_h)}
    if kind == "spin_tone":
        out[:, comp] = np.cos(cov["phase"] + rng.uniform(0, 2 * np.pi))
        return out, {"unit": "nT"}
    raise ValueError(f"unknown kind {kind!r}")


def noise_standard_error(signature, benign, max_lag: int | None = None,
                         nuisance=None, block: int | None = None) -> float:
    """Standard error of the amplitude of ``signature`` fitted with free offsets.

    The least-squares amplitude is ``a' y / |a|^2`` with ``a`` the signature after
    removing the offsets and any ``nuisance`` columns (shape (q, n, 3): terms fitted
    together with it, or the competing effect that could mimic it) by least squares. With
    the noise ``e = s(t) u`` (``s`` its RMS in blocks of ``block`` samples, ``u`` with
    autocovariance ``g_c(k)``) its variance is ``sum_c sum_k g_c(k) r_b,c(k) / |a|^4``
    with ``b = s a``: a signature that is large when the noise is large (a rotation or a
    scale error on storm days) is measured less well than stationary noise suggests. The
    sum runs (with a Bartlett taper) up to ``max_lag`` samples (default ``n // 20``): a
    few correlation times of the noise are enough, longer sums only add estimation noise.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> x = np.zeros((10000, 3)); x[:, 0] = 1.0; x[5000:, 0] = 2.0
    >>> se = noise_standard_error(x, rng.normal(0, 1.0, (10000, 3)), max_lag=10)
    >>> bool(abs(se / 0.02 - 1) < 0.05)
    True
    """
    a = np.asarray(signature, dtype=float)
    e = np.asarray(benign, dtype=float)
    a = a - a.mean(axis=0)
    e = e - e.mean(axis=0)
    n = a.shape[0]
    if nuisance is not None and len(nuisance):
        x = np.asarray(nuisance, dtype=float)
        x = (x - x.mean(axis=1, keepdims=True)).reshape(len(x), -1)
        coef, *_ = np.linalg.lstsq(x.T, a.reshape(-1), rcond=None)
        a = a - (coef @ x).reshape(a.shape)
    if block:
        idx = np.arange(n) // int(block)
        cnt = np.bincount(idx)
        level = np.sqrt(np.stack([np.bincount(idx, weights=e[:, c] ** 2) / cnt
                                  for c in range(e.shape[1])], axis=1))[idx]
        level = np.where(level > 0, level, 1.0)
        e, b = e / level, a * level
    else:
        b = a
    nfft = 1 << int(np.ceil(np.log2(2 * n)))
    lag = max(n // 20, 1) if max_lag is None else int(min(max_lag, n))
    var = 0.0
    for c in range(a.shape[1]):
        if not np.any(np.abs(a[:, c]) > 1e-12 * (np.abs(a).max() + 1e-300)):
            continue
        fe = np.fft.rfft(e[:, c], nfft)
        fb = np.fft.rfft(b[:, c], nfft)
        ge = np.fft.irfft(fe * np.conj(fe), nfft)[:lag] / n
        rb = np.fft.irfft(fb * np.conj(fb), nfft)[:lag]
        # a tapered sum (Bartlett window) keeps the estimate positive for long lags
        w = 1.0 - np.arange(lag) / lag
        var += ge[0] * rb[0] + 2.0 * float(np.sum(w[1:] * ge[1:] * rb[1:]))
    norm2 = float(np.sum(a * a))
    return float(np.sqrt(max(var, 0.0)) / norm2) if norm2 > 0 else float("inf")


def _best_step(signature, comp: int, bg: Background, margin_days: float = 0.25):
    """The single-component step (on an hourly grid) most like ``signature``, (1, n, 3)."""
    a = signature[:, comp] - signature[:, comp].mean()
    day = bg.day
    n = a.size
    cs = np.cumsum(a)
    k = np.arange(1, n)
    # least-squares fit of a centred step after sample k: explained = S_k^2 n / (k (n - k))
    explained = cs[:-1] ** 2 * n / (k * (n - k))
    ok = (day[1:] - day[0] >= margin_days) & (day[-1] - day[1:] >= margin_days)
    j = int(np.argmax(np.where(ok, explained, -1.0))) + 1
    out = np.zeros((1, n, 3))
    out[0, j:, comp] = 1.0
    return out


def _columns_of(kind: str, comp: int, bg: Background, cov: dict):
    """Regressors the loop fits for ``kind`` in one component (or about one axis)."""
    m = bg.month
    n = bg.n
    out = []

    def col(v, c=comp):
        x = np.zeros((n, 3))
        x[:, c] = v
        out.append(x)

    phi = 2 * np.pi * m.local_time_h / 24.0
    if kind == "diurnal3":
        for k in (1, 2, 3):
            col(np.cos(k * phi))
            col(np.sin(k * phi))
    elif kind == "drift":
        col(bg.day)
    elif kind == "scale":
        col(m.model_nT[:, comp])
    elif kind == "activity":
        col(m.kp)
    return np.array(out) if out else np.zeros((0, n, 3))


def _competitors(kind: str, signature, comp: int, bg: Background, cov: dict):
    """Columns of the term that could mimic ``kind`` best (the separation the loop needs)
    and the number of its hyper-parameter values the loop scans (1 if none)."""
    if kind in ("drift", "drift_change"):
        from magcal.discover.scan import n_step_trials

        return _best_step(signature, comp, bg), n_step_trials(float(bg.t_s[-1] - bg.t_s[0]))
    if kind == "step":
        return _columns_of("drift", comp, bg, cov), 1.0
    if kind == "diurnal":
        return _columns_of("scale", comp, bg, cov), 1.0
    if kind in ("scale", "temperature"):
        return _columns_of("diurnal3", comp, bg, cov), 1.0
    if kind == "rotation":
        return np.concatenate([_columns_of("diurnal3", c, bg, cov) for c in range(3)]), 1.0
    return np.zeros((0, bg.n, 3)), 1.0


def z_detect(kind: str, span_s: float, settings=None) -> float:
    """Single-coefficient z at the detectability threshold of ``kind``.

    The loop adds a component of an effect when its Wald test reaches ``z_component``
    (after a Bonferroni correction over the step times or periods scanned); with ``q``
    coefficients per component (a phase: cos and sin) that is a chi-squared quantile.
    The threshold stands ``Z_POWER`` above it.

    Examples
    --------
    >>> round(z_detect("drift", 30 * 86400.0), 1), round(z_detect("step", 30 * 86400.0), 1)
    (5.7, 6.4)
    """
    from scipy import stats

    from magcal.discover.loop import DiscoverySettings, _look_elsewhere
    from magcal.discover.scan import n_period_trials, n_step_trials

    s = settings or DiscoverySettings()
    trials = {"step": n_step_trials(span_s), "drift_change": n_step_trials(span_s),
              "periodic": n_period_trials(span_s)}.get(kind, 1.0)
    z_need = max(_look_elsewhere(s.z_component, trials), s.z_min if trials == 1 else 0.0)
    q = _N_PARAMS[kind]
    chi = float(stats.chi2.isf(stats.norm.sf(z_need), q))
    return float(np.sqrt(chi)) + Z_POWER


def detectability_threshold(kind: str, bg: Background, signature=None, rng=None, cov=None,
                            comp: int = 0, separated: bool = True) -> float:
    """Amplitude (natural unit) of ``kind`` at its detectability threshold.

    The larger of two amplitudes: the one at which the effect stands :func:`z_detect`
    standard errors out (to be seen), and, with ``separated``, the one at which its part
    that the competing term could not mimic (a step for a drift, a drift for a step,
    local-time harmonics for a rotation, a scale or a temperature effect, a scale for a
    diurnal term) stands ``Z_SEPARATE + sqrt(2 ln trials)`` standard errors out (to be
    named right; ``trials`` the step times the loop scans when the competitor is a step,
    else 1). The
    standard errors are :func:`noise_standard_error` on the background's own noise with
    the offsets and the terms fitted with the effect free (``kp`` beside ``dst`` for
    activity), plus the competitor for the second.
    """
    cov = cov or {}
    if signature is None:
        signature, _ = _unit(kind, comp, bg, rng or np.random.default_rng(0), cov)
    own = _columns_of(kind, comp, bg, cov) if kind == "activity" else np.zeros((0, bg.n, 3))
    lag = int(2 * _DAY_S / _cadence(bg))
    day = round(_DAY_S / _cadence(bg))
    se = noise_standard_error(signature, bg.benign, max_lag=lag, nuisance=own, block=day)
    thr = z_detect(kind, float(bg.t_s[-1] - bg.t_s[0])) * se
    comp_cols, comp_trials = _competitors(kind, signature, comp, bg, cov)
    if separated and len(comp_cols):
        se_perp = noise_standard_error(signature, bg.benign, max_lag=lag, block=day,
                                       nuisance=np.concatenate([own, comp_cols]))
        # a scanned competitor (the best of many step times) mimics noise by chance up to
        # sqrt(2 ln trials) standard errors: the unique part must stand out beyond that
        z_sep = Z_SEPARATE + np.sqrt(2 * np.log(comp_trials))
        thr = max(thr, z_sep * se_perp)
    return float(thr)


def _cadence(bg: Background) -> float:
    return float(np.median(np.diff(bg.t_s))) if bg.n > 1 else 60.0


@dataclass(frozen=True)
class Hidden:
    """One injected effect: its kind, the name discovery must give, where and how big."""

    kind: str
    name: str
    component: str
    amplitude: float
    threshold: float
    params: dict
    signal: np.ndarray

    def describe(self) -> str:
        return (f"{self.kind}[{self.component}] {self.amplitude:.4g} "
                f"({self.amplitude / self.threshold:.2f}x threshold) {self.params}")


@dataclass(frozen=True)
class GapCase:
    """Measured, model and covariate frames of a month with hidden effects."""

    measured: pd.DataFrame
    model: pd.DataFrame
    covariates: pd.DataFrame
    hidden: tuple
    offset_nT: np.ndarray
    background: Background

    @property
    def truth(self) -> np.ndarray:
        total = np.zeros((self.background.n, 3))
        for h in self.hidden:
            total += h.signal
        return total

    @property
    def noise_floor_nT(self) -> float:
        return self.background.noise_floor_nT


def draw_hidden(kind: str, bg: Background, rng: np.random.Generator, cov: dict,
                factor=(1.0, 2.0), component: int | None = None) -> Hidden:
    """One hidden effect of ``kind`` at a random component (or rotation axis), onset,
    period and phase, with amplitude ``uniform(*factor)`` times its threshold and a
    random sign."""
    if component is None:
        component = int(rng.integers(0, 3)) if kind != "rotation" else int(rng.integers(1, 3))
    sig, params = _unit(kind, component, bg, rng, cov)
    thr = detectability_threshold(kind, bg, sig, cov=cov, comp=component)
    amp = float(rng.uniform(*factor) * thr * rng.choice([-1.0, 1.0]))
    return Hidden(kind=kind, name=KINDS[kind], component=COMPONENTS[component],
                  amplitude=amp, threshold=thr, params=params, signal=amp * sig)


def make_gap_case(kinds=(), *, seed: int = 7, draw_seed: int = 0, n_days: float = 30.0,
                  cadence_s: float = 60.0, red_std_nT: float = 2.0, factor=(1.0, 2.0),
                  components=None, offset_nT=None) -> GapCase:
    """A month with one hidden effect per entry of ``kinds`` (random everything else).

    Parameters
    ----------
    kinds : sequence of str
        Keys of :data:`KINDS`; empty for an effect-free month.
    seed : int
        The base month (model field, Kp, storms); cached, so reuse a few.
    draw_seed : int
        Seeds the background noise, the effects' random parameters and the offset.
    factor : (float, float)
        Amplitudes are drawn uniformly in this range of multiples of the threshold.
    components : sequence of int or None, optional
        Force the component (or rotation axis) of each effect.

    Examples
    --------
    >>> case = make_gap_case(["step"], n_days=4, cadence_s=600.0, draw_seed=3)
    >>> case.hidden[0].name, case.measured.shape
    ('step', (576, 3))
    """
    rng = np.random.default_rng([seed, draw_seed])
    bg = make_background(seed, n_days=n_days, cadence_s=cadence_s, red_std_nT=red_std_nT,
                         noise_seed=int(rng.integers(2**31)))
    m = bg.month
    cov = {"temperature": wandering_temperature(bg, rng), "kp": m.kp, "dst": m.dst,
           "phase": spin_phase(bg.t_s)}
    hidden = []
    for i, kind in enumerate(kinds):
        comp = None if components is None else components[i]
        hidden.append(draw_hidden(kind, bg, rng, cov, factor=factor, component=comp))
    offset = (rng.uniform(-5, 5, 3) if offset_nT is None
              else np.asarray(offset_nT, dtype=float))
    truth = sum((h.signal for h in hidden), np.zeros((bg.n, 3)))
    index = pd.DatetimeIndex(m.times, name="time").tz_localize("UTC")
    meas = m.model_nT + offset[None, :] + truth + bg.benign
    if "spin_tone" not in kinds:
        cov.pop("phase")
    return GapCase(measured=pd.DataFrame(meas, index=index, columns=list(COMPONENTS)),
                   model=pd.DataFrame(m.model_nT, index=index, columns=list(COMPONENTS)),
                   covariates=pd.DataFrame(cov, index=index), hidden=tuple(hidden),
                   offset_nT=offset, background=bg)
