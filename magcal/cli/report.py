"""``magcal report``: uncertainty report (HTML, optional PDF) of a products folder."""

from __future__ import annotations

from pathlib import Path

from magcal.cli._common import add_output
from magcal.errors import InputError


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "report", help="uncertainty report (HTML and PDF) for a processed data set",
        description=(
            "Read the products of a processed data set (the folder 'magcal demo' writes: "
            "ac/, offsets/, alignment/, spin/, discover/) and write one self-contained HTML "
            "report with embedded figures (and optionally a PDF): AC cleaning quality, "
            "offsets over time, alignment angles with posteriors and by window, and an error "
            "budget above and below 0.1 mHz, each number with its source file. Missing "
            "products are reported as missing."))
    p.add_argument("products", help="products folder (e.g. the OUTDIR of 'magcal demo')")
    add_output(p, help_text="output REPORT.html")
    p.add_argument("--pdf", default=None, help="also write this PDF")
    p.set_defaults(file_outputs=("output", "pdf"))
    p.add_argument("--title", default="magcal uncertainty report", help="report title")
    p.set_defaults(func=run)


def run(args) -> int:
    from magcal.report import write_html, write_pdf
    from magcal.report.uncertainty import build_uncertainty_report

    root = Path(args.products)
    if not root.is_dir():
        raise InputError("products folder not found", file=root)
    doc = build_uncertainty_report(root, title=args.title)
    write_html(doc, args.output)
    if args.pdf:
        write_pdf(doc, args.pdf)
    return 0
