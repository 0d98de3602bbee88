"""Uncertainty report of a processed data set (the folder ``magcal demo`` writes).

Reads the product files, never the raw pipeline state, and turns them into one
:class:`~magcal.report.document.Document`: AC cleaning quality, offsets with their
spread over time, alignment angles with posteriors and by window, conjunction results,
spin calibration, discovered model gaps, and an error budget per frequency band
(:mod:`magcal.report.budget`: above and below 0.1 mHz, as the SOSMAG requirements are
stated: < 1 nT above, < 5 nT offset below). Every table and figure names the product
file its numbers come from. A section whose products are missing says so, and no cell
holds NaN: what was not computed says why.

Layout read (relative to the products folder)::

    ac/PARAMS_*.json, ac/CLEAN_*.csv.gz       PiCoG parameters and cleaned data
    ac/PARAMS.json, ac/AC.json                 or: the chain's PiCoG fit and summary
    model/MODEL.csv, model/DATA_HPEN.csv       field magnitudes (alignment error in nT)
    ac/AC_QUALITY.json                         remnants and daily-refit stability
    offsets/OFFSETS.csv, OFFSETS_*.csv         offsets per window (median, variants)
    alignment/ALIGN.json, ALIGN.samples.csv.gz angles, checks, posterior samples
    alignment/*conjunction*.json               validation against a reference craft
    discover/REPORT.json                       model-gap discovery
    spin/CAL.json                              spin calibration
"""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

import numpy as np

from magcal.discover.account import step_interval_text
from magcal.errors import InputError
from magcal.report.budget import ABOVE, BELOW, DIRECTION, Contribution, budget_rows
from magcal.report.document import Document, Figure, Paragraph, Table

COMPONENTS = ("Hp", "He", "Hn")
#: 0.1 mHz: the band split of the requirements (period 2.78 h).
SPLIT_HZ = 1e-4
#: Field magnitude used to turn an angle into nT when no model file is present (GEO).
DEFAULT_FIELD_NT = 100.0


def _rel(path: Path, root: Path) -> str:
    try:
        return str(path.relative_to(root))
    except ValueError:
        return str(path)


def _read_json(path: Path, required=()) -> dict:
    """A product file's JSON object; a malformed one is bad input (exit 2), not a crash.

    Raises
    ------
    InputError
        Not JSON (naming the line and column), not a JSON object, or without a key of
        ``required`` (naming it).

    Examples
    --------
    >>> import tempfile
    >>> p = Path(tempfile.mkdtemp()) / "CAL.json"
    >>> _ = p.write_text('{"schema_version": 1}')
    >>> _read_json(p, required=("spin_tone_before_nT",))
    Traceback (most recent call last):
    ...
    magcal.errors.InputError: ...CAL.json: missing key 'spin_tone_before_nT'
    """
    try:
        doc = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        where = (f"line {exc.lineno} column {exc.colno}: "
                 if isinstance(exc, json.JSONDecodeError) else "")
        raise InputError(f"not valid JSON ({where}{getattr(exc, 'msg', exc)}; truncated?)",
                         file=path) from None
    if not isinstance(doc, dict):
        raise InputError(f"expected a JSON object, found a {type(doc).__name__}", file=path)
    return _require(doc, required, path)


def _require(doc: dict, keys, path: Path, kind=None) -> dict:
    """``doc``, after checking it holds ``keys`` (of type ``kind`` if given)."""
    for key in keys:
        if key not in doc:
            raise InputError(f"missing key {key!r}", file=path)
        if kind is not None and (not isinstance(doc[key], kind)
                                 or isinstance(doc[key], bool)):
            kinds = kind if isinstance(kind, tuple) else (kind,)
            raise InputError(f"key {key!r} is a {type(doc[key]).__name__}, expected a "
                             f"{' or '.join(k.__name__ for k in kinds)}", file=path)
    return doc


def _missing(*names) -> Paragraph:
    return Paragraph("Not available: no " + " or ".join(names) + " in the products folder; "
                     "this section is left out (not an error).")


def _png_of(plot_fn, *args, **kwargs) -> bytes:
    """PNG bytes of a plot function that writes to a path (``fn(path, ...)``)."""
    import matplotlib.pyplot as plt

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "fig.png"
        plot_fn(out, *args, **kwargs)
        plt.close("all")
        return out.read_bytes()


# ------------------------------------------------------------------------- AC cleaning
def _raw_input(params: dict) -> Path | None:
    for item in (params.get("provenance") or {}).get("inputs", []) or []:
        p = Path(item.get("path", "")) if isinstance(item, dict) else Path(str(item))
        if p.is_file():
            return p
    return None


