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
#: Physical range of each covariate (inclusive). A value outside it is a fill value
#: (99999 for a missing Dst, 99 for a missing Kp) or a unit error (Kp x 10): it is
#: missing, counted, and never interpolated as data. Dst reached -589 nT in March 1989
#: and an estimated -850 to -1760 nT in 1859; the spacecraft temperature is in deg C.
COVARIATE_RANGES = {"temperature": (-273.15, 1000.0), "kp": (0.0, 9.0),
                    "dst": (-2000.0, 1000.0), "lon_deg": (-360.0, 360.0),
                    "phase": (-np.inf, np.inf)}
#: A covariate known at fewer than this share of the samples is not used: leaving out
#: more than a quarter of the record to keep one regressor costs the other effects
#: their evidence (Dst for half of a 14-day archive: only the offset was named, the
#: local-time term and the activity were lost); a shorter hole costs less than a
#: made-up value.
MIN_COVARIATE_SHARE = 0.75
#: ... unless the samples it covers still span this many days of data: then its
#: unknown samples are left out instead. Covariates for 15 of the sample month's 30
#: days: not used, the storm field had no regressor (6.72 nT final gap, offset and
#: diurnal); on the 15 days, offset, activity, diurnal and a drift (2.43 nT, the full
#: month 1.81). Dst for 7 of 14 days: on 7 days only the offset was beyond chance
#: (11.4 nT), without Dst four effects (5.93 nT).
MIN_COVARIATE_DAYS = 14.0
#: Field magnitudes further apart than this factor (median of |measured| over median
#: of |model|) are a unit error (nT against pT or uT), not a model gap.
MAX_UNIT_RATIO = 10.0


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
                         f"model: {', '.join(map(str, model.columns))})", column="components",
                         file=_sources(measured) + _sources(model) or None)
    common = measured.index.intersection(model.index)
    files = _sources(measured) + _sources(model)
    if len(common) < 10:
        raise InputError(f"measured and model have only {len(common)} common times "
                         "(they must be on the same time stamps)", column="time",
                         file=files or None)
    meas, mod = measured.loc[common, list(comps)], model.loc[common, list(comps)]
    check_units(meas, mod, file=files or None)
    return meas, mod, comps


def _sources(frame: pd.DataFrame) -> list[str]:
    """The files a reader took ``frame`` from (``attrs["source"]``), for messages."""
    src = frame.attrs.get("source") or []
    return [src] if isinstance(src, str) else [str(f) for f in src]


def columns_not_used(measured: pd.DataFrame, model: pd.DataFrame, components) -> dict:
    """The columns of ``measured`` and ``model`` the discovery leaves aside, and the
    components with no finite value (JSON-ready; empty lists when every column is used).

    A column of one file that the other lacks (``Hn`` missing from MODEL, ``Hp`` renamed
    ``hp`` in MEASURED) is not a component: the discovery runs on the others, and the
    report must say which were left aside, since an effect on them cannot be found.

    Examples
    --------
    >>> t = pd.date_range("2019-11-01", periods=3, freq="1min", tz="UTC")
    >>> meas = pd.DataFrame({"hp": 1.0, "He": 2.0, "Hn": np.nan}, index=t)
    >>> mod = pd.DataFrame({"Hp": 1.0, "He": 2.0, "Hn": 3.0}, index=t)
    >>> columns_not_used(meas, mod, ("He", "Hn"))
    {'measured': ['hp'], 'model': ['Hp'], 'all_missing': ['Hn']}
    """
    comps = set(components)
    empty = [c for c in components if not np.isfinite(measured[c].to_numpy(dtype=float)).any()
             or not np.isfinite(model[c].to_numpy(dtype=float)).any()]
    return {"measured": [str(c) for c in measured.columns
                         if c not in comps and c not in COVARIATES],
            "model": [str(c) for c in model.columns if c not in comps],
            "all_missing": empty}


