"""The main job: the whole magcal chain on ``data_samples/``.

Each stage is a small function that calls the public API of one subpackage, writes its
products under the output folder and returns a :class:`StageResult`. Stages whose
subpackage is not built yet report "not yet available"; a stage that fails reports the
error and the demo continues with the next one, so one broken stage never hides the
others. :func:`run_demo` returns a :class:`DemoSummary`.
"""

from __future__ import annotations

import importlib.util
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, TextIO

from magcal._version import __version__
from magcal.errors import NotYetAvailableError
from magcal.io.jsonio import write_json
from magcal.provenance import make_provenance


@dataclass(frozen=True)
class StageResult:
    """Outcome of one demo stage."""

    name: str
    status: str  # "ok", "not yet available", "failed"
    lines: tuple[str, ...] = ()
    products: tuple[str, ...] = ()
    seconds: float = 0.0
    error: str = ""
    metrics: dict = field(default_factory=dict)


@dataclass(frozen=True)
class DemoSummary:
    """All stage results of one demo run."""

    outdir: Path
    stages: tuple[StageResult, ...] = field(default_factory=tuple)

    @property
    def ok(self) -> bool:
        return all(s.status != "failed" for s in self.stages)

    def text(self) -> str:
        out = [f"magcal {__version__} demo -> {self.outdir}"]
        for s in self.stages:
            out.append(f"[{s.status}] {s.name} ({s.seconds:.1f} s)")
            out += [f"    {line}" for line in s.lines]
            if s.error:
                out.append(f"    error: {s.error}")
        return "\n".join(out)


def require(*modules: str) -> None:
    """Raise :class:`NotYetAvailableError` unless every module can be imported."""
    for name in modules:
        try:
            found = importlib.util.find_spec(name) is not None
        except ModuleNotFoundError:
            found = False
        if not found:
            raise NotYetAvailableError(f"{name} is not built yet")


def _run_stage(name: str, func: Callable, data: Path, outdir: Path,
               context: dict) -> StageResult:
    start = time.perf_counter()
    try:
        out = func(data, outdir, context)
        lines, products = out[0], out[1]
        metrics = out[2] if len(out) > 2 else {}
    except NotYetAvailableError as exc:
        return StageResult(name, "not yet available", (str(exc),),
                           seconds=time.perf_counter() - start)
    except Exception as exc:  # noqa: BLE001 - a failed stage must not hide the others
        detail = traceback.format_exc(limit=3).strip().splitlines()[-1]
        return StageResult(name, "failed", seconds=time.perf_counter() - start,
                           error=f"{type(exc).__name__}: {exc} [{detail}]")
    return StageResult(name, "ok", tuple(lines), tuple(str(p) for p in products),
                       time.perf_counter() - start, metrics=metrics)


def stages() -> list[tuple[str, Callable]]:
    """The demo stages in chain order (imported lazily from :mod:`magcal.demo_stages`)."""
    from magcal import demo_stages

    return demo_stages.STAGES


def run_demo(data: Path, outdir: Path, progress: TextIO | None = None) -> DemoSummary:
    """Run every stage on ``data`` (a data_samples folder), writing into ``outdir``."""
    outdir.mkdir(parents=True, exist_ok=True)
    context: dict = {}
    results = []
    for name, func in stages():
        if progress is not None:
            print(f"-> {name} ...", file=progress, flush=True)
        result = _run_stage(name, func, data, outdir / name.split()[0].lower(), context)
        results.append(result)
        if progress is not None:
            print(f"   {result.status} in {result.seconds:.1f} s", file=progress, flush=True)
    summary = DemoSummary(outdir, tuple(results))
    write_json(outdir / "summary.json", {
        "stages": [s.__dict__ for s in results],
        "provenance": make_provenance("demo", {"data": str(data), "outdir": str(outdir)}),
    })
    return summary
