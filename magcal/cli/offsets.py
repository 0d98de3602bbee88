"""``magcal offsets fit|apply``: DC offsets against the model on quiet days (CONTRACTS §2)."""

from __future__ import annotations

import sys

import numpy as np

from magcal.cli._common import add_model_arguments, add_output, existing_file, positive_float
from magcal.errors import InputError
from magcal.offsets.defaults import MIN_DAY_COVERAGE, MIN_LT_COVERAGE, MIN_PIECE_DAYS


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "offsets", help="DC offsets against the model on quiet days (fit, apply)",
        description="Offsets of AC-cleaned Hpen data: median of data minus model over "
                    "1-min samples with Kp <= kp-max, in sliding windows (SOSMAG paper "
                    "§5.3); apply interpolates between window centres.")
    sub = p.add_subparsers(dest="subverb", required=True, metavar="SUBVERB")
    fit = sub.add_parser("fit", help="fit offsets per sliding window",
                         description="Write OFFSETS.csv: one row per window "
                                     "(center,start,end,Hp,He,Hn,Hp_std,He_std,Hn_std,"
                                     "n_used,fraction_used, then Hp_mad,He_mad,Hn_mad,"
                                     "n_available,reason,days_covered,lt_hours_covered,"
                                     "Hp_se,He_se,Hn_se (1-sigma standard errors, nT),"
                                     "Hp_dof,He_dof,Hn_dof (their degrees of freedom: "
                                     "95 % interval = offset +- t(0.975, dof) se)). "
                                     "Sudden level changes of the offset found in the "
                                     "record's day values are named in the warnings, in "
                                     "the reason of the windows straddling them and in "
                                     "OFFSETS.csv.provenance.json (level_changes).")
    fit.add_argument("input", help="DATA: CSV time,Hp,He,Hn (AC-cleaned, any cadence), GOES-R "
                                   "MAG L2 netCDF or ISTP CDF (format detected)")
    add_model_arguments(fit)
    fit.add_argument("--kp-max", type=float, default=1.0,
                     help="largest Kp used (default 1.0; 1+ = 1.33 is excluded)")
    fit.add_argument("--window-days", type=positive_float, default=28.0,
                     help="window in days, > 0 (default 28)")
    fit.add_argument("--step-days", type=positive_float, default=7.0,
                     help="step in days, > 0 (default 7)")
    fit.add_argument("--min-used", type=int, default=720,
                     help="fewest quiet 1-min samples for a valid window (default 720)")
    fit.add_argument("--min-day-coverage", type=float, default=MIN_DAY_COVERAGE,
                     metavar="FRACTION",
                     help="fewest of a window's days that must hold quiet samples, as a "
                          f"fraction (default {MIN_DAY_COVERAGE:g}); thinner windows are NaN")
    fit.add_argument("--min-lt-coverage", type=float, default=MIN_LT_COVERAGE,
                     metavar="FRACTION",
                     help="fewest of the 24 local-time hours that must hold quiet samples, "
                          f"as a fraction (default {MIN_LT_COVERAGE:g}); thinner windows "
                          "are NaN")
    fit.add_argument("--method", choices=("median", "lt_balanced"), default="median",
                     help="median (default, CONTRACTS §2) or lt_balanced: mean over 24 "
                          "local-time bins of per-bin medians")
    fit.add_argument("--split-at-level-changes", action="store_true",
                     help="cut the windows at each level change of the offset found: a "
                          "window straddling one becomes two pieces with their own "
                          f"medians and errors (pieces under {MIN_PIECE_DAYS:g} days are "
                          "NaN), OFFSETS.csv gains a 'segment' column, and 'offsets "
                          "apply' interpolates within a segment only (default: off, the "
                          "windows mix both levels)")
    add_output(fit, help_text="OFFSETS.csv")
    fit.set_defaults(func=run_fit)
    app = sub.add_parser("apply", help="subtract interpolated offsets",
                         description="CORRECTED.csv = DATA - offsets interpolated linearly "
                                     "between window centres (end values held); column "
                                     "offset_flag: 0 interpolated, 1 held before the first "
                                     "centre, 2 held after the last, 3 no valid offset, 4 "
                                     "interpolated across a window without a valid "
                                     "offset. Samples interpolated across a level change "
                                     "named by 'offsets fit' are counted. An OFFSETS.csv "
                                     "with a 'segment' column (offsets fit "
                                     "--split-at-level-changes) is interpolated within "
                                     "each segment only, end values held out to the "
                                     "level change; the samples inside a change's 95 % "
                                     "time interval are counted.")
    app.add_argument("input", help="DATA.csv: time,Hp,He,Hn")
    app.add_argument("--offsets", required=True, help="OFFSETS.csv from 'offsets fit'")
    add_output(app, help_text="CORRECTED.csv (time,Hp,He,Hn,offset_flag)")
    app.set_defaults(func=run_apply)


