"""ELFIN-A scalar residual against |IGRF|: the linear floor and the spin-harmonic model.

Usage::

    python workflows/elfin_scalar_floor.py [--data DIR] [--out FILE.csv] [--mechanisms] [--slow]
                                           [--vector-evidence [--knot-s S]]

Per science zone of 2022-01-12: the best 9-parameter scalar calibration (the linear
floor), its residual and fast part (after a 5th-order polynomial), the spin harmonics
left in it (angle of the field in the sensor's spin plane), and what the harmonic model
(constant 4x + drifting 1x, 2x) leaves. ``--vector-evidence`` splits the delivered
vector residual (along/across B, spin-averaged/within-spin, inside/outside auroral
current-sheet signatures) and tests attitude beyond the 0.2 deg bound
(:mod:`magcal.missions.elfin.diagnostics.evidence`). The measuring code is in the library; this
script only reads, calls and prints.

Data: ELFIN SOC (PI V. Angelopoulos, UCLA), "Open Data for Scientific Use".
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from magcal.errors import InputError
from magcal.offline import configure_offline

sys.path.insert(0, str(Path(__file__).resolve().parent))
from elfin_calibration import DEFAULT_DATA, FGS_FILE, STATE_FILE  # noqa: E402

#: CelesTrak space-weather file beside the ELFIN folder (Kp for the T89 candidate).
KP_FILE = "celestrak_SW_2017-2023_subset.txt"


def _mechanisms(data: Path, tab) -> None:
    from magcal.missions.elfin.linear import calibrate_elfin
    from magcal.missions.elfin.files import read_elfin_fgs, read_elfin_state
    from magcal.missions.elfin.diagnostics.mechanisms import (locking_table, power_law,
                                                              timestamp_effect)

    fgs, state = read_elfin_fgs(data / FGS_FILE), read_elfin_state(data / STATE_FILE)
    cal = calibrate_elfin(fgs, state)
    for h in ((1, 2, 3, 4), (4,), (2,)):
        lock = locking_table(cal, harmonics=h)
        print(f"harmonics {h} of the linear vector calibration's scalar residual, median nT: "
              f"fast {lock.fast_nT.median():.1f}, after sensor-locked "
              f"{lock.sensor_locked_nT.median():.1f}, inertial-locked "
              f"{lock.inertial_locked_nT.median():.1f}; sensor better in "
              f"{int((lock.sensor_locked_nT < lock.inertial_locked_nT).sum())}/{len(lock)} zones")
    n, r = power_law(tab["fixed4_nT"], tab["mean_igrf_nT"])
    print(f"4x amplitude ~ |B|^{n:.2f} across zones (log correlation {r:.2f})")
    ts = timestamp_effect(fgs, state)
    print("time-stamp repair: floor changes by at most "
          f"{(ts.floor_raw_nT - ts.floor_repaired_nT).abs().max():.3f} nT "
          f"({int(ts.n_jumps.sum())} paired jumps)")


def _slow(data: Path) -> None:
    from magcal.indices.kp import read_kp
    from magcal.missions.elfin.linear import calibrate_elfin
    from magcal.missions.elfin.harmonic import correct_elfin_calibration
    from magcal.missions.elfin.drift import drift_agreement_table
    from magcal.missions.elfin.files import read_elfin_fgs, read_elfin_state
    from magcal.missions.elfin.diagnostics.reference import screen_slow_part, zone_slow_parts

    fgs, state = read_elfin_fgs(data / FGS_FILE), read_elfin_state(data / STATE_FILE)
    linear = calibrate_elfin(fgs, state)
    harmonic, _ = correct_elfin_calibration(linear)
    kp_file = data.parent / "indices" / KP_FILE
    kp = read_kp(kp_file) if kp_file.is_file() else None
    screen = screen_slow_part(zone_slow_parts(harmonic, state, kp))
    print("slow part of |B| - |IGRF| after the spin-harmonic correction, screened against "
          "reference errors (one coefficient for the day; per zone 1 and |B| free):")
    for row in screen.itertuples():
        per = " ".join(f"{c:.3g}" for c in row.zone_coefficients)
        print(f"  {row.candidate:12s} day coefficient {row.day_coefficient:9.3g}  slow part left "
              f"{row.slow_left_median_nT:5.1f} nT (median)  unit range {row.range_nT:5.1f} nT  "
              f"zones of the other sign {row.zone_sign_changes:2d}  per zone: {per}")
    agree = drift_agreement_table(linear)
    print("2x-spin drift (reference-free) against the slow part, per zone "
          "(linear calibration):")
    print(agree.round(3).to_string(index=False))


def _product(data: Path, knot_s: float | None):
    """The delivered calibration (:func:`magcal.missions.elfin.pipeline.calibrate_elfin_day`);
    with ``knot_s`` the vector step drifts on splines, the fast drift (spin harmonics of
    |B| on ``knot_s`` splines) follows it and the phase is refitted last; without, the
    vector step's drift is a cubic and neither follows."""
    from magcal.missions.elfin.files import read_elfin_fgs, read_elfin_state
    from magcal.missions.elfin.pipeline import ElfinSettings, calibrate_elfin_day

    fgs, state = read_elfin_fgs(data / FGS_FILE), read_elfin_state(data / STATE_FILE)
    splines = knot_s is not None
    settings = ElfinSettings(vector_knot_s=knot_s if splines else 0.0,
                             fast_knot_s=knot_s if splines else 30.0,
                             fast_drift=splines, phase_refit=splines)
    return calibrate_elfin_day(fgs, state, settings, diagnostics=False).calibration, state


