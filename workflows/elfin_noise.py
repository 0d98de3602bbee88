"""The ELFIN-A calibration on noisier counts: seeded white plus correlated noise.

The real day (2022-01-12) is calibrated with instrument noise added to its counts
(:func:`magcal.missions.elfin.noise.noise_trials`): per body axis, white noise plus an
Ornstein-Uhlenbeck part (a fluxgate offset wandering with a correlation time), turned
into counts through the clean calibration, one draw per seed. Printed per noise level:

* how much of the noise reaches each product (``transfer``: the RMS of the product's
  change over the noise's RMS; above 1 the calibration would add to the noise), and
  the residuals against IGRF next to the noise-free day's;
* the share of each zone the detector leaves out of the fits (noise must not read as
  a natural field);
* 40 s pulses across B (east-west, along-track) injected into the noisy counts at a
  drawn place in every zone: the energy kept and the distortion, and whether the
  stated bridge error (``bridge_rms_nT``) covers the pulse's error over its left-out
  samples, over all seeds and zones.

Usage::

    python workflows/elfin_noise.py [--zones 1,4,7,10] [--seeds 10] [--first-seed 0]
                                    [--levels moderate,heavy,none] [--out FOLDER]

Levels (nT per body axis, correlation time 30 s): ``moderate`` white 2 + correlated 5,
``heavy`` white 10 + correlated 20; ``none`` adds nothing (the real day's own noise,
the pulses at drawn places: the bridge error's coverage without added noise). About
15 s per seed and level on an idle core for the default 4 zones. Reads
``../shared/real-data/elfin/``; with ``--out`` the tables are written as CSV.
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
ZONES = (1, 4, 7, 10)
#: name -> (white nT, correlated nT, correlation time s), per body axis.
LEVELS = {"moderate": (2.0, 5.0, 30.0), "heavy": (10.0, 20.0, 30.0), "none": (0.0, 0.0, 30.0)}


def summarize(passes, kept) -> list[str]:
    """Lines of the printed summary of one level (:func:`noise_trials` tables)."""
    import numpy as np

    lines = []
    clean = passes[passes["seed"] < 0].set_index("product")
    noisy = passes[passes["seed"] >= 0]
    lines.append(f"  {'product':24s} {'transfer':>17s} {'scalar nT':>16s} {'fast nT':>14s} "
                 f"{'vector nT':>16s}   (median [max] over seeds; noise-free day after ->)")
    for name, g in noisy.groupby("product", sort=False):
        c = clean.loc[name]
        lines.append(
            f"  {name:24s} {g['transfer'].median():8.3f} [{g['transfer'].max():.3f}] "
            f"{g['scalar_rms_nT'].median():7.2f} -> {c['scalar_rms_nT']:5.2f} "
            f"{g['scalar_fast_nT'].median():6.2f} -> {c['scalar_fast_nT']:5.2f} "
            f"{g['vector_rms_nT'].median():7.2f} -> {c['vector_rms_nT']:5.2f}")
    shares = noisy["left_out_share"].dropna()
    lines.append(f"  noise RMS {noisy['noise_rms_nT'].median():.1f} nT (vector norm); "
                 f"left out by the detector (zone median): {shares.median():.1%} "
                 f"[{shares.min():.1%}-{shares.max():.1%}] against "
                 f"{clean['left_out_share'].dropna().iloc[0]:.1%} noise-free")
    if kept.empty:
        return lines
    last = kept[kept["product"] == kept["product"].iloc[-1]]
    for kind, g in last.groupby("signal", sort=False):
        lines.append(f"  {kind}: energy kept {g['energy_kept'].median():.1%} "
                     f"[{g['energy_kept'].quantile(0.1):.1%} at the 10th percentile], "
                     f"distortion {g['distortion'].median():.1%}")
    both = last.dropna(subset=["error_rms_nT", "bridge_rms_nT"])
    if len(both):
        ratio = (both["error_rms_nT"] / both["bridge_rms_nT"]).to_numpy()
        lines.append(f"  bridge error: {len(ratio)} pulses left out; error within the stated "
                     f"bridge_rms_nT in {np.mean(ratio <= 1):.0%}, within twice it in "
                     f"{np.mean(ratio <= 2):.0%} (ratio median {np.median(ratio):.2f}, "
                     f"largest {ratio.max():.2f})")
    return lines


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--zones", default=",".join(map(str, ZONES)))
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--levels", default="moderate,heavy")
    parser.add_argument("--out", type=Path)
    args = parser.parse_args(argv)
    if not (DATA / FGS_FILE).exists():
        print(f"ELFIN data not found in {DATA}", file=sys.stderr)
        return 2
    levels = [x.strip() for x in args.levels.split(",") if x.strip()]
    unknown = [x for x in levels if x not in LEVELS]
    if unknown:
        print(f"unknown levels {unknown} (known: {', '.join(LEVELS)})", file=sys.stderr)
        return 2

    from magcal.missions.elfin.files import read_elfin_fgs, read_elfin_state
    from magcal.missions.elfin.injection import select_zones
    from magcal.missions.elfin.noise import noise_trials

    zones = tuple(int(z) for z in args.zones.split(","))
    fgs = select_zones(read_elfin_fgs(DATA / FGS_FILE), zones)
    state = read_elfin_state(DATA / STATE_FILE)
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    print(f"ELFIN-A 2022-01-12, zones {zones}, seeds {seeds.start}-{seeds.stop - 1}. "
          "Data: ELFIN SOC (PI V. Angelopoulos, UCLA), Open Data for Scientific Use.")
    for level in levels:
        white, red, tau = LEVELS[level]
        start = time.perf_counter()
        passes, kept = noise_trials(fgs, state, seeds=seeds, white_nT=white, red_nT=red,
                                    red_tau_s=tau, progress=lambda m: print("  " + m,
                                                                            flush=True))
        print(f"\n== {level}: white {white:g} nT + correlated {red:g} nT ({tau:g} s) per "
              f"body axis, {time.perf_counter() - start:.0f} s")
        print("\n".join(summarize(passes, kept)), flush=True)
        if args.out is not None:
            args.out.mkdir(parents=True, exist_ok=True)
            passes.to_csv(args.out / f"noise_{level}_passes.csv", index=False)
            kept.to_csv(args.out / f"noise_{level}_kept.csv", index=False)
    return 0


if __name__ == "__main__":
    sys.exit(main())
