"""``magcal model``: IGRF + Tsyganenko field at the spacecraft in Hpen (CONTRACTS §2)."""

from __future__ import annotations

import sys

import numpy as np

from magcal.cli._common import add_output, existing_file
from magcal.errors import InputError

GEO_R_RE = 6.6


def add_model_arguments(p) -> None:
    """Options shared by ``model`` and ``offsets fit``."""
    p.add_argument("--kp", required=True, metavar="KP_FILE",
                   help="Kp file: GFZ Kp_ap_Ap_SN_F107 text, GFZ Kp_def CSV, CelesTrak "
                        "space-weather text or CSV time,kp (format detected)")
    p.add_argument("--model", default="T89", type=str.upper,
                   choices=("IGRF", "T89", "T96", "T01", "T04"),
                   help="field model: IGRF only, or IGRF + T89 (Kp), T96, T01, T04 = "
                        "TS04/TS05 (solar-wind drivers, --drivers); default T89")
    p.add_argument("--drivers", metavar="FILE",
                   help="Qin-Denton or OMNI2 hourly text, or CSV with IRBEM input columns "
                        "(needed by T96, T01, T04)")
    p.add_argument("--longitude", type=float, metavar="DEG",
                   help="geostationary longitude (deg east; r = 6.6 RE, latitude 0); "
                        "otherwise DATA.csv needs columns lon_deg,lat_deg,r_re")
    p.add_argument("--cache-dir", metavar="DIR",
                   help="on-disk cache of model evaluations (reruns are near free)")
    p.add_argument("--jobs", type=int, default=None,
                   help="worker processes for the model (default: all usable cores)")


def load_inputs(args, frame):
    """Position, Kp series and drivers for the rows of ``frame``; raises InputError."""
    from magcal.indices import read_drivers, read_kp

    src = frame.attrs.get("source")
    if args.longitude is not None:
        if not -360.0 <= args.longitude <= 360.0:
            raise InputError(f"--longitude {args.longitude} is not an angle in degrees")
        lon, lat, r = float(args.longitude), 0.0, GEO_R_RE
    else:
        cols = ("lon_deg", "lat_deg", "r_re")
        missing = [c for c in cols if c not in frame.columns]
        if missing:
            raise InputError("give --longitude or columns lon_deg,lat_deg,r_re "
                             f"(missing {', '.join(missing)})", file=src, column=missing[0])
        lon, lat, r = (frame[c].to_numpy(dtype=float) for c in cols)
    kp = read_kp(existing_file(args.kp))
    drivers = None
    if args.drivers:
        drivers = read_drivers(existing_file(args.drivers))
    elif args.model in ("T96", "T01", "T04"):
        raise InputError(f"model {args.model} needs --drivers (solar-wind inputs)")
    return lon, lat, r, kp, drivers


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "model", help="Tsyganenko/IGRF model field at the spacecraft in Hpen",
        description="Evaluate IGRF + a Tsyganenko model (IRBEM, through spacepy) at the "
                    "times of DATA.csv and write it in Hpen (time,Hp,He,Hn). Samples whose "
                    "inputs are out of the model's range are written as NaN and counted.")
    p.add_argument("input", help="DATA.csv: time[,Hp,He,Hn][,lon_deg,lat_deg,r_re]")
    add_model_arguments(p)
    p.add_argument("--cadence", type=float, default=60.0, metavar="S",
                   help="evaluation cadence in s; denser times are interpolated (default 60)")
    add_output(p, help_text="MODEL.csv (time,Hp,He,Hn)")
    p.set_defaults(func=run)


def run(args) -> int:
    import pandas as pd

    from magcal.indices import drivers_at, kp_at
    from magcal.io.csv import read_csv_frame, write_csv_frame
    from magcal.models.field import model_field_hpen

    path = existing_file(args.input)
    frame = read_csv_frame(path)
    lon, lat, r, kp, drivers = load_inputs(args, frame)
    times = frame.index.tz_convert("UTC").tz_localize(None).to_numpy()
    kp_values = kp_at(kp, frame.index)
    drv = drivers_at(drivers, frame.index) if drivers is not None else None
    if args.model == "T89" and np.all(np.isnan(kp_values)):
        raise InputError("the Kp file does not cover the data times", file=args.kp)
    res = model_field_hpen(times, lon, lat, r, model=args.model, kp=kp_values, drivers=drv,
                           cadence_s=args.cadence, n_jobs=args.jobs,
                           cache_dir=args.cache_dir)
    out = pd.DataFrame(res.b_hpen_nT, index=frame.index, columns=["Hp", "He", "Hn"])
    prov = res.provenance
    prov["inputs"] = [str(path), str(args.kp)] + ([str(args.drivers)] if args.drivers else [])
    prov["report"] = res.summary()
    write_csv_frame(args.output, out, provenance=prov)
    why = ", ".join(f"{k}: {v}" for k, v in res.reasons.items()
                    if not k.startswith("info:")) or "none"
    info = "; ".join(f"{k[5:].strip()}: {v}" for k, v in res.reasons.items()
                     if k.startswith("info:"))
    print(f"magcal model: {len(out)} samples, {res.model}, {res.n_invalid} NaN "
          f"(reasons: {why}){'; ' + info if info else ''}; cache hits {res.cache_hits}",
          file=sys.stderr)
    return 0
