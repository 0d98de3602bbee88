"""``run_chain``: one configuration in, every product and a manifest out.

The runner reads the configuration, optionally simulates its input (the demo), then
runs the stages in chain order::

    frames, ac (fit phase) -> partitions (read, common frame, PiCoG, Hpen, 1-min
    model; one Dask task per file) -> read -> offsets -> corrected -> model
    -> truth -> alignment -> discover -> report

where the model tables, the alignment and discovery are single tasks started on a
worker as soon as their inputs exist and recorded in this order when done
(:mod:`magcal.chain.archive`; the spinning chain runs in memory,
:mod:`magcal.chain.spin`). Each stage's :class:`~magcal.chain.product.StageProduct` is
written to ``OUTDIR/<stage>/`` and listed in ``OUTDIR/MANIFEST.json`` with its SHA-256
and the SHA-256 of the inputs it was made from (CONTRACTS §7). A stage whose inputs
are unchanged since the last run into the same OUTDIR is skipped (its marker in
``OUTDIR/.partitions`` names its key and files). A stage that cannot run on the data
(e.g. alignment on minutes of data) or a file that cannot be read is listed under
``failed`` with its reason; the rest complete.
"""

from __future__ import annotations

import json
import threading
import time
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Callable

from magcal._version import __version__
from magcal.chain.config import ChainConfig, read_chain_config
from magcal.chain.partition import STATE_DIR, digest
from magcal.chain.product import StageProduct, without_wall_clock
from magcal.errors import InputError
from magcal.io.atomic import atomic_path
from magcal.io.jsonio import write_json
from magcal.provenance import file_sha256, files_sha256, make_provenance


@dataclass(frozen=True)
class StageRecord:
    """What one stage did: its product (or failure), timing, and whether it was
    skipped because its inputs had not changed since the last run."""

    stage: str
    status: str  # "ok" or "failed"
    seconds: float
    product: StageProduct | None = None
    paths: tuple = ()
    error: str = ""
    skipped: bool = False


@dataclass(frozen=True)
class ChainResult:
    """Everything a chain run produced.

    Attributes
    ----------
    outdir : pathlib.Path
    records : tuple of StageRecord
    manifest : dict
        The content of ``MANIFEST.json``.
    extras : dict
        Stage outputs a caller may score (e.g. the demo against its truth); a stage
        skipped as unchanged leaves None.
    partitions : PartitionSummary or None
        Files done, skipped and failed (archive runs).
    """

    outdir: Path
    records: tuple = ()
    manifest: dict = field(default_factory=dict)
    extras: dict = field(default_factory=dict)
    partitions: object = None

    @property
    def failed(self) -> list:
        """Failed stages and partitions (``StageRecord``-like: ``stage``, ``error``)."""
        stages = [r for r in self.records if r.status != "ok"]
        parts = [StageRecord(f"partition {Path(f['partition']).name}", "failed", 0.0,
                             error=f["reason"])
                 for f in (self.partitions.failed if self.partitions else ())]
        return stages + parts

    @property
    def warnings(self) -> list[str]:
        return [f"{r.stage}: {w}" for r in self.records if r.product for w in r.product.warnings]

    def text(self) -> str:
        """Console summary: one block per stage, then the partitions."""
        out = [f"magcal {__version__} run -> {self.outdir}"]
        for r in self.records:
            state = "skipped, unchanged" if r.skipped else f"{r.seconds:.1f} s"
            out.append(f"[{r.status}] {r.stage} ({state})")
            if r.product is not None:
                out += [f"    {line}" for line in r.product.lines]
            if r.error:
                out.append(f"    reason: {r.error}")
        if self.partitions is not None:
            out.append(self.partitions.text())
        return "\n".join(out)


