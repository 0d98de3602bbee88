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
    p.add_argument("--window-days", type=float, default=None,
                   help="also report angles in consecutive windows of this length (days)")
    add_output(p, help_text="output ALIGN.json")
    p.set_defaults(func=run)


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
    return times, d, r, int(common.size), int(data.shape[0]), int(ref.shape[0])


def run(args) -> int:
    from magcal.alignment.estimator import Aligner
    from magcal.alignment.windows import angles_by_window
    from magcal.io.jsonio import write_json
    from magcal.provenance import make_provenance

    data_path = existing_file(args.data)
    ref_path = existing_file(args.reference)
    times, d, r, n_matched, n_data, n_ref = _matched(data_path, ref_path)
    aligner = Aligner(fit_offset=not args.no_offset, fit_scale=args.fit_scale, mcmc=args.mcmc,
                      rng=np.random.default_rng(args.seed), max_steps=args.max_steps)
    aligner.fit(times, d, r)
    payload = aligner.result_.to_json()
    payload["matched_rows"] = {"data_rows": n_data, "reference_rows": n_ref,
                               "matched": n_matched}
    if args.mcmc:
        payload["closed_form"] = {k: v for k, v in aligner.closed_form_.to_json().items()
                                  if k in ("angles_deg", "std_deg", "ci95_deg", "method")}
    if args.window_days:
        win = angles_by_window(times, d, r, window_s=args.window_days * 86400.0,
                               fit_offset=not args.no_offset, fit_scale=args.fit_scale)
        payload["windows"] = {k: v for k, v in win.to_json().items()
                              if k not in ("schema_version", "magcal_version")}
    payload["provenance"] = make_provenance(
        "align", {"mcmc": args.mcmc, "seed": args.seed, "fit_offset": not args.no_offset,
                  "fit_scale": args.fit_scale, "max_steps": args.max_steps,
                  "window_days": args.window_days},
        inputs=[data_path, ref_path])
    write_json(args.output, payload)
    return 0
