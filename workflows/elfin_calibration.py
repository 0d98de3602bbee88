"""ELFIN-A fluxgate counts calibrated end to end against IGRF, zone by zone.

Usage::

    python workflows/elfin_calibration.py [--data DIR] [--out elfin-calibration-out]

``--data`` defaults to ``../shared/real-data/elfin`` beside the repository that holds
this script (found from the script's own path, so any working directory will do).

Reads the level-1 FGS counts and the state file of 2022-01-12, splits the 12 science
zones, repairs paired time-stamp jumps, derives the spin phase from the counts, fits
the calibration (gains, coupling, offsets, slow offset drift and spin-axis tilt, spline
phase) against IGRF at the spacecraft in the despun frame, then by default corrects
what the linear model leaves: the spin harmonics of ``|B|`` (cubic non-linearity,
drifting offsets and gain ratio; ``--linear-only`` stops before), the spin-plane gain
drift within each pass (the slow part of ``|B| - |IGRF|``; ``--no-gain-drift``) and
the vector-only body-fixed spin harmonics with a spin-axis tilt within 0.2 deg
(``--no-vector-correction``, ``--tilt-bound-deg``). ``--joint`` adds the joint fit
across zones (about 60 s; scored, delivered only if no worse). It writes

* ``elfin_calibration.json``: per-zone table (RMS residuals, gains, offsets, spin
  period, phase jumps, time-stamp jumps), timing-offset scan, provenance, credit;
* ``elfin_calibrated.csv``: ``time,zone,used,bx_gei,by_gei,bz_gei,...`` (nT);
* ``elfin_residuals.png``: calibrated minus IGRF per zone.

The steps, the scores and the JSON document are
:func:`magcal.missions.elfin.pipeline.calibrate_elfin_day`; this script parses, prints
and writes. ``magcal run data_samples/chain/ELFIN.toml -o OUT`` runs the same pipeline
through the chain (``[spin] units = "counts"``).

Data: ELFIN SOC (PI V. Angelopoulos, UCLA), "Open Data for Scientific Use".
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from magcal.errors import InputError
from magcal.io.jsonio import write_json
from magcal.offline import configure_offline
from magcal.provenance import make_provenance
from magcal.missions.elfin.linear import CREDIT
from magcal.missions.elfin.pipeline import ElfinSettings, calibrate_elfin_day, plot_residuals

#: The repository holding this script (as called, and with symbolic links resolved).
REPO_ROOTS = (Path(__file__).absolute().parents[1], Path(__file__).resolve().parents[1])
FGS_FILE = "ela_l1_fgs_20220112_v01.cdf"
STATE_FILE = "ela_l1_state_defn_20220112_v01.cdf"


def default_data_dir() -> Path:
    """``../shared/real-data/elfin`` beside the repository, wherever the script is run from."""
    candidates = [root.parent / "shared" / "real-data" / "elfin" for root in REPO_ROOTS]
    return next((c for c in candidates if (c / FGS_FILE).is_file()), candidates[0])


DEFAULT_DATA = default_data_dir()


def main(argv=None) -> int:
    """Run the workflow; bad or missing input is one line on stderr and exit status 2."""
    try:
        return _run(argv)
    except InputError as exc:
        print(f"elfin_calibration: error: {exc}", file=sys.stderr)
        return 2


def _run(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA,
                    help=f"folder with {FGS_FILE} and {STATE_FILE} (default {DEFAULT_DATA})")
    ap.add_argument("--out", type=Path, default=Path("elfin-calibration-out"),
                    help="output folder (default: elfin-calibration-out in the working "
                         "directory)")
    ap.add_argument("--no-scan", action="store_true", help="skip the timing-offset scan")
    ap.add_argument("--linear-only", action="store_true",
                    help="skip the spin-harmonic correction (the linear calibration only)")
    ap.add_argument("--no-gain-drift", action="store_true",
                    help="skip the spin-plane gain drift (the slow part of |B| - |IGRF|; "
                         "applied after the spin-harmonic correction by default) and the "
                         "vector step that follows it")
    ap.add_argument("--no-vector-correction", action="store_true",
                    help="skip the vector-only step after the gain drift (body-fixed spin "
                         "harmonics: a 2x wobble of the spin-plane angle, a drifting 1x "
                         "spin-axis coupling; spin-axis tilt)")
    ap.add_argument("--tilt-bound-deg", type=float, default=0.2,
                    help="bound of the per-zone spin-axis tilt in the vector step (default "
                         "0.2 deg, the attitude file's uncertainty; 0: no tilt)")
    ap.add_argument("--vector-knot-s", type=float, default=30.0,
                    help="knot spacing (s) of the vector step's spline drifts (default 30; "
                         "0: a cubic in time over the zone)")
    ap.add_argument("--no-fast-drift", action="store_true",
                    help="skip the 1x/2x harmonics of |B| drifting on 30 s splines (after "
                         "the vector step)")
    ap.add_argument("--no-phase-refit", action="store_true",
                    help="skip the final spin-phase refit (240 s knots)")
    ap.add_argument("--no-detect", action="store_true",
                    help="fit every step on every sample instead of leaving the disturbed "
                         "intervals located from the counts out (about 2.5 times faster; "
                         "localized natural fields across B are then absorbed)")
    ap.add_argument("--no-trials", action="store_true",
                    help="skip the trials that measure the product's stated errors (the "
                         "bridge error over left-out intervals, the heights of kept pulses "
                         "along B and the kept level steps: bridge_trials, pulse_trials and "
                         "level_trials 0; about half the time); the calibration is the same")
    ap.add_argument("--joint", action="store_true",
                    help="also run the joint fit across zones (shared sensor, per-zone "
                         "offsets and attitude; about 60 s, never delivered on 2022-01-12)")
    ap.add_argument("--no-joint", action="store_true",
                    help="accepted for older scripts: the joint fit is off unless --joint")
    args = ap.parse_args(argv)
    configure_offline()
    from magcal.missions.elfin.files import read_elfin_fgs, read_elfin_state
    from magcal.io.csv import write_csv_frame

    fgs_path, state_path = args.data / FGS_FILE, args.data / STATE_FILE
    for path in (fgs_path, state_path):
        if not path.is_file():
            raise InputError("ELFIN file not found (give --data DIR with the ELFIN-A files "
                             "of 2022-01-12)", file=path)
    fgs, state = read_elfin_fgs(fgs_path), read_elfin_state(state_path)
    prov = make_provenance("elfin calibration against IGRF", {"model": "IGRF (IRBEM)"},
                           inputs=[fgs_path, state_path])
    settings = ElfinSettings(harmonic=not args.linear_only, gain_drift=not args.no_gain_drift,
                             vector_step=not args.no_vector_correction,
                             tilt_bound_deg=args.tilt_bound_deg,
                             vector_knot_s=args.vector_knot_s,
                             fast_drift=not args.no_fast_drift,
                             phase_refit=not args.no_phase_refit,
                             joint=args.joint and not args.no_joint, scan=not args.no_scan,
                             detect_disturbed=not args.no_detect,
                             **(dict(bridge_trials=0, pulse_trials=0, level_trials=0,
                                     perp_trials=0)
                                if args.no_trials else {}))
    day = calibrate_elfin_day(fgs, state, settings, provenance=prov)
    cal, tab, ripple, joint, scan = (day.calibration, day.linear.table(), day.ripple,
                                     day.joint, day.scan)
    correction = day.steps.get("spin_harmonic_correction")
    drift, agreement = day.steps.get("gain_drift"), day.steps.get("drift_agreement")
    vector = day.steps.get("vector_correction")
    medians = day.medians()
    args.out.mkdir(parents=True, exist_ok=True)
    write_json(args.out / "elfin_calibration.json", day.to_json())
    write_csv_frame(args.out / "elfin_calibrated.csv", day.calibrated_table())
    plot_residuals(args.out / "elfin_residuals.png", cal,
                   "ELFIN-A 2022-01-12: calibrated minus IGRF")

    print(f"ELFIN-A 2022-01-12, {len(cal.zones)} science zones, calibrated against IGRF")
    print(f"  {CREDIT}")
    print("  zone start            |dB| rms  vec rms (X,Y,Z)        12-par vec  gains nT/count"
          "            period s")
    for z, row in zip(cal.zones, tab.itertuples()):
        print(f"  {z.start[:19]}  {z.rms_scalar_nT:6.1f}  "
              f"{row.rms_vector_nT:6.1f} ({', '.join(f'{v:.0f}' for v in z.rms_vector_nT)})"
              f"  {row.rms_vector_constant_nT:8.1f}  "
              f"{', '.join(f'{g:.5f}' for g in z.gains_nT_per_count)}  {z.spin_period_s:.4f}")
    da = np.abs(np.r_[ripple.aniso_a_ripple - ripple.aniso_a_igrf,
                      ripple.aniso_b_ripple - ripple.aniso_b_igrf])
    print(f"  spin-ripple cross-check: anisotropy differs by at most {da.max():.1e}; "
          f"spin-plane offsets by {ripple.offset_diff_nT.min():.0f}-"
          f"{ripple.offset_diff_nT.max():.0f} nT (ripple std "
          f"{ripple.offset_std_nT.max():.0f} nT)")
    if correction is not None:
        med = correction.drop(columns=["zone", "fixed_amplitudes_nT", "drift_rms_nT",
                                       "fixed_std_nT", "fixed_at_45000nT"]).median()
        print("  spin-harmonic correction (median over zones, nT): scalar RMS "
              f"{med['scalar_rms_before_nT']:.1f} -> {med['scalar_rms_after_nT']:.1f}, "
              f"fast part {med['scalar_fast_before_nT']:.1f} -> "
              f"{med['scalar_fast_after_nT']:.1f}, vector RMS "
              f"{med['vector_rms_before_nT']:.1f} -> {med['vector_rms_after_nT']:.1f}")
        amp = np.array([d[4] for d in correction["fixed_at_45000nT"]])
        err = np.array([d[4] for d in correction["fixed_std_nT"]])
        print(f"  4x non-linearity at |B_perp| = 45000 nT: {amp.mean():.1f} nT mean over zones, "
              f"spread {amp.std(ddof=1):.1f} nT (per-zone standard error "
              f"{np.median(err):.2f} nT)")
    if drift is not None:
        med = drift.drop(columns=["zone"]).select_dtypes("number").median()
        print("  spin-plane gain drift (median over zones): "
              f"{100 * med['gain_drift_pp']:.2f} % p-p; scalar RMS "
              f"{med['scalar_rms_before_nT']:.1f} -> {med['scalar_rms_after_nT']:.1f} nT, slow "
              f"part {med['scalar_slow_before_nT']:.1f} -> {med['scalar_slow_after_nT']:.1f}, "
              f"fast part {med['scalar_fast_after_nT']:.1f}, vector RMS "
              f"{med['vector_rms_before_nT']:.1f} -> {med['vector_rms_after_nT']:.1f}")
        agree = agreement["correlation"].abs()
        pair = agreement["drift_k1_nT"] / agreement["drift_km1_nT"]
        print(f"  2x-harmonic drift vs slow part: |correlation| >= 0.9 in "
              f"{int((agree >= 0.9).sum())}/{len(agree)} zones (median "
              f"{agree.median():.2f}), ratio {agreement['ratio'].median():.2f} median; vector "
              f"e^(i psi)/e^(-i psi) drift ratio within 0.85-1.2 in "
              f"{int(((pair > 0.85) & (pair < 1.2)).sum())}/{len(pair)} zones (one-direction "
              "gain drift)")
    if vector is not None:
        med = vector[["vector_rms_before_nT", "vector_rms_after_nT"]].median()
        print(f"  vector-only step: vector RMS {med.iloc[0]:.1f} -> {med.iloc[1]:.1f} nT (median); "
              f"spin-axis tilt on the {args.tilt_bound_deg} deg bound in "
              f"{int(vector['tilt_at_bound'].sum())}/{len(vector)} zones")
    st = day.stability
    threshold = st['spread']['gain1_nT_per_count']['threshold']
    print(f"  stable across zones (chi2/dof < {threshold:.2f}, "
          f"{st['block_s']:g} s block errors): {', '.join(st['stable']) or 'none'}; "
          f"{len(st['per_zone'])} per zone (parameter_stability in the JSON)")
    print("  zone medians (nT)      |B|-|IGRF|  fast part  slow part  vector RMS (x, y, z GEI)")
    for name, m in medians.items():
        print(f"  {name:22s} {m['scalar_rms_nT']:9.1f}  {m['scalar_fast_nT']:9.1f}  "
              f"{m['scalar_slow_nT']:9.1f}  {m['vector_rms_nT']:6.1f} ({m['vector_rms_x_nT']:.0f}, "
              f"{m['vector_rms_y_nT']:.0f}, {m['vector_rms_z_nT']:.0f})")
    if joint is not None:
        sh = joint["shared"]
        print(f"  joint fit: cubic 4x at 45000 nT {sh['cubic_4x_at_45000nT_nT']:.1f} nT "
              f"(eps {sh['cubic_eps'][0]:.2e} +- {sh['cubic_eps'][1]:.1e}); "
              f"{len(joint['attitude_at_bound'])} attitude angles on the bound")
        print(f"  delivered: {joint['delivered']} ({joint['reason']})")
    if scan:
        best = {k: float(np.median(v["rms_vector_nT"])) for k, v in scan.items()}
        print("  timing scan (median vector RMS nT by shift s): "
              + ", ".join(f"{k}: {v:.1f}" for k, v in best.items()))
    print(f"  wrote {args.out}/elfin_calibration.json, elfin_calibrated.csv, elfin_residuals.png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
