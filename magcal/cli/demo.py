"""``magcal demo``: ``magcal run`` on the chain configurations of ``data_samples/``
(the main job, CONTRACTS §6); see :mod:`magcal.demo`."""

from __future__ import annotations

import sys
from pathlib import Path

from magcal.errors import InputError


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "demo", help="run the whole chain on data_samples/ (the main job)",
        description="magcal run on data_samples/chain/CHAIN.toml (a simulated quarter of raw "
                    "two-sensor daily files through every stage: frames, PiCoG, Hpen, model, "
                    "offsets, corrected data, alignment, discovery, report, scored against "
                    "the injected truth) and data_samples/chain/SPIN.toml (the spinning "
                    "chain), writing products and manifests to OUTDIR.")
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

    def progress(line: str) -> None:
        print(line, file=sys.stderr, flush=True)

    results = run_demo(data, Path(args.output), progress=None if args.quiet else progress)
    for result in results:
        print(result.text())
        for warning in result.warnings:
            print(f"magcal demo: warning: {warning}", file=sys.stderr)
    return 3 if any(r.failed for r in results) else 0
