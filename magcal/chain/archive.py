"""The geostationary chain over an archive: partitioned by input file, run on Dask.

Phases of :func:`archive_stages` (driven by :func:`magcal.chain.runner.run_chain`):

1. **fit**: frames and PiCoG on the first ``[picog] fit_days`` days of data, at most
   ``[picog] fit_max_samples`` samples (the upload matrices are constant, they are the
   product), as a task on a worker while the other workers read the next files ahead;
   the files are read once, on the workers, and the frames read here go to their
   partitions; the result is cached as ``.partitions/fit-<key>.json``, the key being
   the SHA-256 of the files used and of the configuration;
2. **partitions**: one task per input file (:mod:`magcal.chain.partition`): common
   frame, PiCoG, Hpen, 1-min averages and model field, written atomically to
   ``.partitions/<stem>-<key>.npz``; a file whose key is unchanged and whose Kp and
   driver records (around its own times) are unchanged is skipped;
3. **offsets** on the concatenated 1-min results (one task: medians of a year of 1-min
   samples take well under a second, less than shipping the data to workers); windows
   touching a failed partition name it in their ``reason``; ``OFFSETS.csv`` is replaced
   atomically, the previous version kept in ``offsets/previous/``;
4. **corrected**: one task per UTC day, the interpolated offsets applied to the stored
   full-cadence Hpen; a day is rewritten only when its partitions or the offset windows
   its interpolation uses changed;
5. **alignment and discovery** on the 1-min record, each one task on a worker
   (:class:`MinuteTask`) started as soon as its inputs exist, so it runs while the
   driver writes the model tables and the offsets and the other worker writes the
   corrected days; discovery is given means of the record when it is long
   (:func:`magcal.chain.calibrate.discovery_interval`);
6. **truth, report** in the driver. Every stage is skipped when its inputs are unchanged.

Only a few partitions' full-cadence data are in memory at once (one per worker, plus
the partitions of one day in the corrected stage); the driver holds the 1-min record,
and so does a worker running the alignment or discovery.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pandas as pd

from magcal.chain.config import ChainConfig
from magcal.chain.partition import (
    FULL_ARRAYS,
    GAP_SAMPLES,
    MINUTE_ARRAYS,
    STATE_DIR,
    FrameApply,
    PartitionTask,
    digest,
    read_partition_arrays,
    read_partition_meta,
    run_partition,
)
from magcal.chain.prepare import HPEN, CleanedData, MinuteData
from magcal.chain.product import StageProduct, without_wall_clock
from magcal.errors import InputError
from magcal.io.atomic import atomic_path
from magcal.io.jsonio import to_jsonable
from magcal.provenance import make_provenance

_DAY_NS = 86_400 * 10**9


@dataclass(frozen=True)
class PartitionSummary:
    """What the partition phase did: files done, skipped (unchanged) and failed."""

    done: tuple = ()
    skipped: tuple = ()
    failed: tuple = ()  # ({"partition", "stage", "reason"}, ...)
    seconds: float = 0.0
    samples: int = 0

    def text(self) -> str:
        out = [f"partitions: {len(self.done)} done, {len(self.skipped)} skipped (unchanged), "
               f"{len(self.failed)} failed in {self.seconds:.1f} s"]
        out += [f"    failed {f['partition']}: {f['reason']}" for f in self.failed]
        return "\n".join(out)


def hash_inputs(files: list[Path]) -> list[str]:
    """SHA-256 of every input file, in the driver on one thread per core (a task per
    file on the workers would cost a rerun, which needs no worker, their start-up)."""
    from magcal.provenance import files_sha256

    return files_sha256(files)


def import_later_libraries() -> None:
    """Import what the driver's later stages use (SciPy's stats package for the offsets
    alone takes 1.5 s): started in a driver thread when the partitions start, it runs
    while the workers work instead of in the offsets stage."""
    import magcal.offsets  # noqa: F401


# ------------------------------------------------------------------------------ fit
def _config_part(cfg: ChainConfig) -> dict:
    """The configuration a partition's result depends on. The Kp and driver files are
    not in it: a partition depends only on their records around its own times
    (:func:`index_digest`), so appending a month to the Kp file leaves earlier
    partitions valid."""
    from magcal._version import __version__

    model = {k: v for k, v in cfg["model"].items() if k not in ("jobs", "cache_dir")}
    inp = {k: v for k, v in cfg["input"].items() if k not in ("files", "simulate")}
    return {"version": __version__, "input": inp, "position": cfg["position"],
            "model": model, "cadence_s": cfg["offsets"]["cadence_s"], "qc": cfg["qc"]}


def read_index_tables(cfg: ChainConfig) -> dict:
    """The Kp series and the driver table of the configuration (None when not given)."""
    from magcal.indices import read_drivers, read_kp

    out = {}
    for name, rel, reader in (("kp", cfg["kp"]["file"], read_kp),
                              ("drivers", cfg["model"]["drivers"], read_drivers)):
        path = cfg.resolve(rel)
        out[name] = reader(path) if path is not None and path.is_file() else None
    return out


def index_digest(tables: dict, start: str, end: str, margin_h: float = 3.0) -> str:
    """SHA-256 of the Kp and driver records a partition from ``start`` to ``end`` uses.

    Kp is a 3-hour step function: the records from ``margin_h`` hours before ``start``
    to ``end``; drivers are interpolated across gaps of at most 3 hours: the records
    within ``margin_h`` hours on both sides.
    """
    parts = {}
    for name, table in sorted(tables.items()):
        if table is None:
            parts[name] = None
            continue
        lo = pd.Timestamp(start) - pd.Timedelta(hours=margin_h)
        hi = pd.Timestamp(end) + (pd.Timedelta(0) if name == "kp"
                                  else pd.Timedelta(hours=margin_h))
        rows = table[(table.index >= lo) & (table.index <= hi)]
        frame = rows.to_frame() if isinstance(rows, pd.Series) else rows
        parts[name] = {"t": rows.index.as_unit("ns").asi8.tolist(),
                       "v": frame.to_numpy(dtype=float).tolist(),
                       "c": [str(c) for c in frame.columns]}
    return digest(parts)[:24]


def read_file(job) -> dict:
    """One file read on a worker, ``job = (path, format)``: ``{"span": [first, last,
    samples],
    "frame": the read_any frame}`` or ``{"error": reason}`` (a task: it never raises).
    The fit phase takes the spans of the first files and the frames of those it fits on
    from one read."""
    from magcal.io.formats import read_any

    path, fmt = job
    try:
        frame = read_any(path, fmt)
        if len(frame.index) == 0:
            raise InputError("no samples", file=path)
    except InputError as exc:
        return {"error": str(exc)}
    return {"span": [str(frame.index[0]), str(frame.index[-1]), len(frame)], "frame": frame}


def _fit_files(cfg: ChainConfig, files, shas, state: Path, engine):
    """The readable files starting within ``fit_days`` of the first readable one (as
    many as keep the samples within ``[picog] fit_max_samples``, at least one), the
    frames of the files read here (``{path: frame}``: those and the few after them
    read to find where the fit days end, which their partitions take) and whether the
    sample limit ended the fit files before ``fit_days``.

    The files whose spans are not yet known are read on the workers, as many files at a
    time as there are workers; their spans are cached in ``state/spans.json`` by
    checksum, so a rerun finds the fit files (and the cached fit) without reading.
    """
    spans_path = state / "spans.json"
    spans = json.loads(spans_path.read_text()) if spans_path.is_file() else {}
    chosen, first, errors, frames = [], None, [], {}
    limit = pd.Timedelta(days=float(cfg["picog"]["fit_days"]))
    cap, samples, capped = cfg["picog"]["fit_max_samples"], 0, False
    pairs = list(zip(files, shas))
    done = False
    for k in range(0, len(pairs), engine.workers):
        batch = pairs[k:k + engine.workers]
        todo = [(path, sha) for path, sha in batch if len(spans.get(sha, ())) < 3]
        jobs = [(str(path), cfg["input"]["format"]) for path, _ in todo]
        for (path, sha), res in zip(todo, engine.map(read_file, jobs, "fit files")):
            if "error" in res:
                errors.append(InputError(res["error"]))
            else:
                spans[sha] = res["span"]
                frames[path] = res["frame"]
        for path, sha in batch:
            if sha not in spans:
                continue
            start = pd.Timestamp(spans[sha][0])
            first = start if first is None else first
            capped = bool(chosen) and samples + spans[sha][2] > cap
            if start - first >= limit or capped:
                done = True
                break
            chosen.append(path)
            samples += spans[sha][2]
        if done:
            break
    with atomic_path(spans_path) as tmp:
        tmp.write_text(json.dumps(spans, sort_keys=True))
    if not chosen:
        raise errors[0] if errors else InputError("no input file", file=cfg.path)
    return chosen, frames, capped


#: Files per worker read ahead while a worker fits (one 1 s day is read in about a
#: second, the fit of 3 such days takes 2-3 s): they are held in the driver until
#: their partitions start, so a few days at most.
READ_AHEAD_ROUNDS = 2


@dataclass(frozen=True)
class FitTask:
    """The fit phase's work for a worker: the fit files' frames (as read) and the key."""

    config: ChainConfig
    files: tuple
    frames: tuple
    key: str
    capped: bool = False  # the sample limit, not fit_days, ended the fit files


def fit_on_worker(task: FitTask) -> dict:
    """Frames and PiCoG on the fit files: the fit artefact as JSON, or ``{"error":
    reason}`` (a task: it never raises). It runs on a worker, whose BLAS uses one
    thread whatever the number of workers (the driver's would use every core and, with
    the workers busy, spin for them), while the other workers read ahead."""
    from magcal.chain import prepare

    cfg = task.config
    try:
        series = prepare.series_from_frames(cfg, list(task.files), list(task.frames))
        qc = prepare.quality_control(series, cfg)
        series = prepare.mask_series(series, qc)  # flagged samples stay out of the fit
        common, frames = prepare.run_frames(series, cfg)
        _, ac = prepare.run_ac(common, cfg)
    except InputError as exc:
        return {"error": str(exc)}
    params = ac.documents.get("PARAMS.json")
    upload = ({"M": params["M"], "G": params["G"]}
              if ac.summary.get("delivered") == "cleaned" else None)
    if upload is not None and ac.summary.get("product") in ("ground", "band_limited"):
        upload["ground"] = params["ground"]   # issue 22: the band-selective product
    fit = FrameApply(key=task.key, sensors=common.sensors, target=common.target,
                     transforms=common.transforms, to_hpen=np.asarray(common.to_hpen),
                     upload=upload)
    names = [str(f) for f in task.files]
    picog = cfg["picog"]
    note = f"fitted on {len(names)} file(s): the first {picog['fit_days']:g} days"
    if task.capped:
        note = (f"fitted on {len(names)} file(s), {len(series)} samples: the first "
                f"of the first {picog['fit_days']:g} days within [picog] fit_max_samples = "
                f"{picog['fit_max_samples']} (the fit's memory grows with its samples)")
    sample = {"fit_files": names, "fit_samples": len(series),
              "fit_samples_flagged": int(qc.excluded.sum()), "fit_qc": qc.counts(),
              "fit_max_samples": picog["fit_max_samples"],
              "fit_capped_by_samples": task.capped}
    if qc.excluded.any():
        note += (f"; quality control left {int(qc.excluded.sum())} of {len(series)} samples "
                 "out of the fit (" + ", ".join(f"{k} {v}" for k, v in qc.counts().items())
                 + ")")
    frames = replace(frames, summary={**frames.summary, "fit_files": names})
    ac = replace(ac, summary={**ac.summary, **sample}, lines=ac.lines + (note,),
                 provenance={**(ac.provenance or {}), "fit_sample": sample})
    return _fit_to_json(fit, frames, ac)


def fit_phase(cfg: ChainConfig, files, shas, state: Path, engine):
    """Frames and PiCoG on the first days: ``(FrameApply, frames product, ac product,
    read)``, ``read`` being the frames of the files read here (``{path: frame}``), which
    their partitions take instead of reading the files again.

    Cached in ``state`` under the SHA-256 of the files used and of the configuration
    of frames, PiCoG and input (not of Kp, model or position, which it does not use).
    """
    from magcal.provenance import file_sha256

    fmt = cfg["input"]["format"]
    fit_files, frames_read, capped = _fit_files(cfg, files, shas, state, engine)
    by_path = dict(zip(files, shas))
    plan = cfg["picog"]["plan"]
    plan_path = cfg.resolve(plan) if plan not in ("auto", "none") else None
    config = _config_part(cfg)
    key = digest({"files": [by_path[f] for f in fit_files], "frames": cfg["frames"],
                  "picog": cfg["picog"], "version": config["version"], "qc": cfg["qc"],
                  "input": config["input"],
                  "plan": file_sha256(plan_path) if plan_path and plan_path.is_file()
                  else None})
    path = state / f"fit-{key[:24]}.json"
    if path.is_file():
        return (*_fit_from_json(json.loads(path.read_text())), frames_read)
    todo = [f for f in fit_files if f not in frames_read]  # spans known from a last run
    for f, res in zip(todo, engine.map(read_file, [(str(f), fmt) for f in todo],
                                       "fit files")):
        if "error" in res:
            raise InputError(res["error"])
        frames_read[f] = res["frame"]
    fitting = engine.submit(fit_on_worker, FitTask(cfg, tuple(fit_files), tuple(
        frames_read[f] for f in fit_files), key, capped))
    # meanwhile the other workers read the next files for their partitions (every
    # partition is redone when the fit is: its key names the fit)
    ahead = [f for f in files if f not in frames_read][:READ_AHEAD_ROUNDS * engine.workers]
    reading = [(f, engine.submit(read_file, (str(f), fmt))) for f in ahead]
    doc = fitting.result()
    if "error" in doc:
        raise InputError(doc["error"])
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(doc, allow_nan=False))
    for f, pending in reading:
        res = pending.result()
        if "frame" in res:  # an unreadable file fails later, in its own partition
            frames_read[f] = res["frame"]
    return (*_fit_from_json(doc), frames_read)  # the objects a rerun restores


def _product_to_json(product: StageProduct) -> dict:
    if product.tables or product.writers:
        raise ValueError(f"stage {product.stage}: only summaries and documents are cached")
    return to_jsonable({"stage": product.stage, "summary": product.summary,
                        "lines": product.lines, "documents": product.documents,
                        "provenance": product.provenance, "warnings": product.warnings})


def _product_from_json(doc: dict) -> StageProduct:
    return StageProduct(stage=doc["stage"], summary=doc["summary"], lines=tuple(doc["lines"]),
                        documents=doc["documents"], provenance=doc["provenance"],
                        warnings=tuple(doc["warnings"]))


def _fit_to_json(fit: FrameApply, frames: StageProduct, ac: StageProduct) -> dict:
    """The fit artefact as plain JSON (never pickled: the cache is read back as input)."""
    return {"fit": to_jsonable({"key": fit.key, "sensors": fit.sensors, "target": fit.target,
                                "transforms": {s: [m, o] for s, (m, o) in
                                               fit.transforms.items()},
                                "to_hpen": fit.to_hpen, "upload": fit.upload}),
            "frames": _product_to_json(frames), "ac": _product_to_json(ac)}


def _fit_from_json(doc: dict):
    f = doc["fit"]
    fit = FrameApply(key=f["key"], sensors=tuple(f["sensors"]), target=f["target"],
                     transforms={s: (np.asarray(m, dtype=float), np.asarray(o, dtype=float))
                                 for s, (m, o) in f["transforms"].items()},
                     to_hpen=np.asarray(f["to_hpen"], dtype=float), upload=f["upload"])
    return fit, _product_from_json(doc["frames"]), _product_from_json(doc["ac"])


# ----------------------------------------------------------------------- partitions
def run_partitions(cfg: ChainConfig, files, shas, fit: FrameApply, state: Path, engine,
                   read: dict | None = None):
    """Process every file whose result is missing; ``(records in time order, failed,
    summary)``. ``read`` holds frames the fit phase read (``{path: frame}``): their
    partitions start from them instead of reading the files again."""
    import time

    from magcal.chain.partition import partition_columns

    start = time.perf_counter()
    part = digest(_config_part(cfg))
    tables = read_index_tables(cfg)
    for path in list(read or {}):  # the driver holds (and ships) only what partitions use
        read[path] = partition_columns(read[path], fit.sensors)
    tasks, skipped, records = [], [], []
    for path, sha in zip(files, shas):
        key = digest({"file": sha, "config": part, "fit": fit.key})[:24]
        result = state / f"{Path(path).stem}-{key}.npz"
        if result.is_file():
            try:
                meta = read_partition_meta(result)
            except (OSError, ValueError, KeyError):
                meta = None  # unreadable leftover: recompute
            if meta is not None and meta.get("index_digest") == index_digest(
                    tables, meta["start"], meta["end"]):
                records.append({"file": str(path), "sha256": sha, "key": key,
                                "result": str(result), "status": "ok", **meta})
                skipped.append(str(path))
                continue
        tasks.append(PartitionTask(config=cfg, file=str(path), sha256=sha, key=key,
                                   result=str(result), fit=fit, tables=tables,
                                   frame=(read or {}).get(path)))
    records += engine.map(run_partition, tasks, "partitions")
    for r in records:  # the key downstream stages see names the index records as well
        if r["status"] == "ok":
            r["key"] = f"{r['key']}:{r['index_digest']}"
    ok = sorted((r for r in records if r["status"] == "ok"), key=lambda r: r["start"])
    failed = tuple({"partition": r["file"], "stage": "partition", "reason": r["reason"]}
                   for r in records if r["status"] != "ok")
    failed += missing_days(ok, failed)
    done = tuple(r["file"] for r in records if r["status"] == "ok" and r["file"] not in
                 skipped)
    if not ok:
        raise InputError(f"every partition failed; {failed[0]['partition']}: "
                         f"{failed[0]['reason']}")
    samples = sum(r["n_samples"] for r in ok if r["file"] in done)
    return ok, failed, PartitionSummary(done, tuple(skipped), failed,
                                        time.perf_counter() - start, samples)


def missing_days(ok, failed) -> tuple:
    """Failure entries for the UTC days inside the archive's span that no input file
    covers: a day absent from the daily file sequence fails as its own partition.

    A run of uncovered days between two readable files (``ok``, in time order) that
    has a failed file between them in file order is that file's (it is named by
    :func:`mark_failed_windows`); any other uncovered day is missing. Each entry has
    ``partition`` (the day), ``stage``, ``reason`` and ``day``.
    """
    failed_files = sorted(f["partition"] for f in failed)
    out = []
    for before, after in zip(ok, ok[1:]):
        first = pd.Timestamp(before["days"][-1]) + pd.Timedelta(days=1)
        last = pd.Timestamp(after["days"][0]) - pd.Timedelta(days=1)
        lo, hi = sorted((before["file"], after["file"]))
        if first > last or any(lo < f < hi for f in failed_files):
            continue
        for day in pd.date_range(first, last, freq="D"):
            out.append({"partition": f"{day:%Y-%m-%d}", "stage": "partition", "day":
                        f"{day:%Y-%m-%d}", "reason": "no input file covers this day "
                        f"(between {Path(before['file']).name} and {Path(after['file']).name})"})
    return tuple(out)


def prune_partitions(state: Path, records, fit_key: str) -> int:
    """Remove partition results and fit artefacts this run does not use; return how many.

    Results of files that left the archive, changed, or were made under another
    configuration would otherwise pile up (several MB per day of 1 s data). Only
    ``*.npz`` results and ``fit-*.json`` artefacts are touched.
    """
    keep = {Path(r["result"]).name for r in records} | {f"fit-{fit_key[:24]}.json"}
    removed = 0
    for path in list(state.glob("*.npz")) + list(state.glob("fit-*.json")):
        if path.name not in keep:
            path.unlink(missing_ok=True)
            removed += 1
    return removed


def gather_minutes(records) -> MinuteData:
    """The 1-min results of every partition, in time order (duplicate times dropped)."""
    parts = [read_partition_arrays(Path(r["result"]), MINUTE_ARRAYS) for r in records]
    cat = {n: np.concatenate([p[n] for p in parts]) for n in MINUTE_ARRAYS}
    order = np.argsort(cat["t_min"], kind="stable")
    t = cat["t_min"][order]
    keep = np.r_[True, t[1:] != t[:-1]]
    pick = order[keep]
    return MinuteData(times=cat["t_min"][pick], hpen=cat["hpen_min"][pick],
                      model=cat["model_min"][pick], kp=cat["kp"][pick],
                      lon_deg=cat["lon_deg"][pick], lat_deg=cat["lat_deg"][pick],
                      r_re=cat["r_re"][pick])


def gather_full(records) -> CleanedData:
    """The full-cadence cleaned and raw Hpen of every partition (records of a few days
    only: the truth stage and input-cadence alignment)."""
    parts = [read_partition_arrays(Path(r["result"]), FULL_ARRAYS) for r in records]
    t = np.concatenate([p["t_full"] for p in parts])
    order = np.argsort(t, kind="stable")
    keep = np.r_[True, t[order][1:] != t[order][:-1]]
    pick = order[keep]
    index = pd.DatetimeIndex(t[pick], name="time").tz_localize("UTC")
    return CleanedData(index, np.concatenate([p["hpen_full"] for p in parts])[pick],
                       np.concatenate([p["raw_full"] for p in parts])[pick],
                       np.concatenate([p["quality_full"] for p in parts])[pick])


# ------------------------------------------------------------------ stage products
def read_product(cfg: ChainConfig, files, shas, records, summary: PartitionSummary):
    """The ``read`` stage product from the partition records (no data re-read)."""
    samples = sum(r["n_samples"] for r in records)
    cadence = float(np.median([r["cadence_s"] for r in records]))
    start, end = records[0]["start"], max(r["end"] for r in records)
    span_h = (pd.Timestamp(end) - pd.Timestamp(start)).total_seconds() / 3600.0
    sensors = sorted({s for r in records for s in r["sensors"]})
    doc = {"files": [str(f) for f in files], "n_samples": samples, "cadence_s": cadence,
           "sensors": sensors, "span_hours": span_h, "start": start, "end": end,
           "n_partitions": len(files), "failed": list(summary.failed),
           "model_warnings": sorted({w for r in records for w in r.get("warnings", [])})}
    prov = make_provenance("read", {"format": cfg["input"]["format"]}, wall_clock=False)
    prov["inputs"] = [{"path": str(f), "sha256": s, "bytes": Path(f).stat().st_size}
                      for f, s in zip(files, shas)]
    line = (f"{len(files)} file(s), {samples} samples at {cadence:g} s over {span_h:.2f} h; "
            f"sensors {', '.join(sensors)}")
    faults = archive_faults(records, cadence)
    doc["quality"] = faults["quality"]
    doc["archive_faults"] = faults["warnings"]
    lines = (line,) + faults["lines"]
    return None, StageProduct(stage="read", summary=doc, lines=lines, provenance=prov,
                              warnings=tuple(faults["warnings"]))


def archive_faults(records, cadence_s: float) -> dict:
    """What the partitions found wrong with the archive, each fault named with its file:
    samples QC flagged, repairs the readers made (duplicate samples dropped, fills,
    a truncated last line...), files at another cadence or in another format than most,
    identical and overlapping files, and 1-min samples without Kp.

    Returns ``{"warnings": [...], "lines": (...), "quality": {flag name: samples}}``.
    """
    out, quality = [], {}
    name = {r["file"]: Path(r["file"]).name for r in records}
    for r in records:
        qc = r.get("qc") or {}
        for k, v in (qc.get("counts") or {}).items():
            quality[k] = quality.get(k, 0) + v
        if qc.get("n_flagged"):
            parts = ", ".join(f"{k} {v}" for k, v in qc["counts"].items())
            out.append(f"{r['file']}: quality control flagged {qc['n_flagged']} of "
                       f"{r['n_samples']} samples ({parts}); they are kept, flagged, in the "
                       "corrected product and left out of every fit")
        repairs: dict = {}
        for rep in r.get("repairs") or []:  # one line per kind (fills come per column)
            repairs[rep["what"]] = repairs.get(rep["what"], 0) + int(rep["count"])
        out += [f"{r['file']}: {what} ({n})" for what, n in repairs.items()]
        if cadence_s > 0 and abs(r["cadence_s"] / cadence_s - 1) > 0.05:
            out.append(f"{r['file']}: cadence {r['cadence_s']:g} s where the archive's is "
                       f"{cadence_s:g} s (used at its own cadence)")
        out += [f"{r['file']}: no samples from {a} to {b} ({sec / 3600:.1f} h, a time jump "
                "inside the file)" for a, b, sec in r.get("gaps") or []]
        if r.get("n_no_kp"):
            out.append(f"{r['file']}: no Kp for {r['n_no_kp']} of {r['n_minutes']} averaged "
                       "samples (a hole in the Kp file): they are not quiet-time candidates")
    formats = [r.get("format") or "?" for r in records]
    common = max(set(formats), key=formats.count) if formats else "?"
    out += [f"{r['file']}: format {f} among {common} files (read as {f})"
            for r, f in zip(records, formats) if f != common]
    by_sha: dict = {}
    for r in records:
        by_sha.setdefault(r["sha256"], []).append(r["file"])
    copies = {f for group in by_sha.values() for f in group[1:]}
    for group in by_sha.values():
        out += [f"{f}: an identical copy of {group[0]}; its samples are used once"
                for f in group[1:]]
    latest_end, latest_file = None, None
    for r in sorted(records, key=lambda r: (r["start"], r["file"])):
        if r["file"] in copies:
            continue
        if latest_end is not None and r["start"] > latest_end:
            gap_s = (pd.Timestamp(r["start"]) - pd.Timestamp(latest_end)).total_seconds()
            if gap_s > max(GAP_SAMPLES * cadence_s, 600.0):
                out.append(f"no file holds samples from {latest_end} to {r['start']} "
                           f"({gap_s / 3600:.1f} h, between {name[latest_file]} and "
                           f"{name[r['file']]})")
        if latest_end is not None and r["start"] <= latest_end:
            out.append(f"{r['file']}: overlaps {latest_file} from {r['start']} to "
                       f"{min(r['end'], latest_end)}; at a time both hold, the sample of "
                       f"the file that starts first ({name[latest_file]}) is used")
        if latest_end is None or r["end"] > latest_end:
            latest_end, latest_file = r["end"], r["file"]
    lines = (("archive faults: " + "; ".join(out[:3]) + (f"; ... ({len(out)} in all, "
              "see MANIFEST.json warnings)" if len(out) > 3 else "")),) if out else ()
    return {"warnings": out, "lines": lines, "quality": quality}


def model_product(minute: MinuteData, cfg: ChainConfig, records):
    """MODEL.csv and DATA_HPEN.csv (1-min) from the concatenated partitions."""
    index = pd.DatetimeIndex(minute.times, name="time").tz_localize("UTC")
    data = pd.DataFrame(minute.hpen, index=index, columns=list(HPEN))
    for c in ("lon_deg", "lat_deg", "r_re"):
        data[c] = getattr(minute, c)
    n_invalid = int((~np.isfinite(minute.model).all(axis=1)).sum())
    kp_ok = np.isfinite(minute.kp)
    med = np.nanmedian(minute.hpen - minute.model, axis=0).tolist()
    summary = {"model": cfg["model"]["name"].upper(), "n_samples": len(minute.times),
               "n_invalid": n_invalid,
               "kp_range": [float(minute.kp[kp_ok].min()), float(minute.kp[kp_ok].max())]
               if kp_ok.any() else None, "data_minus_model_median_nT": med}
    kp_path = cfg.resolve(cfg["kp"]["file"])
    model = {k: v for k, v in cfg["model"].items() if k != "jobs"}  # same whatever the workers
    prov = make_provenance("model", {"model": model, "position": cfg["position"],
                                     "cadence_s": cfg["offsets"]["cadence_s"]},
                           inputs=[kp_path] if kp_path is not None else [], wall_clock=False)
    line = (f"{len(minute.times)} samples at {cfg['offsets']['cadence_s']:g} s from "
            f"{len(records)} partition(s); {summary['model']} at the spacecraft "
            f"({n_invalid} NaN); median data - model "
            + ", ".join(f"{c} {v:+.2f}" for c, v in zip(HPEN, med)) + " nT")
    product = StageProduct(stage="model", summary=summary, lines=(line,),
                           provenance=prov,
                           tables={"MODEL.csv": pd.DataFrame(minute.model, index=index,
                                                             columns=list(HPEN)),
                                   "DATA_HPEN.csv": data})
    return minute, product


def mark_failed_windows(table, failed, records):
    """Name the failed partitions in the ``reason`` of the windows that touch them.

    A failed file's times are unknown (it could not be read): it is placed in the gap
    between the neighbouring readable files in file order (from the sample after the
    previous file's last one to the next file's first sample). A missing day (an entry
    with ``day``, :func:`missing_days`) marks the windows that touch that UTC day.
    """
    if not failed:
        return table
    by_file = {r["file"]: r for r in records}
    order = sorted(set(by_file) | {f["partition"] for f in failed if "day" not in f})
    start = table.start.astype("datetime64[ns]").astype(np.int64)
    end = table.end.astype("datetime64[ns]").astype(np.int64)
    reasons = list(table.reason) if len(table.reason) else [""] * len(start)
    for f in failed:
        if "day" in f:  # a day no file covers (missing_days)
            lo = pd.Timestamp(f["day"]).value
            hi, note = lo + _DAY_NS, f"no input file for {f['day']}"
        else:
            lo, hi = _file_gap(order, order.index(f["partition"]), by_file)
            note = f"partition {Path(f['partition']).name} failed ({f['reason']})"
        for w in np.flatnonzero((start < hi) & (end > lo)):
            reasons[w] = f"{reasons[w]}; {note}" if reasons[w] else note
    return replace(table, reason=tuple(reasons))


def _file_gap(order, k, by_file):
    """Times (ns) of the gap between the readable files around ``order[k]`` in file
    order: from where the previous file's next sample would have been to the next
    file's first sample (open at an end without a readable neighbour)."""
    before = [by_file[o] for o in order[:k] if o in by_file]
    after = [by_file[o]["start"] for o in order[k + 1:] if o in by_file]
    lo = (pd.Timestamp(before[-1]["end"]).value + int(before[-1]["cadence_s"] * 1e9)
          if before else np.iinfo(np.int64).min)
    hi = pd.Timestamp(after[0]).value if after else np.iinfo(np.int64).max
    return lo, hi