class _Run:
    """Book-keeping of one run: stage records, manifest entries, progress, and the
    markers that let a rerun skip a stage whose inputs are unchanged."""

    def __init__(self, outdir: Path, inputs: list[dict], progress: Callable[[str], None] | None):
        self.outdir = outdir
        self.records: list[StageRecord] = []
        self.entries: list[dict] = []
        self.inputs = inputs
        self.progress = progress or (lambda text: None)
        self.partitions = None
        self._checked: dict = {}  # (stage, key) -> its intact marker or None

    def add_entry(self, path: Path, stage: str, inputs: list[str], sha: str | None = None):
        self.entries.append({"path": Path(path).relative_to(self.outdir).as_posix(),
                             "stage": stage, "sha256": sha or file_sha256(path),
                             "inputs": list(inputs)})

    def fail(self, name: str, error: Exception, seconds: float = 0.0) -> None:
        self.records.append(StageRecord(name, "failed", seconds, error=str(error)))
        self.progress(f"   failed: {error}")

    def _marker(self, name: str) -> Path:
        from magcal.chain.partition import STATE_DIR

        return self.outdir / STATE_DIR / f"stage-{name}.json"

    def _finished(self, name: str, key: str) -> dict | None:
        """The marker of a stage whose last run had ``key`` and left its files intact
        (checked once per run: the corrected stage's files are hundreds of MB)."""
        if (name, key) not in self._checked:
            self._checked[name, key] = self._check_marker(name, key)
        return self._checked[name, key]

    def _check_marker(self, name: str, key: str) -> dict | None:
        marker = self._marker(name)
        if not marker.is_file():
            return None
        done = json.loads(marker.read_text())
        if done.get("key") != key:
            return None
        paths = [self.outdir / e["path"] for e in done["entries"]]
        if not all(p.is_file() for p in paths) or files_sha256(paths) != [
                e["sha256"] for e in done["entries"]]:
            return None
        return done

    def unchanged(self, name: str, key: str) -> bool:
        """Whether :meth:`stage` with ``key`` will skip ``name`` (so a caller need not
        start its work)."""
        return self._finished(name, key) is not None

    def _reuse(self, name: str, key: str) -> bool:
        """Record a stage as skipped when its marker has ``key`` and its files are intact."""
        done = self._finished(name, key)
        if done is None:
            return False
        self.entries += done["entries"]
        product = StageProduct(stage=name, lines=tuple(done["lines"]),
                               warnings=tuple(done["warnings"]))
        self.records.append(StageRecord(name, "ok", 0.0, product,
                                        tuple(self.outdir / e["path"] for e in done["entries"]),
                                        skipped=True))
        self.progress(f"-> {name}: unchanged, skipped")
        return True

    def stage(self, name: str, func: Callable, *args, required: bool = True,
              key: str | None = None, reuse: bool = True):
        """Run one stage; write its product; on failure record it (and re-raise if the
        later stages need its output). With ``key``, a stage whose last run had the same
        key and left its files intact is not run again (its value is then None), unless
        ``reuse`` is False (its value is needed): it runs and its marker is written.

        ``func`` returns ``(value, product)``, or ``(value, product, seconds)`` when
        the work ran on a worker (:func:`magcal.chain.archive.timed`): the record then
        holds the worker's seconds, not the driver's wait.
        """
        if key is not None and reuse and self._reuse(name, key):
            return None
        self.progress(f"-> {name}")
        start = time.perf_counter()
        first = len(self.entries)
        try:
            value, product, *worker = func(*args)
        except InputError as exc:
            self.fail(name, exc, time.perf_counter() - start)
            if required:
                raise
            return None
        paths = product.write(self.outdir / product.stage)
        for p in paths:
            self.add_entry(p, product.stage, [i["sha256"] for i in self.inputs])
        seconds = worker[0] if worker else time.perf_counter() - start
        self.records.append(StageRecord(name, "ok", seconds, product, tuple(paths)))
        if key is not None:
            with atomic_path(self._marker(name)) as tmp:
                tmp.write_text(json.dumps({"key": key, "entries": self.entries[first:],
                                           "lines": list(product.lines),
                                           "warnings": list(product.warnings)}))
        self.progress(f"   ok in {self.records[-1].seconds:.1f} s")
        return value

    def manifest(self, config: ChainConfig, engine: str = "") -> dict:
        failed = [{"partition": r.stage, "stage": r.stage, "reason": r.error}
                  for r in self.records if r.status != "ok"]
        parts = self.partitions
        if parts is not None:
            failed += [dict(f) for f in parts.failed]
        return {"products": self.entries, "failed": failed, "inputs": self.inputs,
                "warnings": [f"{r.stage}: {w}" for r in self.records if r.product
                             for w in r.product.warnings],
                "stages": [{"stage": r.stage, "status": r.status, "seconds": r.seconds,
                            "skipped": r.skipped} for r in self.records],
                "partitions": None if parts is None else {
                    "done": list(parts.done), "skipped": list(parts.skipped),
                    "seconds": parts.seconds, "samples_done": parts.samples},
                "engine": engine,
                "provenance": make_provenance("run", config.as_dict(), inputs=[config.path])}