def check_units(measured: pd.DataFrame, model: pd.DataFrame, file=None) -> None:
    """Refuse measured and model whose field magnitudes differ by a unit's factor.

    The median magnitude of each (over the samples where both are finite) must be
    within :data:`MAX_UNIT_RATIO` of the other's: a file in pT or uT against one in nT
    (a factor of 1000) would otherwise be "discovered" as an offset and a scale of
    hundreds of percent. A model of zeros (a residual given as measured) is not judged.

    Raises
    ------
    InputError
        Naming ``file``, both medians and their ratio.

    Examples
    --------
    >>> t = pd.date_range("2019-11-01", periods=20, freq="1min", tz="UTC")
    >>> mod = pd.DataFrame({"Hp": np.full(20, 100.0)}, index=t)
    >>> check_units(mod * 1.3, mod)
    >>> try:
    ...     check_units(mod * 1000, mod, file="m.csv")
    ... except InputError as exc:
    ...     print(exc.message.split(":")[0])
    median field magnitude of measured 1e+05 nT against the model's 100 nT (1000x)
    """
    a = np.linalg.norm(measured.to_numpy(dtype=float), axis=1)
    b = np.linalg.norm(model.to_numpy(dtype=float), axis=1)
    ok = np.isfinite(a) & np.isfinite(b)
    if ok.sum() < 10:
        return
    ma, mb = float(np.median(a[ok])), float(np.median(b[ok]))
    if mb <= 0 or ma <= 0:
        return
    ratio = ma / mb
    if not 1 / MAX_UNIT_RATIO <= ratio <= MAX_UNIT_RATIO:
        shown = f"{ratio:.4g}x" if ratio >= 1 else f"1/{1 / ratio:.4g}"
        raise InputError(f"median field magnitude of measured {ma:.3g} nT against the "
                         f"model's {mb:.3g} nT ({shown}): wrong units? (both must be in nT)",
                         file=file)


#: Tests of :func:`screen_samples`, in the order they are applied.
SCREEN_TESTS = {
    "spike": "beyond 8 robust sigma of an 11-sample running median of measured - model, "
             "with a jump in and a jump out (at most 5 samples)",
    "implausible_vs_model": "|measured| further from |model| than max(1000 nT, 0.5 |model|) "
                            "(fill values such as 99999 or 65535, a stuck converter)",
    "saturated": "a component repeating the record's extreme value for 3 or more samples "
                 "(clipped at the instrument's range)",
    "stuck": "every component repeating one reading for 10 or more samples",
}


def screen_samples(measured: pd.DataFrame, model: pd.DataFrame):
    """Leave out the samples of ``measured`` no fit should see, and count them by test.

    The chain's quality checks (:mod:`magcal.qc.checks`, the same defaults as its
    ``[qc]`` section) on what the discovery is given: spikes of measured - model
    (:func:`magcal.qc.checks.spike_mask`), magnitudes implausible against the model (fill values
    like 99999 that the readers do not know, a saturated converter at 65535), a
    component clipped at the record's extreme, and stuck readings. One 65535 run of
    two hours in a month is 3500 nT of gap RMS: left in, no effect is beyond chance
    and every real one is lost.

    Parameters
    ----------
    measured, model : pandas.DataFrame
        Aligned frames (:func:`align_frames`), the same columns.

    Returns
    -------
    (pandas.DataFrame, dict)
        ``measured`` with the left-out samples NaN in every component, and
        ``{"test": ..., "samples": n, "first": ISO time or None, "by_test": {...}}``
        (``by_test``: samples each test flagged, a sample counted under the first).

    Examples
    --------
    >>> t = pd.date_range("2019-11-01", periods=600, freq="1min", tz="UTC")
    >>> model = pd.DataFrame({"Hp": np.full(600, 100.0)}, index=t)
    >>> meas = model + np.random.default_rng(0).normal(0, 1, (600, 1))
    >>> meas.iloc[[100, 101]] = 180.0
    >>> meas.iloc[300:340] = 99999.0
    >>> clean, left_out = screen_samples(meas, model)
    >>> left_out["samples"], left_out["by_test"]["implausible_vs_model"]
    (42, 40)
    """
    from magcal.qc.checks import implausible_mask, saturation_mask, spike_mask, stuck_mask

    resid = np.array((measured - model).to_numpy(dtype=float))
    values = measured.to_numpy(dtype=float)
    implausible = implausible_mask(values, model.to_numpy(dtype=float))
    # the gross samples out first: a 99999 run would raise the spike test's local scale
    resid[implausible] = np.nan
    masks = {"spike": spike_mask(resid), "implausible_vs_model": implausible,
             "saturated": saturation_mask(values), "stuck": stuck_mask(values)}
    bad = np.zeros(len(measured), dtype=bool)
    by_test = {}
    for name in SCREEN_TESTS:
        new = masks[name] & ~bad & np.isfinite(values).any(axis=1)
        by_test[name] = int(new.sum())
        bad |= new
    out = measured.copy()
    out[bad] = np.nan
    first = measured.index[bad][0].isoformat() if bad.any() else None
    return out, {"test": "; ".join(f"{k}: {v}" for k, v in SCREEN_TESTS.items()),
                 "samples": int(bad.sum()), "first": first, "by_test": by_test}