# -------------------------------------------------------------------------- offsets
def replace_keeping_previous(write, path: Path) -> Path:
    """Write a product with ``write(path)`` beside ``path`` and swap it in atomically;
    an existing different version moves to ``<folder>/previous/<stem>.<n><suffix>``
    (and its ``.provenance.json`` with it). An identical one is left untouched."""
    import filecmp
    import os
    import tempfile

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    scratch = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".scratch",
                                    dir=path.parent))
    try:
        write(scratch / path.name)
        names = [p.name for p in sorted(scratch.iterdir())]
        same = path.is_file() and all((path.parent / n).is_file() and filecmp.cmp(
            scratch / n, path.parent / n, shallow=False) for n in names)
        if not same:
            if path.is_file():
                previous = path.parent / "previous"
                previous.mkdir(exist_ok=True)
                n = 1 + sum(1 for _ in previous.glob(f"{path.stem}.*{path.suffix}"))
                for name in names:
                    old = path.parent / name
                    if old.is_file():
                        os.replace(old, previous / name.replace(path.name,
                                                                f"{path.stem}.{n}{path.suffix}"))
            for name in sorted(names, key=lambda x: x == path.name):  # main file last
                os.replace(scratch / name, path.parent / name)
        return path
    finally:
        for leftover in scratch.iterdir():
            leftover.unlink()
        scratch.rmdir()