def ac_section(root: Path, budget: list) -> tuple:
    from magcal.io.csv import read_csv_frame

    folder = root / "ac"
    params_files = sorted(folder.glob("PARAMS_*.json")) if folder.is_dir() else []
    if not params_files and (folder / "PARAMS.json").is_file():
        return chain_ac_items(root, budget)
    if not params_files:
        budget.append(Contribution(ABOVE, "AC cleaning floor", None,
                                   "not computed: no AC cleaning products (ac/)"))
        return (_missing("ac/PARAMS_*.json", "ac/PARAMS.json"),)
    items = [Paragraph("PiCoG removes the spacecraft's AC disturbances (periods shorter than "
                       "a few hours). Quality numbers: how much disturbance power the "
                       "cleaning removed (PSD ratio raw / cleaned, where the raw input is "
                       "reachable through the parameters' provenance), whether the upload "
                       "matrices sum to the identity, and how much two cleaning plans "
                       "disagree above 0.1 mHz (a floor of the cleaning uncertainty).")]
    rows, cleaned = [], {}
    hp_ratio: dict[str, float] = {}
    for pf in params_files:
        name = pf.stem.removeprefix("PARAMS_")
        params = _require(_read_json(pf), ("M",), pf, kind=dict)
        ident = float(np.abs(sum(np.asarray(m, dtype=float) for m in params["M"].values())
                             - np.eye(3)).max())
        steps = params.get("steps", [])
        alphas = [s.get("alpha") for s in steps if s.get("alpha") is not None]
        clean_path = folder / f"CLEAN_{name}.csv.gz"
        ratio = np.nan
        if clean_path.is_file():
            frame = read_csv_frame(clean_path)
            cleaned[name] = (clean_path, frame)
            raw_path = _raw_input(params)
            target = params.get("target")
            if raw_path is not None and target:
                raw = read_csv_frame(raw_path)
                cols = [f"{target}_{a}" for a in "xyz"]
                if all(c in raw for c in cols):
                    from magcal.ac.plots import plot_psd

                    common = raw.index.intersection(frame.index)
                    r = raw.loc[common, cols].to_numpy(float)
                    c = frame.loc[common, ["x", "y", "z"]].to_numpy(float)
                    dt = float(np.median(np.diff(common.asi8))) * 1e-9
                    # power above 0.1 mHz (the AC band of the requirement): the daily
                    # variation of the ambient field would otherwise dominate both
                    ratio = float(np.sum(highpass_rms(r, dt, SPLIT_HZ) ** 2)
                                  / np.sum(highpass_rms(c, dt, SPLIT_HZ) ** 2))
                    hp_ratio[name] = ratio
                    items.append(Figure.from_matplotlib(
                        plot_psd(r, c, dt, title=f"{name} plan: raw vs cleaned {target}"),
                        caption=f"Power spectral density of raw and cleaned {target}, "
                                f"{name} plan, and their ratio (paper Fig. 9).",
                        source=f"{_rel(raw_path, root)}, {_rel(clean_path, root)}"))
        rows.append((name, len(steps), f"{ident:.1e}",
                     f"{min(alphas):.3f} .. {max(alphas):.3f}" if alphas else "-",
                     f"{ratio:.1f}" if np.isfinite(ratio) else "raw input not found",
                     _rel(pf, root)))
    items.insert(1, Table.from_records(
        ["plan", "steps", "|sum M - I|", "alpha range", "raw/clean power > 0.1 mHz", "source"],
        rows,
        caption="PiCoG parameters per cleaning plan.", source="ac/PARAMS_*.json"))
    if len(cleaned) >= 2:
        # the two plans that remove the most power above 0.1 mHz: their disagreement is a
        # floor of the cleaning error (a plan that fails would only measure its failure)
        ranked = sorted(cleaned.items(), key=lambda kv: -hp_ratio.get(kv[0], 0.0))
        (n1, (p1, f1)), (n2, (p2, f2)) = ranked[:2]
        common = f1.index.intersection(f2.index)
        diff = (f1.loc[common, ["x", "y", "z"]].to_numpy(float)
                - f2.loc[common, ["x", "y", "z"]].to_numpy(float))
        dt = float(np.median(np.diff(common.asi8))) * 1e-9
        hp = highpass_rms(diff, dt, SPLIT_HZ)
        items.append(Table.from_records(
            ["component", "rms above 0.1 mHz (nT)"],
            [(a, float(v)) for a, v in zip("xyz", hp)],
            caption=f"Disagreement of the {n1} and {n2} cleaned data above 0.1 mHz.",
            source=f"{_rel(p1, root)} - {_rel(p2, root)}"))
        budget.append(Contribution(
            ABOVE, "AC cleaning floor", float(np.max(hp)),
            "rms above 0.1 mHz of the difference of the two best cleaning plans (worst axis)",
            f"{_rel(p1, root)} - {_rel(p2, root)}"))
    else:
        budget.append(Contribution(ABOVE, "AC cleaning floor", None, _ONE_PLAN))
    items += ac_quality_items(root)
    return tuple(items)


_ONE_PLAN = ("not computed: one cleaning plan; the floor is the rms above 0.1 mHz of the "
             "difference of two plans' cleaned data (magcal picog fit with a second plan)")


