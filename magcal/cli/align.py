"""``magcal align``: rotation angles about Hp, He, Hn against a reference (CONTRACTS §3).

Parses the arguments, reads the files and calls :mod:`magcal.alignment.product`, which
builds ALIGN.json; prints one line on stderr when the rotation is not determinable.
"""

from __future__ import annotations

import sys

from magcal.cli._common import add_output, existing_file
from magcal.errors import InputError

COLUMNS = ("Hp", "He", "Hn")


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "align", help="rotation angles about Hp, He, Hn against a reference",
        description=(
            "Estimate the small rotation w (degrees about Hp, He, Hn) with "
            "DATA ~= R(w) @ REF, plus a constant offset, with uncertainties that account "
            "for time-correlated model-minus-data errors. Both files are time,Hp,He,Hn; "
            "rows are matched on identical times. When the data cannot determine the "
            "rotation (too little change of the reference's direction over the record, "
            "nuisance terms degenerate with it, or a fit no better than the identity), "
            "ALIGN.json says \"determinable\": false with the reason, the angles are null, "
            "and one line on stderr says why (exit status 0)."))
    p.add_argument("data", help="calibrated data with Hp,He,Hn (nT): CSV, GOES-R netCDF or CDF")
    p.add_argument("--reference", required=True,
                   help="reference field (model or reference spacecraft), CSV time,Hp,He,Hn")
    p.add_argument("--mcmc", action="store_true",
                   help="sample the full posterior with emcee (reports converged, autocorr_steps)")
    p.add_argument("--seed", type=int, default=0, help="random seed for --mcmc (default 0)")
    p.add_argument("--no-offset", action="store_true",
                   help="do not fit a constant offset together with the rotation")
    p.add_argument("--fit-scale", action="store_true", help="also fit a common scale factor")
    p.add_argument("--max-steps", type=int, default=40000,
                   help="stop the sampler here even if not converged (default 40000)")
    p.add_argument("--window-days", default="auto",
                   help="fit the angles in consecutive windows of this length (days) to report "
                        "their spread and check their consistency; intervals are inflated when "
                        "windows disagree beyond their errors (default auto: 7 days for 21+ "
                        "days of data, thirds of the record from 9 days; 0 disables)")
    p.add_argument("--longitude", type=float, default=None,
                   help="east longitude (deg) of a geostationary spacecraft: the local-time "
                        "field is expressed in local time (a lon_deg column in DATA does the "
                        "same)")
    p.add_argument("--lt-harmonics", default="auto",
                   help="harmonics of local time per component fitted as nuisance, so a field "
                        "fixed in local time that the reference lacks is not taken for a "
                        "rotation (default auto: 3 for records of 3 days or more; 0 disables)")
    p.add_argument("--kp", default=None,
                   help="Kp file (any format of 'magcal offsets'): fit only samples with "
                        "Kp <= --kp-max, as the paper selects quiet times; recommended against "
                        "a model, which lacks the storm-time field")
    p.add_argument("--kp-max", type=float, default=1.0,
                   help="largest Kp of a used sample with --kp (default 1.0)")
    # magcal.alignment.gls.NOISE_MODELS, spelled out: importing it costs a second here
    p.add_argument("--noise-model", choices=("ou", "ou+white", "ou+ou+white"),
                   default="ou+ou+white",
                   help="residual noise model: OU (default), OU plus white noise (exact "
                        "Kalman likelihood) or two OU time scales plus white noise (Kalman "
                        "whitening, Whittle fit; efficient on multi-scale and 1/f "
                        "residuals); see the README's alignment section")
    p.add_argument("--max-angle", type=float, default=45.0, metavar="DEG",
                   help="physically sensible range of each angle: a rotation the data cannot "
                        "confine to +-DEG is reported as not determinable (default 45)")
    add_output(p, help_text="output ALIGN.json")
    p.set_defaults(func=run)


def _auto_or_number(text, name, kind=float):
    if text == "auto":
        return "auto"
    try:
        value = kind(text)
    except ValueError:
        raise InputError(f"{name} must be 'auto' or a number, got {text!r}") from None
    if value < 0:
        raise InputError(f"{name} must not be negative, got {text}")
    return value


def run(args) -> int:
    from magcal.alignment.product import (AlignSettings, align_product, match_frames,
                                          quiet_from_kp, resolve_longitude)
    from magcal.io.formats import read_any

    data_path = existing_file(args.data)
    ref_path = existing_file(args.reference)
    if not args.max_angle > 0:
        raise InputError(f"--max-angle must be positive, got {args.max_angle}")
    settings = AlignSettings(
        fit_offset=not args.no_offset, fit_scale=args.fit_scale, mcmc=args.mcmc,
        seed=args.seed, max_steps=args.max_steps,
        window_days=_auto_or_number(args.window_days, "--window-days"),
        lt_harmonics=_auto_or_number(args.lt_harmonics, "--lt-harmonics", int),
        max_angle_deg=args.max_angle, noise_model=args.noise_model)
    pair = match_frames(read_any(data_path, required=COLUMNS),
                        read_any(ref_path, required=COLUMNS),
                        data_name=data_path, ref_name=ref_path)
    lon, lon_source = resolve_longitude(pair, args.longitude, data_name=data_path)
    inputs, quiet, selection = [data_path, ref_path], None, None
    if args.kp is not None:
        from magcal.indices import read_kp

        kp_path = existing_file(args.kp)
        inputs.append(kp_path)
        quiet = quiet_from_kp(pair.times, read_kp(kp_path), args.kp_max, kp_name=kp_path)
        selection = {"kp_file": str(kp_path), "kp_max": args.kp_max}
    product = align_product(pair.times, pair.data, pair.ref, lon_deg=lon,
                            lon_source=lon_source, quiet=quiet, selection=selection,
                            settings=settings, inputs=inputs,
                            matched_rows=pair.matched_rows)
    product.write(args.output)
    if not product.determinable:
        print(f"magcal align: rotation not determinable, angles written as null: "
              f"{product.reason}", file=sys.stderr)
    return 0