def offsets_stage(minute: MinuteData, cfg: ChainConfig, failed, records):
    """The offset product with failed partitions named; previous versions kept."""
    from magcal.chain.calibrate import run_offsets
    from magcal.chain.output import product_format, write_offsets_product
    from magcal.io.products import SUFFIX
    from magcal.offsets import write_offsets_csv

    table, product = run_offsets(minute, cfg)
    table = mark_failed_windows(table, failed, records)
    table = replace(table, provenance=without_wall_clock(table.provenance))
    summary = {**product.summary, "reasons": [r for r in table.reason if r]}

    def writer(path):
        return replace_keeping_previous(lambda p: write_offsets_csv(p, table), path)

    writers = {"OFFSETS.csv": writer}
    fmt = product_format(cfg)
    if fmt != "csv":  # the offset product in the run's format too, beside OFFSETS.csv
        writers[f"OFFSETS{SUFFIX[fmt]}"] = lambda path: replace_keeping_previous(
            lambda p: write_offsets_product(p, table, fmt), path)
    return table, replace(product, summary=summary, writers=writers)


# ------------------------------------------------------------------------ corrected
@dataclass(frozen=True)
class DayTask:
    """One corrected daily file: the day, its partition results, the offset table."""

    day: str
    results: tuple
    table: object
    path: str
    provenance: dict
    #: product format (:mod:`magcal.chain.output`): csv, netcdf or cdf
    fmt: str = "csv"


