"""AC_QUALITY.json: how well each cleaning plan did, assembled for the report.

Constantinescu et al. (2020) judge a cleaning by (Table 2) the remnants of each
disturbance class in the corrected data and (Table 1) the stability of the fitted
parameters over repeated fits. The science lives in :mod:`magcal.ac`: events and
remnants in :mod:`magcal.ac.events`, daily refits and their spread in
:mod:`magcal.ac.stability`. This module picks the sensor pair whose difference shows
the disturbances, runs both for every plan of a products ``ac`` folder and writes
``ac/AC_QUALITY.json``, which the uncertainty report reads.
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from magcal.ac.events import DETECT_SIGMA, remnants
from magcal.ac.stability import daily_refits, stability
from magcal.errors import InputError


def difference_pair(params: dict) -> tuple[str, str]:
    """Sensors whose difference shows the disturbances: (other, target).

    The partner of the target in the first pair stage, else the first other sensor of
    a regression or reference stage (fluxgate partners first).

    Examples
    --------
    >>> difference_pair({"target": "fgmo", "plan": {"stages": [{"kind": "regression",
    ...     "sensors": ["fgmo"], "references": ["amr1", "fgmi"], "orders": []}]}})
    ('fgmi', 'fgmo')
    """
    target = params["target"]
    stages = (params.get("plan") or {}).get("stages", [])
    for st in stages:
        if st["kind"] == "pair" and target in st["sensors"]:
            return next(s for s in st["sensors"] if s != target), target
    others = []
    for st in stages:
        for s in [*st.get("sensors", []), *st.get("references", []),
                  *([st["reference"]] if st.get("reference") else [])]:
            if s != target and s not in others:
                others.append(s)
    if not others:
        raise InputError("the plan names no sensor besides the target")
    # a sensor of the same kind (same name without digits/last letter) first
    stem = target.rstrip("0123456789")[:-1]
    others.sort(key=lambda s: not s.startswith(stem))
    return others[0], target


def ac_quality(raw: pd.DataFrame, cleaned: dict, params: dict, *, refit: bool = True,
               n_sigma: float = DETECT_SIGMA) -> dict:
    """Remnants and (optionally) daily-refit stability of every cleaning plan.

    Parameters
    ----------
    raw : DataFrame
        Multi-sensor input (``<sensor>_x/_y/_z``, UTC DatetimeIndex).
    cleaned : dict name -> DataFrame with ``x, y, z``
    params : dict name -> PARAMS.json document (with ``target``, ``M``, ``plan``)
    refit : bool
        Refit each plan per day (costs about one fit of the whole record per plan).

    Returns
    -------
    dict name -> ``{"pair", "remnants", "stability"}`` (stability missing or
    ``{"skipped": reason}`` when not computed).
    """
    from magcal.ac.estimator import sensor_array
    from magcal.timeconv import epoch_seconds

    out = {}
    for name, prm in params.items():
        other, target = difference_pair(prm)
        clean = cleaned[name]
        common = raw.index.intersection(clean.index)
        r = raw.loc[common]
        t = epoch_seconds(common)
        entry = {"pair": [other, target], "target": target}
        entry["remnants"] = remnants(sensor_array(r, target),
                                     clean.loc[common, ["x", "y", "z"]].to_numpy(float),
                                     sensor_array(r, other) - sensor_array(r, target), t,
                                     n_sigma=n_sigma)
        if refit and prm.get("plan"):
            try:
                fits = daily_refits(raw, prm["plan"], alpha_method=prm.get("alpha_method",
                                                                           "decorrelate"))
                entry["stability"] = stability(raw, fits, prm.get("M"))
            except InputError as exc:
                entry["stability"] = {"skipped": str(exc)}
        out[name] = entry
    return out


def write_ac_quality(ac_dir, raw_path, *, refit: bool = True, out_name: str = "AC_QUALITY.json"
                     ) -> Path:
    """Write ``<ac_dir>/AC_QUALITY.json`` from ``PARAMS_*.json`` and ``CLEAN_*.csv.gz``.

    Parameters
    ----------
    ac_dir : path-like
        Folder with ``PARAMS_<name>.json`` and ``CLEAN_<name>.csv.gz`` (``magcal demo``'s
        ``ac/``).
    raw_path : path-like
        The multi-sensor input the parameters were fitted on.
    refit : bool
        Include the daily-refit stability (about one whole-record fit per plan).

    Returns
    -------
    Path of the product (``plans``: :func:`ac_quality` output, plus ``provenance``).
    """
    from magcal.io.csv import read_csv_frame
    from magcal.io.jsonio import read_json, write_json
    from magcal.provenance import make_provenance

    ac_dir, raw_path = Path(ac_dir), Path(raw_path)
    params, cleaned, inputs = {}, {}, [raw_path]
    for pf in sorted(ac_dir.glob("PARAMS_*.json")):
        name = pf.stem.removeprefix("PARAMS_")
        cp = ac_dir / f"CLEAN_{name}.csv.gz"
        if not cp.is_file():
            continue
        params[name] = read_json(pf, required=("target", "M"))
        cleaned[name] = read_csv_frame(cp)
        inputs += [pf, cp]
    if not params:
        raise InputError("no PARAMS_*.json with a CLEAN_*.csv.gz next to it", file=ac_dir)
    raw = read_csv_frame(raw_path)
    payload = {"plans": ac_quality(raw, cleaned, params, refit=refit),
               "definitions": {
                   "events": "found in the difference of the 'pair' sensors (ambient cancels)",
                   "steps": "median over 90 s after minus before, 15 s either side skipped",
                   "spikes": "peak minus median over 20 s intervals 5 s before and after",
                   "hf": "mean peak-to-peak over 60 s blocks, disturbed minus quiet etalon",
                   "stability": "plan refitted per UTC day; std over days; bmaxdev: largest "
                                "|change| of the corrected field between two days' matrices "
                                "applied to the whole input"},
               "provenance": make_provenance("ac quality", {"refit": refit},
                                             inputs=inputs)}
    out = ac_dir / out_name
    write_json(out, payload)
    return out
