"""The spinning chain on ELFIN counts: ``[spin] units = "counts"``, ``reference = "igrf"``.

A configuration such as::

    [input]
    files = ["ela_l1_fgs_20220112_v01.cdf"]
    [spin]
    units = "counts"
    reference = "igrf"
    state = "ela_l1_state_defn_20220112_v01.cdf"
    disturbed = [["2022-01-12T06:30:00", "2022-01-12T06:31:30"]]  # optional, UTC: left
                             # out of every fit (a natural field known from elsewhere)
    [spin.pipeline]          # optional: magcal.missions.elfin.settings.ElfinSettings
    vector_step = true

runs :func:`magcal.missions.elfin.pipeline.calibrate_elfin_day` in three stages::

    read (FGS counts + state file) -> calibrate (spin/ELFIN_CAL.json: the workflow's
    calibration document; spin/SPIN.json: zone medians per product) -> calibrated
    (calibrated/elfin_calibrated.csv: time,zone,used,bx_gei,by_gei,bz_gei,... nT;
    calibrated/elfin_residuals.png)

A step that makes a zone median worse than the step before is a warning of the
``calibrate`` stage (in the manifest and on stderr), never silent.
"""

from __future__ import annotations

from dataclasses import asdict

from magcal.chain.config import ChainConfig
from magcal.chain.product import StageProduct
from magcal.errors import InputError
from magcal.provenance import file_sha256, make_provenance

#: Score columns printed per product, with their labels.
_LABELS = (("scalar_rms_nT", "|B|-|IGRF|"), ("scalar_fast_nT", "fast part"),
           ("scalar_slow_nT", "slow part"), ("vector_rms_nT", "vector"))


def elfin_inputs(cfg: ChainConfig, files) -> tuple:
    """The FGS file, the state file and the pipeline settings of a counts configuration.

    Raises
    ------
    InputError
        Not exactly one input file, a missing state file, a ``[truth]`` file (no truth
        is known for real counts) or a bad ``[spin.pipeline]`` table.
    """
    from magcal.missions.elfin.settings import ElfinSettings

    if len(files) != 1:
        raise InputError(f"the ELFIN chain takes one FGS file; [input] files matches "
                         f"{len(files)}", file=cfg.path, column="input.files")
    if cfg["truth"]["file"]:
        raise InputError("[truth] does not apply to units = \"counts\" (real counts are "
                         "scored against the reference)", file=cfg.path, column="truth.file")
    state = cfg.resolve(cfg["spin"]["state"])
    if not state.is_file():
        raise InputError("[spin] state: ELFIN state file not found", file=state)
    settings = ElfinSettings.from_mapping(cfg["spin"]["pipeline"], where="[spin] pipeline")
    return files[0], state, settings, [tuple(i) for i in cfg["spin"]["disturbed"]]


def _read(fgs_path, state_path):
    from magcal.missions.elfin.files import read_elfin_fgs, read_elfin_state

    fgs, state = read_elfin_fgs(fgs_path), read_elfin_state(state_path)
    if fgs.attrs.get("probe") != state.attrs.get("probe"):
        raise InputError(f"state file of {state.attrs.get('probe')!r}, FGS file of "
                         f"{fgs.attrs.get('probe')!r}", file=state_path)
    span = (fgs.index[-1] - fgs.index[0]).total_seconds()
    summary = {"probe": fgs.attrs["probe"], "n_samples": int(len(fgs)), "span_s": span,
               "first": str(fgs.index[0]), "last": str(fgs.index[-1]),
               "n_state_records": int(len(state))}
    line = (f"{fgs.attrs['probe']} FGS counts: {len(fgs)} samples from "
            f"{fgs.index[0]:%Y-%m-%d %H:%M:%S} over {span / 3600:.2f} h; {len(state)} state "
            "records")
    return (fgs, state), StageProduct(stage="read", summary=summary, lines=(line,),
                                      provenance=make_provenance(
                                          "read", {}, inputs=[fgs_path, state_path]))