def _bracket_key(table, day: str, partition_keys) -> str:
    """Key of a corrected day: its partitions and the valid windows its interpolation
    uses (the last centre at or before the day, the first at or after its end, and
    those between)."""
    valid = np.flatnonzero(np.isfinite(table.offset_nT).all(axis=1))
    c = table.center.astype("datetime64[ns]").astype(np.int64)[valid]
    t0 = pd.Timestamp(day).value
    t1 = t0 + _DAY_NS
    lo = np.searchsorted(c, t0, side="right") - 1
    hi = np.searchsorted(c, t1, side="left")
    rows = valid[max(lo, 0):min(hi, len(valid) - 1) + 1] if len(valid) else valid
    key = {"partitions": sorted(partition_keys), "centers": c[np.isin(valid, rows)],
           "offsets": table.offset_nT[rows], "flag_meaning": "v3 bridged"}
    changes = getattr(table, "level_changes", ())
    if changes:  # the quality bit of samples interpolated across one (keys unchanged without)
        key["level_changes"] = [str(np.datetime64(ch.time, "s")) for ch in changes]
    if getattr(table, "segment", None) is not None:
        # split at the changes (keys unchanged without): a day's offset may be held from
        # anywhere in its segment, and the near-change bit follows the changes' intervals
        key["segments"] = {"segment": table.segment, "centers": c, "offsets":
                           table.offset_nT[valid],
                           "intervals": [[str(np.datetime64(v, "s")) for v in
                                          (ch.time_lo, ch.time_hi)] for ch in changes]}
    return digest(key)[:24]