def run_chain(config: ChainConfig | str | Path, outdir: str | Path,
              progress: Callable[[str], None] | None = None,
              workers: int | None = None, scheduler=None, engine=None) -> ChainResult:
    """Run the whole chain of a configuration and write every product into ``outdir``.

    A geostationary chain runs partitioned by input file on Dask
    (:mod:`magcal.chain.archive`): a rerun skips the partitions and stages whose inputs
    and configuration are unchanged, and one unreadable file fails only its partition.

    Parameters
    ----------
    config : ChainConfig or path-like
        The configuration or the path of its ``CHAIN.toml``.
    outdir : path-like
        Output folder (created).
    progress : callable, optional
        Called with one line of text per stage start and end; when given, a progress
        bar per partitioned stage also goes to stderr.
    workers : int, optional
        Local Dask worker processes (default: the usable cores).
    scheduler : str or distributed.Client, optional
        A ``dask.distributed`` scheduler address (or client) to run the tasks on
        instead; its workers must see the same file system.
    engine : magcal.chain.engine.Engine, optional
        An open engine to run the tasks on instead of ``workers`` or ``scheduler``; it
        is left open, so several runs share one pool of worker processes (e.g. the
        runs of a test module: spawning and importing a worker costs about a second
        per run).

    Returns
    -------
    ChainResult

    Raises
    ------
    InputError
        Bad configuration, unreadable input, or a stage the later stages depend on
        (reading, frames, AC, model) that cannot run on the data.
    """
    from magcal.chain.engine import Engine

    cfg = config if isinstance(config, ChainConfig) else read_chain_config(config)
    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    extras: dict = {}
    cfg = replace(cfg, outdir=out)
    if workers is not None and workers < 1:
        raise InputError(f"--workers must be at least 1, got {workers}")
    if engine is not None and (workers is not None or scheduler is not None):
        raise InputError("give an open engine or workers/scheduler, not both")
    remove_partial_files(out)
    own = engine is None
    engine = Engine(workers, scheduler, bars=progress is not None) if own else engine
    try:
        if cfg.kind != "spin":  # the workers start while the driver prepares
            engine.start_workers()
        if cfg["input"]["simulate"]:
            extras["simulated"] = _simulate_input(cfg, out, progress)
        cfg.check_paths()
        if cfg.kind != "spin" and cfg["discover"]["enabled"] and cfg["discover"]["covariates"]:
            from magcal.chain.calibrate import read_covariate_file

            read_covariate_file(cfg.resolve(cfg["discover"]["covariates"]))
        files = cfg.input_files()
        if cfg.kind == "spin":
            run = _Run(out, [{"path": str(p), "sha256": file_sha256(p)} for p in files],
                       progress)
        else:
            from magcal.chain.archive import hash_inputs
            from magcal.io.formats import in_time_order

            files = in_time_order(files)
            shas = hash_inputs(files)
            run = _Run(out, [{"path": str(p), "sha256": s} for p, s in zip(files, shas)],
                       progress)
        try:
            if cfg.kind == "spin":
                from magcal.chain.spin import spin_stages

                spin_stages(run, cfg, files, extras)
            else:
                _geostationary_stages(run, cfg, files, shas, extras, engine)
            if cfg["report"]["enabled"]:
                keys = sorted((e["path"], e["sha256"]) for e in run.entries)
                run.stage("report", _report, out, cfg, required=False,
                          key=digest({"products": keys, "report": cfg["report"]}))
        finally:  # a run stopped by bad input still says what it did and why it stopped
            manifest = run.manifest(cfg, engine.description)
            write_json(out / "MANIFEST.json", manifest)
    finally:
        if own:
            engine.close()
    return ChainResult(out, tuple(run.records), manifest, extras, run.partitions)


def remove_partial_files(outdir: Path) -> int:
    """Delete what a killed run left half-written: the temporary files of
    :func:`magcal.io.atomic.atomic_path` (``.<name>.<random>.part<suffix>``) and the
    scratch folders of :func:`magcal.chain.archive.replace_keeping_previous`."""
    import shutil

    removed = 0
    for path in sorted(outdir.rglob(".*"), reverse=True):
        if path.is_file() and ".part" in path.name:
            path.unlink(missing_ok=True)
            removed += 1
        elif path.is_dir() and path.name.endswith(".scratch"):
            shutil.rmtree(path, ignore_errors=True)
            removed += 1
    return removed