def _calibrate(data, settings, inputs, disturbed=()):
    from magcal.missions.elfin.pipeline import calibrate_elfin_day, disturbed_rows

    fgs, state = data
    prov = make_provenance("elfin calibration against IGRF",
                           {"model": "IGRF (IRBEM)", "settings": asdict(settings),
                            "disturbed": [list(i) for i in disturbed]},
                           inputs=inputs)
    skip = disturbed_rows(fgs.index, disturbed) if disturbed else None
    day = calibrate_elfin_day(fgs, state, settings, provenance=prov, fit_exclude=skip)
    medians = day.medians()
    n = len(day.calibration.zones)
    worse = day.worse_measures()
    lines = [f"{n} science zones calibrated against IGRF (zone medians, nT)",
             f"{'product':22s} " + " ".join(f"{label:>10s}" for _, label in _LABELS)]
    for name, m in medians.items():
        flag = ", ".join(label for col, label in _LABELS if col in worse.get(name, ()))
        lines.append(f"{name:22s} " + " ".join(f"{m[col]:10.1f}" for col, _ in _LABELS)
                     + (f"   WORSE than the step before: {flag}" if flag else ""))
    empty = [f"[spin] disturbed interval {a} - {b} holds no FGS sample" for a, b in disturbed
             if not disturbed_rows(fgs.index, [(a, b)]).any()]
    if disturbed:
        lines.append(f"{int(skip.sum())} samples in {len(disturbed)} disturbed interval(s) "
                     "left out of every fit and calibrated")
    if "bridge" in day.steps and len(day.steps["bridge"]):
        rms = day.steps["bridge"]["bridge_rms_nT"]
        lines.append(f"calibration error over the left-out intervals (quiet trial gaps, "
                     f"bridge_rms_nT): {rms.min():.1f}-{rms.max():.1f} nT RMS in "
                     f"{len(rms)} zones")
    if settings.level_steps:
        steps = day.level_step_listing()
        lines.append("spin-axis level kept changed across left-out intervals (level_step): "
                     + ("; ".join(f"zone {x['zone']} {x['start'][11:19]}-{x['end'][11:19]} "
                                  f"UTC {x['step_nT']:+.0f} +- "
                                  f"{x.get('step_error_nT', float('nan')):.0f} nT"
                                  + (f" (spin-axis field std {x['axis_field_std_nT']:.0f} nT:"
                                     " the level trades with the spin-axis gain)"
                                     if x.get("axis_field_small") else "")
                                  for x in steps)
                        if steps else "none")
                     + _judged_note(day.level_step_judged()))
    if settings.pulses_b:
        lines.extend(pulse_lines(day))
    if settings.pulses_perp:
        lines.append(perp_line(day))
    lines.append(f"delivered: {day.delivered}")
    summary = {"n_zones": n, "delivered": day.delivered, "zone_medians_nT": medians,
               "settings": asdict(settings)}
    return day, StageProduct(stage="spin", summary=summary, lines=tuple(lines),
                             documents={"ELFIN_CAL.json": day.to_json()},
                             provenance=prov,
                             warnings=tuple(empty + day.data_warnings() + day.worse_steps()))


def _at(x: dict, key: str) -> str:
    """"zone k hh:mm:ss UTC" of a listing entry (the ISO time under ``key``)."""
    return f"zone {x['zone']} {str(x[key])[11:19]} UTC"


def _judged_note(judged: list[dict]) -> str:
    """How many left-out intervals were judged for a level step and not kept, and the
    largest of their steps (the rest is in ``ELFIN_CAL.json``)."""
    lost = [x for x in judged if not x["kept"]]
    if not lost:
        return ""
    big = max(lost, key=lambda x: abs(x["step_nT"]))
    return (f" ({len(lost)} left-out interval(s) judged and not kept; the largest step: "
            f"{_at(big, 'start')} {big['step_nT']:+.0f} nT, "
            f"{big['why']}; level_steps.judged in ELFIN_CAL.json)")


