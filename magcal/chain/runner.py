"""``run_chain``: one configuration in, every product and a manifest out.

The runner reads the configuration, optionally simulates its input (the demo), reads
the instrument files, then calls the stages in chain order::

    read -> frames -> ac (PiCoG) -> Hpen -> model -> offsets -> corrected
         -> alignment -> discover -> report

Each stage's :class:`~magcal.chain.product.StageProduct` is written to
``OUTDIR/<stage>/`` and listed in ``OUTDIR/MANIFEST.json`` with its SHA-256 and the
SHA-256 of the inputs it was made from (CONTRACTS §7). A stage that cannot run on the
data (e.g. alignment on minutes of data) is listed under ``failed`` with its reason;
the rest complete.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Callable

from magcal._version import __version__
from magcal.chain.config import ChainConfig, read_chain_config
from magcal.chain.product import StageProduct
from magcal.errors import InputError
from magcal.io.jsonio import write_json
from magcal.provenance import file_sha256, make_provenance


@dataclass(frozen=True)
class StageRecord:
    """What one stage did: its product (or failure) and timing."""

    stage: str
    status: str  # "ok" or "failed"
    seconds: float
    product: StageProduct | None = None
    paths: tuple = ()
    error: str = ""


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
        Stage outputs a caller may score (e.g. the demo against its truth).
    """

    outdir: Path
    records: tuple = ()
    manifest: dict = field(default_factory=dict)
    extras: dict = field(default_factory=dict)

    @property
    def failed(self) -> list[StageRecord]:
        return [r for r in self.records if r.status != "ok"]

    @property
    def warnings(self) -> list[str]:
        return [f"{r.stage}: {w}" for r in self.records if r.product for w in r.product.warnings]

    def text(self) -> str:
        """Console summary: one block per stage."""
        out = [f"magcal {__version__} run -> {self.outdir}"]
        for r in self.records:
            out.append(f"[{r.status}] {r.stage} ({r.seconds:.1f} s)")
            if r.product is not None:
                out += [f"    {line}" for line in r.product.lines]
            if r.error:
                out.append(f"    reason: {r.error}")
        return "\n".join(out)


class _Run:
    """Book-keeping of one run: stage records, manifest entries, progress."""

    def __init__(self, outdir: Path, inputs: list[Path], progress: Callable[[str], None] | None):
        self.outdir = outdir
        self.records: list[StageRecord] = []
        self.entries: list[dict] = []
        self.inputs = [{"path": str(p), "sha256": file_sha256(p)} for p in inputs]
        self.progress = progress or (lambda text: None)

    def stage(self, name: str, func: Callable, *args, required: bool = True):
        """Run one stage; write its product; on failure record it (and re-raise if the
        later stages need its output)."""
        self.progress(f"-> {name}")
        start = time.perf_counter()
        try:
            value, product = func(*args)
        except InputError as exc:
            self.records.append(StageRecord(name, "failed", time.perf_counter() - start,
                                            error=str(exc)))
            self.progress(f"   failed: {exc}")
            if required:
                raise
            return None
        paths = product.write(self.outdir / product.stage)
        for p in paths:
            self.entries.append({"path": str(p.relative_to(self.outdir)), "stage": product.stage,
                                 "sha256": file_sha256(p), "inputs": [i["sha256"] for i in
                                                                      self.inputs]})
        self.records.append(StageRecord(name, "ok", time.perf_counter() - start, product,
                                        tuple(paths)))
        self.progress(f"   ok in {self.records[-1].seconds:.1f} s")
        return value

    def manifest(self, config: ChainConfig) -> dict:
        failed = [{"partition": r.stage, "stage": r.stage, "reason": r.error}
                  for r in self.records if r.status != "ok"]
        return {"products": self.entries, "failed": failed, "inputs": self.inputs,
                "warnings": [f"{r.stage}: {w}" for r in self.records if r.product
                             for w in r.product.warnings],
                "stages": [{"stage": r.stage, "status": r.status, "seconds": r.seconds}
                           for r in self.records],
                "provenance": make_provenance("run", config.as_dict(), inputs=[config.path])}


