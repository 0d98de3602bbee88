"""``magcal spincal``: spin-ripple calibration of a spinning spacecraft (CONTRACTS §4)."""

from __future__ import annotations

import numpy as np

from magcal.cli._common import add_output, existing_file
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


def add_spin_arguments(p) -> None:
    """Options shared by ``spincal`` and ``flipper``: how to get the spin phase."""
    p.add_argument("--spin-period", type=float, default=None,
                   help="spin period S in seconds, used when there is no phase column")
    p.add_argument("--t0", default=None,
                   help="reference time (ISO-8601 UTC) of phase 0 with --spin-period "
                        "(default: the first sample)")


def load_spin_data(path, spin_period_s=None, t0=None) -> dict:
    """Read a spinning-spacecraft CSV and resolve the spin phase.

    Returns a dict with ``frame`` (rows with all of b1..b3), ``t_s`` (seconds from the
    first row), ``b`` (n, 3), ``phase`` (unwrapped), ``flip`` (or None),
    ``phase_source`` and ``phase_info``.
    """
    import pandas as pd

    from magcal.io.csv import read_csv_frame
    from magcal.spin.despin import check_period_consistent, phase_from_data, phase_from_period

    frame = read_csv_frame(path, required=["b1", "b2", "b3"])
    good = frame[["b1", "b2", "b3"]].notna().all(axis=1).to_numpy()
    n_missing = int((~good).sum())
    frame = frame[good]
    if len(frame) < 3:
        raise InputError("fewer than 3 rows with all of b1, b2, b3", file=path)
    t = (frame.index - frame.index[0]).total_seconds().to_numpy()
    b = frame[["b1", "b2", "b3"]].to_numpy()
    flip = None
    if "flip" in frame.columns:
        f = frame["flip"].to_numpy()
        if np.isnan(f).any() or not np.all(np.isin(f, (0.0, 1.0))):
            bad = int(np.flatnonzero(np.isnan(f) | ~np.isin(f, (0.0, 1.0)))[0])
            raise InputError("flip must be 0 or 1", file=path, column="flip",
                             row=int(np.flatnonzero(good)[bad]) + 2)
        flip = f.astype(int)
    info: dict = {}
    # The two spin-plane sensors: b1, b2; with the flipper in position 1, b3 and b2.
    plane_x = b[:, 0] if flip is None else np.where(flip == 1, b[:, 2], b[:, 0])
    if "phase" in frame.columns:
        ph = frame["phase"].to_numpy()
        if np.isnan(ph).any():
            bad = int(np.flatnonzero(np.isnan(ph))[0])
            raise InputError("missing spin phase", file=path, column="phase",
                             row=int(np.flatnonzero(good)[bad]) + 2)
        phase = np.unwrap(ph)
        source = "phase column"
    elif spin_period_s is not None:
        t0_s = None
        if t0 is not None:
            try:
                ref = pd.Timestamp(t0)
            except ValueError:
                raise InputError(f"cannot parse --t0 {t0!r} as ISO-8601 UTC") from None
            ref = ref.tz_localize("UTC") if ref.tzinfo is None else ref.tz_convert("UTC")
            t0_s = (ref - frame.index[0]).total_seconds()
        phase = phase_from_period(t, spin_period_s, t0_s)
        source = f"spin period {spin_period_s:g} s"
        try:
            derived, info = phase_from_data(t, plane_x, b[:, 1])
        except InputError:
            derived = None
        if derived is not None:
            try:
                check_period_consistent(t, derived, spin_period_s)
            except InputError as exc:
                raise InputError(exc.message, file=path, column="time") from None
    else:
        phase, info = phase_from_data(t, plane_x, b[:, 1])
        source = "derived from the rotation of b1, b2"
    return {"frame": frame, "t_s": t, "b": b, "phase": phase, "flip": flip,
            "phase_source": source, "phase_info": info, "n_missing_rows": n_missing}


def run(args) -> int:
    from magcal.io.jsonio import read_json, write_json
    from magcal.provenance import make_provenance
    from magcal.spin.ripple import fit_spin_ripple

    src = existing_file(args.input)
    data = load_spin_data(src, args.spin_period, args.t0)
    inputs = [src]
    c0 = o0 = None
    if args.prior:
        prior_path = existing_file(args.prior)
        prior = read_json(prior_path, required=("coupling", "offsets"))
        c0 = np.asarray(prior["coupling"], dtype=float)
        o0 = np.asarray(prior["offsets"], dtype=float)
        if c0.shape != (3, 3) or o0.shape != (3,):
            raise InputError("coupling must be 3x3 and offsets 3 numbers", file=prior_path)
        inputs.append(prior_path)
    sel = np.ones(data["t_s"].size, dtype=bool)
    if data["flip"] is not None:
        sel = data["flip"] == args.flip_state
        if not sel.any():
            raise InputError(f"no rows with flip = {args.flip_state}", file=src, column="flip")
    params = {"spin_period_s": args.spin_period, "t0": args.t0, "harmonics": args.harmonics,
              "spins_per_block": args.spins_per_block, "flip_state": args.flip_state,
              "prior": args.prior}
    try:
        cal = fit_spin_ripple(data["t_s"][sel], data["b"][sel], data["phase"][sel],
                              coupling0=c0, offsets0=o0, n_harmonics=args.harmonics,
                              spins_per_block=args.spins_per_block,
                              provenance=make_provenance("spincal", params, inputs=inputs))
    except InputError as exc:
        raise InputError(exc.message, file=src, column=exc.column) from None
    payload = cal.to_json()
    payload["spin_phase"] = {"source": data["phase_source"], **data["phase_info"]}
    payload["n_rows_missing_values"] = data["n_missing_rows"]
    write_json(args.output, payload)
    return 0