def out_of_range(values: np.ndarray, name: str) -> np.ndarray:
    """Finite values outside the covariate's :data:`COVARIATE_RANGES` (fills, wrong units).

    Examples
    --------
    >>> out_of_range(np.array([-20.0, 99999.0, np.nan]), "dst").tolist()
    [False, True, False]
    """
    lo, hi = COVARIATE_RANGES[name]
    v = np.asarray(values, dtype=float)
    with np.errstate(invalid="ignore"):
        return np.isfinite(v) & ((v < lo) | (v > hi))


def _valid(values, name: str, file=None) -> tuple[np.ndarray, int]:
    """``values`` with out-of-range entries NaN, and how many there were.

    Raises
    ------
    InputError
        When more than half of the finite values are out of range: a unit error (Kp
        given x 10, a longitude in radians is not caught: it is in range), not fills.
    """
    v = np.array(values, dtype=float)
    bad = out_of_range(v, name)
    n_bad, n_finite = int(bad.sum()), int(np.isfinite(v).sum())
    if n_bad and n_bad > 0.5 * n_finite:
        lo, hi = COVARIATE_RANGES[name]
        raise InputError(f"{n_bad} of {n_finite} values outside {lo:g}..{hi:g} (from "
                         f"{np.nanmin(v):g} to {np.nanmax(v):g}): wrong units?", file=file,
                         column=name)
    v[bad] = np.nan
    return v, n_bad


#: A covariate's hole: a step between its values of more than this many of its median
#: spacings. Discovery leaves the samples inside out (:func:`_unknown`); the chain warns
#: about the same holes (``magcal.chain.calibrate._covariate_holes``).
HOLE_SPACINGS = 2.5


def _unknown(t_new: np.ndarray, t_known: np.ndarray) -> np.ndarray:
    """Samples a covariate known at ``t_known`` does not cover.

    Its spacing is the median step of ``t_known``. A sample is not covered more than
    one spacing before the first value or after the last (an hourly Dst stamped at the
    start of its hour, a 3-hourly Kp, cover their interval) or inside a hole of more
    than :data:`HOLE_SPACINGS` spacings; shorter holes are interpolated.
    """
    if t_known.size == 0:
        return np.ones(t_new.size, dtype=bool)
    step = float(np.median(np.diff(t_known))) if t_known.size > 1 else 0.0
    out = (t_new < t_known[0] - step) | (t_new > t_known[-1] + step)
    if t_known.size > 1:
        gaps = np.flatnonzero(np.diff(t_known) > HOLE_SPACINGS * step)
        k = np.searchsorted(t_known, t_new, side="right") - 1
        inside = np.isin(k, gaps)
        out |= inside & (t_new > t_known[np.clip(k, 0, None)])
    return out