def chain_ac_items(root: Path, budget: list) -> tuple:
    """The AC section of a chain run: ``ac/PARAMS.json`` (PiCoG fit) and ``ac/AC.json``
    (what the chain delivered and removed)."""
    folder = root / "ac"
    params = _read_json(folder / "PARAMS.json")
    summary = _read_json(folder / "AC.json") if (folder / "AC.json").is_file() else {}
    src_p, src_s = _rel(folder / "PARAMS.json", root), _rel(folder / "AC.json", root)
    steps = params.get("steps", [])
    alphas = [s.get("alpha") for s in steps if s.get("alpha") is not None]
    ident = params.get("identity_error", summary.get("identity_error"))
    items = [Paragraph(
        "PiCoG removes the spacecraft's AC disturbances; the chain fitted one correction on "
        "its first days and applied it to every partition. Below: the fitted correction, "
        "what the chain delivered, and the power ratio raw / cleaned per frequency band "
        "(the chain's band check: a ratio below 1 means the cleaning added power there).")]
    rows = [("plan", str(summary.get("plan", "-"))),
            ("target / sensors", f"{params.get('target', '-')} / "
                                 + ", ".join(summary.get("sensors", params.get("M", {}))))]
    rows += [("correction steps", str(len(steps))),
             ("alpha range", f"{min(alphas):.3f} .. {max(alphas):.3f}" if alphas else
              "no alpha (no step fitted)"),
             ("|sum M - I|", f"{ident:.1e}" if ident is not None else "not in PARAMS.json"),
             ("delivered", str(summary.get("delivered", "not in AC.json")))]
    if "removed_rms_nT" in summary:
        rows.append(("removed rms (nT)", f"{summary['removed_rms_nT']:.3f}"))
    if "n_bands_worse" in summary:
        rows.append(("band/components worse than raw (constant matrices)",
                     str(summary["n_bands_worse"])))
    if "n_bands_worse_delivered" in summary:
        rows.append((f"band/components worse than raw ({summary.get('product')} product, "
                     "delivered)", str(summary["n_bands_worse_delivered"])))
    if "fit_samples" in summary:
        rows.append(("fit samples (flagged left out)",
                     f"{summary['fit_samples']} ({summary.get('fit_samples_flagged', 0)})"))
    items.append(Table.from_records(["quantity", "value"], rows,
                                    caption="PiCoG correction of the chain run.",
                                    source=f"{src_p}, {src_s}"))
    check = params.get("band_check") or {}
    if check.get("bands_hz") and check.get("reduction"):
        brows = [(f"{lo:.3g} - {hi:.3g}", *[float(r) for r in red])
                 for (lo, hi), red in zip(check["bands_hz"], check["reduction"])]
        items.append(Table.from_records(
            ["band (Hz)", "raw/clean Hp", "raw/clean He", "raw/clean Hn"], brows,
            caption="Power ratio raw / cleaned per band of the fit data (PiCoG band check).",
            source=f"{src_p} band_check", fmt="{:.3f}"))
    else:
        items.append(Paragraph("No band check in ac/PARAMS.json: no power ratio per band."))
    items += [Paragraph("Warning: " + w) for w in summary.get("warnings", [])]
    budget.append(Contribution(ABOVE, "AC cleaning floor", None, _ONE_PLAN))
    return tuple(items)


def _f(v, fmt="{:.2f}"):
    return "-" if v is None or not np.isfinite(v) else fmt.format(v)


def ac_quality_items(root: Path) -> list:
    """Remnants per disturbance class and daily-refit stability from ``ac/AC_QUALITY.json``
    (written by :func:`magcal.report.ac_quality.write_ac_quality`; not computed here,
    the refits cost about one whole-record fit per plan)."""
    path = root / "ac" / "AC_QUALITY.json"
    if not path.is_file():
        return [Paragraph("Remnants per disturbance class and parameter stability: no "
                          "ac/AC_QUALITY.json (magcal.report.ac_quality.write_ac_quality "
                          "writes it).")]
    doc = _read_json(path)
    src = _rel(path, root)
    plans = doc.get("plans", {})
    items = [Paragraph(
        "Remnants (paper Table 2) without truth: events are found in the difference of "
        "two sensors, where the ambient field cancels; at those times the raw target and "
        "the cleaned data are measured. Steps: median over 90 s after minus before; "
        "spikes: peak minus the median over 20 s intervals 5 s either side; high-frequency "
        "noise: mean peak-to-peak over 60 s blocks in the noisiest event-free 10 min "
        "minus that in the quietest (the etalon). Mean |component| and mean module.")]
    rows = []
    for name, e in plans.items():
        rem = e.get("remnants", {})
        for cls in ("steps", "spikes"):
            r = rem.get(cls)
            if not r:
                continue
            raw, cln = r["raw"], r["clean"]
            rows.append((name, cls, r["n"], *[_f(v) for v in raw["mean_abs_nT"]],
                         _f(raw["mean_module_nT"]), *[_f(v) for v in cln["mean_abs_nT"]],
                         _f(cln["mean_module_nT"])))
        hf = rem.get("hf", {})
        if "raw_nT" in hf:
            rows.append((name, f"HF (contrast {hf['contrast']:.1f})", "-",
                         *[_f(v) for v in hf["raw_nT"]], "-",
                         *[_f(v) for v in hf["clean_nT"]], "-"))
    items.append(Table.from_records(
        ["plan", "class", "n", "raw x", "raw y", "raw z", "raw |B|", "clean x", "clean y",
         "clean z", "clean |B|"], rows or [("-",) * 11],
        caption="Disturbance magnitudes in the raw target and remnants in the cleaned "
                "data (nT), pair " + ", ".join(f"{k}: {'-'.join(v.get('pair', []))}"
                                               for k, v in plans.items()) + ".",
        source=src))
    rows, bmax = [], []
    for name, e in plans.items():
        st = e.get("stability") or {}
        if "steps" not in st:
            rows.append((name, st.get("skipped", "not computed"), "-", "-", "-", "-"))
            continue
        for r in st["steps"]:
            step = f"{r['stage']}.{r['order']} {r['i']}-{r['j']}"
            if "std_matrix_max" in r:
                rows.append((name, step, "-", "-", f"matrix {r['std_matrix_max']:.2g}", "-"))
            else:
                rows.append((name, step, _f(r["std_direction_i_deg"]),
                             _f(r["std_direction_ij_deg"]), f"{r['std_alpha']:.2g}",
                             _f(r["mean_alpha"], "{:.3f}")))
        bmax.append((name, ", ".join(st["days"]), _f(st["bmaxdev_nT"], "{:.3f}"),
                     _f(st["bmaxdev_ac_nT"], "{:.3f}")))
    items.append(Table.from_records(
        ["plan", "step (stage.order i-j)", "std dir i (deg)", "std dir ij (deg)",
         "std alpha", "mean alpha"], rows or [("-",) * 6],
        caption="Parameter stability (paper Table 1): the plan refitted on each UTC day "
                "separately, std over the days.", source=src))
    if bmax:
        items.append(Table.from_records(
            ["plan", "days", "Bmaxdev (nT)", "Bmaxdev, means removed (nT)"], bmax,
            caption="Bmaxdev: largest change of the corrected field between two days' "
                    "upload matrices applied to the whole input.", source=src))
    return items