def check_kp_coverage(cfg: ChainConfig, records) -> None:
    """Refuse a Kp file that covers none of the archive's 1-min samples.

    Without Kp the model (T89) is NaN and no sample is a quiet-time candidate: every
    offset window, the alignment and discovery come out empty, and the run used to end
    with exit status 3 and one "hole in the Kp file" warning per file, as if a few days
    were missing. A Kp file of another year is a bad input (exit status 2) naming the
    file and both spans. A Kp file with holes is left to the per-file warnings.

    Raises
    ------
    InputError
        No 1-min sample of any partition has a Kp value.
    """
    kp = cfg["kp"]["file"]
    total = sum(int(r.get("n_minutes", 0)) for r in records)
    if kp is None or not total or any(r.get("n_no_kp", 0) < r.get("n_minutes", 0)
                                      for r in records):
        return
    from magcal.indices import read_kp

    path = cfg.resolve(kp)
    series = read_kp(path)
    held = (f"its values span {series.index[0]:%Y-%m-%dT%H:%M} to "
            f"{series.index[-1]:%Y-%m-%dT%H:%M}" if len(series) else "it has no value")
    start = min(str(r["start"]) for r in records)
    end = max(str(r["end"]) for r in records)
    raise InputError(f"[kp] file covers none of the data ({start[:16]} to {end[:16]}; "
                     f"{held}): no Kp for any of the {total} 1-min samples", file=path,
                     column="kp.file")


def _geostationary_stages(run: _Run, cfg: ChainConfig, files, shas, extras: dict,
                          engine) -> None:
    """Fit phase, partitions on Dask, then the stages on the 1-min record."""
    from magcal.chain import archive

    state = run.outdir / STATE_DIR
    state.mkdir(exist_ok=True)
    run.progress("-> fit: frames and PiCoG on the first "
                 f"{cfg['picog']['fit_days']:g} days")
    start = time.perf_counter()
    try:
        fit, frames, ac, read = archive.fit_phase(cfg, files, shas, state, engine)
    except InputError as exc:
        run.fail("frames", exc, time.perf_counter() - start)
        raise
    run.progress(f"   fit ready in {time.perf_counter() - start:.1f} s")
    run.stage("frames", lambda: (None, frames), key=fit.key)
    run.stage("ac", lambda: (None, ac), key=fit.key)
    run.progress(f"-> partitions ({engine.description})")
    # the driver imports the offsets' libraries while the workers run the partitions
    threading.Thread(target=archive.import_later_libraries, daemon=True).start()
    records, failed, run.partitions = archive.run_partitions(cfg, files, shas, fit, state,
                                                             engine, read)
    del read  # the fit files' frames: not held through the later stages
    check_kp_coverage(cfg, records)
    archive.prune_partitions(state, records, fit.key)
    pkeys = [r["key"] for r in records]
    # discovery needs only the 1-min record: it starts on a worker now and runs while
    # the driver computes the offsets and the other worker the alignment
    discover_key = pending_discover = None
    if cfg["discover"]["enabled"]:
        cov = cfg.resolve(cfg["discover"]["covariates"])
        discover_key = digest({"partitions": pkeys, "cfg": cfg["discover"],
                               "cov": file_sha256(cov) if cov and cov.is_file() else None})
        if not run.unchanged("discover", discover_key):
            pending_discover = engine.submit(archive.timed, (
                archive.discovery_on_minutes, archive.MinuteTask(tuple(records), cfg)))
    run.stage("read", archive.read_product, cfg, files, shas, records, run.partitions,
              key=digest({"shas": shas, "partitions": pkeys, "failed": failed}))
    offsets_path = run.outdir / "offsets" / "OFFSETS.csv"
    from magcal.chain.output import product_format

    fmt = product_format(cfg, files)
    offsets_key = digest({"partitions": pkeys, "files": [r["file"] for r in records],
                          "failed": failed, "offsets": cfg["offsets"],
                          "model": cfg["model"]["name"],
                          **({"format": fmt} if fmt != "csv" else {})})
    truth_path = cfg.resolve(cfg["truth"]["file"]) if cfg["truth"]["file"] else None
    ref = cfg["alignment"]["reference"]
    ref_path = cfg.resolve(ref) if ref != "model" else None

    def keys(offsets_sha: str) -> dict:
        """The keys of the stages made from the offset product with this checksum."""
        written = {"written": "daily_csv v2 quality"}
        if fmt != "csv":  # a CSV run's key is unchanged by the formats
            written["format"] = fmt
        out = {"corrected": digest({"partitions": pkeys, "offsets": offsets_sha,
                                    **written})}
        if cfg["alignment"]["enabled"]:
            out["alignment"] = digest({
                "partitions": pkeys, "offsets": offsets_sha, "cfg": cfg["alignment"],
                "cadence_s": cfg["offsets"]["cadence_s"],
                "ref": file_sha256(ref_path) if ref_path and ref_path.is_file() else None})
        if truth_path is not None:
            out["truth"] = digest({"partitions": pkeys, "offsets": offsets_sha,
                                   "truth": file_sha256(truth_path) if truth_path.is_file()
                                   else None})
        return out

    # a rerun whose offsets and every stage made from them are unchanged skips them all
    # without computing the offsets (whose libraries alone take 1.5 s to import)
    unchanged = (run.unchanged("offsets", offsets_key) and offsets_path.is_file()
                 and all(run.unchanged(n, k) for n, k in keys(file_sha256(offsets_path)
                                                              ).items()))
    minute = table = None
    if unchanged:
        run.stage("offsets", None, key=offsets_key)
    else:
        minute = archive.gather_minutes(records)
        table = run.stage("offsets", archive.offsets_stage, minute, cfg, failed, records,
                          key=offsets_key, reuse=False)
    stage_keys = keys(file_sha256(offsets_path))
    pending_align = None
    if "alignment" in stage_keys and not run.unchanged("alignment", stage_keys["alignment"]):
        # on a worker too, while the corrected days are written
        pending_align = engine.submit(archive.timed, (
            archive.alignment_on_minutes, archive.MinuteTask(tuple(records), cfg, table)))
    # the model tables (two CSV files of every 1-min sample) are written by a worker
    # too, after the alignment (the longest task) has started; the stage is recorded
    # after the corrected days, when they are surely done
    index_files = [cfg.resolve(cfg["kp"]["file"]), cfg.resolve(cfg["model"]["drivers"])]
    model_key = digest({"partitions": pkeys, "index_files": [  # named in its provenance
        file_sha256(p) if p is not None and p.is_file() else None for p in index_files]})
    pending_model = None if run.unchanged("model", model_key) else engine.submit(
        archive.timed, (archive.model_on_minutes, archive.MinuteTask(
            tuple(records), cfg, folder=str(run.outdir / "model"))))
    run.stage("corrected", archive.corrected_stage, run, table, records, cfg, engine,
              key=stage_keys["corrected"])
    run.stage("model", pending_model.result if pending_model else None, key=model_key)
    extras.update(minute=minute, table=table)
    if "truth" in stage_keys:
        from magcal.chain.truth import run_truth

        def truth():
            full = archive.gather_full(records)
            return run_truth(full, table, full.raw_hpen, cfg)

        extras["truth"] = run.stage("truth", truth, required=False, key=stage_keys["truth"])
    if "alignment" in stage_keys:
        extras["align"] = run.stage("alignment", pending_align.result if pending_align
                                    else None, required=False, key=stage_keys["alignment"])
    if discover_key is not None:
        extras["discover"] = run.stage("discover", pending_discover.result if pending_discover
                                       else None, required=False, key=discover_key)


