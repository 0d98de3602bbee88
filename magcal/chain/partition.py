"""One partition of an archive run: one input file from raw sensors to 1-min model data.

A partition task reads one file, rotates its sensors into the common frame with the
matrices of the fit phase, applies the PiCoG upload matrices, rotates to Hpen, averages
to the offsets cadence and evaluates the model there (in-process: no pool inside a
task). Its result is written atomically to ``OUTDIR/.partitions/<stem>-<key>.npz``: the
key names the file's SHA-256, the configuration that shapes the result and the fit
artefact, so a rerun finds finished partitions by name and skips them.

Task functions take and return plain picklable values and never raise: a corrupt day
fails only its own partition, with the reason in the returned record.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from magcal.chain.config import ChainConfig
from magcal.errors import InputError
from magcal.io.atomic import atomic_path
from magcal.io.jsonio import to_jsonable

#: Folder of OUTDIR holding partition results and stage markers (not products).
STATE_DIR = ".partitions"

#: Arrays of a partition file: full-cadence (``t_full``...) and offsets-cadence (``t_min``...).
FULL_ARRAYS = ("t_full", "hpen_full", "raw_full", "quality_full")
MINUTE_ARRAYS = ("t_min", "hpen_min", "model_min", "kp", "lon_deg", "lat_deg", "r_re")


def digest(obj) -> str:
    """SHA-256 of the canonical JSON of ``obj`` (keys sorted): a key of cached work."""
    text = json.dumps(to_jsonable(obj), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


@dataclass(frozen=True)
class FrameApply:
    """What a partition needs of the fit phase: frames, PiCoG upload, Hpen rotation.

    Attributes
    ----------
    key : str
        The fit artefact key (SHA-256 of its files and configuration).
    sensors : tuple of str
    target : str
    transforms : dict
        ``sensor -> (matrix (3, 3), offset_nT (3,))`` into the common frame.
    to_hpen : ndarray, shape (3, 3)
    upload : dict or None
        ``{"M": {sensor: 3x3}, "G": [3]}`` applied with G added back, or None when
        the raw target is delivered (no plan, one sensor, or cleaning worse than raw).
    """

    key: str
    sensors: tuple
    target: str
    transforms: dict
    to_hpen: np.ndarray
    upload: dict | None = None


@dataclass(frozen=True)
class PartitionTask:
    """One input file to process (all fields picklable for Dask workers)."""

    config: ChainConfig
    file: str
    sha256: str
    key: str
    result: str
    fit: FrameApply
    #: The Kp series and driver table (:func:`magcal.chain.archive.read_index_tables`),
    #: read once by the driver instead of once per partition; None: read them here.
    tables: dict | None = None
    #: The file as the fit phase read it (``read_any``), or None: read it here.
    frame: object = None


def run_partition(task: PartitionTask) -> dict:
    """Process one partition; return its record (``status`` ok or failed, ``reason``).

    Never raises: any error of this file is reported in the record so the other
    partitions complete.
    """
    from magcal.offline import configure_offline

    configure_offline()
    base = {"file": task.file, "sha256": task.sha256, "key": task.key, "result": task.result}
    try:
        return {**base, "status": "ok", **_process(task)}
    except InputError as exc:
        return {**base, "status": "failed", "reason": str(exc)}
    except Exception as exc:  # noqa: BLE001 - one bad file must not stop the archive
        return {**base, "status": "failed", "reason": f"{type(exc).__name__}: {exc}"}


def _process(task: PartitionTask) -> dict:
    import warnings

    from magcal.chain.archive import index_digest, read_index_tables
    from magcal.chain.prepare import (
        CleanedData,
        apply_frame,
        load_series,
        naive_times,
        quality_control,
        run_model,
        series_from_frames,
    )
    from magcal.qc.flags import EXCLUDE, IMPLAUSIBLE
    from magcal.qc.flags import counts as flag_counts

    cfg = task.config
    fit = task.fit
    tables = task.tables if task.tables is not None else read_index_tables(cfg)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        series = (load_series(cfg, [Path(task.file)]) if task.frame is None else
                  series_from_frames(cfg, [Path(task.file)], [task.frame]))
        _check_sensors(series, fit, task.file)
        qc = quality_control(series, cfg)
        vectors = {s: apply_frame(series[s], fit.transforms[s]) for s in fit.sensors}
        raw = vectors[fit.target]
        cleaned = raw
        if fit.upload is not None:
            from magcal.ac.estimator import apply_upload

            common = series.with_vectors(vectors, "to common frame", components=("x", "y", "z"))
            out = apply_upload(common.select(fit.sensors).to_frame(), fit.upload["M"],
                               fit.upload["G"], pure_ac=True)
            cleaned = out[["x", "y", "z"]].to_numpy(dtype=float)
        to_hpen = np.asarray(fit.to_hpen, dtype=float)
        data = CleanedData(series.times, cleaned @ to_hpen.T, raw @ to_hpen.T)
        one_job = replace(cfg, sections={**cfg.sections, "model": {**cfg["model"], "jobs": 1}})
        flags = qc.flags
        # the averages and the model see only the samples QC keeps; the product keeps all
        minute, product = run_model(series, _masked(data, flags), one_job, tables)
        implausible = _implausible(data, minute, cfg)
        if (implausible & ~((flags & EXCLUDE) != 0)).any():
            flags = flags | np.where(implausible, IMPLAUSIBLE, 0).astype(np.uint16)
            minute, product = run_model(series, _masked(data, flags), one_job, tables)
    arrays = {"t_full": naive_times(series.times).astype(np.int64),
              "hpen_full": data.hpen, "raw_full": data.raw_hpen, "quality_full": flags,
              "t_min": minute.times.astype("datetime64[ns]").astype(np.int64),
              "hpen_min": minute.hpen, "model_min": minute.model, "kp": minute.kp,
              "lon_deg": minute.lon_deg, "lat_deg": minute.lat_deg, "r_re": minute.r_re}
    t = series.times
    days = sorted({str(d.date()) for d in t.floor("D").unique()})
    read_step = series.provenance[0] if series.provenance else {}
    meta = {"n_samples": len(series), "cadence_s": float(series.cadence_s),
            "sensors": [s for s in series.sensors if s], "start": str(t[0]),
            "end": str(t[-1]), "days": days, "n_minutes": len(minute.times),
            "n_model_invalid": int(product.summary.get("n_invalid", 0)),
            "n_no_kp": int(np.count_nonzero(~np.isfinite(minute.kp))),
            "warnings": list(product.warnings),
            "qc": {"n_flagged": int(np.count_nonzero(flags & EXCLUDE)),
                   "counts": flag_counts(flags), "by_sensor": qc.by_sensor},
            "repairs": [r for r in read_step.get("repairs", []) if r.get("count")],
            "format": ",".join(read_step.get("formats", [])),
            # the Kp and driver records this partition used (a rerun compares them)
            "index_digest": index_digest(tables, str(t[0]), str(t[-1]))}
    write_partition(Path(task.result), arrays, meta)
    return meta


def _check_sensors(series, fit: FrameApply, file: str) -> None:
    """A file without every sensor the fit used fails its partition with a reason that
    names what it has (not a KeyError from deep inside)."""
    missing = [s for s in fit.sensors if s not in series.sensors]
    if missing:
        raise InputError(f"has no sensor {', '.join(missing)} (it has "
                         f"{', '.join(s for s in series.sensors if s) or 'none'}); the "
                         f"archive's fit used {', '.join(fit.sensors)}", file=file)


def _masked(data, flags):
    """``data`` with the samples QC excludes set to NaN."""
    from magcal.chain.prepare import CleanedData
    from magcal.qc import masked

    return CleanedData(data.times, masked(data.hpen, flags), masked(data.raw_hpen, flags))


def _implausible(data, minute, cfg: ChainConfig) -> np.ndarray:
    """Full-cadence samples whose raw magnitude is implausible against the model field
    (interpolated from the offsets cadence, held beyond its first and last time)."""
    from magcal.chain.prepare import naive_times
    from magcal.qc import QCSettings, plausibility_flags

    t = naive_times(data.times).astype(np.int64)
    tm = minute.times.astype("datetime64[ns]").astype(np.int64)
    ok = np.isfinite(minute.model).all(axis=1)
    if not ok.any():
        return np.zeros(len(t), dtype=bool)
    model = np.column_stack([np.interp(t, tm[ok], minute.model[ok, k]) for k in range(3)])
    return plausibility_flags(data.raw_hpen, model, QCSettings.from_mapping(cfg["qc"])) != 0


def write_partition(path: Path, arrays: dict, meta: dict) -> Path:
    """Write a partition result atomically (``.npz`` with its record as JSON)."""
    with atomic_path(path) as tmp, open(tmp, "wb") as handle:
        np.savez(handle, meta=np.array(json.dumps(meta)), **arrays)
    return path


def read_partition_meta(path: Path) -> dict:
    """The record of a finished partition."""
    with np.load(path) as z:
        return json.loads(str(z["meta"]))


def read_partition_arrays(path: Path, names) -> dict:
    """The named arrays of a finished partition (times as ``datetime64[ns]``)."""
    out = {}
    with np.load(path) as z:
        for name in names:
            value = z[name]
            out[name] = value.astype("datetime64[ns]") if name.startswith("t_") else value
    return out