def highpass_rms(x, dt_s: float, f_hz: float) -> np.ndarray:
    """RMS per column of ``x`` above ``f_hz`` (FFT brick-wall, mean removed, NaN -> 0).

    Examples
    --------
    >>> t = np.arange(100000.0)
    >>> x = np.stack([np.sin(2 * np.pi * t / 100.0), np.sin(2 * np.pi * t / 50000.0)], 1)
    >>> highpass_rms(x, 1.0, 1e-4).round(3)
    array([0.707, 0.   ])
    """
    x = np.asarray(x, dtype=float)
    x = np.where(np.isfinite(x), x, np.nan)
    x = np.nan_to_num(x - np.nanmean(x, axis=0))
    spec = np.fft.rfft(x, axis=0)
    f = np.fft.rfftfreq(x.shape[0], dt_s)
    spec[f < f_hz] = 0.0
    return np.sqrt(np.mean(np.fft.irfft(spec, n=x.shape[0], axis=0) ** 2, axis=0))


# ----------------------------------------------------------------------------- offsets
def offsets_section(root: Path, budget: list) -> tuple:
    from magcal.offsets.table import read_offsets_csv

    folder = root / "offsets"
    main = folder / "OFFSETS.csv"
    if not main.is_file():
        budget.append(Contribution(BELOW, "offset: standard error", None,
                                   "not computed: no offsets/OFFSETS.csv"))
        return (_missing("offsets/OFFSETS.csv"),)
    table = read_offsets_csv(main)
    ok = np.isfinite(table.offset_nT).all(axis=1)
    se = table.se_nT if table.se_nT is not None else np.full(table.offset_nT.shape, np.nan)
    has_se = bool(np.isfinite(se[ok]).any())
    items = [Paragraph("DC offsets: median of data minus model over quiet samples in sliding "
                       "windows. The standard error (se) is how well a window's offset is "
                       "known (correlated residuals accounted for); the spread (std) is that "
                       "of the selected samples, shown apart: it is not the offset's error.")]
    half = table.interval95()
    rows = []
    for k in np.flatnonzero(ok):
        rows.append((str(np.datetime64(table.center[k], "s")),
                     *[float(v) for v in table.offset_nT[k]],
                     *[float(v) if np.isfinite(v) else "not computed" for v in se[k]],
                     *[float(v) if np.isfinite(v) else "not computed" for v in half[k]],
                     *[float(v) for v in table.std_nT[k]], int(table.n_used[k])))
    items.append(Table.from_records(
        ["centre", "Hp (nT)", "He (nT)", "Hn (nT)", "Hp se", "He se", "Hn se", "Hp 95 %",
         "He 95 %", "Hn 95 %", "Hp spread", "He spread", "Hn spread", "n used"],
        rows or [("no window with an offset",) + ("-",) * 13],
        caption="Offsets per window (median estimator), 1-sigma standard errors, "
                "half-widths of the 95 % intervals (Student's t on the standard "
                "error's degrees of freedom, the `*_dof` columns; 1.96 where a file "
                "has none) and the spread (std) of the selected samples (nT).",
        source=_rel(main, root), fmt="{:.2f}"))
    if not ok.all():
        reason = np.asarray(table.reason if table.reason is not None and len(table.reason)
                            else [""] * len(table), dtype=object)
        reasons = sorted({str(r) for r in reason[~ok] if str(r) not in ("", "nan", "None")})
        items.append(Paragraph(f"{int((~ok).sum())} window(s) without an offset, left out "
                               "of the table: " + ("; ".join(reasons) or "no reason given")
                               + "."))
    changes = tuple(getattr(table, "level_changes", ()) or ())
    if changes:
        items.append(Table.from_records(
            ["day of the change", "95 % interval"] + [f"{c} (nT)" for c in COMPONENTS],
            [(str(np.datetime64(ch.time, "D")),
              f"{np.datetime64(ch.time_lo, 'D')} .. {np.datetime64(ch.time_hi, 'D')}",
              *[f"{v:+.2f} +- {e:.2f}" for v, e in zip(ch.size_nT, ch.se_nT)])
             for ch in changes],
            caption="Sudden level changes of the offset found in the record "
                    "(magcal.offsets.levels; size new minus old level, 1-sigma). "
                    + ("The windows were split at each (split_at_level_changes): the "
                       "offsets either side come from that side's samples alone, and "
                       "corrected samples inside a change's 95 % interval carry quality "
                       "bit 256." if table.segment is not None else
                       "The windows straddling one mix both levels, and corrected samples "
                       "interpolated across it carry quality bit 128."),
            source=_rel(main, root)))
    if ok.any():
        spread = (np.nanmax(table.offset_nT[ok], axis=0)
                  - np.nanmin(table.offset_nT[ok], axis=0))
        items.append(Table.from_records(
            ["quantity"] + [f"{c} (nT)" for c in COMPONENTS],
            [("range over windows", *map(float, spread))],
            caption="Variation of the offsets over the record.", source=_rel(main, root),
            fmt="{:.2f}"))
    from magcal.offsets.plots import plot_offsets

    items.append(Figure(_png_of(plot_offsets, table), "Offsets per window; error bars: "
                        + ("1-sigma standard errors, shaded: the spread of the selected "
                           "samples" if has_se else "spread of the selected samples (this "
                           "OFFSETS.csv has no standard errors)") + " (paper Fig. 20).",
                        _rel(main, root)))
    variants = sorted(p for p in folder.glob("OFFSETS_*.csv"))
    worst_diff = np.full(3, np.nan)
    for var in variants:
        other = read_offsets_csv(var)
        n = min(len(other.center), len(table.center))
        same = other.center[:n] == table.center[:n]
        d = np.abs(other.offset_nT[:n][same] - table.offset_nT[:n][same])
        worst = np.nanmax(d, axis=0) if d.size else np.full(3, np.nan)
        worst_diff = np.fmax(worst_diff, worst)
        items.append(Table.from_records(
            ["comparison"] + [f"max |diff| {c} (nT)" for c in COMPONENTS],
            [(f"{main.name} vs {var.name}", *map(float, worst))],
            caption="Estimator disagreement per window (same windows).",
            source=f"{_rel(main, root)}, {_rel(var, root)}", fmt="{:.2f}"))
    src = _rel(main, root)
    budget.append(Contribution(
        BELOW, "offset: standard error",
        float(np.nanmax(se[ok])) if has_se else None,
        "largest 1-sigma standard error of a window offset (any component)" if has_se else
        _NO_OFFSET if not ok.any() else
        "not computed: OFFSETS.csv has no Hp_se,He_se,Hn_se (written before they existed)",
        src))
    budget.append(Contribution(
        BELOW, "offset: estimator disagreement",
        float(np.nanmax(worst_diff)) if np.isfinite(worst_diff).any() else None,
        "largest |difference| of two offset estimators in a window" if variants else
        "not computed: one offset estimator (no OFFSETS_*.csv variant to compare)",
        ", ".join(_rel(v, root) for v in variants) or "-"))
    mean_std = np.nanmean(table.std_nT[ok], axis=0) if ok.any() else np.full(3, np.nan)
    budget.append(Contribution(
        BELOW, "offset: spread of quiet data - model",
        float(np.nanmax(mean_std)) if np.isfinite(mean_std).any() else None,
        "per-sample std (largest component): the model error per sample; its effect on a "
        "window's offset is in the standard error" if ok.any() else _NO_OFFSET, src,
        combined=False))
    return tuple(items)