def write_corrected_day(task: DayTask) -> dict:
    """Apply the interpolated offsets to one day's full-cadence Hpen; write its CSV."""
    from magcal.chain.daily_csv import write_day_csv
    from magcal.offsets import apply_offsets
    from magcal.provenance import file_sha256
    from magcal.offsets.apply import (FLAG_MEANING, across_level_change, near_level_change,
                                      quality_bits)
    from magcal.qc.flags import counts as flag_counts

    try:
        data = gather_full([{"result": r} for r in task.results])
        t0 = pd.Timestamp(task.day, tz="UTC")
        day = (data.times >= t0) & (data.times < t0 + pd.Timedelta(days=1))
        times, hpen = data.times[day], data.hpen[day]
        t = times.tz_localize(None).as_unit("ns").to_numpy()
        if np.isfinite(task.table.offset_nT).all(axis=1).any():
            corr, _, flag = apply_offsets(t, hpen, task.table)
        else:
            corr, flag = hpen.copy(), np.full(len(t), 3, dtype=np.int8)
        flag = np.asarray(flag, dtype=int)
        quality = data.quality[day] | quality_bits(flag, across_level_change(t, task.table),
                                                   near_level_change(t, task.table))
        if task.fmt == "csv":
            write_day_csv(Path(task.path), times, corr, HPEN, flag, extra={"quality": quality},
                          provenance=task.provenance or None)
        else:
            from magcal.chain.output import write_day_product

            write_day_product(task.path, task.fmt, times,
                              {**dict(zip(HPEN, corr.T)), "offset_flag": flag,
                               "quality": quality},
                              provenance=task.provenance or None)
        counts = np.bincount(flag, minlength=len(FLAG_MEANING))[:len(FLAG_MEANING)]
        return {"day": task.day, "status": "ok", "sha256": file_sha256(task.path),
                "n": len(times), "flags": counts.tolist(), "quality": flag_counts(quality)}
    except Exception as exc:  # noqa: BLE001 - one day must not stop the others
        return {"day": task.day, "status": "failed", "reason": f"{type(exc).__name__}: {exc}"}


