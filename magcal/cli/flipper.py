"""``magcal flipper``: spin-axis offset O3 from flipper intervals (CONTRACTS §4)."""

from __future__ import annotations

import numpy as np

from magcal.cli._common import add_output, existing_file
from magcal.cli.spincal import add_spin_arguments, load_spin_data
from magcal.errors import InputError


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "flipper", help="spin-axis offset from flipper measurements",
        description="Estimate the offset O3 of the spin-axis sensor from the spin average "
                    "of sensor 3 while the flipper (column flip = 1) turns it into the spin "
                    "plane. With --cal (CAL.json of flip position 0) the leak of the "
                    "spin-axis field through the sensor's tilt is removed, and the completed "
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
    from magcal.spin.flipper import flipper_offset

    src = existing_file(args.input)
    data = load_spin_data(src, args.spin_period, args.t0)
    if data["flip"] is None:
        raise InputError("no flip column: flipper intervals missing (need rows with flip = 1 "
                         "and flip = 0)", file=src, column="flip")
    inputs = [src]
    c = o = None
    cal_doc = None
    if args.cal:
        cal_path = existing_file(args.cal)
        cal_doc = read_json(cal_path, required=("coupling", "offsets"))
        c = np.asarray(cal_doc["coupling"], dtype=float)
        o = np.asarray(cal_doc["offsets"], dtype=float)
        inputs.append(cal_path)
    elif args.complete:
        raise InputError("--complete needs --cal CAL.json")
    params = {"spin_period_s": args.spin_period, "t0": args.t0, "cal": args.cal}
    try:
        res = flipper_offset(data["t_s"], data["b"], data["phase"], data["flip"],
                             coupling=c, offsets=o,
                             provenance=make_provenance("flipper", params, inputs=inputs))
    except InputError as exc:
        raise InputError(exc.message, file=src, column=exc.column) from None
    payload = res.to_json()
    payload["spin_phase"] = {"source": data["phase_source"], **data["phase_info"]}
    write_json(args.output, payload)
    if args.complete:
        d_o3 = res.O3 - o[2]
        o_new = o.copy()
        o_new[:2] -= np.linalg.solve(c[:2, :2], c[:2, 2] * d_o3)
        o_new[2] = res.O3
        done = dict(cal_doc)
        done["offsets"] = o_new.tolist()
        done["determined"] = list(cal_doc.get("determined", [])) + ["O3"]
        done["fixed"] = [n for n in cal_doc.get("fixed", []) if n != "O3"]
        done.setdefault("std", {})["O3"] = res.O3_std
        done["notes"] = list(cal_doc.get("notes", [])) + [
            f"O3 from the flipper ({args.input}): O1, O2 adjusted to keep the spin plane"]
        write_json(args.complete, done)
    return 0
