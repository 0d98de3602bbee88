"""Does the stated error of a kept level step cover the truth? (ELFIN-A)

With ``ElfinSettings.level_steps`` the product keeps a current sheet's new spin-axis
level across a left-out interval (:mod:`magcal.missions.elfin.levels`), and
``level_trials`` states each step's error from a sheet of its size put into other
zones' counts and measured again (:func:`magcal.missions.elfin.levels.level_trials`).
Here a 300 nT east-west sheet (20 s rise, to the zone's end) is injected into one zone
at a time (every zone, at 0.35, 0.5 and 0.65 of its span: 36 whole-day runs) through
the clean linear calibration, the day is calibrated as delivered and the level kept
(injected minus clean, along the sheet, :func:`~magcal.missions.elfin.levels.kept_level`)
compared with the truth and the stated error.

Usage::

    python workflows/elfin_level_trials.py [--trials 3] [--centres 0.35,0.5,0.65]
        [--scale 1.0] [--zones 0,1,...]

About 35 s per run on an idle core (20 minutes for the 36; two processes with
``--zones`` halve it). Reads ``../shared/real-data/elfin/``. Measured (300 nT): stated
errors 9-243 nT (median 42), the kept level within them in 64 % of the cases and
within twice them in 92 % (largest ratio 2.2; kept levels 247-427 nT). With
``--scale 0.5`` (150 nT): 25 of 36 kept as a step, 24 of them within the stated error
(28-130 nT) and all within twice it; the other 11 are lost (no step, no error stated).
With ``--scale -1`` (the opposite polarity, the trial sheets of the kept step's sign):
34 of 36 stepped, the kept level within the stated error (15-239 nT, median 50) in
75 % and within twice it in 92 %; lost are zones 7 and 8 at mid-zone (no step). (With
all of a zone's steps decided at once, zone 8 at 0.65 had the sheet's step, +228 nT,
and a false one across the real disturbance before it, -199 nT: -35 nT kept of -300;
72 % and 86 %.) The stated error is the
``level_error_nT`` the product gives the rows read (all the zone's steps up to them);
the step shown is the zone's step nearest the sheet.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
DATA = HERE.parent.parent / "shared" / "real-data" / "elfin"
FGS_FILE = "ela_l1_fgs_20220112_v01.cdf"
STATE_FILE = "ela_l1_state_defn_20220112_v01.cdf"


def main(argv=None) -> int:
    import numpy as np
    import pandas as pd

    from magcal.missions.elfin.files import read_elfin_fgs, read_elfin_state
    from magcal.missions.elfin.injection import SIGNALS, directions, inject_counts, \
        signal_gei
    from magcal.missions.elfin.levels import TRIAL_SETTLE_S, kept_level
    from magcal.missions.elfin.linear import CREDIT
    from magcal.missions.elfin.pipeline import ElfinSettings, calibrate_elfin_day

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--trials", type=int, default=3, help="level_trials (other zones)")
    ap.add_argument("--centres", default="0.35,0.5,0.65",
                    help="places in the zone (fractions of its span), each in every zone")
    ap.add_argument("--scale", type=float, default=1.0,
                    help="sheet size as a multiple of 300 nT")
    ap.add_argument("--zones", default="all", help="zone numbers, comma-separated")
    args = ap.parse_args(argv)
    if not (args.data / FGS_FILE).is_file():
        print(f"real data not found: {args.data / FGS_FILE}", file=sys.stderr)
        return 2
    fgs = read_elfin_fgs(args.data / FGS_FILE)
    state = read_elfin_state(args.data / STATE_FILE)
    centres = [float(c) for c in args.centres.split(",")]
    truth = args.scale * SIGNALS["sheet_ew"][0]
    print(f"ELFIN-A 2022-01-12: a {truth:g} nT east-west current sheet in one zone at a "
          f"time, delivered settings with level_trials = {args.trials}\n{CREDIT}")
    s = ElfinSettings(level_trials=args.trials, bridge_trials=0, pulse_trials=0,
                      perp_trials=0)
    clean = calibrate_elfin_day(fgs, state, ElfinSettings(bridge_trials=0, pulse_trials=0,
                                                          level_trials=0, perp_trials=0),
                                diagnostics=False)
    f = clean.linear.field
    cf = clean.calibration.field
    zones = list(dict.fromkeys(f["zone"].to_numpy()))
    if args.zones != "all":
        zones = [k for k in zones if k in {int(z) for z in args.zones.split(",")}]
    ns = f.index.as_unit("ns").asi8
    rows = []
    for c in centres:
        for k in zones:
            z = (f["zone"] == k).to_numpy()
            zf = f[z]
            sig = args.scale * signal_gei("sheet_ew", zf, state, centre=c)
            t = (ns[z] - ns[z][0]) / 1e9
            tu = t[zf["used"].to_numpy() == 1]
            t0 = tu[0] + c * (tu[-1] - tu[0])
            u = directions(zf.index, state, zf[["igrf_x_gei", "igrf_y_gei",
                                                "igrf_z_gei"]].to_numpy(float))["ew"]
            start = time.perf_counter()
            day = calibrate_elfin_day(inject_counts(fgs, clean.linear, {k: sig}), state, s,
                                      diagnostics=False)
            df = day.calibration.field[z]
            kept = kept_level(df, cf[z], u, t, t0)
            # the error the product states for the level after the sheet: the
            # level_error_nT its rows carry (all the zone's steps up to them)
            read = (t >= t0 + TRIAL_SETTLE_S) & (df["used"].to_numpy() == 1) \
                & (df["fit"].to_numpy() == 1)
            carried = day.level_error_column()[z][read]
            trials = day.steps.get("level_trials", pd.DataFrame(columns=["zone"]))
            mine = trials[trials["zone"] == k]
            # the zone's step nearest the sheet (others are steps the sheet caused
            # elsewhere, e.g. across a real disturbance before it)
            when = ns[z][0] / 1e9 + t0
            mid = [(pd.Timestamp(a, tz="UTC").value + pd.Timestamp(b, tz="UTC").value) / 2e9
                   for a, b in zip(mine["start"], mine["end"])] if len(mine) else []
            near = mine.iloc[int(np.argmin(np.abs(np.asarray(mid) - when)))] if mid else None
            row = {"zone": int(k), "centre": c, "kept_nT": kept, "n_steps": len(mine),
                   "step_nT": float(near["step_nT"]) if near is not None else float("nan"),
                   "step_error_nT": float(np.median(carried)) if carried.size
                   and np.isfinite(carried).any() else float("nan"),
                   "n_trials": len(near["trial_levels_nT"]) if near is not None else 0}
            rows.append(row)
            print(f"  zone {k:2d} at {c:.2f}: kept {kept:6.1f} nT (step {row['step_nT']:6.1f}"
                  f"{f'; {len(mine)} steps in the zone' if len(mine) > 1 else ''}), stated "
                  f"error {row['step_error_nT']:5.1f} nT ({row['n_trials']} trials; "
                  f"{time.perf_counter() - start:.0f} s)", flush=True)
    tab = pd.DataFrame(rows)
    ratio = (tab["kept_nT"] - truth).abs() / tab["step_error_nT"]
    print(f"\n{len(tab)} cases, {int(tab['step_error_nT'].notna().sum())} stepped "
          f"({int((tab['n_steps'] > 1).sum())} with more than one step in the zone): truth "
          f"within the stated error in {(ratio <= 1).mean():.0%}, within twice it in "
          f"{(ratio <= 2).mean():.0%} (unstepped cases count as outside); stated errors "
          f"{tab['step_error_nT'].min():.0f}-{tab['step_error_nT'].max():.0f} nT (median "
          f"{tab['step_error_nT'].median():.0f}); kept levels {tab['kept_nT'].min():.0f}-"
          f"{tab['kept_nT'].max():.0f} nT, error RMS "
          f"{np.sqrt(np.mean((tab['kept_nT'] - truth) ** 2)):.0f} nT")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
