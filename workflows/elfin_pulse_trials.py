"""Does the stated height error of a kept pulse along B cover the truth? (ELFIN-A)

With ``ElfinSettings.pulses_b`` the product keeps Gaussian pulses along B found in its
``|B|`` residual (:mod:`magcal.missions.elfin.pulses`), and ``pulse_trials`` states each
one's height error from the same pulse put into other zones' counts and found again
(:func:`magcal.missions.elfin.pulses.pulse_trials`). Here a 100 nT pulse along B of
90 s FWHM is injected into one zone at a time (every zone, at 0.35, 0.5 and 0.65 of its
span: 36 whole-day runs) through the clean linear calibration, the day is calibrated
with ``pulses_b`` and the kept height compared with the truth and the stated error.

Usage::

    python workflows/elfin_pulse_trials.py [--trials 6] [--centres 0.35,0.5,0.65]

About 30 s per run on an idle core (18 minutes for the 36). Reads
``../shared/real-data/elfin/``. Measured: stated errors 8-65 nT (median 38), the truth
within them in 81 % of the cases and within twice them in all (heights 65-158 nT).
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
    import pandas as pd

    from magcal.missions.elfin.files import read_elfin_fgs, read_elfin_state
    from magcal.missions.elfin.injection import SIGNALS, inject_counts, signal_gei
    from magcal.missions.elfin.linear import CREDIT
    from magcal.missions.elfin.pipeline import ElfinSettings, calibrate_elfin_day

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--trials", type=int, default=6, help="pulse_trials (other zones)")
    ap.add_argument("--centres", default="0.35,0.5,0.65",
                    help="places in the zone (fractions of its span); zone k gets the "
                         "(k + run)-th, one run per place")
    args = ap.parse_args(argv)
    if not (args.data / FGS_FILE).is_file():
        print(f"real data not found: {args.data / FGS_FILE}", file=sys.stderr)
        return 2
    fgs = read_elfin_fgs(args.data / FGS_FILE)
    state = read_elfin_state(args.data / STATE_FILE)
    centres = [float(c) for c in args.centres.split(",")]
    truth = SIGNALS["pulse_b"][0]
    print(f"ELFIN-A 2022-01-12: a {truth:g} nT pulse along B (90 s FWHM) in one zone at a "
          f"time, pulses_b with pulse_trials = {args.trials}\n{CREDIT}")
    s = ElfinSettings(pulses_b=True, pulse_trials=args.trials, bridge_trials=0)
    clean = calibrate_elfin_day(fgs, state, ElfinSettings(bridge_trials=0), diagnostics=False)
    f = clean.linear.field
    zones = list(dict.fromkeys(f["zone"].to_numpy()))
    rows = []
    for run in range(len(centres)):
        for i, k in enumerate(zones):
            c = centres[(i + run) % len(centres)]
            sig = signal_gei("pulse_b", f[f["zone"] == k], state, centre=c)
            t0 = time.perf_counter()
            day = calibrate_elfin_day(inject_counts(fgs, clean.linear, {k: sig}), state, s,
                                      diagnostics=False)
            trials = day.steps.get("pulse_trials", pd.DataFrame(columns=["zone"]))
            mine = trials[trials["zone"] == k]
            row = {"zone": int(k), "centre": c,
                   "height_nT": float(mine["height_nT"].iloc[0]) if len(mine) else 0.0,
                   "height_error_nT": float(mine["height_error_nT"].iloc[0]) if len(mine)
                   else float("nan"),
                   "n_trials": len(mine["trial_heights_nT"].iloc[0]) if len(mine) else 0}
            rows.append(row)
            print(f"  zone {k:2d} at {c:.2f}: kept {row['height_nT']:6.1f} nT, stated error "
                  f"{row['height_error_nT']:5.1f} nT ({row['n_trials']} trials; "
                  f"{time.perf_counter() - t0:.0f} s)", flush=True)
    tab = pd.DataFrame(rows)
    ratio = (tab["height_nT"] - truth).abs() / tab["height_error_nT"]
    print(f"\n{len(tab)} cases: truth within the stated error in {(ratio <= 1).mean():.0%}, "
          f"within twice it in {(ratio <= 2).mean():.0%}; stated errors "
          f"{tab['height_error_nT'].min():.0f}-{tab['height_error_nT'].max():.0f} nT "
          f"(median {tab['height_error_nT'].median():.0f}); kept heights "
          f"{tab['height_nT'].min():.0f}-{tab['height_nT'].max():.0f} nT "
          f"(no pulse kept: {int((tab['height_nT'] == 0).sum())})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
