"""The first stages of a geostationary chain: input, frames, AC cleaning, model field.

Each function takes the data (a :class:`~magcal.timeseries.VectorSeries` or arrays
derived from it) and the :class:`~magcal.chain.config.ChainConfig`, calls the stage's
library estimator, and returns the data for the next stage together with a
:class:`~magcal.chain.product.StageProduct`. Nothing here parses arguments or prints:
:func:`magcal.chain.runner.run_chain` drives the stages, the CLI prints.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from magcal.chain.config import ChainConfig
from magcal.chain.product import StageProduct
from magcal.errors import InputError
from magcal.provenance import make_provenance
from magcal.stats import finite_rms
from magcal.timeseries import VectorSeries

HPEN = ("Hp", "He", "Hn")


def naive_times(index: pd.DatetimeIndex) -> np.ndarray:
    """UTC ``datetime64[ns]`` values of a tz-aware index."""
    return index.tz_convert("UTC").tz_localize(None).as_unit("ns").to_numpy()


# ----------------------------------------------------------------------------- input
def load_series(config: ChainConfig, files: list[Path]) -> VectorSeries:
    """Read every input file (format detected by content) into one validated series.

    Files are concatenated in time order; columns missing from a file are NaN there;
    exact duplicate samples (overlapping files) are dropped and counted.
    """
    from magcal.io.formats import read_any

    fmt = config["input"]["format"]
    return series_from_frames(config, files, [read_any(path, fmt) for path in files])


def series_from_frames(config: ChainConfig, files: list[Path], frames: list) -> VectorSeries:
    """:func:`load_series` of frames already read (``read_any`` of each file, in the
    order of ``files``), e.g. read on the workers of an archive run."""
    repairs = []
    for path, frame in zip(files, frames):
        repairs += [dict(r, file=str(path)) for r in frame.attrs.get("repairs", [])]
    joined = pd.concat(frames, axis=0, sort=False) if len(frames) > 1 else frames[0]
    joined = joined.sort_index(kind="stable")
    series = VectorSeries.from_frame(joined, frame_name=config["input"]["frame"],
                                     spacecraft=config["input"]["spacecraft"],
                                     source=files[0] if len(files) == 1 else f"{len(files)} files",
                                     on_duplicate="drop", mixed_cadence="allow")
    step = {"step": "read", "files": [str(p) for p in files], "repairs": repairs,
            "formats": sorted({f.attrs.get("format", "?") for f in frames})}
    meta = dict(series.meta, sensor_frames=dict(frames[0].attrs.get("sensor_frames") or {}))
    return series.replace(provenance=(step,) + series.provenance, meta=meta)


def quality_control(series: VectorSeries, config: ChainConfig):
    """The quality flags (:func:`magcal.qc.flag_samples`) of the sensors the chain uses
    (and the frames' reference), on the readings as read."""
    from magcal.qc import QCSettings, flag_samples

    names = list(_sensors(series, config))
    ref = config["frames"]["reference"]
    if ref and ref in series.sensors and ref not in names:
        names.append(ref)
    sensors = list(_sensors(series, config))  # distinct sensors (the reference is not)
    return flag_samples(series.times.as_unit("ns").asi8, {s: series[s] for s in names},
                        series.cadence_s, QCSettings.from_mapping(config["qc"]),
                        independent=sensors)


def mask_series(series: VectorSeries, qc) -> VectorSeries:
    """``series`` with every vector of the samples QC excludes set to NaN (for fits)."""
    bad = qc.excluded
    if not bad.any():
        return series
    data = series.data.copy()
    data.iloc[bad, :] = np.nan
    step = {"step": "qc", "excluded_samples": int(bad.sum()), "counts": qc.counts()}
    return series.replace(data=data, provenance=series.provenance + (step,))


def _sensors(series: VectorSeries, config: ChainConfig) -> list[str]:
    wanted = config["input"]["sensors"]
    if wanted is None:
        reference = config["frames"]["reference"]
        wanted = [s for s in series.sensors
                  if s and s != reference and s not in ("gse", "gsm", "eci")]
        if config["frames"]["to_common"]:
            wanted = [s for s in wanted if s in config["frames"]["to_common"]] or wanted
    for s in wanted:
        series[s]  # clear error naming the sensor
    return list(wanted)


# ---------------------------------------------------------------------------- frames
@dataclass(frozen=True)
class CommonFrameData:
    """Sensors in the common frame and the rotation from the common frame to Hpen."""

    series: VectorSeries
    sensors: tuple
    target: str
    to_hpen: np.ndarray
    input_hpen: np.ndarray | None = None
    transforms: dict = field(default_factory=dict)


def apply_frame(b_sensor, transform) -> np.ndarray:
    """Sensor readings (n, 3) in the common frame: ``(b - offset) @ matrix.T``.

    ``transform`` is ``(matrix, offset_nT)`` as :class:`CommonFrameData` keeps it, so a
    partition of an archive is rotated exactly as the data the matrices were fitted on.
    """
    matrix, offset = transform
    # a C-ordered transpose: (n, 3) @ (3, 3) is 4x faster than with the transposed view
    return (np.asarray(b_sensor, dtype=float) - np.asarray(offset, dtype=float)) \
        @ np.ascontiguousarray(np.asarray(matrix, dtype=float).T)


def run_frames(series: VectorSeries, config: ChainConfig) -> tuple[CommonFrameData,
                                                                    StageProduct]:
    """Rotate every sensor into the common frame and find the common-to-Hpen rotation.

    Matrices come from the configuration, or are estimated against the input's reference
    field (``[frames] reference``; :func:`magcal.frames.estimate.estimate_rotation`).
    When the input holds its own ``Hp, He, Hn`` the Hpen rotation is checked against it.
    """
    from magcal.frames.estimate import estimate_rotation

    fr = config["frames"]
    sensors = _sensors(series, config)
    target = config["input"]["target"] or (sensors[0] if len(sensors) == 1 else None)
    if target is None or target not in sensors:
        raise InputError(f"[input] target {target!r} must be one of the sensors "
                         f"{', '.join(sensors)}", file=config.path, column="input.target")
    ref = series[fr["reference"]] if fr["reference"] else None
    own = series.meta.get("sensor_frames") or {}
    unrotated = {s: own[s] for s in sensors
                 if s in own and fr["to_common"].get(s, "identity") == "identity"}
    if len(set(unrotated.values())) > 1:
        raise InputError("the input's sensors are each in their own frame ("
                         + ", ".join(f"{s}: {f}" for s, f in unrotated.items())
                         + "): give [frames] to_common for them (a matrix or \"estimate\")",
                         file=config.path, column="frames.to_common")
    vectors, doc, lines, warnings, transforms = {}, {"sensors": {}}, [], [], {}
    for s in sensors:
        spec = fr["to_common"].get(s, "identity")
        b = series[s]
        if spec == "estimate":
            fit = estimate_rotation(b, ref, fit_offset=fr["fit_offset"])
            transforms[s] = (np.asarray(fit.matrix, dtype=float),
                             np.asarray(fit.offset_nT, dtype=float))
            vectors[s] = apply_frame(b, transforms[s])
            doc["sensors"][s] = {"source": f"estimated against {fr['reference']}",
                                 **fit.to_json()}
            lines.append(f"{s} -> common frame: estimated against {fr['reference']}, "
                         f"reproduces it to {fit.rms_nT:.3f} nT rms (rotation only "
                         f"{fit.rms_rotation_only_nT:.3f} nT; angle std "
                         f"{', '.join(f'{a:.2f}' for a in fit.angle_std_deg)} deg)")
            if fit.condition > 1e4:
                warnings.append(f"{s}: the field varies by only {fit.field_variation_nT:.1f} nT "
                                f"rms in the record; the rotation about the field direction "
                                f"is poorly determined (condition {fit.condition:.1e})")
        else:
            matrix = np.eye(3) if spec == "identity" else np.asarray(spec, dtype=float)
            transforms[s] = (matrix, np.zeros(3))
            vectors[s] = apply_frame(b, transforms[s])
            doc["sensors"][s] = {"source": "configuration", "matrix": matrix.tolist()}
    to_hpen, hpen_doc = _to_hpen(series, config, vectors, target, ref)
    doc["to_hpen"] = hpen_doc
    if "check_rms_nT" in hpen_doc:
        lines.append(f"common -> Hpen ({hpen_doc['source']}): reproduces the input's own "
                     f"Hp,He,Hn to {hpen_doc['check_rms_nT']:.3f} nT rms")
    common = series.with_vectors(vectors, "to common frame", components=("x", "y", "z"),
                                 frame=config["input"]["frame"],
                                 matrices={k: v.get("matrix") for k, v in doc["sensors"].items()})
    prov = make_provenance("frames", {"frames": fr, "sensors": sensors, "target": target},
                           history=series.provenance)
    product = StageProduct(stage="frames", summary=doc, lines=tuple(lines),
                           provenance=prov, warnings=tuple(warnings))
    own = series[""] if "" in series.sensors and all(
        c in series.data[""].columns for c in HPEN) else None
    return CommonFrameData(common, tuple(sensors), target, to_hpen, own, transforms), product


def _to_hpen(series: VectorSeries, config: ChainConfig, vectors: dict, target: str, ref):
    from magcal.frames.estimate import estimate_rotation

    spec = config["frames"]["to_hpen"]
    own = "" in series.sensors and series.components == HPEN or (
        "" in series.sensors and all(c in series.data[""].columns for c in HPEN))
    file_hpen = series[""] if own else None
    if spec is None:
        spec = "identity" if config["input"]["frame"].lower() == "hpen" else (
            "estimate" if own else None)
        if spec is None:
            raise InputError("[frames] to_hpen is needed when the common frame is not "
                             "hpen", file=config.path, column="frames.to_hpen")
    doc: dict = {}
    if spec == "estimate":
        if file_hpen is None:
            raise InputError("[frames] to_hpen = 'estimate' needs Hp,He,Hn in the input",
                             file=config.path, column="frames.to_hpen")
        basis = ref if ref is not None else vectors[target]
        fit = estimate_rotation(basis, file_hpen, fit_offset=False)
        matrix = fit.matrix
        doc = {"source": "estimated against the input's Hp,He,Hn", **fit.to_json()}
    else:
        matrix = np.eye(3) if spec == "identity" else np.asarray(spec, dtype=float)
        doc = {"source": "configuration" if spec != "identity" else "identity",
               "matrix": matrix.tolist()}
    if file_hpen is not None and ref is not None:
        doc["check_rms_nT"] = finite_rms(ref @ matrix.T - file_hpen)
    return matrix, doc


# -------------------------------------------------------------------------------- AC
@dataclass(frozen=True)
class CleanedData:
    """The AC-cleaned target in Hpen at the input cadence (and the raw target, to
    compare)."""

    times: pd.DatetimeIndex
    hpen: np.ndarray
    raw_hpen: np.ndarray
    #: Per-sample quality flags (:mod:`magcal.qc.flags`), when known.
    quality: np.ndarray | None = None


def _plan_for(config: ChainConfig, target: str):
    from magcal.ac.plan import read_plan

    spec = config["picog"]["plan"]
    if spec in ("auto", "none"):
        return spec, None, [], {}
    path = config.resolve(spec)
    if not path.is_file():
        raise InputError("[picog] plan file not found", file=path)
    plan, opts = read_plan(path)
    if plan.target != target:
        raise InputError(f"plan target {plan.target!r} differs from [input] target "
                         f"{target!r}", file=path)
    return "plan", plan, [path], opts


def run_ac(data: CommonFrameData, config: ChainConfig) -> tuple[CleanedData, StageProduct]:
    """PiCoG on the sensors in the common frame; the cleaned target rotated to Hpen.

    The DC offset G of the correction is added back (``pure_ac``), so the product keeps
    the target's own DC level: AC cleaning removes the spacecraft's varying fields, the
    offsets stage handles DC.
    With ``plan = "none"`` or a single sensor the target passes through unchanged.
    """
    kind, plan, plan_files, opts = _plan_for(config, data.target)
    raw = data.series[data.target]
    summary: dict = {"target": data.target, "sensors": list(data.sensors), "plan": kind,
                     "delivered": "raw"}
    documents, lines, warnings = {}, [], []
    cleaned = raw
    if kind == "none" or len(data.sensors) < 2:
        lines.append("no AC cleaning (plan none or a single sensor)")
    else:
        cleaned, params, ground = _picog(data, kind, plan, opts, plan_files, config)
        documents["PARAMS.json"] = params
        summary.update(_ac_metrics(raw, cleaned, data, params), delivered="cleaned")
        lines.append(f"PiCoG ({kind}): the constant matrices removed "
                     f"{summary['removed_rms_nT']:.3f} nT rms (AC) from {data.target}, worse "
                     f"than raw in {summary['n_bands_worse']} band/component(s); "
                     f"|sum M - I| = {summary['identity_error']:.1e}")
        warnings += [f"PiCoG: {w}" for w in params.get("warnings") or []]
        worse = params.get("worse_than_raw") or []
        if worse and config["picog"]["on_worse"] == "raw":
            # never worse than raw (issue 22): the band-selective product, else raw
            summary.update(product=ground[1].kind if ground[1] else "raw",
                           product_reason=ground[1].reason if ground[1] else
                           "no band-selective product (sample grid)")
            if summary["product"] in ("ground", "band_limited", "on_board"):
                cleaned = ground[0]
                summary["removed_rms_nT"] = _ac_metrics(raw, cleaned, data, params)[
                    "removed_rms_nT"]
                warnings.append(f"PiCoG's constant matrices made {len(worse)} band/component(s) "
                                f"worse than raw: the {summary['product']} product is delivered "
                                f"({summary['product_reason']})")
                check = ground[1].check
                left = ""
                if check is not None:
                    summary["n_bands_worse_delivered"] = len(check.worse_than_raw)
                    left = (", its own band check passing in every band/component"
                            if not check.worse_than_raw else
                            f", worse than raw in {len(check.worse_than_raw)} "
                            "band/component(s)")
                lines.append(f"delivered instead: the {summary['product']} product, which "
                             f"removed {summary['removed_rms_nT']:.3f} nT rms (AC){left}")
            else:
                cleaned, summary["delivered"] = raw, "raw"
                warnings.append(f"PiCoG made {len(worse)} band/component(s) worse than raw: the "
                                f"product carries the uncleaned {data.target} ([picog] on_worse "
                                "= \"keep\" delivers the cleaned one): "
                                f"{summary['product_reason']}")
                lines.append("cleaning worse than raw in some band: uncleaned target delivered")
    hpen = cleaned @ data.to_hpen.T
    if data.input_hpen is not None:
        own = data.input_hpen
        summary["hpen_vs_input_rms_nT"] = finite_rms(hpen - own)
        summary["hpen_vs_input_mean_nT"] = np.nanmean(hpen - own, axis=0).tolist()
        lines.append(f"Hpen of the product against the input's own Hp,He,Hn: "
                     f"{summary['hpen_vs_input_rms_nT']:.3f} nT rms")
    prov = make_provenance("ac", {"picog": config["picog"], "target": data.target},
                           inputs=plan_files, history=data.series.provenance)
    product = StageProduct(stage="ac", summary=summary, lines=tuple(lines),
                           documents=documents, provenance=prov, warnings=tuple(warnings))
    return CleanedData(data.series.times, hpen, raw @ data.to_hpen.T), product


def _picog(data: CommonFrameData, kind: str, plan, opts: dict, plan_files, config):
    """Fit PiCoG and apply it with its DC offset G added back; return (cleaned, PARAMS)."""
    from magcal.ac.estimator import PiCoG, apply_upload

    frame = data.series.select(data.sensors).to_frame()
    model = PiCoG(plan, target=data.target, auto=kind == "auto",
                  alpha_method=opts.get("alpha_method", "decorrelate"))
    model.fit(frame)
    prov = make_provenance("picog fit", {"plan": config["picog"]["plan"],
                                         "target": data.target}, inputs=plan_files)
    out = apply_upload(frame, model.M_, model.G_, pure_ac=True)
    params = model.to_params(prov)
    ground = (None, None)
    if params.get("ground"):
        from magcal.ac.estimator import deliver_frame

        g_out, delivery = deliver_frame(frame, data.target, out, params["ground"])
        ground = (g_out[["x", "y", "z"]].to_numpy(dtype=float), delivery)
    return out[["x", "y", "z"]].to_numpy(dtype=float), params, ground


def _ac_metrics(raw, cleaned, data: CommonFrameData, params: dict) -> dict:
    """What the correction took out of the target (AC part) and the band check verdict."""
    removed = raw - cleaned
    removed = removed - np.nanmean(removed, axis=0)
    ident = float(np.abs(sum(np.asarray(m) for m in params["M"].values()) - np.eye(3)).max())
    return {"removed_rms_nT": finite_rms(removed), "identity_error": ident,
            "G_nT": params.get("G"), "n_bands_worse": len(params.get("worse_than_raw") or [])}


# ------------------------------------------------------------------ averages and model
@dataclass(frozen=True)
class MinuteData:
    """1-min averages of the cleaned Hpen field with the model and Kp on the same times."""

    times: np.ndarray
    hpen: np.ndarray
    model: np.ndarray
    kp: np.ndarray
    lon_deg: np.ndarray
    lat_deg: np.ndarray
    r_re: np.ndarray


def _position(series: VectorSeries, config: ChainConfig, times: np.ndarray):
    pos = config["position"]
    if pos["longitude_deg"] is not None:
        n = len(times)
        return (np.full(n, float(pos["longitude_deg"])), np.full(n, float(pos["latitude_deg"])),
                np.full(n, float(pos["r_re"])))
    cols = ("lon_deg", "lat_deg", "r_re")
    missing = [c for c in cols if c not in series.aux.columns]
    if missing:
        raise InputError(f"[position] columns = true but the input has no {missing[0]}",
                         file=config.path, column=missing[0])
    t = series.times.asi8
    tq = times.astype("datetime64[ns]").astype(np.int64)
    out = []
    for c in cols:
        v = series.aux[c].to_numpy(dtype=float)
        ok = np.isfinite(v)
        if not ok.any():
            raise InputError(f"input column {c} holds no value", column=c, file=config.path)
        if c == "lon_deg":
            v = np.degrees(np.unwrap(np.radians(v[ok])))
            out.append((np.interp(tq, t[ok], v) + 180.0) % 360.0 - 180.0)
        else:
            out.append(np.interp(tq, t[ok], v[ok]))
    return tuple(out)


def run_model(series: VectorSeries, cleaned: CleanedData, config: ChainConfig,
              tables: dict | None = None) -> tuple[MinuteData, StageProduct]:
    """Average the cleaned field to the offsets cadence and evaluate the model there.

    ``tables`` may hold the Kp series and driver table already read
    (:func:`magcal.chain.archive.read_index_tables`), so a partition reads each file
    once; a file whose table is None there is read here."""
    tables = tables or {}
    from magcal.indices import drivers_at, kp_at, read_drivers, read_kp
    from magcal.models.field import model_field_hpen
    from magcal.offsets import average_to_cadence

    cad = float(config["offsets"]["cadence_s"])
    t_all = naive_times(cleaned.times)
    if series.cadence_s < cad:
        times, hpen, _ = average_to_cadence(t_all, cleaned.hpen, cad)
    else:
        times, hpen = t_all, cleaned.hpen
    if len(times) == 0:
        raise InputError(f"no {cad:g} s bin holds enough samples for an average",
                         file=config.path)
    kp_path = config.resolve(config["kp"]["file"])
    name = config["model"]["name"].upper()
    inputs = []
    kp_values = np.full(len(times), np.nan)
    if kp_path is not None:
        kp = tables.get("kp")
        kp_values = kp_at(read_kp(kp_path) if kp is None else kp, times)
        inputs.append(kp_path)
    elif name == "T89":
        raise InputError("[kp] file is needed by T89 and the quiet-time selection",
                         file=config.path, column="kp.file")
    drivers = None
    drv_path = config.resolve(config["model"]["drivers"])
    if drv_path is not None:
        table = tables.get("drivers")
        drivers = drivers_at(read_drivers(drv_path) if table is None else table,
                             pd.DatetimeIndex(times, tz="UTC"))
        inputs.append(drv_path)
    elif name in ("T96", "T01", "T04"):
        raise InputError(f"[model] {name} needs drivers = <file>", file=config.path)
    # Kp missing for some or all of these times (a hole in the Kp file): T89 is NaN
    # there (counted in the model's n_invalid and named by the run), the data stay
    lon, lat, r = _position(series, config, times)
    res = model_field_hpen(times, lon, lat, r, model=name, kp=kp_values, drivers=drivers,
                           cadence_s=config["model"]["cadence_s"], n_jobs=config["model"]["jobs"],
                           cache_dir=config.resolve(config["model"]["cache_dir"]))
    index = pd.DatetimeIndex(times, tz="UTC", name="time")
    prov = make_provenance("model", {"model": config["model"], "position": config["position"],
                                     "cadence_s": cad}, inputs=inputs)
    minute = MinuteData(times, hpen, res.b_hpen_nT, kp_values, lon, lat, r)
    data_table = pd.DataFrame(hpen, index=index, columns=list(HPEN))
    for c, v in (("lon_deg", lon), ("lat_deg", lat), ("r_re", r)):
        data_table[c] = v
    resid = hpen - res.b_hpen_nT
    summary = {"model": res.model, "n_samples": len(times), "n_invalid": res.n_invalid,
               "reasons": res.reasons, "kp_range": [float(np.nanmin(kp_values)),
                                                    float(np.nanmax(kp_values))]
               if np.isfinite(kp_values).any() else None,
               "data_minus_model_median_nT": np.nanmedian(resid, axis=0).tolist()}
    lines = (f"{len(times)} samples at {cad:g} s; {res.model} at the spacecraft "
             f"({res.n_invalid} NaN); median data - model "
             + ", ".join(f"{c} {v:+.2f}" for c, v in zip(HPEN, summary[
                 "data_minus_model_median_nT"])) + " nT",)
    product = StageProduct(
        stage="model", summary=summary, lines=lines, provenance=prov,
        tables={"MODEL.csv": pd.DataFrame(res.b_hpen_nT, index=index, columns=list(HPEN)),
                "DATA_HPEN.csv": data_table})
    return minute, product