_NO_OFFSET = "not computed: no window has an offset (reasons in DC offsets)"


# --------------------------------------------------------------------------- alignment
def _window_angles_from_json(win: dict):
    from magcal.alignment.windows import WindowAngles

    w = win["windows"]
    arr = lambda key: np.array([[x[key][c] for c in COMPONENTS] for x in w])  # noqa: E731
    vec = lambda key: np.array([win[key][c] for c in COMPONENTS], dtype=float)  # noqa: E731
    return WindowAngles(
        start=np.array([x["start"] for x in w], dtype="datetime64[ns]"),
        end=np.array([x["end"] for x in w], dtype="datetime64[ns]"),
        angles_deg=arr("angles_deg"), std_deg=arr("std_deg"),
        n_used=np.array([x["n_used"] for x in w]), mean_deg=vec("mean_deg"),
        mean_std_deg=vec("mean_std_deg"), spread_deg=vec("spread_deg"),
        chi2_per_dof=vec("chi2_per_dof"), drift_deg_per_day=vec("drift_deg_per_day"),
        drift_std_deg_per_day=vec("drift_std_deg_per_day"))


def _corner_figure(samples_path: Path, doc: dict):
    import pandas as pd

    from magcal.alignment.plots import plot_posterior_corner

    frame = pd.read_csv(samples_path)
    names = [c.replace("angle_deg_", "w_") for c in frame.columns]

    class _Posterior:  # the attributes plot_posterior_corner reads
        samples = frame.to_numpy(float)
        mcmc = {"sample_names": names}
        converged = bool(doc.get("converged"))
        autocorr_steps = float(doc.get("autocorr_steps") or np.nan)

    return plot_posterior_corner(_Posterior())


