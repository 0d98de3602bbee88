"""``magcal run CHAIN.toml -o OUTDIR``: the whole chain from one configuration (CONTRACTS §7)."""

from __future__ import annotations

import sys

from magcal.cli._common import existing_file

#: Exit status when some stages (partitions) failed and the rest completed.
EXIT_PARTIAL = 3


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "run", help="run the whole chain from a CHAIN.toml configuration",
        description="Read the instrument files of CHAIN.toml (CSV, GOES-R netCDF or CDF, "
                    "detected by content) and run every stage: sensor frames, PiCoG, Hpen, "
                    "model field, quiet selection, offset product, corrected data, "
                    "alignment, discovery, report; or the spinning-spacecraft chain when the "
                    "file has a [spin] section. Products and MANIFEST.json go to OUTDIR. "
                    "An archive of files is partitioned by file on Dask; a rerun skips "
                    "unchanged partitions and stages. Exit 0 all done, 3 some stages or "
                    "partitions failed (named in the manifest), 2 bad configuration or input.")
    p.add_argument("config", help="CHAIN.toml (schema in the README)")
    p.add_argument("-o", "--output", required=True, help="output folder OUTDIR")
    p.add_argument("--workers", type=int, default=None,
                   help="local Dask worker processes (default: the usable cores)")
    p.add_argument("--scheduler", default=None,
                   help="address of a running dask.distributed scheduler (tcp://host:port) "
                        "to run the partitions on; its workers must see the same files")
    p.add_argument("--quiet", action="store_true",
                   help="print only the summary (no progress lines or bars)")
    p.set_defaults(func=run)


def run(args) -> int:
    from magcal.chain import run_chain

    config = existing_file(args.config)

    def progress(line: str) -> None:
        print(line, file=sys.stderr, flush=True)

    result = run_chain(config, args.output, progress=None if args.quiet else progress,
                       workers=args.workers, scheduler=args.scheduler)
    print(result.text())
    for warning in result.warnings:
        print(f"magcal run: warning: {warning}", file=sys.stderr)
    for rec in result.failed:
        print(f"magcal run: {rec.stage} failed: {rec.error}", file=sys.stderr)
    return EXIT_PARTIAL if result.failed else 0
