"""``magcal picog fit|apply``: PiCoG AC cleaning (CONTRACTS §1)."""

from __future__ import annotations

import sys

from magcal.cli._common import add_output, existing_file
from magcal.errors import InputError

INPUT_HELP = "multi-sensor file (CSV, GOES-R netCDF or CDF; detected by content)"


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "picog", help="AC cleaning of multi-sensor data with PiCoG (fit, apply)",
        description="Principal-component gradiometer (Constantinescu et al. 2020): fit "
                    "correction matrices from a multi-sensor CSV (time,<sensor>_x,_y,_z,...) "
                    "and apply them as one linear combination of the sensors.")
    sub = p.add_subparsers(dest="subverb", required=True)

    f = sub.add_parser("fit", help="fit the correction and write PARAMS.json",
                       description="Fit with a PLAN.toml, or let --auto choose stages, pairs, "
                                   "windows and orders for --target.")
    f.add_argument("input", help=INPUT_HELP)
    f.add_argument("--plan", help="PLAN.toml (stages and orders)")
    f.add_argument("--target", help="sensor whose cleaned data is the product (with --auto)")
    f.add_argument("--auto", action="store_true", help="choose the plan automatically")
    f.add_argument("--alpha-method", choices=("decorrelate", "variance"), default=None,
                   help="alpha refined by decorrelation (default) or Eq. 14 only")
    add_output(f, help_text="PARAMS.json")
    f.set_defaults(func=run_fit)

    a = sub.add_parser("apply", help="apply PARAMS.json and write the cleaned target",
                       description="Cleaned target = sum_k M[k] @ B_k + G (G: the DC offset "
                                   "of the correction, Eq. 31); rows where a needed sensor "
                                   "is missing are NaN with flag=1.")
    a.add_argument("input", help=INPUT_HELP)
    a.add_argument("--params", required=True, help="PARAMS.json from 'picog fit'")
    offset = a.add_mutually_exclusive_group()
    offset.add_argument("--keep-correction-offset", action="store_true",
                        help="leave the DC offset G of the correction in the output (the bare "
                             "sum_k M[k] @ B_k, which carries the other sensors' steady "
                             "fields); by default G is added back so the product keeps the "
                             "target's mean field")
    offset.add_argument("--pure-ac", action="store_true",
                        help="add back the DC offset G of the correction (Eq. 32); now the "
                             "default, kept for compatibility")
    a.add_argument("--on-board", action="store_true",
                   help="deliver the on-board product (the constant matrices) even in bands "
                        "where it is worse than raw (warned); by default the band-selective "
                        "ground product is delivered, never above 1.1x the raw power in any "
                        "band (else band-limited or the raw target, with the reason on "
                        "stderr and in CLEAN.json next to the output)")
    add_output(a, help_text="CLEAN.csv (time,x,y,z,flag)")
    a.set_defaults(func=run_apply)


def run_fit(args) -> int:
    from magcal.ac.estimator import PiCoG
    from magcal.ac.plan import read_plan
    from magcal.io.formats import read_any
    from magcal.io.jsonio import write_json
    from magcal.provenance import make_provenance

    src = existing_file(args.input)
    if args.plan and args.auto:
        raise InputError("give either --plan or --auto, not both")
    if not args.plan and not args.auto:
        raise InputError("give --plan PLAN.toml, or --target SENSOR --auto")
    inputs = [src]
    plan, opts = None, {}
    if args.plan:
        plan_path = existing_file(args.plan)
        plan, opts = read_plan(plan_path)
        inputs.append(plan_path)
    elif not args.target:
        raise InputError("--auto needs --target SENSOR")
    frame = read_any(src)
    alpha_method = args.alpha_method or opts.get("alpha_method", "decorrelate")
    model = PiCoG(plan, target=args.target, auto=args.auto, alpha_method=alpha_method)
    try:
        model.fit(frame)
    except InputError as exc:
        if exc.file is None:
            raise InputError(exc.message, file=src, row=exc.row, column=exc.column) from None
        raise
    prov = make_provenance("picog fit", {"plan": args.plan, "auto": args.auto,
                                         "target": model.target_,
                                         "alpha_method": alpha_method},
                           inputs=inputs)
    write_json(args.output, model.to_params(prov))
    if args.auto:
        for line in model.summary_lines():
            print(line)
    for warning in model.warnings_:
        print(f"magcal picog fit: warning: {warning}", file=sys.stderr)
    return 0


def run_apply(args) -> int:
    from magcal.ac.estimator import apply_params
    from magcal.io.csv import write_csv_frame
    from magcal.io.formats import read_any
    from magcal.io.jsonio import read_json, write_json

    src = existing_file(args.input)
    params_path = existing_file(args.params)
    doc = read_json(params_path, required=("M", "target"))
    frame = read_any(src)
    try:
        out, warnings = apply_params(frame, doc, pure_ac=args.pure_ac,
                                     keep_correction_offset=args.keep_correction_offset,
                                     on_board=args.on_board, file=params_path)
    except InputError as exc:
        if exc.file is not None:
            raise
        raise InputError(exc.message, file=src, column=exc.column) from None
    write_csv_frame(args.output, out, float_format="%.6f")
    delivery = out.attrs.get("delivery")
    if delivery is not None:
        from pathlib import Path

        from magcal.provenance import make_provenance

        side = Path(args.output).with_suffix(".json")
        write_json(side, {**delivery, "product": str(args.output),
                          "provenance": make_provenance("picog apply", {
                              "params": str(params_path)}, inputs=[src, params_path])})
        print(f"magcal picog apply: delivered {delivery['delivered']} ({delivery['reason']}); "
              f"per-band record in {side}", file=sys.stderr)
    for warning in warnings:
        print(f"magcal picog apply: warning: {warning}", file=sys.stderr)
    return 0