def alignment_section(root: Path, budget: list) -> tuple:
    path = root / "alignment" / "ALIGN.json"
    if not path.is_file():
        budget += [Contribution(b, "alignment", None, "not computed: no alignment/ALIGN.json")
                   for b in (DIRECTION, BELOW)]
        return (_missing("alignment/ALIGN.json"),)
    doc = _read_json(path, required=("method", "n_used"))
    src = _rel(path, root)
    items = [Paragraph(
        f"Rotation of the data against the reference (method {doc['method']}, "
        f"{doc['n_used']} samples" + (f", Kp <= {doc['selection']['kp_max']:g}"
                                      if (doc.get("selection") or {}).get("kp_max") else "")
        + (f", {doc['lt_harmonics']} local-time harmonics fitted as nuisance"
           if doc.get("lt_harmonics") else "") + ").")]
    if doc.get("determinable") is False:
        items.append(Paragraph("The data do not determine the rotation: "
                               f"{doc.get('reason') or 'see ALIGN.json'}. No angles are "
                               "reported and the error budget has no alignment value."))
        why = "not computed: the data do not determine the rotation (see Alignment)"
        budget += [Contribution(b, "alignment", None, why, src) for b in (DIRECTION, BELOW)]
        items += [Paragraph("Warning: " + w) for w in doc.get("warnings", [])]
        return tuple(items)
    _require(doc, ("angles_deg", "std_deg", "ci95_deg"), path, kind=dict)
    rows = [(c, doc["angles_deg"][c], doc["std_deg"][c], doc["ci95_deg"][c][0],
             doc["ci95_deg"][c][1]) for c in COMPONENTS]
    items.append(Table.from_records(
        ["angle about", "angle (deg)", "std (deg)", "95% low", "95% high"], rows,
        caption="Alignment angles (CONTRACTS §3 convention: data ~= R(w) @ reference).",
        source=src, fmt="{:.3f}"))
    if doc["method"] == "emcee":
        items.append(Paragraph(
            f"MCMC converged: {doc.get('converged')} (chain longer than "
            f"{doc['mcmc'].get('min_autocorr_times', 50):g} autocorrelation times of "
            f"{doc.get('autocorr_steps', float('nan')):.1f} steps; "
            f"{doc['mcmc'].get('n_steps')} steps)."))
    for w in doc.get("warnings", []):
        items.append(Paragraph("Warning: " + w))
    lt = doc.get("local_time_field")
    if lt:
        items.append(Table.from_records(
            ["component", "peak-to-peak (nT)", "Wald p-value"],
            [(c, lt["peak_to_peak_nT"][c], lt["p_value"][c]) for c in COMPONENTS],
            caption=f"Fitted local-time field the reference lacks ({lt['time_base']}).",
            source=f"{src} local_time_field", fmt="{:.3g}"))
    chk = doc.get("local_time_check")
    if chk and "angles_without_lt_deg" in chk:
        items.append(Table.from_records(
            ["angle about", "with LT field (deg)", "without (deg)", "shift (sigma)"],
            [(c, chk["angles_with_lt_deg"][c], chk["angles_without_lt_deg"][c],
              chk["shift_sigma"][c]) for c in COMPONENTS],
            caption="How much the angles depend on the local-time nuisance field.",
            source=f"{src} local_time_check", fmt="{:.2f}"))
    samples = path.with_name(path.stem + ".samples.csv.gz")
    if samples.is_file():
        items.append(Figure.from_matplotlib(
            _corner_figure(samples, doc),
            caption="Posterior of the three angles (median and 95 % interval dashed), as "
                    "sampled: the table above adds the window checks' inflation and "
                    "systematic where the warnings say so.",
            source=_rel(samples, root)))
    else:
        items.append(Paragraph("No posterior samples file (ALIGN.samples.csv.gz, written by "
                               "'magcal align --mcmc'): no corner plot."))
    win = doc.get("windows")
    if win and win.get("windows"):
        from magcal.alignment.plots import plot_angles_by_window

        wa = _window_angles_from_json(win)
        items.append(Table.from_records(
            ["angle about", "whole record (window spread) deg", "weighted mean", "chi2/dof"],
            [(c, win.get("paper_style", {}).get(c, "-"), win["mean_deg"][c],
              win["chi2_per_dof"][c]) for c in COMPONENTS],
            caption="Angles by window, quoted as the paper does: angle (spread).",
            source=f"{src} windows", fmt="{:.2f}"))
        items.append(Figure.from_matplotlib(
            plot_angles_by_window(wa), caption="Angles fitted per window with 1-std error "
            "bars, weighted mean and drift.", source=f"{src} windows"))
    std_deg = float(max(doc["std_deg"].values()))
    budget.append(Contribution(DIRECTION, "alignment: angle std", std_deg,
                               "largest of the three angle standard deviations", src))
    field, how = _field_magnitude(root)
    budget.append(Contribution(BELOW, "alignment", np.deg2rad(std_deg) * field,
                               f"angle std (rad) x {field:.0f} nT ({how})", src))
    hf, hf_how = _field_above_split(root)
    budget.append(Contribution(
        ABOVE, "alignment", None if hf is None else np.deg2rad(std_deg) * hf,
        hf_how if hf is None else f"angle std (rad) x {hf:.2f} nT rms of the measured field "
        "above 0.1 mHz", src))
    noise = doc.get("noise") or {}
    if "std_nT" in noise:
        tot = max(float(np.hypot(noise["std_nT"][c], (noise.get("white_std_nT") or {}).get(
            c, 0.0))) for c in COMPONENTS)
        budget.append(Contribution(
            BELOW, "model error per sample", tot,
            "data - (rotated) model noise std of the alignment noise model, largest "
            "component: the model's miss per sample; its effect on offsets and angles is in "
            "their standard errors", f"{src} noise", combined=False))
    return tuple(items)