def _simulate_input(cfg: ChainConfig, out: Path, progress) -> dict:
    """Write the simulated raw archive of ``[input] simulate`` into ``OUTDIR/raw``.

    ``simulate`` holds ``seed`` and any :class:`~magcal.simulate.archive.ArchiveConfig`
    field; the configuration names the files written as ``{outdir}/raw/...``.
    """
    import numpy as np

    from magcal.simulate.archive import ArchiveConfig, simulate_archive, write_archive_files

    spec = dict(cfg["input"]["simulate"])
    seed = spec.pop("seed", None)
    known = {f.name for f in fields(ArchiveConfig)}
    unknown = [k for k in spec if k not in known]
    if not isinstance(seed, int) or unknown:
        raise InputError("[input] simulate needs an integer seed and only "
                         f"{', '.join(sorted(known))}" + (f" (unknown {unknown[0]!r})"
                                                           if unknown else ""),
                         file=cfg.path, column="input.simulate")
    spec = {k: tuple(v) if isinstance(v, list) else v for k, v in spec.items()}
    if progress:
        progress(f"-> simulate the raw input (seed {seed}) into {out / 'raw'}")
    result = simulate_archive(ArchiveConfig(**spec), rng=np.random.default_rng(seed))
    return write_archive_files(result, out / "raw")


def _report(out: Path, cfg: ChainConfig):
    from magcal.report import write_html, write_pdf
    from magcal.report.uncertainty import build_uncertainty_report

    doc = build_uncertainty_report(out)
    doc.provenance = without_wall_clock(doc.provenance)

    def html(path):
        return write_html(doc, path)

    writers = {"REPORT.html": html}
    if cfg["report"]["pdf"]:
        writers["REPORT.pdf"] = lambda path: write_pdf(doc, path)
    return doc, StageProduct(stage="report", summary={"sections": [s.title for s in
                                                                     doc.sections]},
                             lines=(f"uncertainty report with {len(doc.sections)} sections",),
                             writers=writers)
