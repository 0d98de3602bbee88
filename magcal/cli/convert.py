"""``magcal convert INPUT -o OUTPUT``: any supported instrument file as CSV or ISTP CDF."""

from __future__ import annotations

import sys

from magcal.io.formats import FORMATS


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "convert", help="convert an instrument file (CSV, GOES-R netCDF, CDF) to CSV or CDF",
        description="Read one or more files of any supported format (detected by content: "
                    "CSV with a time header, GOES-R MAG L2 netCDF4, ISTP CDF) and write them, "
                    "joined in time order, as a CONTRACTS §0 CSV or an ISTP CDF.")
    p.add_argument("inputs", nargs="+", help="input file(s)")
    p.add_argument("-o", "--output", required=True, help="output file (.csv, .csv.gz or .cdf)")
    p.add_argument("--to", choices=("csv", "cdf"), default=None,
                   help="output format (default: from the output name; CSV unless .cdf)")
    p.add_argument("--format", choices=("auto",) + FORMATS, default="auto",
                   help="input format (default: detected from the content)")
    p.set_defaults(func=run)


def run(args) -> int:
    from magcal.io.formats import convert_files

    fmt = args.to or ("cdf" if str(args.output).lower().endswith(".cdf") else "csv")
    frame = convert_files(args.inputs, args.output, fmt, input_format=args.format)
    print(f"magcal convert: {len(frame)} samples, {frame.shape[1]} columns from "
          f"{len(args.inputs)} file(s) ({', '.join(sorted(set(frame.attrs['formats'])))}) "
          f"-> {args.output} ({fmt})", file=sys.stderr)
    return 0
