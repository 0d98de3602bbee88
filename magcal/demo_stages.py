"""The stages of ``magcal demo``, one function each, in chain order.

A stage takes ``(data_dir, stage_outdir, context)`` and returns ``(lines, products)``:
summary lines for the console and the product files it wrote. ``context`` carries
results from earlier stages (e.g. the corrected month for alignment).
"""

from __future__ import annotations

from pathlib import Path

from magcal.demo import require
from magcal.errors import NotYetAvailableError


def _amr1_stage(start: str, end: str) -> str:
    """PLAN.toml stage: AMR1 cleans both fluxgates on an interval around the midnight step."""
    return ('[[stage]]\nreference = "amr1"\nsensors = ["fgmo", "fgmi"]\n'
            f'orders = [ {{ interval = ["{start}", "{end}"] }} ]\n')


# The paper's three pair orders (PiCoG §4), shared by the plans below.
_PAIR_ORDERS = "{ window_s = 100 }, { window_s = 700 }, { window_s = 16000 }"
_PAIR = '[[stage]]\npair = ["fgmo", "fgmi"]\n'
_COHERENT = 'target = "fgmo"\ndirection = "coherent"\nhighpass_s = 1800\n'

PAPER_PLAN = ("""# The paper's chain (PiCoG §4): AMR1 cleans both fluxgates on an interval around the
# midnight disturbance, then the fluxgates clean each other to third order.
target = "fgmo"
""" + _amr1_stage("2019-03-04T15:10", "2019-03-04T16:15")
              + _PAIR + f"orders = [ {_PAIR_ORDERS} ]\n")

COHERENT_PLAN = ("""# The paper's chain with magcal's fix for a varying ambient field: each direction comes
# from the part of the sensor that varies with the sensor difference (where the ambient
# field cancels), and a 30 min high-pass removes the daily variation before fitting.
""" + _COHERENT + _amr1_stage("2019-03-04T15:10", "2019-03-04T16:15")
                 + _PAIR + f"orders = [ {_PAIR_ORDERS} ]\n")

JOINT_PLAN = ("""# The coherent plan with the boom pair fitted jointly: one constant 3x3 per sensor
# balancing the scan windows, the 6 s tone band and clean intervals around the largest
# steps, so weak disturbers are not left to whichever order dominates.
""" + _COHERENT + _amr1_stage("2019-03-04T15:25:12", "2019-03-04T16:30:12")
              + _PAIR + "joint = true\nevent_half_s = 120\nmin_snr = 5\n"
              + f"orders = [ {_PAIR_ORDERS},\n           {{ band_hz = [0.1664, 0.1669] }} ]\n")

REGRESSION_PLAN = """# magcal's extension for non-orthogonal disturbers: every other sensor is a reference.
target = "fgmo"
[[stage]]
regression = ["fgmo"]
references = ["fgmi", "amr1", "amr2"]
orders = [ { detrend_s = 3600 } ]
"""


def stage_ac(data: Path, out: Path, context: dict):
    require("magcal.ac.chain", "magcal.cli.picog")
    import numpy as np

    from magcal.io.csv import read_csv_frame
    from magcal.io.jsonio import read_json

    src = data / "geostationary_3days_1s.csv.gz"
    truth = read_csv_frame(data / "geostationary_3days_truth.csv.gz")
    raw = read_csv_frame(src)
    want = truth[["fgmo_x", "fgmo_y", "fgmo_z"]].to_numpy()
    raw_res = raw[["fgmo_x", "fgmo_y", "fgmo_z"]].to_numpy() - want
    raw_res -= np.nanmean(raw_res, axis=0)
    lines = [f"raw fgmo - truth: rms {np.sqrt(np.nanmean(raw_res ** 2)):.3f} nT (mean removed)"]
    products, metrics = [], {}
    out.mkdir(parents=True, exist_ok=True)
    for name, text in (("paper", PAPER_PLAN), ("coherent", COHERENT_PLAN),
                       ("joint", JOINT_PLAN), ("regression", REGRESSION_PLAN)):
        plan = out / f"PLAN_{name}.toml"
        plan.write_text(text)
        params, clean = out / f"PARAMS_{name}.json", out / f"CLEAN_{name}.csv.gz"
        _cli("picog", "fit", src, "--plan", plan, "-o", params)
        _cli("picog", "apply", src, "--params", params, "-o", clean)
        cleaned = read_csv_frame(clean)[["x", "y", "z"]].to_numpy()
        res = cleaned - want
        res -= np.nanmean(res, axis=0)  # the DC offset G is not part of the AC comparison
        ratio = np.nanmean(raw_res ** 2) / np.nanmean(res ** 2)
        ident = np.abs(sum(np.asarray(m) for m in read_json(params)["M"].values())
                       - np.eye(3)).max()
        lines.append(f"{name} plan: rms {np.sqrt(np.nanmean(res ** 2)):.3f} nT, disturbance "
                     f"power reduced {ratio:.1f}x; |sum M - I| = {ident:.1e}")
        products += [plan, params, clean]
        metrics[name] = {"power_reduction": float(ratio), "identity_error": float(ident),
                         "rms_nT": float(np.sqrt(np.nanmean(res ** 2)))}
    from magcal.report.ac_quality import write_ac_quality

    quality = write_ac_quality(out, src)  # remnants and daily-refit stability
    products.append(quality)
    lines.append(f"AC quality (remnants per disturbance class, day-to-day stability): "
                 f"{quality.name}")
    context["ac_params"] = out / "PARAMS_regression.json"
    return lines, products, metrics


