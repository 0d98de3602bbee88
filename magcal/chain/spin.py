"""The spinning-spacecraft chain: spin-ripple calibration, flipper, despun product.

A configuration with a ``[spin]`` section runs, on one CONTRACTS §4 file
(``time,b1,b2,b3[,phase][,flip]``)::

    read -> spincal (8 determinable parameters, Galileo style) -> flipper (spin-axis
    offset O3, when the file has flip states) -> despun (calibrated, despun BX,BY,BZ)

With ``units = "counts"`` (ELFIN FGS counts against IGRF) the stages are those of
:mod:`magcal.chain.spin_elfin` instead.

Products: ``spin/CAL.json``, ``spin/FLIP.json``, ``spin/CAL_full.json`` (the
calibration completed with O3), ``despun/DESPUN.csv``, and, with ``[truth] file``
(a JSON with the true ``coupling`` and ``offsets``), ``truth/TRUTH.json``.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from magcal.chain.config import ChainConfig
from magcal.chain.product import StageProduct
from magcal.errors import InputError
from magcal.provenance import make_provenance


def _load(cfg: ChainConfig, files):
    from magcal.spin.inputs import load_spin_data

    if len(files) != 1:
        raise InputError(f"the spinning chain takes one file; [input] files matches "
                         f"{len(files)}", file=cfg.path, column="input.files")
    data = load_spin_data(files[0], cfg["spin"]["spin_period_s"], scale=1.0)
    from magcal.spin.screen import describe_screened

    summary = {"n_samples": int(len(data.t_s)), "span_s": float(data.t_s[-1] - data.t_s[0]),
               "has_flip": data.flip is not None, "spin_phase": data.phase_record(),
               "screened": data.screened}
    line = (f"{len(data.t_s)} samples over {summary['span_s'] / 3600:.2f} h; phase from "
            f"{data.phase_source}; flip states {'present' if data.flip is not None else 'none'}")
    screened = describe_screened(data.screened)
    lines = (line,) + ((f"screened: {screened} (fills, saturated or stuck runs, spikes of "
                        "|B|; left out of every stage)",) if screened else ())
    return data, StageProduct(stage="read", summary=summary, lines=lines,
                              provenance=make_provenance("read", {}, inputs=files))


def _spincal(data, cfg: ChainConfig, files):
    from magcal.spin.product import spincal

    product = spincal(data, provenance=make_provenance("spincal", cfg["spin"], inputs=files))
    doc = product.to_json()
    before = max(max(v) for v in doc["spin_tone_before_nT"].values())
    after = max(max(v) for v in doc["spin_tone_after_nT"].values())
    lines = (f"determined {len(doc['determined'])} of 12: {', '.join(doc['determined'])}",
             f"largest spin tone {before:.3f} nT before -> {after:.4f} nT after")
    # spincal's own never-worse guard (tone_worse, per component and harmonic against
    # its noise floor) decides and words the warning; a second rule here on the largest
    # tone alone warned on clean records where a tone moved within its noise
    return doc, StageProduct(stage="spin", summary={"spin_tone_before_nT": before,
                                                    "spin_tone_after_nT": after},
                             lines=lines, documents={"CAL.json": doc},
                             warnings=tuple(product.warnings))


def _flipper(cal_doc: dict, cfg: ChainConfig, files):
    from magcal.spin.inputs import load_spin_data
    from magcal.spin.product import complete_calibration, flipper

    data = load_spin_data(files[0], cfg["spin"]["spin_period_s"], require_flip=True)
    product = flipper(data, coupling=cal_doc["coupling"], offsets=cal_doc["offsets"],
                      covariance=cal_doc.get("covariance"),
                      determined=cal_doc.get("determined", ()),
                      provenance=make_provenance("flipper", cfg["spin"], inputs=files))
    flip = product.to_json()
    full = complete_calibration(cal_doc, product.result.O3, product.result.O3_std,
                                str(files[0]))
    line = (f"flipper O3 = {flip['O3']:.3f} +- {flip['O3_std']:.3f} nT (data "
            f"{flip['O3_std_data']:.3f}, calibration {flip['O3_std_calibration']:.3f})")
    return full, StageProduct(stage="spin", summary={"O3": flip["O3"],
                                                     "O3_std": flip["O3_std"]},
                              lines=(line,), documents={"FLIP.json": flip,
                                                        "CAL_full.json": full})


def _despun(data, cal: dict, times: pd.DatetimeIndex):
    from magcal.spin.despin import despin

    c = np.asarray(cal["coupling"], dtype=float)
    o = np.asarray(cal["offsets"], dtype=float)
    b_sc = (data.b - o) @ c.T
    despun = despin(b_sc, data.phase)
    frame = pd.DataFrame(despun, index=times, columns=["BX", "BY", "BZ"])
    line = (f"{len(frame)} calibrated, despun samples; mean BX, BY, BZ "
            + ", ".join(f"{v:+.2f}" for v in np.nanmean(despun, axis=0)) + " nT")
    return frame, StageProduct(stage="despun", summary={"n_samples": len(frame)},
                               lines=(line,), tables={"DESPUN.csv": frame},
                               provenance=make_provenance("despin", {"calibration": cal}))


def _truth(cal: dict, cfg: ChainConfig):
    from magcal.io.jsonio import read_json

    path = cfg.resolve(cfg["truth"]["file"])
    truth = read_json(path, required=("coupling", "offsets"))
    c_err = np.asarray(cal["coupling"]) - np.asarray(truth["coupling"])
    o_err = np.asarray(cal["offsets"]) - np.asarray(truth["offsets"])
    # the spin-plane rows are fixed only up to a turn about the spin axis: score the
    # entries that turn leaves unchanged (c31, c32, O1, O2) and O3 from the flipper
    summary = {"max_c3x_error_deg": float(np.degrees(np.abs(c_err[2, :2]).max())),
               "max_o12_error_nT": float(np.abs(o_err[:2]).max()),
               "o3_error_nT": float(o_err[2])}
    line = (f"vs truth: c31, c32 within {summary['max_c3x_error_deg']:.4f} deg, O1, O2 within "
            f"{summary['max_o12_error_nT']:.4f} nT, O3 error {summary['o3_error_nT']:+.3f} nT")
    return summary, StageProduct(stage="truth", summary=summary, lines=(line,))


def spin_stages(run, cfg: ChainConfig, files, extras: dict) -> None:
    """Run the spinning-spacecraft stages through the runner's book-keeping
    (``units = "counts"``: the ELFIN stages of :mod:`magcal.chain.spin_elfin`)."""
    from magcal.io.formats import read_any

    if cfg["spin"]["units"] == "counts":
        from magcal.chain.spin_elfin import elfin_stages

        elfin_stages(run, cfg, files, extras)
        return

    data = run.stage("read", _load, cfg, files)
    cal = run.stage("spincal", _spincal, data, cfg, files)
    if cfg["spin"]["flipper"] and data.flip is not None:
        cal = run.stage("flipper", _flipper, cal, cfg, files)
    frame = read_any(files[0])
    first = frame.index[frame[["b1", "b2", "b3"]].notna().all(axis=1).to_numpy()][0]
    times = (first + pd.to_timedelta(np.round(data.t_s * 1e9).astype(np.int64), unit="ns")
             ).rename("time")
    extras["despun"] = run.stage("despun", _despun, data, cal, times)
    if cfg["truth"]["file"]:
        extras["truth"] = run.stage("truth", _truth, cal, cfg, required=False)
    extras["calibration"] = cal