def run_chain(config: ChainConfig | str | Path, outdir: str | Path,
              progress: Callable[[str], None] | None = None,
              workers: int | None = None) -> ChainResult:
    """Run the whole chain of a configuration and write every product into ``outdir``.

    Parameters
    ----------
    config : ChainConfig or path-like
        The configuration or the path of its ``CHAIN.toml``.
    outdir : path-like
        Output folder (created).
    progress : callable, optional
        Called with one line of text per stage start and end.
    workers : int, optional
        Worker processes of the parallel stages (model field); default the
        configuration's ``[model] jobs`` or the usable cores.

    Returns
    -------
    ChainResult

    Raises
    ------
    InputError
        Bad configuration, unreadable input, or a stage the later stages depend on
        (reading, frames, AC, model) that cannot run on the data.
    """
    cfg = config if isinstance(config, ChainConfig) else read_chain_config(config)
    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    extras: dict = {}
    cfg = replace(cfg, outdir=out)
    if workers is not None:
        if workers < 1:
            raise InputError(f"--workers must be at least 1, got {workers}")
        cfg.sections["model"]["jobs"] = workers
    if cfg["input"]["simulate"]:
        extras["simulated"] = _simulate_input(cfg, out, progress)
    files = cfg.input_files()
    run = _Run(out, files, progress)
    try:
        if cfg.kind == "spin":
            from magcal.chain.spin import spin_stages

            spin_stages(run, cfg, files, extras)
        else:
            _geostationary_stages(run, cfg, files, extras)
        if cfg["report"]["enabled"]:
            run.stage("report", _report, out, cfg, required=False)
    finally:  # a run stopped by bad input still says what it did and why it stopped
        manifest = run.manifest(cfg)
        write_json(out / "MANIFEST.json", manifest)
    return ChainResult(out, tuple(run.records), manifest, extras)


def _geostationary_stages(run: _Run, cfg: ChainConfig, files, extras: dict) -> None:
    from magcal.chain import calibrate, prepare

    series = run.stage("read", _read, cfg, files)
    common = run.stage("frames", prepare.run_frames, series, cfg)
    cleaned = run.stage("ac", prepare.run_ac, common, cfg)
    minute = run.stage("model", prepare.run_model, series, cleaned, cfg)
    table = run.stage("offsets", calibrate.run_offsets, minute, cfg)
    corrected = run.stage("corrected", calibrate.run_corrected, cleaned, minute, table, cfg)
    extras.update(series=series, cleaned=cleaned, minute=minute, table=table,
                  corrected=corrected)
    if cfg["truth"]["file"]:
        from magcal.chain.truth import run_truth

        extras["truth"] = run.stage("truth", run_truth, cleaned, table, cleaned.raw_hpen, cfg,
                                    required=False)
    if cfg["alignment"]["enabled"]:
        extras["align"] = run.stage("alignment", calibrate.run_alignment, corrected, minute,
                                    cfg, required=False)
    if cfg["discover"]["enabled"]:
        extras["discover"] = run.stage("discover", calibrate.run_discovery, minute, cfg,
                                       required=False)


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


def _read(cfg: ChainConfig, files):
    from magcal.chain.prepare import load_series

    series = load_series(cfg, files)
    span_h = (series.times[-1] - series.times[0]).total_seconds() / 3600.0
    summary = {"files": [str(f) for f in files], "n_samples": len(series),
               "cadence_s": series.cadence_s, "sensors": [s for s in series.sensors if s],
               "span_hours": span_h, "start": str(series.times[0]),
               "end": str(series.times[-1]), "history": list(series.provenance)}
    line = (f"{len(files)} file(s), {len(series)} samples at {series.cadence_s:g} s over "
            f"{span_h:.2f} h; sensors {', '.join(summary['sensors'])}")
    return series, StageProduct(stage="read", summary=summary, lines=(line,),
                                provenance=make_provenance("read", {}, inputs=files))


def _report(out: Path, cfg: ChainConfig):
    from magcal.report import write_html, write_pdf
    from magcal.report.uncertainty import build_uncertainty_report

    doc = build_uncertainty_report(out)

    def html(path):
        return write_html(doc, path)

    writers = {"REPORT.html": html}
    if cfg["report"]["pdf"]:
        writers["REPORT.pdf"] = lambda path: write_pdf(doc, path)
    return doc, StageProduct(stage="report", summary={"sections": [s.title for s in
                                                                     doc.sections]},
                             lines=(f"uncertainty report with {len(doc.sections)} sections",),
                             writers=writers)