def corrected_stage(run, table, records, cfg: ChainConfig, engine):
    """Daily corrected files, rewritten only for days whose inputs changed (or whose
    file no longer has the checksum it was written with)."""
    from magcal.chain.output import corrected_name, other_formats, product_format
    from magcal.offsets import FLAG_MEANING
    from magcal.qc import FLAG_NAMES

    fmt = product_format(cfg)
    out = run.outdir / "corrected"
    marker = run.outdir / STATE_DIR / "corrected.json"
    done = json.loads(marker.read_text()) if marker.is_file() else {}
    by_day: dict[str, list] = {}
    for r in records:
        for d in r["days"]:
            by_day.setdefault(d, []).append(r)
    prov = make_provenance("offsets apply", {"flag_meaning": FLAG_MEANING}, wall_clock=False)
    tasks, keys, unchanged = [], {}, []
    for d, parts in sorted(by_day.items()):
        keys[d] = _bracket_key(table, d, [p["key"] for p in parts])
        path = out / corrected_name(d, fmt)
        old = done.get(d)
        if old and old["key"] == keys[d] and path.is_file():
            unchanged.append((d, path, old["sha256"]))
            continue
        tasks.append(DayTask(d, tuple(p["result"] for p in parts), table, str(path), prov,
                             fmt))
    # a day whose file was edited since is written again
    for (d, path, sha), now in zip(unchanged, hash_inputs([p for _, p, _ in unchanged])):
        if now != sha:
            parts = by_day[d]
            tasks.append(DayTask(d, tuple(p["result"] for p in parts), table, str(path), prov,
                                 fmt))
    tasks.sort(key=lambda t: t.day)
    results = engine.map(write_corrected_day, tasks, "corrected days")
    for res in results:
        if res["status"] == "ok":
            done[res["day"]] = {**res, "key": keys[res["day"]]}
    for d in sorted(set(done) - set(by_day)):  # its file is gone or now fails
        (out / corrected_name(d, fmt)).unlink(missing_ok=True)
    for d in sorted(done):  # an earlier run's file of the day in another format
        for stale in other_formats(out, d, fmt):
            stale.unlink()
    done = {d: v for d, v in done.items() if d in by_day}
    with atomic_path(marker) as tmp:
        tmp.write_text(json.dumps(done, sort_keys=True))
    inputs = {d: [p["sha256"] for p in parts] for d, parts in by_day.items()}
    for d in sorted(done):
        run.add_entry(out / corrected_name(d, fmt), "corrected", inputs[d],
                      done[d]["sha256"])
    n_flags = len(FLAG_MEANING)
    # a day written before a flag value existed has fewer counts: none of that value
    counts = (np.sum([np.pad(done[d]["flags"], (0, n_flags - len(done[d]["flags"])))
                      for d in done], axis=0) if done else np.zeros(n_flags, int))
    n = int(sum(done[d]["n"] for d in done))
    failed = [f"{r['day']}: {r['reason']}" for r in results if r["status"] != "ok"]
    valid = bool(np.isfinite(table.offset_nT).all(axis=1).any())
    quality: dict = {}
    for d in done:
        for name, k in done[d].get("quality", {}).items():
            quality[name] = quality.get(name, 0) + k
    summary = {"n_samples": n, "n_files": len(done),
               "flags": {FLAG_MEANING[k]: int(counts[k]) for k in range(n_flags)},
               "quality": {"bits": {str(b): name for b, name in FLAG_NAMES.items()},
                           "counts": quality},
               "failed_days": failed}
    lines = (f"{n} samples in {len(done)} daily files ({len(tasks) - len(failed)} rewritten); "
             f"interpolated {counts[0]}, held {counts[1] + counts[2]}, no offset {counts[3]}"
             + (f", bridged over a window without an offset {counts[4]}" if counts[4] else ""),
             "quality column: " + (", ".join(f"{k} {v}" for k, v in quality.items())
                                   or "every sample good"))
    warnings = (() if valid else
                ("no valid offset: corrected files hold the uncorrected data (offset_flag 3)",))
    warnings += tuple(f"corrected day failed: {f}" for f in failed)
    return None, StageProduct(stage="corrected", summary=summary, lines=lines,
                              provenance=prov, warnings=warnings)


