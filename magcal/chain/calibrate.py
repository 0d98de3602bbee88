"""The DC stages of a geostationary chain: offsets, corrected data, alignment, discovery.

Like :mod:`magcal.chain.prepare`, each function calls one library estimator and returns
its :class:`~magcal.chain.product.StageProduct`; :func:`magcal.chain.runner.run_chain`
drives them.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import pandas as pd

from magcal.chain.config import ChainConfig
from magcal.chain.prepare import HPEN, MinuteData
from magcal.chain.product import StageProduct, without_wall_clock
from magcal.errors import InputError
from magcal.provenance import make_provenance


def _index(times) -> pd.DatetimeIndex:
    return pd.DatetimeIndex(np.asarray(times, dtype="datetime64[ns]"), name="time").tz_localize(
        "UTC")


def run_offsets(minute: MinuteData, config: ChainConfig):
    """The sliding-window offset product (CONTRACTS §2) from quiet 1-min samples."""
    from magcal.offsets import OffsetEstimator, write_offsets_csv

    cfg = config["offsets"]
    est = OffsetEstimator(kp_max=cfg["kp_max"], window_days=cfg["window_days"],
                          step_days=cfg["step_days"], min_used=cfg["min_used"],
                          method=cfg["method"],
                          split_at_level_changes=cfg["split_at_level_changes"])
    prov = make_provenance("offsets", {"offsets": cfg, "model": config["model"]["name"]},
                           wall_clock=False)
    est.fit(minute.times, minute.hpen, minute.model, minute.kp, lon_deg=minute.lon_deg,
            provenance=prov)
    table = est.table_
    valid = np.isfinite(table.offset_nT).all(axis=1)
    summary = {"n_windows": int(len(valid)), "n_valid": int(valid.sum()),
               "n_quiet": est.n_quiet_, "span_days": est.span_days_,
               "offsets_nT": {c: table.offset_nT[:, k].tolist() for k, c in enumerate(HPEN)},
               "reasons": [r for r in table.reason if r],
               "level_changes": [c.to_dict() for c in table.level_changes]}
    lines = [f"{int(valid.sum())}/{len(valid)} valid {cfg['window_days']:g}-day windows "
             f"({est.n_quiet_} quiet samples at Kp <= {cfg['kp_max']:g})"]
    if valid.any():
        med = np.nanmedian(table.offset_nT[valid], axis=0)
        lines.append("median offset " + ", ".join(f"{c} {v:+.2f}" for c, v in zip(HPEN, med))
                     + " nT")
    warnings = list(est.warnings_)
    if not valid.any():
        first = next((r for r in table.reason if r), "no quiet samples")
        warnings.append(f"no valid offset window: {first}")
    product = StageProduct(stage="offsets", summary=summary, lines=tuple(lines),
                           writers={"OFFSETS.csv": lambda p: write_offsets_csv(p, table)},
                           provenance=prov, warnings=tuple(warnings))
    return table, product


@dataclass(frozen=True)
class CorrectedData:
    """Offset-corrected Hpen at the 1-min cadence (for alignment and discovery) and at
    the input cadence."""

    times: np.ndarray
    hpen: np.ndarray
    flag: np.ndarray
    full_times: np.ndarray
    full_hpen: np.ndarray


def _reference(minute: MinuteData, config: ChainConfig):
    ref = config["alignment"]["reference"]
    if ref == "model":
        return minute.model, []
    from magcal.io.formats import read_any

    path = config.resolve(ref)
    frame = read_any(path, required=HPEN)
    out = frame[list(HPEN)].reindex(_index(minute.times)).to_numpy(dtype=float)
    return out, [path]


def _at_input_cadence(corrected: CorrectedData, minute: MinuteData, ref: np.ndarray):
    """Corrected data at the input cadence with the reference, Kp and longitude
    interpolated from the 1-min grid (the model field is smooth on that scale)."""
    t = corrected.full_times.astype(np.int64)
    tm = minute.times.astype("datetime64[ns]").astype(np.int64)
    ok = np.isfinite(ref).all(axis=1)
    ref_full = np.column_stack([np.interp(t, tm[ok], ref[ok, k], left=np.nan, right=np.nan)
                                for k in range(3)]) if ok.sum() > 1 else np.full((len(t), 3),
                                                                                 np.nan)
    k = np.clip(np.searchsorted(tm, t), 0, len(tm) - 1)
    return (corrected.full_times, corrected.full_hpen, ref_full, minute.kp[k],
            minute.lon_deg[k])


def run_alignment(corrected: CorrectedData, minute: MinuteData, config: ChainConfig):
    """Rotation angles about Hp, He, Hn against the model or a reference spacecraft.

    Fitted on the 1-min averages, or at the input cadence with ``[alignment]
    cadence_s = 0`` (records of minutes).
    """
    from magcal.alignment.product import AlignSettings, align_product
    from magcal.offsets import quiet_mask

    cfg = config["alignment"]
    ref, ref_files = _reference(minute, config)
    times, data, kp, lon = corrected.times, corrected.hpen, minute.kp, minute.lon_deg
    if cfg["cadence_s"] == 0:
        times, data, ref, kp, lon = _at_input_cadence(corrected, minute, ref)
    elif cfg["cadence_s"] != config["offsets"]["cadence_s"]:
        raise InputError("[alignment] cadence_s must be 0 (input cadence) or the offsets "
                         f"cadence ({config['offsets']['cadence_s']:g} s)", file=config.path)
    quiet, selection = None, {"kp_max": None}
    if np.isfinite(kp).any():
        quiet = quiet_mask(kp, cfg["kp_max"])
        selection = {"kp_max": cfg["kp_max"], "used_rows": int(quiet.sum()),
                     "quiet_fraction": float(quiet.mean())}
    window = cfg["window_days"]
    settings = AlignSettings(mcmc=cfg["mcmc"], seed=cfg["seed"],
                             lt_harmonics=cfg["lt_harmonics"],
                             window_days=None if window == 0 else window,
                             noise_model=cfg["noise_model"])
    product = align_product(times, data, ref, lon_deg=lon,
                            lon_source="[position]", quiet=quiet, selection=selection,
                            settings=settings, rng=np.random.default_rng(cfg["seed"]),
                            inputs=ref_files)
    product = replace(product, provenance=without_wall_clock(product.provenance))
    doc = product.to_json()
    warnings = []
    if doc.get("determinable") is False:
        warnings.append(f"alignment not determinable: {doc.get('reason', '')}")
    ang, std = doc.get("angles_deg") or {}, doc.get("std_deg") or {}
    if doc.get("determinable") is False or not ang:
        line = f"angles not determinable: {doc.get('reason', 'see ALIGN.json')}"
    else:
        line = "angles " + ", ".join(f"{c} {ang[c]:+.3f} +- {std[c]:.3f}" for c in HPEN) + " deg"
    return doc, StageProduct(stage="alignment", summary={"determinable":
                                                         doc.get("determinable", True)},
                             lines=(line,), writers={"ALIGN.json": product.write},
                             provenance=doc.get("provenance", {}), warnings=tuple(warnings))


#: Most samples discovery is given. Its memory and time grow with the samples (about
#: 6.5 kB and 0.23 ms per 1-min sample: a year of 1-min data took 3 GB in the driver),
#: so a longer record is averaged to the shortest of :data:`DISCOVERY_INTERVALS_S`
#: that keeps it under this many samples. The effects it names (offsets, drifts,
#: steps, local-time harmonics, rotations, activity) live on hours to months.
DISCOVERY_MAX_SAMPLES = 50_000
#: Averaging intervals discovery may use (s), shortest first; longer records use
#: whole multiples of a day's divisors in hours.
DISCOVERY_INTERVALS_S = (60, 120, 300, 600, 900, 1800, 3600, 7200, 10800, 21600, 43200, 86400)


def discovery_interval(minute: MinuteData, cadence_s: float) -> float:
    """Averaging interval (s) that keeps :data:`DISCOVERY_MAX_SAMPLES` or fewer samples.

    The record's span (first to last sample plus one cadence) divided by the interval
    bounds the number of means; the interval is never shorter than ``cadence_s`` (the
    record is then used as it is).

    Examples
    --------
    >>> t = np.datetime64("2019-01-01", "ns") + np.arange(335 * 1440) * np.timedelta64(60, "s")
    >>> m = MinuteData(t, *(np.zeros((len(t), 3)),) * 2, *(np.zeros(len(t)),) * 4)
    >>> discovery_interval(m, 60.0), discovery_interval(replace(m, times=t[:91 * 1440]), 60.0)
    (600.0, 300.0)
    """
    t = np.asarray(minute.times, dtype="datetime64[ns]").astype(np.int64)
    span_s = (t[-1] - t[0]) / 1e9 + cadence_s if len(t) else 0.0
    for interval in DISCOVERY_INTERVALS_S:
        if interval >= cadence_s and span_s / interval <= DISCOVERY_MAX_SAMPLES:
            return float(max(interval, cadence_s))
    return float(max(DISCOVERY_INTERVALS_S[-1], cadence_s))


def mean_record(minute: MinuteData, interval_s: float, cadence_s: float) -> MinuteData:
    """Means of ``minute`` over UTC-aligned bins of ``interval_s`` (labelled at their
    centres), from the samples with both data and model; a bin needs half of its
    samples. ``interval_s <= cadence_s`` returns ``minute`` itself.

    Kp and the position are averaged over the same samples (NaN stays NaN only where a
    bin has no finite value).
    """
    if interval_s <= cadence_s:
        return minute
    t = np.asarray(minute.times, dtype="datetime64[ns]").astype(np.int64)
    step = int(round(interval_s * 1e9))
    ok = np.isfinite(minute.hpen).all(axis=1) & np.isfinite(minute.model).all(axis=1)
    bins, inverse = np.unique(t[ok] // step, return_inverse=True)
    keep = np.bincount(inverse, minlength=len(bins)) >= 0.5 * interval_s / cadence_s

    def means(values):
        v = np.asarray(values, dtype=float)[ok].reshape(int(ok.sum()), -1)
        finite = np.isfinite(v)
        sums = np.column_stack([np.bincount(inverse, np.where(finite[:, k], v[:, k], 0.0),
                                            len(bins)) for k in range(v.shape[1])])
        counts = np.column_stack([np.bincount(inverse, finite[:, k], len(bins))
                                  for k in range(v.shape[1])])
        with np.errstate(invalid="ignore", divide="ignore"):
            out = np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)[keep]
        return out if np.ndim(values) == 2 else out[:, 0]

    times = (bins[keep] * step + step // 2).astype("datetime64[ns]")
    return MinuteData(times, means(minute.hpen), means(minute.model), means(minute.kp),
                      means(minute.lon_deg), means(minute.lat_deg), means(minute.r_re))


def _covariate_holes(raw: pd.DataFrame, index: pd.DatetimeIndex, path) -> list[str]:
    """Warnings naming the holes of each covariate column of a file over the record's
    span (a jump of more than :data:`~magcal.discover.inputs.HOLE_SPACINGS` of its own
    median spacing, or a missing start or end): discovery leaves out the samples there,
    or does not use a covariate that covers fewer than half of them
    (:func:`magcal.discover.inputs.prepare_covariates`), and a user should know where."""
    from magcal.discover.inputs import HOLE_SPACINGS

    out = []
    t0, t1 = index.as_unit("ns")[0], index.as_unit("ns")[-1]
    for c in raw.columns:
        v = pd.to_numeric(raw[c], errors="coerce")
        tv = v.index[np.isfinite(v.to_numpy(dtype=float))].as_unit("ns")
        if tv.size < 2:
            out.append(f"{path}: column {c} has fewer than 2 values; not used")
            continue
        step = np.median(np.diff(tv.asi8))
        edges = np.concatenate([[t0.value], tv.asi8, [t1.value]])  # ns
        edges = np.clip(edges, t0.value, t1.value)
        jumps = np.flatnonzero(np.diff(edges) > HOLE_SPACINGS * step)
        if jumps.size:
            k = jumps[np.argmax(np.diff(edges)[jumps])]
            a, b = pd.Timestamp(edges[k]), pd.Timestamp(edges[k + 1])
            out.append(f"{path}: {jumps.size} hole(s) in {c} within the record, the longest "
                       f"{(b - a).total_seconds() / 3600:.1f} h from {a:%Y-%m-%dT%H:%M} to "
                       f"{b:%Y-%m-%dT%H:%M}; discovery does not bridge them (REPORT.json "
                       "'covariates' and 'screened')")
    return out


def discovery_warnings(result) -> list[str]:
    """What the discovery left aside, as warning lines: its covariates' sentences
    (:func:`magcal.discover.account.covariate_lines`) and the bad samples left out."""
    from magcal.discover.account import covariate_lines

    out = covariate_lines(result)
    if result.screened.get("samples"):
        out.append(f"left out {result.screened['samples']} bad sample(s) "
                   f"({result.screened.get('by_test')})")
    return out


def read_covariate_file(path) -> pd.DataFrame:
    """Read ``[discover] covariates``, refusing a file discovery could not use.

    The chain calls it before the partitions run, so that a file with no data row or
    no covariate column (a ``Dst`` header where ``dst`` is expected) is a bad
    configuration (exit status 2, naming the key) instead of a discovery stage that
    fails (exit status 3) after the whole archive was processed.

    Parameters
    ----------
    path : path-like
        The covariate file (any format :func:`magcal.io.formats.read_any` reads).

    Returns
    -------
    pandas.DataFrame
        The file's columns at its own times.

    Raises
    ------
    InputError
        Unreadable, no data row, or none of
        :data:`magcal.discover.inputs.COVARIATES` among its columns.
    """
    from magcal.discover.inputs import COVARIATES
    from magcal.io.formats import read_any

    try:
        raw = read_any(path)
    except InputError as exc:
        raise InputError(f"[discover] covariates: {exc}", file=path,
                         column="discover.covariates") from exc
    if not set(COVARIATES) & set(raw.columns):
        raise InputError("[discover] covariates: no covariate column (expected any of "
                         f"{', '.join(COVARIATES)}; the file has "
                         f"{', '.join(map(str, raw.columns))})", file=path,
                         column="discover.covariates")
    return raw


def run_discovery(minute: MinuteData, config: ChainConfig):
    """Model-gap discovery on the cleaned data against the model (CONTRACTS §5).

    It runs on the 1-min record when that has at most :data:`DISCOVERY_MAX_SAMPLES`
    samples, else on its means over the interval :func:`discovery_interval` picks
    (10 min for a year); ``REPORT.json``'s provenance names the interval and the number
    of samples used.
    """
    from magcal.discover.loop import discover_gap

    cfg = config["discover"]
    cadence = float(config["offsets"]["cadence_s"])
    interval = discovery_interval(minute, cadence)
    minute = mean_record(minute, interval, cadence)
    index = _index(minute.times)
    measured = pd.DataFrame(minute.hpen, index=index, columns=list(HPEN))
    model = pd.DataFrame(minute.model, index=index, columns=list(HPEN))
    ok = np.isfinite(minute.hpen).all(axis=1) & np.isfinite(minute.model).all(axis=1)
    if ok.sum() < 60:
        raise InputError(f"only {int(ok.sum())} samples with data and model for discovery "
                         "(need 60)", file=config.path)
    cov_path = config.resolve(cfg["covariates"])
    covariates = pd.DataFrame({"kp": minute.kp, "lon_deg": minute.lon_deg}, index=index)[ok]
    inputs, warnings = [], []
    if cov_path is not None:
        raw_cov = read_covariate_file(cov_path)
        # the file's columns at their own times (their union with the record's): the
        # discovery interpolates each over its own spacing and knows its holes; taken
        # to the nearest record sample, an hourly Dst was a value every hour with holes
        # between
        extra = raw_cov.rename(columns={c: f"{c}_file" for c in raw_cov.columns
                                        if c in covariates.columns})
        covariates = pd.concat([covariates, extra], axis=1).sort_index()
        covariates.attrs["source"] = [str(cov_path)]
        inputs.append(cov_path)
        warnings += _covariate_holes(raw_cov, index[ok], cov_path)
    result = discover_gap(measured[ok], model[ok], covariates=covariates,
                          longitude_deg=float(np.nanmedian(minute.lon_deg)),
                          max_effects=cfg["max_effects"])
    warnings += discovery_warnings(result)
    sampling = {"interval_s": interval, "n_samples": int(ok.sum()),
                "max_samples": DISCOVERY_MAX_SAMPLES,
                "rule": f"means over the shortest interval of {list(DISCOVERY_INTERVALS_S)} s "
                        f"(not below the {cadence:g} s cadence) that gives at most "
                        f"{DISCOVERY_MAX_SAMPLES} samples"}
    prov = make_provenance("discover", {"discover": cfg, "sampling": sampling},
                           inputs=inputs, wall_clock=False)
    doc = result.with_provenance(prov).to_json()
    lines = [f"on {int(ok.sum())} samples at {interval:g} s: gap rms "
             f"{doc['gap_initial']['rms_nT']:.2f} -> {doc['gap_final']['rms_nT']:.2f} "
             f"nT; stopped because {doc['stopped_because']}"]
    lines += [f"+ {e['name']} ({', '.join(e['components'])}): {e['rms_before_nT']:.2f} -> "
              f"{e['rms_after_nT']:.2f} nT" for e in doc["effects"]]
    return doc, StageProduct(stage="discover", summary={"effects": [e["name"] for e in
                                                                      doc["effects"]]},
                             lines=tuple(lines), documents={"REPORT.json": doc},
                             provenance=prov, warnings=tuple(warnings))
