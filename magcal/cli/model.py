"""``magcal model``: IGRF + Tsyganenko field at the spacecraft in Hpen (CONTRACTS §2)."""

from __future__ import annotations

import sys

from magcal.cli._common import add_model_arguments, add_output, existing_file


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "model", help="Tsyganenko/IGRF model field at the spacecraft in Hpen",
        description="Evaluate IGRF + a Tsyganenko model (IRBEM, through spacepy) at the "
                    "times of DATA.csv and write it in Hpen (time,Hp,He,Hn). Samples whose "
                    "inputs are out of the model's range are written as NaN and counted.")
    p.add_argument("input", help="DATA: CSV time[,Hp,He,Hn][,lon_deg,lat_deg,r_re], GOES-R "
                                 "MAG L2 netCDF or ISTP CDF (format detected)")
    add_model_arguments(p)
    p.add_argument("--cadence", type=float, default=60.0, metavar="S",
                   help="evaluation cadence in s; denser times are interpolated (default 60)")
    add_output(p, help_text="MODEL.csv (time,Hp,He,Hn)")
    p.set_defaults(func=run)


def run(args) -> int:
    import pandas as pd

    from magcal.io.csv import write_csv_frame
    from magcal.io.formats import read_any
    from magcal.models.inputs import model_field_for, model_inputs

    frame = read_any(existing_file(args.input))
    inp = model_inputs(frame, longitude_deg=args.longitude, kp_path=args.kp,
                       drivers_path=args.drivers, model=args.model)
    res = model_field_for(frame, inp, cadence_s=args.cadence, n_jobs=args.jobs,
                          cache_dir=args.cache_dir)
    out = pd.DataFrame(res.b_hpen_nT, index=frame.index, columns=["Hp", "He", "Hn"])
    write_csv_frame(args.output, out, provenance=res.provenance)
    why = ", ".join(f"{k}: {v}" for k, v in res.reasons.items()
                    if not k.startswith("info:")) or "none"
    info = "; ".join(f"{k[5:].strip()}: {v}" for k, v in res.reasons.items()
                     if k.startswith("info:"))
    print(f"magcal model: {len(out)} samples, {res.model}, {res.n_invalid} NaN "
          f"(reasons: {why}){'; ' + info if info else ''}; cache hits {res.cache_hits}",
          file=sys.stderr)
    return 0
