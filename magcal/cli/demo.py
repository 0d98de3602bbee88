"""``magcal demo``: run the whole chain on ``data_samples/`` (the main job, CONTRACTS §6).

The demo is a thin driver: each stage calls the public API of its subpackage through
:mod:`magcal.demo`, writes its products to OUTDIR and contributes a line to the
summary. A stage whose subpackage is not built yet prints "not yet available" and the
demo goes on.
"""

from __future__ import annotations

import sys
from pathlib import Path

from magcal.errors import InputError


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "demo", help="run the whole chain on data_samples/ (the main job)",
        description="Run AC cleaning, model comparison and monthly offsets, alignment, spin "
                    "calibration and model-gap discovery on the embedded data_samples/, "
                    "writing products and a report to OUTDIR.")
    p.add_argument("-o", "--output", default="magcal-demo",
                   help="output directory (default: magcal-demo/)")
    p.add_argument("--data", default=None,
                   help="folder with the sample data (default: ./data_samples, else the "
                        "data_samples/ beside the installed package source)")
    p.add_argument("--quiet", action="store_true", help="print only the summary")
    p.set_defaults(func=run)


def find_data_samples(explicit: str | None = None) -> Path:
    """Locate ``data_samples/``: the explicit path, ./data_samples, or the source checkout's."""
    candidates = [Path(explicit)] if explicit else [
        Path.cwd() / "data_samples", Path(__file__).resolve().parents[2] / "data_samples"]
    for c in candidates:
        if (c / "README.md").is_file():
            return c
    raise InputError("data_samples/ not found (run from the repository root, pass --data, or "
                     "regenerate it with: python workflows/make_data_samples.py)",
                     file=candidates[0])


def run(args) -> int:
    from magcal.demo import run_demo

    data = find_data_samples(args.data)
    summary = run_demo(data, Path(args.output), progress=None if args.quiet else sys.stdout)
    print(summary.text())
    return 0 if summary.ok else 1