def _sun(data: Path) -> None:
    from magcal.missions.elfin.diagnostics.sun import sun_locked_test

    cal, state = _product(data, None)
    print("fast part of |B| - |IGRF| (nT) left by: Sun-locked harmonics (1x, 2x of the Sun's "
          "angle in the body), a control angle drifting the other way, field-locked "
          "harmonics, field-locked 1x/2x drifting on 60 s splines (product: cubic drifts)")
    print(sun_locked_test(cal, state).round(2).to_string(index=False))


def _vector_evidence(data: Path, knot_s: float | None) -> None:
    from magcal.missions.elfin.diagnostics.evidence import (evidence_verdict, field_latitude,
                                                            vector_evidence)

    cal, state = _product(data, knot_s)
    ev = vector_evidence(cal, field_latitude(cal, state))
    drift = ("polynomial (cubic)" if knot_s is None
             else f"{knot_s:g} s splines, + fast drift + phase refit")
    print(f"vector residual against IGRF split per zone (nT per component; vector step drift: "
          f"{drift}); flags: auroral current-sheet signatures (spin-averaged across-B "
          "structure > 10 nT over 20 s at |centred-dipole mlat| >= 60 deg)")
    cols = ["zone", "flagged_fraction", "scalar", "vector", "along", "across", "across_slow",
            "across_fast", "ratio", "ratio_out", "scalar_fast", "vector_fast", "ratio_fast",
            "plane", "axis_slow", "ratio_plane", "bz_fraction",
            "ratio_out_tilt_free", "ratio_out_tilt_drift", "across_slow_sub",
            "across_slow_auroral", "ratio_sub_tilt_drift", "ratio_auroral_tilt_predicted",
            "transverse_predicted_scalar_nT", "axial1x_rms_nT", "axial1x_line_fraction"]
    print(ev[cols].round(2).to_string(index=False))
    v = evidence_verdict(ev)
    print(f"vector / scalar, zone median (max; zones within {v['target']}x):")
    for name in ("ratio", "ratio_out", "ratio_fast", "ratio_plane", "ratio_out_tilt_free",
                 "ratio_out_tilt_drift", "ratio_sub_tilt_drift", "ratio_auroral_tilt_predicted"):
        r = v[name]
        print(f"  {name:30s} {r['median']:5.2f} ({r['max']:5.2f}; "
              f"{r['zones_within']}/{r['zones']})")
    print(f"  the drifting tilt reaches {v['tilt_drift_max_deg']:.2f} deg and exceeds 0.2 deg in "
          f"{v['zones_beyond_attitude']}/{len(ev)} zones")


def main(argv=None) -> int:
    """Run; bad or missing input is one line on stderr and exit status 2."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA,
                    help=f"folder with {FGS_FILE} and {STATE_FILE}")
    ap.add_argument("--out", type=Path, default=None, help="also write the table as CSV")
    ap.add_argument("--mechanisms", action="store_true",
                    help="also print the mechanism tests (locking, power law, time stamps)")
    ap.add_argument("--slow", action="store_true",
                    help="also screen the slow part against reference errors (time offset, "
                         "frame rotation, orbit, T89, ring current) and compare it with the "
                         "2x-spin drift")
    ap.add_argument("--vector-evidence", action="store_true",
                    help="also split the delivered vector residual (along/across B, "
                         "spin-averaged/within-spin, in/outside auroral current sheets) and "
                         "test attitude beyond 0.2 deg")
    ap.add_argument("--knot-s", type=float, default=30.0,
                    help="knot spacing (s) of the vector step's drifting harmonics and of the "
                         "fast drift after it, for --vector-evidence (default 30; 0: the "
                         "cubic polynomial, no fast drift and no phase refit)")
    ap.add_argument("--sun", action="store_true",
                    help="also test a Sun-locked term (solar-array currents) against a control "
                         "angle and a field-locked drift")
    ap.add_argument("--drift-degree", type=int, default=3,
                    help="degree of the drifting 1x/2x coefficients (default 3)")
    args = ap.parse_args(argv)
    configure_offline()
    from magcal.missions.elfin.linear import CREDIT
    from magcal.missions.elfin.files import read_elfin_fgs, read_elfin_state
    from magcal.missions.elfin.scalar import scalar_floor_table, scalar_zones

    try:
        for name in (FGS_FILE, STATE_FILE):
            if not (args.data / name).is_file():
                raise InputError("ELFIN file not found (give --data DIR)", file=args.data / name)
        zones = scalar_zones(read_elfin_fgs(args.data / FGS_FILE),
                             read_elfin_state(args.data / STATE_FILE))
    except InputError as exc:
        print(f"elfin_scalar_floor: error: {exc}", file=sys.stderr)
        return 2
    tab = scalar_floor_table(zones, drift_degree=args.drift_degree)
    print(f"ELFIN-A 2022-01-12 scalar residual |B| - |IGRF| per zone (nT); {CREDIT}")
    cols = ["zone", "sun_fraction", "floor_rms_nT", "floor_fast_nT", "amp1_nT", "amp2_nT",
            "amp3_nT", "amp4_nT", "drift1_rms_nT", "drift2_rms_nT", "model_fast_nT"]
    print(tab[cols].round(1).to_string(index=False))
    med = tab[cols[2:]].median()
    print("median: " + ", ".join(f"{k} {v:.1f}" for k, v in med.items()))
    if args.mechanisms:
        _mechanisms(args.data, tab)
    if args.slow:
        _slow(args.data)
    if args.vector_evidence:
        _vector_evidence(args.data, args.knot_s or None)
    if args.sun:
        _sun(args.data)
    if args.out is not None:
        tab.to_csv(args.out, index=False)
        print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
