"""Monthly DC offsets of AC-cleaned geostationary data (SOSMAG paper §5.3, issue 4).

Given AC-cleaned Hpen data, the position and a Kp file, writes into OUTDIR:

* ``OFFSETS.csv`` (+ ``.provenance.json``) and ``OFFSETS.cdf`` (ISTP attributes,
  provenance in the global attributes): one row/record per 28-day window, step 7 days;
* ``CORRECTED.csv``: the data minus the interpolated offsets, with ``offset_flag``;
* ``fig19_residual_local_time.png``: data minus model vs local time, one curve per month;
* ``fig20_offsets.png``: the offsets with their spreads;
* ``summary.json``: counts, fractions selected, peak-to-peak of the local-time curves.

Usage::

    python workflows/monthly_offsets.py DATA.csv --kp KP_FILE --longitude 128.2 -o OUTDIR
    python workflows/monthly_offsets.py --simulate-days 90 -o OUTDIR   # simulated input
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np


def main(argv=None) -> int:
    """Run the workflow; bad input is one line on stderr and exit status 2."""
    from magcal.errors import InputError

    try:
        return _run(argv)
    except InputError as exc:
        print(f"monthly_offsets: error: {exc}", file=sys.stderr)
        return 2


def _run(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("input", nargs="?", help="DATA.csv time,Hp,He,Hn (AC-cleaned)")
    parser.add_argument("--kp", help="Kp file (any format magcal reads)")
    parser.add_argument("--longitude", type=float, default=None)
    parser.add_argument("--model", default="T89")
    parser.add_argument("--drivers", default=None)
    parser.add_argument("--kp-max", type=float, default=1.0)
    parser.add_argument("--window-days", type=float, default=28.0)
    parser.add_argument("--step-days", type=float, default=7.0)
    parser.add_argument("--method", choices=("median", "lt_balanced"), default="median")
    parser.add_argument("--simulate-days", type=float, default=None,
                        help="ignore INPUT and run on simulate_month data of this length")
    parser.add_argument("--seed", type=int, default=2019)
    parser.add_argument("--cache-dir", default=None)
    parser.add_argument("-o", "--output", required=True, help="output folder")
    args = parser.parse_args(argv)

    from magcal.offline import configure_offline

    configure_offline()
    from magcal.io.jsonio import write_json
    from magcal.offsets import apply_offsets, fit_offsets_frame, write_offsets_csv
    from magcal.offsets.plots import plot_offsets, plot_residual_local_time
    from magcal.provenance import make_provenance

    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    inputs = []
    if args.simulate_days:
        from magcal.indices import write_kp_csv
        from magcal.io.csv import write_csv_frame
        from magcal.simulate.month import MonthConfig, simulate_month

        sim = simulate_month(MonthConfig(n_days=args.simulate_days),
                             rng=np.random.default_rng(args.seed))
        write_csv_frame(out / "simulated_DATA.csv", sim.to_frame())
        write_kp_csv(out / "simulated_KP.csv", sim.kp_3h, thirds=True)
        args.input, args.kp = str(out / "simulated_DATA.csv"), str(out / "simulated_KP.csv")
        args.longitude = sim.config.lon_deg if args.longitude is None else args.longitude
    if not args.input or not args.kp:
        parser.error("give DATA.csv and --kp, or --simulate-days")
    from magcal.io.csv import read_csv_frame, write_csv_frame
    from magcal.models.inputs import model_inputs

    frame = read_csv_frame(args.input, required=["Hp", "He", "Hn"])
    inp = model_inputs(frame, longitude_deg=args.longitude, kp_path=args.kp,
                       drivers_path=args.drivers, model=args.model)
    inputs += [args.input, *inp.files]
    times = frame.index.tz_convert("UTC").tz_localize(None).to_numpy()
    params = {k: getattr(args, k) for k in ("model", "kp_max", "window_days", "step_days",
                                            "method", "longitude", "simulate_days")}
    prov = make_provenance("monthly offsets", params, inputs=inputs)
    table, det = fit_offsets_frame(frame, inp, kp_max=args.kp_max,
                                   window_days=args.window_days, step_days=args.step_days,
                                   method=args.method, cache_dir=args.cache_dir,
                                   provenance=prov)
    for warning in table.warnings:
        print(f"monthly offsets: warning: {warning}", file=sys.stderr)
    write_offsets_csv(out / "OFFSETS.csv", table)
    _write_cdf(out / "OFFSETS.cdf", table, prov)
    corrected, _, flag = apply_offsets(times, frame[["Hp", "He", "Hn"]].to_numpy(), table)
    import pandas as pd

    corr = pd.DataFrame(corrected, index=frame.index, columns=["Hp", "He", "Hn"])
    corr["offset_flag"] = flag.astype(int)
    write_csv_frame(out / "CORRECTED.csv", corr,
                    provenance=make_provenance("offsets apply", {}, inputs=inputs,
                                               history=[prov]))
    diff = det["data"] - det["model"]
    lon_lt = det["lon_deg"]
    pp = plot_residual_local_time(out / "fig19_residual_local_time.png", det["times"], diff,
                                  lon_lt, selected=det["quiet"])
    plot_offsets(out / "fig20_offsets.png", table)
    summary = {"n_windows": len(table), "n_valid": int(table.valid.sum()),
               "fraction_quiet": float(np.mean(det["quiet"])),
               "local_time_peak_to_peak_nT": {"Hp": pp[:, 0], "He": pp[:, 1], "Hn": pp[:, 2]},
               "model_report": det["model_report"], "provenance": prov}
    write_json(out / "summary.json", summary)
    print(f"monthly offsets: {len(table)} windows ({int(table.valid.sum())} valid), "
          f"{np.mean(det['quiet']):.1%} quiet 1-min samples -> {out}")
    return 0


def _write_cdf(path, table, prov) -> None:
    """OFFSETS.cdf via magcal.io.cdf.write_cdf_product (ISTP attributes, provenance)."""
    from magcal.io.cdf import write_cdf_product

    labels = {"labels": ["Hp", "He", "Hn"]}
    variables = {
        "offset_hpen": (table.offset_nT, {"UNITS": "nT", "CATDESC":
                        "DC offset (median of data minus model, Kp <= kp_max) in Hpen",
                        **labels}),
        "offset_std": (table.std_nT, {"UNITS": "nT", "CATDESC":
                       "standard deviation of the selected differences", **labels}),
        "offset_mad": (table.mad_nT, {"UNITS": "nT", "CATDESC":
                       "median absolute deviation x 1.4826 of the selected differences",
                       **labels}),
        "n_used": (table.n_used.astype(np.int64), {"CATDESC": "samples used"}),
        "fraction_used": (table.fraction_used, {"CATDESC": "fraction of samples selected"}),
        "days_covered": (np.asarray(table.days_covered, dtype=np.int64),
                         {"CATDESC": "UTC days of the window holding used samples"}),
        "lt_hours_covered": (np.asarray(table.lt_hours_covered, dtype=np.int64),
                             {"CATDESC": "local-time hours (of 24) holding used samples, "
                                         "-1 unknown"}),
    }
    gattrs = {"Project": "magcal", "Source_name": "GK2A>GEO-KOMPSAT-2A",
              "Data_type": "L3>offsets", "Descriptor": "MAG>magnetometer",
              "Logical_source_description": "sliding-window DC offsets against a field model",
              "PI_name": "n/a", "PI_affiliation": "n/a", "Mission_group": "GEO-KOMPSAT",
              "TEXT": "DC offsets per 28-day window stepped by 7 days (SOSMAG paper 5.3); "
                      "Epoch is the window centre."}
    write_cdf_product(path, table.center, variables, gattrs, provenance=prov)


if __name__ == "__main__":
    sys.exit(main())