MONTH_LON_DEG = 128.2  # GK-2A slot of the simulated month


def stage_offsets(data: Path, out: Path, context: dict):
    require("magcal.offsets.estimator", "magcal.models.field")
    import numpy as np
    import pandas as pd

    from magcal.indices import read_kp
    from magcal.io.csv import read_csv_frame, write_csv_frame
    from magcal.offsets import apply_offsets, fit_offsets, write_offsets_csv
    from magcal.offsets.plots import plot_offsets, plot_residual_local_time
    from magcal.provenance import make_provenance

    src, kp_path = data / "month_1min_hpen.csv.gz", data / "month_kp.csv"
    frame = read_csv_frame(src, required=["Hp", "He", "Hn"])
    truth = read_csv_frame(data / "month_truth.csv.gz")
    kp = read_kp(kp_path)
    times = frame.index.tz_convert("UTC").tz_localize(None).to_numpy()
    values = frame[["Hp", "He", "Hn"]].to_numpy()
    products, lines, tables, metrics = [], [], {}, {}
    out.mkdir(parents=True, exist_ok=True)
    for method in ("median", "lt_balanced"):
        prov = make_provenance("offsets fit", {"method": method, "model": "T89", "kp_max": 1.0,
                                               "window_days": 28, "step_days": 7,
                                               "longitude_deg": MONTH_LON_DEG},
                               inputs=[src, kp_path])
        table, det = fit_offsets(times, values, MONTH_LON_DEG, 0.0, 6.6, kp, model="T89",
                                 kp_max=1.0, window_days=28, step_days=7, method=method,
                                 provenance=prov)
        name = "OFFSETS.csv" if method == "median" else f"OFFSETS_{method}.csv"
        products.append(write_offsets_csv(out / name, table))
        tables[method] = table
        # truth at the window centres (the truth offsets drift slowly: interpolate)
        t_truth = truth.index.tz_convert("UTC").tz_localize(None).to_numpy().astype("int64")
        centres = np.asarray(table.center, dtype="datetime64[ns]").astype("int64")
        ok = np.isfinite(table.offset_nT).all(axis=1)
        true_c = np.column_stack([np.interp(centres, t_truth, truth[f"offset_{c}"].to_numpy())
                                  for c in ("Hp", "He", "Hn")])
        err = np.abs(table.offset_nT - true_c)[ok]
        worst = err.max(axis=0) if err.size else np.full(3, np.nan)
        metrics[method] = {"worst_error_nT": worst.tolist(), "n_valid": int(ok.sum())}
        lines.append(f"{method}: {int(ok.sum())}/{len(ok)} valid windows, worst |error| vs "
                     f"truth Hp {worst[0]:.2f}, He {worst[1]:.2f}, Hn {worst[2]:.2f} nT")
    quiet = det["quiet"]
    lines.insert(0, f"{quiet.mean():.1%} of 1-min samples at Kp <= 1 selected")
    model = pd.DataFrame(det["model"], index=pd.DatetimeIndex(det["times"], tz="UTC",
                                                              name="time"),
                         columns=["Hp", "He", "Hn"])
    products.append(write_csv_frame(out / "MODEL_T89.csv.gz", model))
    corrected, _, flag = apply_offsets(times, values, tables["lt_balanced"])
    corr = pd.DataFrame(corrected, index=frame.index, columns=["Hp", "He", "Hn"])
    corr["offset_flag"] = flag.astype(int)
    products.append(write_csv_frame(out / "CORRECTED.csv.gz", corr))
    pp = plot_residual_local_time(out / "fig19_residual_local_time.png", det["times"],
                                  det["data"] - det["model"], det["lon_deg"], selected=quiet)
    plot_offsets(out / "fig20_offsets.png", tables["median"])
    products += [out / "fig19_residual_local_time.png", out / "fig20_offsets.png"]
    pp = np.atleast_2d(pp)
    lines.append("data - T89 varies with local time by "
                 f"{pp[0, 0]:.1f} / {pp[0, 1]:.1f} / {pp[0, 2]:.1f} nT peak-to-peak in "
                 "Hp / He / Hn (the field T89 lacks)")
    context.update(month_corrected=out / "CORRECTED.csv.gz", month_model=out / "MODEL_T89.csv.gz",
                   offsets_table=tables["median"], offsets_quiet_fraction=float(quiet.mean()))
    metrics["quiet_fraction"] = float(quiet.mean())
    return lines, products, metrics