def _field_magnitude(root: Path) -> tuple[float, str]:
    """Mean |B| of the model field (nT), or the geostationary default."""
    import pandas as pd

    path = root / "model" / "MODEL.csv"
    if path.is_file():
        b = pd.read_csv(path, usecols=list(COMPONENTS)).to_numpy(float)
        mag = np.sqrt(np.sum(b ** 2, axis=1))
        if np.isfinite(mag).any():
            return float(np.nanmean(mag)), "mean |B| of model/MODEL.csv"
    return DEFAULT_FIELD_NT, "geostationary |B|; no model/MODEL.csv"


def _field_above_split(root: Path) -> tuple[float | None, str]:
    """Largest rms above 0.1 mHz of the measured Hpen field (nT), or why not."""
    import pandas as pd

    path = root / "model" / "DATA_HPEN.csv"
    if not path.is_file():
        return None, "not computed: no model/DATA_HPEN.csv (measured field) to scale the angle"
    frame = pd.read_csv(path, usecols=["time", *COMPONENTS], parse_dates=["time"])
    t = frame["time"].to_numpy("datetime64[ns]").astype("int64") * 1e-9
    if t.size < 3:
        return None, "not computed: fewer than 3 measured samples"
    dt = float(np.median(np.diff(t)))
    return float(np.max(highpass_rms(frame[list(COMPONENTS)].to_numpy(float), dt,
                                     SPLIT_HZ))), ""


def conjunction_section(root: Path) -> tuple:
    files = sorted((root / "alignment").glob("*onjunction*.json")) if (
        root / "alignment").is_dir() else []
    if not files:
        return (_missing("alignment/*conjunction*.json"),)
    items = []
    for f in files:
        doc = _read_json(f)
        rows = [(k, v) for k, v in doc.items() if isinstance(v, (int, float, str, bool))
                and k not in ("schema_version", "magcal_version")]
        for k, v in doc.items():
            if isinstance(v, dict) and set(v) == set(COMPONENTS):
                rows.append((k, ", ".join(f"{c} {float(v[c]):.3g}" for c in COMPONENTS)))
        items.append(Table.from_records(["quantity", "value"], rows,
                                        caption="Conjunction validation.", source=_rel(f, root)))
    return tuple(items)


def discover_section(root: Path) -> tuple:
    path = root / "discover" / "REPORT.json"
    if not path.is_file():
        return (_missing("discover/REPORT.json"),)
    doc = _read_json(path, required=("gap_initial", "gap_final"))

    def amplitude(e):
        amp, se = e.get("amplitude_nT") or {}, e.get("amplitude_se_nT") or {}
        if not amp:
            return "not computed (REPORT.json written before amplitudes existed)"
        return ", ".join(f"{c} {amp[c]:.3f} +- {se.get(c, float('nan')):.3f}" for c in amp)

    def when(e):  # a step's or a drift break's time and its 95 % interval
        p = e.get("parameters") or {}
        for key in ("time", "break_time"):
            if key in p:
                return p[key][:16].replace("T", " ") + step_interval_text(p)
        return "-"

    rows = [(e["name"], ",".join(e.get("components", [])), when(e), e["rms_before_nT"],
             e["rms_after_nT"], amplitude(e)) for e in doc.get("effects", [])]
    return (Paragraph(f"Gap between measured and model: {doc['gap_initial']['rms_nT']:.3f} nT "
                      f"rms at the start, {doc['gap_final']['rms_nT']:.3f} nT after the "
                      f"effects below ({doc.get('stopped_because', '')})."),
            Table.from_records(["effect", "components", "time (UTC)", "rms before (nT)",
                                "rms after (nT)",
                                "amplitude (rms over the record, nT) +- standard error"],
                               rows, caption="Effects in the order they were added; "
                               "a step's time or a drift's break time with its 95 % "
                               "interval (it happened after the first time, by the second); "
                               "standard errors under the OU + white noise model fitted to "
                               "the final residual (discover/REPORT.json amplitude_noise).",
                               source=_rel(path, root), fmt="{:.3f}"))