# ------------------------------------------------------- stages on the 1-min record
@dataclass(frozen=True)
class MinuteTask:
    """A stage on the whole 1-min record run as one task on a worker: the partition
    records it reads the record from (not the record itself: shipping a year of 1-min
    samples to a worker costs more than reading them there), the configuration and,
    for the alignment, the offset table."""

    records: tuple
    config: ChainConfig
    table: object = None
    folder: str = ""


def timed(job) -> tuple:
    """``func(task)`` of ``job = (func, task)`` with the seconds it took on the worker:
    ``(value, product, seconds)`` for :meth:`magcal.chain.runner._Run.stage`."""
    import time

    func, task = job
    start = time.perf_counter()
    value, product = func(task)
    return value, product, time.perf_counter() - start


def model_on_minutes(task: MinuteTask):
    """The model stage (:func:`model_product`) with its tables written into
    ``task.folder`` on the worker (formatting a year of 1-min CSV takes seconds)."""
    minute = gather_minutes(task.records)
    _, product = model_product(minute, task.config, task.records)
    return None, product.with_tables_written(task.folder)


def discovery_on_minutes(task: MinuteTask):
    """Model-gap discovery (:func:`magcal.chain.calibrate.run_discovery`) on the 1-min
    record of ``task.records``."""
    from magcal.chain.calibrate import run_discovery

    return run_discovery(gather_minutes(task.records), task.config)


