"""``magcal spincal``: spin-ripple calibration of a spinning spacecraft (CONTRACTS §4)."""

from __future__ import annotations

import sys

from magcal.cli._common import add_output, add_spin_arguments, existing_file, print_screened
from magcal.errors import InputError


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "spincal", help="spin-ripple calibration of a spinning spacecraft",
        description="Find the coupling matrix C and offsets O (B = C (b - O)) that minimise "
                    "the power at 1x and 2x the spin frequency in the despun field "
                    "(Kivelson et al. 1992, App. 2). Only 8 of the 12 parameters are "
                    "determinable this way; c11, c12, c33, O3 keep their priors. Input: "
                    "time,b1,b2,b3[,phase][,flip]; without a phase column the phase is "
                    "2 pi (t - t0) / S with --spin-period S, or derived from the data.")
    p.add_argument("input", help="CSV time,b1,b2,b3 with optional phase (rad) and flip (0/1)")
    add_spin_arguments(p)
    p.add_argument("--prior", help="CAL.json whose coupling and offsets are the priors "
                                   "(default: identity and zero)")
    p.add_argument("--harmonics", type=int, default=2,
                   help="spin harmonics to minimise (default 2: 1x and 2x)")
    p.add_argument("--spins-per-block", type=int, default=1,
                   help="whole spins per analysis block (default 1)")
    p.add_argument("--flip-state", type=int, choices=(0, 1), default=0,
                   help="with a flip column, calibrate the rows in this position (default 0)")
    add_output(p, help_text="CAL.json")
    p.set_defaults(func=run)


def run(args) -> int:
    from magcal.io.jsonio import read_json, write_json
    from magcal.provenance import make_provenance
    from magcal.spin.inputs import load_spin_data
    from magcal.spin.product import spincal

    src = existing_file(args.input)
    data = load_spin_data(src, args.spin_period, args.t0, scale=args.scale,
                          spin_sense=args.spin_sense, flip_state=args.flip_state,
                          screen=not args.no_screen)
    inputs = [src]
    c0 = o0 = None
    if args.prior:
        prior_path = existing_file(args.prior)
        prior = read_json(prior_path, required=("coupling", "offsets"))
        c0, o0 = prior["coupling"], prior["offsets"]
        inputs.append(prior_path)
    params = {"spin_period_s": args.spin_period, "t0": args.t0, "harmonics": args.harmonics,
              "spins_per_block": args.spins_per_block, "flip_state": args.flip_state,
              "prior": args.prior, "scale": args.scale, "spin_sense": args.spin_sense,
              "screen": not args.no_screen}
    try:
        product = spincal(data, coupling0=c0, offsets0=o0, n_harmonics=args.harmonics,
                          spins_per_block=args.spins_per_block, flip_state=args.flip_state,
                          provenance=make_provenance("spincal", params, inputs=inputs))
    except InputError as exc:
        if exc.file is None and args.prior:
            raise InputError(exc.message, file=args.prior, column=exc.column) from None
        raise
    write_json(args.output, product.to_json())
    print_screened("magcal spincal", data.screened)
    for warning in product.warnings:
        print(f"magcal spincal: warning: {warning}", file=sys.stderr)
    return 0
