"""``magcal convert INPUT -o OUTPUT``: any supported instrument file as CSV, ISTP CDF or
CF-1.8 netCDF4."""

from __future__ import annotations

import sys

from magcal.cli._common import add_output
from magcal.io.formats import FORMATS


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "convert",
        help="convert an instrument file (CSV, GOES-R netCDF, CDF) to CSV, CDF or netCDF",
        description="Read one or more files of any supported format (detected by content: "
                    "CSV with a time header, GOES-R MAG L2 netCDF4, ISTP CDF) and write them, "
                    "joined in time order, as a CONTRACTS §0 CSV, an ISTP CDF or a CF-1.8 "
                    "netCDF4 file.")
    p.add_argument("inputs", nargs="+", help="input file(s)")
    add_output(p, help_text="output file (.csv, .csv.gz, .cdf or .nc)")
    p.add_argument("--to", choices=("csv", "cdf", "netcdf"), default=None,
                   help="output format (default: from the output name; CSV unless .cdf "
                        "or .nc)")
    p.add_argument("--format", choices=("auto",) + FORMATS, default="auto",
                   help="input format (default: detected from the content)")
    p.set_defaults(func=run)


def run(args) -> int:
    from magcal.io.formats import convert_files

    name = str(args.output).lower()
    fmt = args.to or ("cdf" if name.endswith(".cdf") else
                      "netcdf" if name.endswith(".nc") else "csv")
    frame = convert_files(args.inputs, args.output, fmt, input_format=args.format)
    print(f"magcal convert: {len(frame)} samples, {frame.shape[1]} columns from "
          f"{len(args.inputs)} file(s) ({', '.join(sorted(set(frame.attrs['formats'])))}) "
          f"-> {args.output} ({fmt})", file=sys.stderr)
    return 0
