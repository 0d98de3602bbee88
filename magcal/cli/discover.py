"""``magcal discover``: find, name and add what the model is missing (CONTRACTS §5)."""

from __future__ import annotations

import sys

from magcal.cli._common import add_output, existing_file
from magcal.errors import InputError


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "discover", help="find, name and add what the model is missing",
        description="Fit the vocabulary of gap effects (offset, drift, diurnal, temperature, "
                    "scale, rotation, activity, spin_tone, step, periodic) to measured - "
                    "model, add the one with the strongest held-out evidence (days as "
                    "cross-validation blocks), refit and repeat until no candidate earns "
                    "its parameters. Writes REPORT.json and prints the account.")
    p.add_argument("measured", help="MEASURED (time plus component columns, e.g. Hp,He,Hn; "
                   "CSV, GOES-R netCDF or CDF)")
    p.add_argument("model", help="MODEL.csv with the same component columns")
    p.add_argument("--covariates", help="COV.csv: time plus any of temperature (deg C), kp, "
                                        "dst (nT), lon_deg, phase (rad)")
    p.add_argument("--longitude", type=float,
                   help="spacecraft east longitude in deg, for local time (else lon_deg)")
    p.add_argument("--max-effects", type=int, default=8, help="most effects to add (default 8)")
    p.add_argument("--plot", help="also write a PNG of the residual before and after")
    p.add_argument("--no-screen", action="store_true",
                   help="keep spikes of measured - model (by default samples beyond 8 robust "
                        "sigma with a jump in and out are left out, counted in REPORT.json "
                        "'screened')")
    add_output(p, help_text="REPORT.json")
    p.set_defaults(func=run)


def run(args) -> int:
    from magcal.discover import discover_gap
    from magcal.io.formats import read_any
    from magcal.io.jsonio import write_json
    from magcal.provenance import make_provenance

    meas_path = existing_file(args.measured)
    model_path = existing_file(args.model)
    measured = read_any(meas_path)
    model = read_any(model_path)
    shared = [c for c in measured.columns if c in model.columns]
    if not shared:
        raise InputError("no component column in common with MODEL.csv "
                         f"({', '.join(model.columns)})", file=meas_path,
                         column=",".join(measured.columns))
    cov = None
    inputs = [meas_path, model_path]
    if args.covariates:
        cov_path = existing_file(args.covariates)
        cov = read_any(cov_path)
        known = {"temperature", "kp", "dst", "lon_deg", "phase"}
        if not known & set(cov.columns):
            raise InputError("no covariate column (expected any of temperature, kp, dst, "
                             "lon_deg, phase)", file=cov_path, column=",".join(cov.columns))
        inputs.append(cov_path)
    if args.max_effects < 0:
        raise InputError(f"--max-effects must be >= 0, got {args.max_effects}")
    if args.longitude is not None and not -360.0 <= args.longitude <= 360.0:
        raise InputError(f"--longitude {args.longitude} outside [-360, 360]")
    try:
        result = discover_gap(measured, model, cov, longitude_deg=args.longitude,
                              max_effects=args.max_effects, screen=not args.no_screen)
    except InputError as exc:
        if exc.file is None:
            raise InputError(exc.message, file=meas_path, row=exc.row,
                             column=exc.column) from None
        raise
    # what the readers repaired (fill values turned NaN, ...) is said, not only done
    repairs = {str(path): frame.attrs.get("repairs") for path, frame in
               zip(inputs, (measured, model, cov)) if frame is not None
               and frame.attrs.get("repairs")}
    params = {"longitude": args.longitude, "max_effects": args.max_effects,
              "screen": not args.no_screen, "input_repairs": repairs}
    result = result.with_provenance(make_provenance("discover", params, inputs=inputs))
    if args.plot:
        from magcal.discover.plots import plot_gap

        plot_gap(result, args.plot)
    write_json(args.output, result.to_json())
    for path, done in repairs.items():
        for rep in done:
            print(f"{path}: {rep['what']} in {rep.get('column', '?')} ({rep['count']})",
                  file=sys.stderr)
    for line in result.account():
        print(line, file=sys.stderr)
    return 0
