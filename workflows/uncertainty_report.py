"""Uncertainty report of a processed data set, end to end.

Usage::

    python workflows/uncertainty_report.py [PRODUCTS_DIR] [-o OUTDIR]

With PRODUCTS_DIR (e.g. the OUTDIR of ``magcal demo``) the report is built from it.
Without, a small products folder is made first from the simulated month (30 days of
1-min Hpen data against T89 with the local-time field T89 lacks): offsets (median and
local-time balanced), the offset-corrected month, the alignment of ``magcal align --kp
--longitude --mcmc`` on it; then the report library writes REPORT.html and REPORT.pdf.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path


def make_month_products(out: Path, seed: int = 20191101) -> Path:
    """Offsets, corrected month, model and ALIGN.json of the simulated month under ``out``."""
    import numpy as np
    import pandas as pd

    from magcal.alignment.product import (AlignSettings, align_product, match_frames,
                                          quiet_from_kp)
    from magcal.indices import read_kp, write_kp_csv
    from magcal.io.csv import read_csv_frame, write_csv_frame
    from magcal.offsets import apply_offsets, fit_offsets, write_offsets_csv
    from magcal.simulate.month import MonthConfig, simulate_month

    cfg = MonthConfig()
    month = simulate_month(cfg, rng=np.random.default_rng(seed))
    (out / "offsets").mkdir(parents=True, exist_ok=True)
    (out / "alignment").mkdir(parents=True, exist_ok=True)
    kp_path = write_kp_csv(out / "offsets" / "kp.csv", month.kp_3h)
    kp = month.kp_3h
    tables = {}
    for method in ("median", "lt_balanced"):
        table, det = fit_offsets(month.times, month.measured_nT, cfg.lon_deg, 0.0, cfg.r_re,
                                 kp, model="T89", kp_max=1.0, window_days=28, step_days=7,
                                 method=method)
        name = "OFFSETS.csv" if method == "median" else f"OFFSETS_{method}.csv"
        write_offsets_csv(out / "offsets" / name, table)
        tables[method] = table
    idx = pd.DatetimeIndex(month.times, name="time").tz_localize("UTC")
    corrected, _, _ = apply_offsets(month.times, month.measured_nT, tables["lt_balanced"])
    write_csv_frame(out / "offsets" / "CORRECTED.csv.gz",
                    pd.DataFrame(corrected, index=idx, columns=["Hp", "He", "Hn"]))
    write_csv_frame(out / "offsets" / "MODEL_T89.csv.gz",
                    pd.DataFrame(det["model"], index=idx, columns=["Hp", "He", "Hn"]))
    # ALIGN.json as `magcal align CORRECTED --reference MODEL --kp --longitude --mcmc
    # --seed 2019` writes it, through the same library call
    data_path, ref_path = out / "offsets" / "CORRECTED.csv.gz", out / "offsets" / "MODEL_T89.csv.gz"
    pair = match_frames(read_csv_frame(data_path), read_csv_frame(ref_path),
                        data_name=data_path, ref_name=ref_path)
    quiet = quiet_from_kp(pair.times, read_kp(kp_path), 1.0, kp_name=kp_path)
    product = align_product(pair.times, pair.data, pair.ref, lon_deg=float(cfg.lon_deg),
                            lon_source="--longitude", quiet=quiet,
                            selection={"kp_file": str(kp_path), "kp_max": 1.0},
                            settings=AlignSettings(mcmc=True, seed=2019),
                            inputs=[data_path, ref_path, kp_path],
                            matched_rows=pair.matched_rows)
    product.write(out / "alignment" / "ALIGN.json")
    return out


def main_(argv=None) -> int:
    """Run the workflow; bad input is one line on stderr and exit status 2."""
    from magcal.errors import InputError

    try:
        return _run(argv)
    except InputError as exc:
        print(f"uncertainty_report: error: {exc}", file=sys.stderr)
        return 2


def _run(argv=None) -> int:
    from magcal.errors import InputError
    from magcal.offline import configure_offline

    configure_offline()
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("products", nargs="?", default=None,
                    help="products folder (default: make one from the simulated month)")
    ap.add_argument("-o", "--outdir", default="uncertainty-report",
                    help="output folder (default: uncertainty-report in the working "
                         "directory)")
    args = ap.parse_args(argv)
    from magcal.report import write_html, write_pdf
    from magcal.report.uncertainty import build_uncertainty_report

    if args.products and not Path(args.products).is_dir():
        raise InputError("products folder not found", file=args.products)
    out = Path(args.outdir)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    products = Path(args.products) if args.products else make_month_products(out / "products")
    doc = build_uncertainty_report(products, title="magcal uncertainty report")
    write_html(doc, out / "REPORT.html")
    write_pdf(doc, out / "REPORT.pdf")
    print(f"report of {products} -> {out / 'REPORT.html'}, {out / 'REPORT.pdf'} "
          f"({time.perf_counter() - t0:.1f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main_())
