"""Turn frames (measured, model, covariates) into the arrays the discovery core uses."""

from __future__ import annotations

from typing import Mapping

import numpy as np
import pandas as pd

from magcal.discover.effects import EffectInputs, local_time_h
from magcal.errors import InputError

#: Covariate columns understood by the discovery (CONTRACTS §5).
COVARIATES = ("temperature", "kp", "dst", "lon_deg", "phase")
#: Covariates that are step-like (held until the next value rather than interpolated).
_HELD = ("kp",)


def to_unix_seconds(times) -> np.ndarray:
    """Seconds since 1970-01-01 UTC from a DatetimeIndex, datetime64 or float array.

    Examples
    --------
    >>> to_unix_seconds(pd.DatetimeIndex(["1970-01-02T00:00:00Z"]))
    array([86400.])
    """
    if isinstance(times, pd.DatetimeIndex):
        idx = times.tz_convert("UTC") if times.tz is not None else times
        return idx.as_unit("ns").asi8 / 1e9
    arr = np.asarray(times)
    if np.issubdtype(arr.dtype, np.datetime64):
        return arr.astype("datetime64[ns]").astype(np.int64) / 1e9
    return arr.astype(float)


def align_frames(measured: pd.DataFrame, model: pd.DataFrame):
    """Join measured and model on common times; return ``(meas, model, components)``.

    Components are the columns of ``measured`` (except covariate columns) also in
    ``model``, in the order of ``measured``.
    """
    comps = tuple(c for c in measured.columns if c in model.columns and c not in COVARIATES)
    if not comps:
        raise InputError("measured and model share no component column "
                         f"(measured: {', '.join(map(str, measured.columns))}; "
                         f"model: {', '.join(map(str, model.columns))})", column="components")
    common = measured.index.intersection(model.index)
    if len(common) < 10:
        raise InputError(f"measured and model have only {len(common)} common times "
                         "(they must be on the same time stamps)", column="time")
    return measured.loc[common, list(comps)], model.loc[common, list(comps)], comps


def screen_spikes(measured: pd.DataFrame, model: pd.DataFrame):
    """Leave out the samples of ``measured`` that are spikes of ``measured - model``.

    A spike is a run of at most five samples beyond 8 robust sigmas of an 11-sample
    running median, with a jump into it and a jump out of it
    (:func:`magcal.qc.checks.spike_mask`, the test the chain's quality screen uses); a
    step jumps once and is kept. Tested on the residual, where the model's own
    variation is gone. A spike of tens of nT in a month of 1-min data is a large share
    of its variance: left in, it is fitted by whatever effect it happens to
    correlate with (a scale, a rotation).

    Parameters
    ----------
    measured, model : pandas.DataFrame
        Aligned frames (:func:`align_frames`), the same columns.

    Returns
    -------
    (pandas.DataFrame, dict)
        ``measured`` with the spike samples NaN in every component, and what was left
        out: ``{"test": ..., "samples": n, "first": ISO time or None}``.

    Examples
    --------
    >>> t = pd.date_range("2019-11-01", periods=600, freq="1min", tz="UTC")
    >>> model = pd.DataFrame({"Hp": np.zeros(600)}, index=t)
    >>> meas = model + np.random.default_rng(0).normal(0, 1, (600, 1))
    >>> meas.iloc[[100, 101, 400]] = 80.0
    >>> clean, left_out = screen_spikes(meas, model)
    >>> left_out["samples"], int(clean["Hp"].isna().sum())
    (3, 3)
    """
    from magcal.qc.checks import spike_mask

    bad = spike_mask((measured - model).to_numpy(dtype=float))
    out = measured.copy()
    out[bad] = np.nan
    first = measured.index[bad][0].isoformat() if bad.any() else None
    return out, {"test": "spike: beyond 8 robust sigma of an 11-sample running median of "
                         "measured - model, with a jump in and a jump out (at most 5 samples)",
                 "samples": int(bad.sum()), "first": first}


def _interp_onto(t_new: np.ndarray, t_old: np.ndarray, values: np.ndarray, name: str):
    ok = np.isfinite(values)
    if ok.sum() == 0:
        return None
    tv, vv = t_old[ok], values[ok]
    if name == "phase":
        vv = np.unwrap(vv)
        return np.mod(np.interp(t_new, tv, vv), 2 * np.pi)
    if name in _HELD:
        k = np.clip(np.searchsorted(tv, t_new, side="right") - 1, 0, len(tv) - 1)
        return vv[k]
    return np.interp(t_new, tv, vv)


def covariates_on(times_s: np.ndarray, covariates) -> dict:
    """Covariate arrays on ``times_s`` (gaps filled by interpolation in time).

    ``covariates`` is a DataFrame with a time index, or a mapping of arrays already on
    ``times_s``. Unknown columns are ignored; an all-missing column is dropped.
    """
    out: dict = {}
    if covariates is None:
        return out
    if isinstance(covariates, pd.DataFrame):
        t_old = to_unix_seconds(covariates.index)
        for name in COVARIATES:
            if name in covariates.columns:
                v = _interp_onto(times_s, t_old, covariates[name].to_numpy(dtype=float), name)
                if v is not None:
                    out[name] = v
        return out
    if isinstance(covariates, Mapping):
        for name in COVARIATES:
            if name in covariates and covariates[name] is not None:
                v = np.asarray(covariates[name], dtype=float)
                if v.shape != times_s.shape:
                    raise InputError(f"covariate {name} has {v.size} values for "
                                     f"{times_s.size} times", column=name)
                v = _interp_onto(times_s, times_s, v, name)
                if v is not None:
                    out[name] = v
        return out
    raise TypeError("covariates must be a DataFrame or a mapping of arrays")


def build_inputs(times, model, components, covariates=None, longitude_deg=None):
    """Build :class:`EffectInputs`; return ``(inputs, index)`` (index None for arrays).

    Local time comes from ``longitude_deg`` if given, else from a ``lon_deg`` covariate.
    """
    index = None
    if isinstance(model, pd.DataFrame):
        if times is None:
            times = model.index
        index = pd.DatetimeIndex(times) if not isinstance(times, pd.DatetimeIndex) else times
        missing = [c for c in components if c not in model.columns]
        if missing:
            raise InputError(f"model lacks component(s) {', '.join(missing)}",
                             column=missing[0])
        mod = model.loc[:, list(components)].to_numpy(dtype=float)
    else:
        mod = np.asarray(model, dtype=float)
        if mod.ndim != 2 or mod.shape[1] != len(components):
            raise InputError(f"model must have shape (n, {len(components)})")
    t = to_unix_seconds(times)
    if t.shape[0] != mod.shape[0]:
        raise InputError(f"{t.shape[0]} times for {mod.shape[0]} model rows")
    cov = covariates_on(t, covariates)
    lon = cov.pop("lon_deg", None)
    if longitude_deg is not None:
        lon = float(longitude_deg)
    lt = local_time_h(t, lon) if lon is not None else None
    inputs = EffectInputs(times_s=t, model=mod, components=tuple(components),
                          covariates=cov, local_time_h=lt)
    return inputs, index
