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
from magcal.chain.prepare import HPEN, CleanedData, MinuteData, naive_times
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
                          method=cfg["method"])
    prov = without_wall_clock(make_provenance("offsets", {"offsets": cfg,
                                                          "model": config["model"]["name"]}))
    est.fit(minute.times, minute.hpen, minute.model, minute.kp, lon_deg=minute.lon_deg,
            provenance=prov)
    table = est.table_
    valid = np.isfinite(table.offset_nT).all(axis=1)
    summary = {"n_windows": int(len(valid)), "n_valid": int(valid.sum()),
               "n_quiet": est.n_quiet_, "span_days": est.span_days_,
               "offsets_nT": {c: table.offset_nT[:, k].tolist() for k, c in enumerate(HPEN)},
               "reasons": [r for r in table.reason if r]}
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


def run_corrected(cleaned: CleanedData, minute: MinuteData, table, config: ChainConfig):
    """Subtract the interpolated offsets; one ``corrected/CORRECTED_<day>.csv`` per UTC day.

    When no window is valid, the data are written uncorrected with ``offset_flag = 3``
    (no valid offset) so the files still cover the input's times.
    """
    from magcal.offsets import FLAG_MEANING, apply_offsets

    t_all = naive_times(cleaned.times)
    valid = np.isfinite(table.offset_nT).all(axis=1).any()
    if valid:
        corr, _, flag = apply_offsets(t_all, cleaned.hpen, table)
        corr_min, _, flag_min = apply_offsets(minute.times, minute.hpen, table)
    else:
        corr, flag = cleaned.hpen.copy(), np.full(len(t_all), 3, dtype=np.int8)
        corr_min, flag_min = minute.hpen.copy(), np.full(len(minute.times), 3, dtype=np.int8)
    frame = pd.DataFrame(corr, index=cleaned.times, columns=list(HPEN))
    frame["offset_flag"] = np.asarray(flag, dtype=int)
    days = frame.index.floor("D")
    tables = {f"CORRECTED_{day:%Y%m%d}.csv": part for day, part in frame.groupby(days)}
    counts = np.bincount(np.asarray(flag, dtype=int), minlength=4)
    summary = {"n_samples": int(len(frame)), "n_files": len(tables),
               "flags": {FLAG_MEANING[k]: int(counts[k]) for k in range(4)}}
    lines = (f"{len(frame)} samples in {len(tables)} daily files; interpolated {counts[0]}, "
             f"held {counts[1] + counts[2]}, no offset {counts[3]}",)
    warnings = ("no valid offset: corrected files hold the uncorrected data (offset_flag 3)",
                ) if not valid else ()
    prov = make_provenance("offsets apply", {"flag_meaning": FLAG_MEANING})
    product = StageProduct(stage="corrected", summary=summary, lines=lines, tables=tables,
                           provenance=prov, warnings=warnings)
    return CorrectedData(minute.times, corr_min, np.asarray(flag_min), t_all, corr), product


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
                             window_days=None if window == 0 else window)
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


def run_discovery(minute: MinuteData, config: ChainConfig):
    """Model-gap discovery on the cleaned 1-min data against the model (CONTRACTS §5)."""
    from magcal.discover.loop import discover_gap
    from magcal.io.formats import read_any

    cfg = config["discover"]
    index = _index(minute.times)
    measured = pd.DataFrame(minute.hpen, index=index, columns=list(HPEN))
    model = pd.DataFrame(minute.model, index=index, columns=list(HPEN))
    ok = np.isfinite(minute.hpen).all(axis=1) & np.isfinite(minute.model).all(axis=1)
    if ok.sum() < 60:
        raise InputError(f"only {int(ok.sum())} samples with data and model for discovery "
                         "(need 60)", file=config.path)
    cov_path = config.resolve(cfg["covariates"])
    covariates = pd.DataFrame({"kp": minute.kp, "lon_deg": minute.lon_deg}, index=index)
    inputs = []
    if cov_path is not None:
        extra = read_any(cov_path)
        covariates = covariates.join(extra.reindex(index, method="nearest",
                                                   tolerance=pd.Timedelta("90s")),
                                     rsuffix="_file")
        inputs.append(cov_path)
    result = discover_gap(measured[ok], model[ok], covariates=covariates[ok],
                          longitude_deg=float(np.nanmedian(minute.lon_deg)),
                          max_effects=cfg["max_effects"])
    prov = without_wall_clock(make_provenance("discover", {"discover": cfg}, inputs=inputs))
    doc = result.with_provenance(prov).to_json()
    lines = [f"gap rms {doc['gap_initial']['rms_nT']:.2f} -> {doc['gap_final']['rms_nT']:.2f} "
             f"nT; stopped because {doc['stopped_because']}"]
    lines += [f"+ {e['name']} ({', '.join(e['components'])}): {e['rms_before_nT']:.2f} -> "
              f"{e['rms_after_nT']:.2f} nT" for e in doc["effects"]]
    return doc, StageProduct(stage="discover", summary={"effects": [e["name"] for e in
                                                                      doc["effects"]]},
                             lines=tuple(lines), documents={"REPORT.json": doc},
                             provenance=prov)