def spin_section(root: Path) -> tuple:
    path = root / "spin" / "CAL.json"
    if not path.is_file():
        return (_missing("spin/CAL.json"),)
    doc = _require(_read_json(path), ("spin_tone_before_nT", "spin_tone_after_nT"), path,
                   kind=dict)
    before, after = doc["spin_tone_before_nT"], doc["spin_tone_after_nT"]
    rows = [(k, *[float(x) for x in before[k]], *[float(x) for x in after[k]]) for k in before]
    items = [Paragraph("Spin calibration: determined " + ", ".join(doc.get("determined", []))
                       + "; held at priors: " + (", ".join(doc.get("fixed", [])) or "none")),
             Table.from_records(["axis", "1x before (nT)", "2x before", "1x after", "2x after"],
                                rows, caption="Spin-tone amplitudes before and after.",
                                source=_rel(path, root), fmt="{:.4f}")]
    params = _spin_parameter_rows(doc)
    if params:
        items.append(Table.from_records(
            ["parameter", "value", "std", "95 % half-width", "bias correction",
             "leakage correction"], params,
            caption="Determined parameters (coupling c_ij, dimensionless; offsets O_i, nT) "
                    "with their stated errors: the std is a root mean square error where "
                    "the natural waves' estimated bias is left in, the bias correction is "
                    "what was subtracted from the least-squares value and the leakage "
                    "correction what was added for the waves' tones leaking through the "
                    "record's ends (magcal.spin.ripple.solve_ripple).",
            source=_rel(path, root), fmt="{:.6g}"))
    flip = root / "spin" / "FLIP.json"
    if flip.is_file():
        fd = _require(_read_json(flip), ("O3", "O3_std"), flip, kind=(int, float))
        parts = [float(fd.get(k, float("nan"))) for k in ("O3_std_data", "O3_std_calibration")]
        items.append(Table.from_records(
            ["O3 (nT)", "std", "95 % half-width", "data's part", "calibration's part",
             "dof (data)"],
            [(float(fd["O3"]), float(fd["O3_std"]), 1.96 * float(fd["O3_std"]), *parts,
              str(fd.get("O3_dof", "not computed")))],
            caption="Spin-axis offset from the flipper: the std is the data's part (sine "
                    "multitapers, scaled to Student's t on its degrees of freedom) and the "
                    "position-0 calibration's part (its covariance carried through) in "
                    "quadrature.", source=_rel(flip, root), fmt="{:.6g}"))
    return tuple(items)


def _spin_parameter_rows(doc: dict) -> list:
    """Rows (name, value, std, 1.96 std, bias correction, leakage correction) of a
    CAL.json's determined parameters (NaN where the file has no such key); [] when it
    states no errors.

    Examples
    --------
    >>> _spin_parameter_rows({"coupling": [[1, 0, 0], [0.5, 1, 0], [0, 0, 1]],
    ...                       "offsets": [1.0, 2.0, 3.0], "determined": ["c21", "O2"],
    ...                       "std": {"c21": 0.1, "O2": 0.5}, "bias_correction": {"c21": 0.0}})
    [('c21', 0.5, 0.1, 0.196, 0.0, nan), ('O2', 2.0, 0.5, 0.98, nan, nan)]
    """
    std = doc.get("std") or {}
    names = [n for n in doc.get("determined", []) if n in std]
    if not names:
        return []
    from magcal.spin.ripple import PARAM_NAMES

    values = dict(zip(PARAM_NAMES, [float(v) for v in np.ravel(doc["coupling"])]
                      + [float(v) for v in doc["offsets"]]))
    bias = doc.get("bias_correction") or {}
    leak = doc.get("leakage_correction") or {}
    return [(n, values.get(n, float("nan")), float(std[n]), round(1.96 * float(std[n]), 12),
             float(bias.get(n, float("nan"))), float(leak.get(n, float("nan"))))
            for n in names]


def build_uncertainty_report(products_dir, title: str = "magcal uncertainty report"
                             ) -> Document:
    """Build the uncertainty report of a products folder.

    Parameters
    ----------
    products_dir : path-like
        Folder with the layout of ``magcal demo`` (see the module docstring).
    title : str

    Returns
    -------
    Document
        Sections: error budget, AC cleaning, offsets, alignment, conjunction, spin,
        model gaps. Missing products give a one-line "not available" section.

    Examples
    --------
    >>> import tempfile
    >>> doc = build_uncertainty_report(tempfile.mkdtemp())
    >>> [s.title for s in doc.sections][:2]
    ['Error budget by frequency band', 'AC cleaning (PiCoG)']
    """
    from magcal.provenance import make_provenance

    root = Path(products_dir)
    budget: list = []
    ac = ac_section(root, budget)
    offsets = offsets_section(root, budget)
    align = alignment_section(root, budget)
    budget.append(Contribution(
        BELOW, "model bias common to all samples", None,
        "not computed: a bias of the reference model that all samples share is absorbed "
        "by the offsets and invisible in data - model; only a conjunction with a reference "
        "craft measures it (the paper found about 2 nT in Hn against MMS)"))
    doc = Document(title, subtitle=f"products: {root}")
    doc.section("Error budget by frequency band",
                Paragraph("Requirements (SOSMAG, Magnes et al. 2020, Table 1 and Sect. 7): "
                          "error < 1 nT above 0.1 mHz, offset error < 5 nT below 0.1 mHz, "
                          "alignment within 10 deg. Per band the contributions are measured "
                          "from the products (the source column names the file) and "
                          "combined as independent errors (root sum of squares); a "
                          "contribution that was not computed says why, and its band total "
                          "is then a lower bound. Rows marked (not added) are shown for "
                          "information: their effect is already inside another row."),
                Table.from_records(["band", "contribution", "value", "unit", "how / why not",
                                    "source"], budget_rows(budget),
                                   caption="Error budget.", source="see column"))
    doc.section("AC cleaning (PiCoG)", *ac)
    doc.section("DC offsets", *offsets)
    doc.section("Alignment", *align)
    doc.section("Conjunction validation", *conjunction_section(root))
    doc.section("Spin calibration", *spin_section(root))
    doc.section("Model-gap discovery", *discover_section(root))
    files = sorted(p for p in root.rglob("*") if p.is_file() and p.suffix in (".json", ".csv",
                                                                              ".gz"))
    doc.provenance = make_provenance("report", {"products_dir": str(root)}, inputs=files)
    return doc