def run_fit(args) -> int:
    from magcal.io.formats import read_any
    from magcal.models.inputs import model_inputs
    from magcal.offsets import fit_offsets_frame, write_offsets_csv
    from magcal.provenance import make_provenance

    path = existing_file(args.input)
    frame = read_any(path, required=["Hp", "He", "Hn"])
    inp = model_inputs(frame, longitude_deg=args.longitude, kp_path=args.kp,
                       drivers_path=args.drivers, model=args.model)
    params = {k: getattr(args, k) for k in ("model", "kp_max", "window_days", "step_days",
                                            "min_used", "method", "longitude",
                                            "min_day_coverage", "min_lt_coverage",
                                            "split_at_level_changes")}
    table, details = fit_offsets_frame(
        frame, inp, kp_max=args.kp_max, window_days=args.window_days,
        step_days=args.step_days, min_used=args.min_used, method=args.method,
        min_day_fraction=args.min_day_coverage, min_lt_fraction=args.min_lt_coverage,
        n_jobs=args.jobs, cache_dir=args.cache_dir,
        split_at_level_changes=args.split_at_level_changes,
        provenance=make_provenance("offsets fit", params, inputs=[path, *inp.files]))
    write_offsets_csv(args.output, table)
    for warning in table.warnings:
        print(f"magcal offsets fit: warning: {warning}", file=sys.stderr)
    thin = sum(r.startswith("coverage too thin") for r in table.reason)
    n_changes = len(table.level_changes)
    changes = (f", {n_changes} level change{'s' if n_changes > 1 else ''} of the offset"
               if n_changes else "")
    if n_changes and table.segment is not None:
        changes += f", windows split at {'them' if n_changes > 1 else 'it'}"
    test = getattr(table, "level_test", None) or {}
    if test and not test.get("tested", True):
        changes += f"; {test.get('why') or 'level changes not looked for'}"
    print(f"magcal offsets fit: {len(table)} windows ({int(table.valid.sum())} valid"
          f"{f', {thin} with coverage too thin to trust' if thin else ''}{changes}), "
          f"{np.mean(details['quiet']):.1%} of 1-min samples at Kp <= {args.kp_max:g}",
          file=sys.stderr)
    return 0


def run_apply(args) -> int:
    import pandas as pd

    from magcal.io.csv import write_csv_frame
    from magcal.io.formats import read_any
    from magcal.offsets import (across_level_change, apply_offsets, outside_valid_windows,
                                read_offsets_csv)
    from magcal.offsets.apply import near_level_change
    from magcal.offsets.apply import skipped_windows_note
    from magcal.provenance import make_provenance

    path = existing_file(args.input)
    frame = read_any(path, required=["Hp", "He", "Hn"])
    table = read_offsets_csv(existing_file(args.offsets))
    if not table.valid.any():
        raise InputError("no window with a valid offset", file=args.offsets)
    times = frame.index.tz_convert("UTC").tz_localize(None).to_numpy()
    corrected, _, flag = apply_offsets(times, frame[["Hp", "He", "Hn"]].to_numpy(), table)
    out = pd.DataFrame(corrected, index=frame.index, columns=["Hp", "He", "Hn"])
    out["offset_flag"] = flag.astype(int)
    prov = make_provenance("offsets apply", {}, inputs=[path, args.offsets])
    write_csv_frame(args.output, out, provenance=prov)
    skipped = skipped_windows_note(table)
    if skipped:
        print(f"magcal offsets apply: warning: {skipped}", file=sys.stderr)
    outside = int(outside_valid_windows(times, table).sum())
    if outside:
        print(f"magcal offsets apply: warning: {outside} of {len(out)} samples lie in no "
              "valid window (offset held or interpolated from windows that never saw them)",
              file=sys.stderr)
    counts = np.bincount(flag, minlength=5)
    bridged = (f", bridged over a window without an offset {counts[4]}" if counts[4]
               else "")
    across = int(across_level_change(times, table).sum())
    near = int(near_level_change(times, table).sum())
    days = ", ".join(str(np.datetime64(c.time, "D")) for c in table.level_changes)
    if table.level_changes and table.segment is not None:
        print(f"magcal offsets apply: offsets split at the level change"
              f"{'s' if len(table.level_changes) > 1 else ''} of the offset ({days}): "
              f"{near} of {len(out)} samples lie inside a change's 95 % time interval, "
              "where which side's offset applies is uncertain (quality bit "
              "offset_near_level_change)", file=sys.stderr)
        if across:
            print(f"magcal offsets apply: warning: {across} of {len(out)} samples in a "
                  "segment without a valid window take their offset from across a level "
                  "change (quality bit offset_interpolated_across_level_change)",
                  file=sys.stderr)
    elif table.level_changes:
        print(f"magcal offsets apply: warning: {across} of {len(out)} samples interpolated "
              f"across a level change of the offset ({days}): their offset mixes both "
              "levels, off by up to the change (quality bit "
              "offset_interpolated_across_level_change)",
              file=sys.stderr)
    print(f"magcal offsets apply: {len(out)} samples; interpolated {counts[0]}, held "
          f"{counts[1] + counts[2]}, no offset {counts[3]}{bridged}"
          f"{f', across a level change {across}' if across else ''}"
          f"{f', near a level change {near}' if near else ''}", file=sys.stderr)
    return 0