def stage_alignment(data: Path, out: Path, context: dict):
    require("magcal.alignment.posterior", "magcal.cli.align")
    import numpy as np

    from magcal.io.jsonio import read_json

    if "month_corrected" not in context:
        raise NotYetAvailableError("needs the offsets stage's corrected month")
    out.mkdir(parents=True, exist_ok=True)
    align = out / "ALIGN.json"
    # Quiet times only (Kp <= 1, as for the offsets) and local-time harmonics as nuisance:
    # the discovery stage showed that T89 lacks a field fixed in local time, which would
    # otherwise be taken for a rotation.
    _cli("align", context["month_corrected"], "--reference", context["month_model"], "--mcmc",
         "--seed", "2019", "--longitude", MONTH_LON_DEG, "--kp", data / "month_kp.csv",
         "-o", align)
    res = read_json(align)
    ang, std, ci = res["angles_deg"], res["std_deg"], res["ci95_deg"]
    lines = ["angles about Hp, He, Hn (deg; the simulated month has no rotation, truth 0): "
             + ", ".join(f"{k} {ang[k]:+.3f} +- {std[k]:.3f} [{ci[k][0]:+.3f}, {ci[k][1]:+.3f}]"
                         for k in ("Hp", "He", "Hn")),
             f"method {res['method']}, n_used {res['n_used']}, MCMC converged: "
             f"{res.get('converged')} (autocorrelation {np.max(res.get('autocorr_steps') or [np.nan]):.0f} "
             "steps)"]
    inside = all(ci[k][0] <= 0.0 <= ci[k][1] for k in ("Hp", "He", "Hn"))
    lines.append("truth inside every 95% interval" if inside
                 else "truth OUTSIDE a 95% interval")
    if res.get("warning") or res.get("noise", {}).get("warning"):
        lines.append(f"warning: {res.get('warning') or res['noise']['warning']}")
    context["align_json"] = align
    return lines, [align], {"angles_deg": ang, "std_deg": std, "truth_inside_ci95": inside}


def _cli(*argv, log: Path | None = None) -> None:
    """Run a magcal verb in-process; a non-zero status is a stage failure.

    The verb's console output goes to ``log`` (default: ``cli.log`` beside the output
    named after ``-o``) so the demo summary stays short.
    """
    import contextlib
    import io

    from magcal.cli import main

    args = [str(a) for a in argv]
    if log is None and "-o" in args:
        log = Path(args[args.index("-o") + 1]).parent / "cli.log"
    buffer, errors = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(buffer), contextlib.redirect_stderr(errors):
        status = main(args)
    if log is not None:
        log.parent.mkdir(parents=True, exist_ok=True)
        with open(log, "a") as handle:
            handle.write(f"$ magcal {' '.join(args)}\n{buffer.getvalue()}{errors.getvalue()}\n")
    if status != 0:
        raise RuntimeError(f"magcal {' '.join(args)} exited with status {status}: "
                           f"{errors.getvalue().strip()}")


