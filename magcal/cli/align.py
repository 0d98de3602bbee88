"""``magcal align``: rotation angles about Hp, He, Hn against a reference (CONTRACTS §3)."""

from __future__ import annotations

import numpy as np

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
            "rows are matched on identical times."))
    p.add_argument("data", help="calibrated data, CSV time,Hp,He,Hn (nT)")
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


def _matched(data_path, ref_path):
    from magcal.io.csv import read_csv_frame

    data = read_csv_frame(data_path, required=COLUMNS)
    ref = read_csv_frame(ref_path, required=COLUMNS)
    common = data.index.intersection(ref.index)
    if common.size == 0:
        raise InputError("no time in common with the data file", file=ref_path, column="time")
    d = data.loc[common, list(COLUMNS)].to_numpy(dtype=float)
    r = ref.loc[common, list(COLUMNS)].to_numpy(dtype=float)
    ok = np.isfinite(d).all(axis=1) & np.isfinite(r).all(axis=1)
    if ok.sum() < 10:
        raise InputError(f"only {int(ok.sum())} matched rows with finite Hp, He, Hn in both "
                         "files (need at least 10)", file=data_path)
    naive = common.tz_convert("UTC").tz_localize(None) if common.tz is not None else common
    times = naive.to_numpy().astype("datetime64[ns]")
    lon = data.loc[common, "lon_deg"].to_numpy(dtype=float) if "lon_deg" in data else None
    return times, d, r, int(common.size), int(data.shape[0]), int(ref.shape[0]), lon


def run(args) -> int:
    from magcal.alignment.estimator import Aligner
    from magcal.io.jsonio import write_json
    from magcal.provenance import make_provenance

    data_path = existing_file(args.data)
    ref_path = existing_file(args.reference)
    lt_harmonics = _auto_or_number(args.lt_harmonics, "--lt-harmonics", int)
    window_days = _auto_or_number(args.window_days, "--window-days")
    times, d, r, n_matched, n_data, n_ref, lon = _matched(data_path, ref_path)
    lon_source = "lon_deg column" if lon is not None else None
    if args.longitude is not None:
        lon, lon_source = args.longitude, "--longitude"
    elif lon is not None and not np.isfinite(lon).all():
        raise InputError("lon_deg has missing values in matched rows", file=data_path,
                         column="lon_deg")
    inputs = [data_path, ref_path]
    selection = {"kp_file": None, "kp_max": None, "used_rows": n_matched}
    if args.kp is not None:
        from magcal.indices import kp_at, read_kp
        from magcal.offsets.estimator import quiet_mask

        kp_path = existing_file(args.kp)
        inputs.append(kp_path)
        quiet = quiet_mask(kp_at(read_kp(kp_path), times), args.kp_max)
        if quiet.sum() < 10:
            raise InputError(f"only {int(quiet.sum())} matched rows with Kp <= {args.kp_max:g}",
                             file=kp_path)
        d = np.where(quiet[:, None], d, np.nan)
        selection = {"kp_file": str(kp_path), "kp_max": args.kp_max,
                     "used_rows": int(quiet.sum()), "quiet_fraction": float(quiet.mean())}
    aligner = Aligner(fit_offset=not args.no_offset, fit_scale=args.fit_scale, mcmc=args.mcmc,
                      rng=np.random.default_rng(args.seed), max_steps=args.max_steps,
                      lt_harmonics=lt_harmonics,
                      window_days=None if window_days == 0 else window_days)
    aligner.fit(times, d, r, lon_deg=lon)
    payload = aligner.result_.to_json()
    if args.kp is None:
        payload["warnings"].append(
            "no --kp given: all samples used; a model reference lacks the storm-time field, "
            "which can bias the angles in every window alike (see window_consistency)")
    payload["matched_rows"] = {"data_rows": n_data, "reference_rows": n_ref,
                               "matched": n_matched}
    payload["selection"] = selection
    payload["lt_harmonics"] = aligner.lt_harmonics_
    payload["longitude"] = {"source": lon_source,
                            "lon_deg": None if lon is None else float(np.median(lon))}
    if args.mcmc:
        payload["closed_form"] = {k: v for k, v in aligner.closed_form_.to_json().items()
                                  if k in ("angles_deg", "std_deg", "ci95_deg", "method")}
    if aligner.windows_ is not None:
        win = aligner.windows_
        payload["windows"] = {k: v for k, v in win.to_json().items()
                              if k not in ("schema_version", "magcal_version")}
        payload["windows"]["paper_style"] = {
            c: f"{a:.2f} ({s:.2f})" for c, a, s in zip(COLUMNS, aligner.result_.angles_deg,
                                                       win.spread_deg)}
        payload["windows"]["paper_style_meaning"] = (
            "angle of the whole record (standard deviation of the window angles), as "
            "the SOSMAG paper quotes 1.7 (4.0), -0.5 (1.4), -0.5 (1.9) deg")
    payload["provenance"] = make_provenance(
        "align", {"mcmc": args.mcmc, "seed": args.seed, "fit_offset": not args.no_offset,
                  "fit_scale": args.fit_scale, "max_steps": args.max_steps,
                  "window_days": args.window_days, "lt_harmonics": args.lt_harmonics,
                  "longitude": args.longitude, "kp_max": args.kp_max if args.kp else None},
        inputs=inputs)
    if args.mcmc and aligner.result_.samples is not None:
        samples_path = samples_path_for(args.output)
        payload["mcmc"]["samples_file"] = samples_path.name
        _write_samples(samples_path, aligner.result_)
    write_json(args.output, payload)
    return 0


def samples_path_for(output):
    """Side file of the posterior samples: ``ALIGN.json`` -> ``ALIGN.samples.csv.gz``."""
    from pathlib import Path

    out = Path(output)
    return out.with_name(out.stem + ".samples.csv.gz")


def _write_samples(path, result) -> None:
    """Posterior samples (angles in degrees, as named in ``mcmc.sample_names``), atomically."""
    import pandas as pd

    from magcal.io.atomic import atomic_path

    names = [n.replace("w_", "angle_deg_") for n in result.mcmc["sample_names"]]
    frame = pd.DataFrame(result.samples, columns=names)
    with atomic_path(path) as tmp:
        frame.to_csv(tmp, index=False, float_format="%.6g", compression="gzip")
