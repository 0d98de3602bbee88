"""``magcal qc INPUT... -o QUALITY.csv``: the per-sample quality flag of any input files."""

from __future__ import annotations

import json
import sys

from magcal.cli._common import add_output, positive_float
from magcal.io.formats import FORMATS


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "qc", help="flag spikes, saturated/stuck values, fills and time anomalies",
        description="Run the sample quality checks of 'magcal run' on any input files "
                    "(joined in time order) and write time,quality (CONTRACTS 7.1 bits: "
                    "1 spike, 2 saturated or stuck, 4 fill or non-finite, 8 time anomaly; "
                    "16 and 32 are set by the chain only). The summary (JSON) goes to stdout.")
    p.add_argument("inputs", nargs="+", help="input file(s), any supported format")
    add_output(p, help_text="output CSV: time,quality")
    p.add_argument("--config", metavar="CHAIN.toml",
                   help="take the thresholds from this configuration's [qc] section")
    p.add_argument("--sensors", help="comma-separated, physically distinct sensors to check "
                                      "(default: all, frames of one sensor included); a "
                                      "spike that two of them show at once is a field "
                                      "(a spacecraft pulse), not flagged")
    p.add_argument("--range-nt", type=positive_float, default=None, metavar="NT",
                   help="declared instrument range in nT (> 0): |component| >= NT is "
                        "saturated")
    p.add_argument("--format", choices=("auto",) + FORMATS, default="auto",
                   help="input format (default: detected from the content)")
    p.set_defaults(func=run)


def run(args) -> int:
    from dataclasses import replace

    from magcal.io.csv import write_csv_frame
    from magcal.qc import QCSettings
    from magcal.qc.files import check_files

    settings = QCSettings()
    if args.config:
        from magcal.chain.config import read_chain_config

        settings = QCSettings.from_mapping(read_chain_config(args.config)["qc"])
    if args.range_nt is not None:
        settings = replace(settings, range_nT=args.range_nt)
    sensors = [s.strip() for s in args.sensors.split(",")] if args.sensors else None
    res = check_files(args.inputs, settings, sensors=sensors, input_format=args.format)
    write_csv_frame(args.output, res.to_frame(), provenance=res.to_json())
    summary = res.to_json()
    for line in res.warnings():
        print(f"magcal qc: warning: {line}", file=sys.stderr)
    keys = ("n_samples", "n_flagged", "counts", "by_sensor", "checked", "incomplete", "units",
            "columns_not_checked", "time_gaps")
    print(json.dumps({k: summary[k] for k in keys if k in summary}, indent=1))
    print(f"magcal qc: {summary['n_flagged']} of {summary['n_samples']} samples flagged "
          f"-> {args.output}", file=sys.stderr)
    return 0