def prepare_covariates(times_s: np.ndarray, covariates, longitude_deg=None):
    """Covariates on ``times_s`` with what each covers: the discovery's input check.

    Values outside a covariate's physical range (:data:`COVARIATE_RANGES`: a 99999 Dst
    fill, a Kp of 99) are missing, not data. A covariate is *unknown* at a sample
    outside its own time span or inside one of its holes (:func:`_unknown`): it is
    never extrapolated or bridged there. A covariate known at fewer than
    :data:`MIN_COVARIATE_SHARE` of the samples and on fewer than
    :data:`MIN_COVARIATE_DAYS` days of them is not used; the others are used, and the
    samples where one of them is unknown are to be left out of the fit (``unknown``),
    since any value put there would be made up. ``lon_deg`` is not checked when
    ``longitude_deg`` is given (it is then not used).

    Parameters
    ----------
    times_s : ndarray
        Sample times, seconds since 1970.
    covariates : pandas.DataFrame or mapping or None
        As :func:`covariates_on`; a DataFrame's ``attrs["source"]`` names its file in
        errors.
    longitude_deg : float, optional
        The longitude given instead of a ``lon_deg`` column.

    Returns
    -------
    (dict, ndarray, dict)
        Arrays on ``times_s`` of the covariates used (interpolated where known),
        the boolean mask of samples where a used one is unknown, and per column
        ``{"used", "samples_known", "out_of_range", "first", "last", "reason"}``
        (JSON-ready).

    Raises
    ------
    InputError
        A DataFrame of covariates none of which covers any sample (they do not overlap
        the data in time), or a column mostly out of range (wrong units).

    Examples
    --------
    >>> t = pd.date_range("2019-11-01", periods=600, freq="1min", tz="UTC")
    >>> cov = pd.DataFrame({"dst": np.r_[np.full(400, -20.0), [99999.0], np.full(99, -20.0)]},
    ...                    index=t[:500])
    >>> arrays, unknown, report = prepare_covariates(to_unix_seconds(t), cov)
    >>> int(unknown.sum()), report["dst"]["out_of_range"], report["dst"]["used"]
    (99, 1, True)
    """
    out: dict = {}
    report: dict = {}
    unknown = np.zeros(times_s.size, dtype=bool)
    if covariates is None:
        return out, unknown, report
    if isinstance(covariates, pd.DataFrame):
        file = _sources(covariates) or None
        t_old = to_unix_seconds(covariates.index)
        columns = {name: covariates[name].to_numpy(dtype=float) for name in COVARIATES
                   if name in covariates.columns}
    elif isinstance(covariates, Mapping):
        file, t_old, columns = None, times_s, _mapped_columns(covariates, times_s)
    else:
        raise TypeError("covariates must be a DataFrame or a mapping of arrays")
    span = (_iso(times_s[0]), _iso(times_s[-1])) if times_s.size else (None, None)
    spacing_s = float(np.median(np.diff(times_s))) if times_s.size > 1 else 0.0
    for name, raw in columns.items():
        if name == "lon_deg" and longitude_deg is not None:
            continue
        v, n_bad = _valid(raw, name, file)
        ok = np.isfinite(v)
        miss = _unknown(times_s, t_old[ok])
        known = int((~miss).sum())
        entry = {"used": False, "samples_known": known, "out_of_range": n_bad,
                 "first": _iso(t_old[ok][0]) if ok.any() else None,
                 "last": _iso(t_old[ok][-1]) if ok.any() else None}
        if known == 0:
            entry["reason"] = (f"no value covers the samples ({span[0]} to {span[1]})"
                               if ok.any() else "no valid value in range")
        elif (known < MIN_COVARIATE_SHARE * times_s.size
              and known * spacing_s < MIN_COVARIATE_DAYS * 86400.0):
            entry["reason"] = (f"known at only {known} of {times_s.size} samples (fewer "
                               f"than {MIN_COVARIATE_SHARE:.0%}, and under "
                               f"{MIN_COVARIATE_DAYS:g} days)")
        else:
            entry["used"] = True
            out[name] = _interp_onto(times_s, t_old, v, name)
            unknown |= miss
        report[name] = entry
    if isinstance(covariates, pd.DataFrame) and report and not any(
            e["samples_known"] for e in report.values()):
        firsts = [e["first"] for e in report.values() if e["first"]]
        lasts = [e["last"] for e in report.values() if e["last"]]
        held = f"its values span {min(firsts)} to {max(lasts)}" if firsts else "no valid value"
        raise InputError(f"the covariates cover none of the samples ({span[0]} to "
                         f"{span[1]}; {held}): "
                         + "; ".join(f"{k} {e['samples_known']}" for k, e in report.items())
                         + f" of {times_s.size} samples covered", file=file,
                         column=",".join(report))
    return out, unknown, report


def _mapped_columns(covariates: Mapping, times_s: np.ndarray) -> dict:
    """The known covariates of a mapping of arrays, one value per time, as floats.

    Raises
    ------
    InputError
        A covariate whose length is not that of ``times_s``.
    """
    out = {}
    for name in COVARIATES:
        if name in covariates and covariates[name] is not None:
            v = np.asarray(covariates[name], dtype=float)
            if v.shape != times_s.shape:
                raise InputError(f"covariate {name} has {v.size} values for "
                                 f"{times_s.size} times", column=name)
            out[name] = v
    return out


def _iso(seconds: float) -> str:
    return pd.Timestamp(float(seconds), unit="s", tz="UTC").isoformat()


def _interp_onto(t_new: np.ndarray, t_old: np.ndarray, values: np.ndarray, name: str):
    ok = np.isfinite(values) & ~out_of_range(values, name)
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
        for name, v in _mapped_columns(covariates, times_s).items():
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