def stage_spin(data: Path, out: Path, context: dict):
    require("magcal.spin.ripple", "magcal.cli.spincal", "magcal.cli.flipper")
    import numpy as np

    from magcal.io.jsonio import read_json

    src = data / "spinning_galileo_5h.csv.gz"
    cal_path, flip_path, full_path = out / "CAL.json", out / "FLIP.json", out / "CAL_full.json"
    _cli("spincal", src, "-o", cal_path)
    _cli("flipper", src, "--cal", cal_path, "--complete", full_path, "-o", flip_path)
    cal, flip, full = read_json(cal_path), read_json(flip_path), read_json(full_path)
    truth = read_json(data / "spinning_galileo_truth.json")
    det = cal["determined"]
    # spin tones: {"BX": [1x, 2x], "BY": [...], "BZ": [...]} in nT
    before = max(max(v) for v in cal["spin_tone_before_nT"].values())
    after = max(max(v) for v in cal["spin_tone_after_nT"].values())
    err_o3 = flip["O3"] - truth["offsets"][2]
    c_err = np.asarray(cal["coupling"]) - np.asarray(truth["coupling"])
    o_err = np.asarray(cal["offsets"]) - np.asarray(truth["offsets"])
    # With identity priors the spin-plane rows are fixed only up to a turn about the spin
    # axis (the cal coil sets it), so score the entries that turn leaves unchanged.
    c_det = [c_err[2, 0], c_err[2, 1]]
    o_det = [o_err[0], o_err[1]]
    lines = [f"determined {len(det)} of 12 parameters: {', '.join(det)}",
             f"largest spin tone {before:.3f} nT before -> {after:.4f} nT after calibration",
             f"flipper O3 = {flip['O3']:.3f} +- {flip['O3_std']:.3f} nT "
             f"(truth {truth['offsets'][2]:.3f}, error {err_o3:+.3f} nT)",
             f"vs truth: max |c31, c32 error| {np.degrees(np.abs(c_det).max()):.4f} deg, "
             f"max |O1, O2 error| {np.abs(o_det).max():.4f} nT; held at priors: "
             f"{', '.join(cal['fixed'])}"]
    metrics = {"spin_tone_before_nT": before, "spin_tone_after_nT": after,
               "o3_error_nT": float(err_o3), "o3_std_nT": float(flip["O3_std"]),
               "max_c3x_error_deg": float(np.degrees(np.abs(c_det).max())),
               "max_o12_error_nT": float(np.abs(o_det).max())}
    return lines, [cal_path, flip_path, full_path], metrics


def stage_discover(data: Path, out: Path, context: dict):
    require("magcal.discover.loop", "magcal.cli.discover")
    import numpy as np

    from magcal.io.csv import read_csv_frame
    from magcal.io.jsonio import read_json

    if "month_model" not in context:
        raise NotYetAvailableError("needs the offsets stage's model field")
    out.mkdir(parents=True, exist_ok=True)
    report, plot = out / "REPORT.json", out / "gap.png"
    # The SOSMAG story: the data minus T89 residual varies with local time; is it the
    # spacecraft or the model? Discovery names the missing effect and shows the gap shrink.
    _cli("discover", data / "month_1min_hpen.csv.gz", context["month_model"],
         "--covariates", data / "month_covariates.csv.gz", "--longitude", MONTH_LON_DEG,
         "--plot", plot, "-o", report)
    res = read_json(report)
    lines = [f"gap: rms {res['gap_initial']['rms_nT']:.2f} nT -> {res['gap_final']['rms_nT']:.2f}"
             f" nT; stopped because {res['stopped_because']}"]
    lines += [f"+ {e['name']} ({', '.join(e['components'])}): rms {e['rms_before_nT']:.2f} -> "
              f"{e['rms_after_nT']:.2f} nT" for e in res["effects"]]
    truth = read_csv_frame(data / "month_truth.csv.gz")
    lt = truth[["local_time_Hp", "local_time_He", "local_time_Hn"]].to_numpy()
    lines.append("truth: the model lacks a local-time field of "
                 + " / ".join(f"{v:.1f}" for v in np.ptp(lt, axis=0))
                 + " nT peak-to-peak in Hp / He / Hn")
    lines += [f"account: {line}" for line in res.get("account", [])[1:2]]
    context["discover_report"] = report
    metrics = {"effects": [e["name"] for e in res["effects"]],
               "rms_initial_nT": res["gap_initial"]["rms_nT"],
               "rms_final_nT": res["gap_final"]["rms_nT"]}
    return lines, [report, plot], metrics


def stage_report(data: Path, out: Path, context: dict):
    require("magcal.report.uncertainty", "magcal.cli.report")
    products = out.parent  # the demo's OUTDIR holds every stage's products
    html, pdf = out / "REPORT.html", out / "REPORT.pdf"
    _cli("report", products, "-o", html, "--pdf", pdf)
    size = html.stat().st_size / 1e6
    return ([f"uncertainty report: {html} ({size:.1f} MB, plots embedded) and {pdf}"],
            [html, pdf], {"html_bytes": html.stat().st_size, "pdf_bytes": pdf.stat().st_size})


STAGES = [
    ("AC cleaning (PiCoG)", stage_ac),
    ("offsets against T89 (monthly product)", stage_offsets),
    ("discover model gaps", stage_discover),
    ("alignment against the model", stage_alignment),
    ("spin calibration", stage_spin),
    ("report", stage_report),
]
