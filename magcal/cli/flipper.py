"""``magcal flipper``: spin-axis offset O3 from flipper intervals (CONTRACTS §4)."""

from __future__ import annotations

from magcal.cli._common import add_output, add_spin_arguments, existing_file, print_screened
from magcal.errors import InputError


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "flipper", help="spin-axis offset from flipper measurements",
        description="Estimate the offset O3 of the spin-axis sensor while the flipper "
                    "(column flip = 1) turns it into the spin plane: the spin-frequency "
                    "tone of the despun sensors 3 and 2. With --cal (CAL.json of flip "
                    "position 0) the tone's direction and the leak of the spin-axis field "
                    "through the sensor's tilt come from that calibration, its covariance "
                    "goes into O3_std (O3_std_calibration), and the completed "
                    "12-parameter calibration can be written with --complete.")
    p.add_argument("input", help="CSV time,b1,b2,b3,flip[,phase]")
    add_spin_arguments(p)
    p.add_argument("--cal", help="CAL.json from 'magcal spincal' (flip position 0)")
    p.add_argument("--complete", help="also write CAL.json completed with O3 (needs --cal)")
    add_output(p, help_text="FLIP.json")
    p.set_defaults(func=run)


def run(args) -> int:
    from magcal.io.jsonio import read_json, write_json
    from magcal.provenance import make_provenance
    from magcal.spin.inputs import load_spin_data
    from magcal.spin.product import complete_calibration, flipper

    src = existing_file(args.input)
    if args.complete and not args.cal:
        raise InputError("--complete needs --cal CAL.json")
    data = load_spin_data(src, args.spin_period, args.t0, scale=args.scale,
                          spin_sense=args.spin_sense, require_flip=True,
                          screen=not args.no_screen)
    inputs = [src]
    cal_doc = None
    if args.cal:
        cal_path = existing_file(args.cal)
        cal_doc = read_json(cal_path, required=("coupling", "offsets"))
        inputs.append(cal_path)
    params = {"spin_period_s": args.spin_period, "t0": args.t0, "cal": args.cal,
              "scale": args.scale, "spin_sense": args.spin_sense,
              "screen": not args.no_screen}
    try:
        product = flipper(data, coupling=None if cal_doc is None else cal_doc["coupling"],
                          offsets=None if cal_doc is None else cal_doc["offsets"],
                          covariance=None if cal_doc is None else cal_doc.get("covariance"),
                          determined=() if cal_doc is None else cal_doc.get("determined", ()),
                          provenance=make_provenance("flipper", params, inputs=inputs))
        done = None if not args.complete else complete_calibration(
            cal_doc, product.result.O3, product.result.O3_std, args.input)
    except InputError as exc:
        if exc.file is None and args.cal:
            raise InputError(exc.message, file=args.cal, column=exc.column) from None
        raise
    write_json(args.output, product.to_json())
    print_screened("magcal flipper", data.screened)
    if done is not None:
        write_json(args.complete, done)
    return 0