def pulse_lines(day) -> list[str]:
    """The CLI's lines on pulses along B: those kept in the product (with their stated
    height errors) and the ``|B|`` structures the search found and removed with the
    gain drift, with the reason (:meth:`~magcal.missions.elfin.pipeline.ElfinDay.
    pulse_search_listing`)."""
    pulses = day.pulse_listing()
    lines = ["pulses along B kept out of the gain drift (pulses_b): "
             + ("; ".join(f"{_at(x, 'centre')} {x['height_nT']:+.0f} +- "
                          f"{x.get('height_error_nT', float('nan')):.0f} nT, "
                          f"FWHM {x['fwhm_s']:.0f} s" for x in pulses)
                if pulses else "none")]
    removed = [x for x in day.pulse_search_listing() if not x["natural"]]
    if removed:
        lines.append("|B| structures found and removed with the gain drift: "
                     + "; ".join(f"{_at(x, 'centre')} {x['height_nT']:+.0f} nT, "
                                 f"FWHM {x['fwhm_s']:.0f} s "
                                 f"({x['why']})" for x in removed))
    return lines


def perp_line(day) -> str:
    """The CLI's line on pulses across B fitted as templates (``pulses_perp``): those
    kept in the fits, and how many detected intervals stay left out."""
    from magcal.missions.elfin.perp import perp_listing

    every = perp_listing(day)
    kept = [x for x in every if x["kept"]]
    unsettled = [x for x in every if x["iterations"] and not x["converged"]]
    trials = day.steps.get("perp_trials")
    errors = {} if trials is None else {(r.zone, r.centre): r.error_rms_nT
                                        for r in trials.itertuples()}

    def error(x):
        e = errors.get((x["zone"], x["centre"]))
        return "" if e is None else f" (error {e:.0f} nT RMS, pulse_error_nT)"

    return ("pulses across B fitted as templates, in the fits (pulses_perp): "
            + ("; ".join(f"{_at(x, 'centre')} {x['height_nT']:.0f} nT, FWHM "
                         f"{x['fwhm_s']:.0f} s{error(x)}" for x in kept) if kept else "none")
            + f"; {len(every) - len(kept)} detected interval(s) left out"
            + (f" ({len(unsettled)} whose backfit did not settle)" if unsettled else ""))


def _calibrated(day, probe: str):
    from magcal.missions.elfin.pipeline import plot_residuals

    table = day.calibrated_table()
    date = f"{table.index[0]:%Y-%m-%d}"
    title = f"ELFIN-{probe[-1:].upper()} {date}: calibrated minus IGRF"
    n_used = int(table["used"].sum())
    f = day.calibration.field
    n_fit = int((f["fit"] == 1).sum()) if "fit" in f.columns else n_used
    line = (f"{len(table)} samples ({n_fit} used in the fit) in "
            f"{table['zone'].nunique()} zones: time,zone,used,bx_gei,by_gei,bz_gei (nT)")
    return table, StageProduct(
        stage="calibrated", summary={"n_samples": len(table), "n_used": n_used,
                                     "zones": sorted(int(z) for z in table["zone"].unique())},
        lines=(line,), tables={"elfin_calibrated.csv": table},
        writers={"elfin_residuals.png": lambda path: plot_residuals(path, day.calibration,
                                                                   title)},
        provenance=make_provenance("calibrated series", {"product": day.delivered}))


def elfin_stages(run, cfg: ChainConfig, files, extras: dict) -> None:
    """Run the ELFIN counts stages through the runner's book-keeping.

    The state file joins the run's inputs (its SHA-256 is recorded with every product).
    """
    fgs_path, state_path, settings, disturbed = elfin_inputs(cfg, files)
    run.inputs.append({"path": str(state_path), "sha256": file_sha256(state_path)})
    data = run.stage("read", _read, fgs_path, state_path)
    day = run.stage("calibrate", _calibrate, data, settings, [fgs_path, state_path],
                    disturbed)
    extras["calibrated"] = run.stage("calibrated", _calibrated, day, data[0].attrs["probe"])
    extras["elfin"] = day