def alignment_on_minutes(task: MinuteTask):
    """The alignment (:func:`magcal.chain.calibrate.run_alignment`) on the 1-min record of
    ``task.records`` corrected with ``task.table``."""
    from magcal.chain.calibrate import run_alignment

    minute = gather_minutes(task.records)
    corrected = corrected_for_alignment(minute, task.table, task.records, task.config)
    return run_alignment(corrected, minute, task.config)


def corrected_for_alignment(minute: MinuteData, table, records, cfg: ChainConfig):
    """Offset-corrected data for the alignment: the 1-min record, and the full-cadence
    record only when ``[alignment] cadence_s = 0`` (records of minutes or hours)."""
    from magcal.chain.calibrate import CorrectedData
    from magcal.offsets import apply_offsets

    valid = np.isfinite(table.offset_nT).all(axis=1).any()

    def correct(t, hpen):
        if valid:
            corr, _, flag = apply_offsets(t, hpen, table)
            return corr, np.asarray(flag)
        return hpen.copy(), np.full(len(t), 3, dtype=np.int8)

    corr_min, flag_min = correct(minute.times, minute.hpen)
    full_t, full = np.empty(0, dtype="datetime64[ns]"), np.empty((0, 3))
    if cfg["alignment"]["cadence_s"] == 0:
        from magcal.qc import masked

        data = gather_full(records)
        full_t = data.times.tz_localize(None).as_unit("ns").to_numpy()
        full = correct(full_t, masked(data.hpen, data.quality))[0]
    return CorrectedData(minute.times, corr_min, flag_min, full_t, full)
