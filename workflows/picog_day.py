"""Clean a simulated GK-2A-like day end to end and write the products.

Three plans on the same day (ULF waves and a substorm in the ambient field, the
simulator's defaults):

- ``paper``: the paper as written (§4): AMR1 cleans both fluxgates on an interval
  around the midnight step, then the boom pair with 100, 700 and 16000 s windows,
  directions from the variance of each sensor;
- ``coherent``: the same stages and windows with ambient-free directions
  (``direction="coherent"``) after removing 30 min running means;
- ``regression``: the non-orthogonal multi-sensor extension;
- ``joint``: the coherent reference stage, then one joint pair stage (``joint = true``,
  :mod:`magcal.ac.joint`): one constant 3x3 per boom sensor fitted over the 100, 700
  and 16000 s scan windows, the 6 s tone band and clean intervals around the midnight
  ramps together.

Writes to OUTDIR (default ``picog-day/``): ``params_<plan>.json`` (PARAMS.json
products), ``upload_matrices.json``, ``metrics.csv`` (overall and per-disturber power
reduction against the truth, exact by linearity; the paper's two band PSD ratios; the
reduction after each order), ``remnants.csv`` (Table-2 style: ramp sizes, spike heights
and high-frequency peak-to-peak in the raw, cleaned and exact-remnant series at the
simulator's event times), and plots.

Run: ``python workflows/picog_day.py [OUTDIR] [--seed N]``
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pandas as pd

from magcal.ac.chain import Order, Plan, Stage, apply_weights, run_chain
from magcal.ac.metrics import (band_reduction, disturbance_power_ratio, hf_peak_to_peak,
                               ramp_sizes, spike_heights)
from magcal.ac.plan import plan_to_dict
from magcal.ac.plots import plot_psd, plot_raw_vs_clean, plot_scan
from magcal.io.jsonio import write_json
from magcal.offline import configure_offline
from magcal.provenance import make_provenance

SENSORS = ("fgmo", "fgmi", "amr1", "amr2")
WINDOWS_S = (100.0, 700.0, 16000.0)
HIGHPASS_S = 1800.0


def paper_plan(md_start_s: float, *, direction: str = "variance",
               highpass_s: float | None = None, n_orders: int = 3) -> Plan:
    """§4: AMR1 cleans both fluxgates on the midnight disturbance, then the boom pair
    with 100, 700 and 16000 s windows (``n_orders`` of them)."""
    kw = {"direction": direction, "highpass_s": highpass_s}
    return Plan("fgmo", (
        Stage("reference", ("fgmo", "fgmi"), reference="amr1",
              orders=(Order(interval=(md_start_s + 600.0, md_start_s + 4500.0), **kw),)),
        Stage("pair", ("fgmo", "fgmi"),
              orders=tuple(Order(window_s=w, **kw) for w in WINDOWS_S[:n_orders]))))


def coherent_plan(md_start_s: float, n_orders: int = 3) -> Plan:
    """The paper's stages and windows with ambient-free directions and 30 min high-pass."""
    return paper_plan(md_start_s, direction="coherent", highpass_s=HIGHPASS_S,
                      n_orders=n_orders)


TONE_BAND_HZ = (0.1664, 0.1669)


def joint_plan(md_start_s: float) -> Plan:
    """Coherent reference stage, then the boom pair as one joint stage."""
    kw = {"direction": "coherent", "highpass_s": HIGHPASS_S}
    return Plan("fgmo", (
        Stage("reference", ("fgmo", "fgmi"), reference="amr1",
              orders=(Order(interval=(md_start_s + 600.0, md_start_s + 4500.0), **kw),)),
        Stage("pair", ("fgmo", "fgmi"), joint=True,
              orders=tuple(Order(window_s=w, **kw) for w in WINDOWS_S)
              + (Order(band_hz=TONE_BAND_HZ, **kw),))))


def regression_plan() -> Plan:
    """Non-orthogonal extension: all other sensors as references, 1 h detrending."""
    return Plan("fgmo", (Stage("regression", ("fgmo",), references=("fgmi", "amr1", "amr2"),
                               orders=(Order(detrend_s=3600.0),)),))


def params_payload(res, plan, sim_prov):
    return {"target": res.target, "M": {k: v.tolist() for k, v in res.M.items()},
            "G": res.G.tolist(), "steps": [s.to_dict() for s in res.steps],
            "identity_error": res.identity_error, "plan": plan_to_dict(plan),
            "provenance": make_provenance("workflows/picog_day", {"simulation": sim_prov})}


def per_disturber(truth, M) -> dict:
    """Power ratio of each disturber at fgmo before / after, exact by linearity: the
    remnant is ``sum_k M_k d_k`` with ``d_k`` its truth field at sensor ``k`` (no noise
    floor; for a linearly polarised disturber the ratio is the same in every band)."""
    return {d: disturbance_power_ratio(per["fgmo"], apply_weights({k: per[k] for k in M}, M))
            for d, per in truth.disturbances.items()}


def event_times_s(truth, times) -> dict:
    """Event times (s since the first sample) by class, from ``truth.events``."""
    t0 = times[0]
    ev = {k: (v - t0).total_seconds().to_numpy() for k, v in truth.events.items()}
    md = ev.get("midnight", np.zeros(0))
    return {"midnight_up": md[0::3], "midnight_down": md[1::3],
            "steps": ev.get("steps", np.zeros(0)), "spikes": ev.get("spikes", np.zeros(0)),
            "hf_noise": ev.get("hf_noise", np.zeros(0))}


def hf_intervals(events: dict) -> tuple[tuple, tuple] | None:
    """Quiet etalon (the first high-frequency off interval) and the disturbed interval
    between the next two spikes after it (the paper's Table 2 definition)."""
    hf, spikes = events["hf_noise"], np.sort(events["spikes"])
    if len(hf) < 2:
        return None
    quiet = (hf[0] + 5.0, hf[1] - 5.0)
    after = spikes[spikes > hf[1]]
    if len(after) < 2:
        return None
    return quiet, (after[0] + 30.0, after[1] - 30.0)


def remnant_rows(name, t_s, series: dict, events: dict) -> list[dict]:
    """Table-2 rows: mean |vector| of ramp sizes and spike heights, and the
    high-frequency peak-to-peak (module of the per-component values)."""
    rows = []
    for label, b in series.items():
        for cls in ("midnight_up", "midnight_down", "steps"):
            r = ramp_sizes(b, t_s, events[cls])
            if len(r):
                rows.append({"plan": name, "series": label, "class": f"{cls} ramp",
                             "n_events": len(r),
                             "mean_magnitude_nT": float(np.mean(np.linalg.norm(r, axis=1)))})
        s = spike_heights(b, t_s, events["spikes"])
        if len(s):
            rows.append({"plan": name, "series": label, "class": "spike height",
                         "n_events": len(s),
                         "mean_magnitude_nT": float(np.mean(np.linalg.norm(s, axis=1)))})
        iv = hf_intervals(events)
        if iv is not None:
            p2p = hf_peak_to_peak(b, t_s, *iv)
            rows.append({"plan": name, "series": label, "class": "hf peak-to-peak",
                         "n_events": 1, "mean_magnitude_nT": float(np.linalg.norm(p2p))})
    return rows


def evaluate(name, res, data, truth, t_s, events) -> tuple[list[dict], list[dict]]:
    """Metric rows and remnant rows of one fitted chain."""
    clean_truth = truth.clean("fgmo")
    rows = [{"plan": name, "quantity": "overall disturbance power ratio",
             "value": disturbance_power_ratio(data["fgmo"] - clean_truth,
                                              res.corrected - clean_truth)}]
    for d, r in per_disturber(truth, res.M).items():
        rows.append({"plan": name, "quantity": f"power ratio {d}", "value": r})
    for band in band_reduction(data["fgmo"], res.corrected, 1.0):
        lo, hi = band["band_s"]
        rows.append({"plan": name, "quantity": f"PSD ratio {lo:g}-{hi:g} s",
                     "value": band["mean_ratio"]})
    rows.append({"plan": name, "quantity": "max |sum M - I|", "value": res.identity_error})
    rows.append({"plan": name, "quantity": "max |one-step - iterative| nT",
                 "value": float(np.max(np.abs(apply_weights(data, res.M) - res.corrected)))})
    n_ill = sum(s.scan.get("n_ill_defined", 0) for s in res.steps if s.scan)
    rows.append({"plan": name, "quantity": "scan windows with ill-defined direction",
                 "value": float(n_ill)})
    remnant = sum(apply_weights({k: per[k] for k in res.M}, res.M)
                  for per in truth.disturbances.values())
    series = {"raw": data["fgmo"], "cleaned": res.corrected,
              "disturbance raw (truth)": truth.disturbance("fgmo"),
              "disturbance remnant (exact)": remnant}
    return rows, remnant_rows(name, t_s, series, events)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("outdir", nargs="?", default="picog-day")
    ap.add_argument("--seed", type=int, default=20190304)
    args = ap.parse_args(argv)
    configure_offline()
    from magcal.simulate.geostationary import GeostationaryConfig, simulate_geostationary

    out = Path(args.outdir)
    out.mkdir(parents=True, exist_ok=True)
    sim = simulate_geostationary(GeostationaryConfig.gk2a_like(),
                                 rng=np.random.default_rng(args.seed))
    truth = sim.truth
    t_s = (sim.times - sim.times[0]).total_seconds().to_numpy()
    data = {s: sim.sensor(s) for s in SENSORS}
    events = event_times_s(truth, sim.times)
    md0 = float(events["midnight_up"][0])
    rows, rem = [], []
    results = {}
    for name, plan in (("paper", paper_plan(md0)), ("coherent", coherent_plan(md0)),
                       ("regression", regression_plan()), ("joint", joint_plan(md0))):
        res = run_chain(data, t_s, plan, keep_scans=(name in ("paper", "coherent")))
        results[name] = res
        write_json(out / f"params_{name}.json", params_payload(res, plan, sim.provenance))
        r, m = evaluate(name, res, data, truth, t_s, events)
        rows += r
        rem += m
        fig = plot_raw_vs_clean(sim.times, data["fgmo"], res.corrected,
                                title=f"fgmo raw vs cleaned ({name})")
        fig.savefig(out / f"raw_vs_clean_{name}.png", dpi=110)
        fig = plot_psd(data["fgmo"], res.corrected, 1.0, title=f"fgmo PSD ({name})")
        fig.savefig(out / f"psd_{name}.png", dpi=110)
    # does each order help? (the paper stopped the AMR stage at one order for this)
    clean_truth = truth.clean("fgmo")
    for name, make in (("paper", lambda k: paper_plan(md0, n_orders=k)),
                       ("coherent", lambda k: coherent_plan(md0, n_orders=k))):
        for k in range(0, 3):
            plan = make(max(k, 1))
            if k == 0:
                plan = Plan("fgmo", plan.stages[:1])
            res = run_chain(data, t_s, plan)
            rows.append({"plan": name, "quantity": f"overall ratio after {k} pair order(s)",
                         "value": disturbance_power_ratio(data["fgmo"] - clean_truth,
                                                          res.corrected - clean_truth)})
    write_json(out / "upload_matrices.json",
               {name: {"M": {k: v.tolist() for k, v in r.M.items()}, "G": r.G.tolist()}
                for name, r in results.items()})
    for name in ("paper", "coherent"):
        for key, (scan, summ) in results[name].scans.items():
            fig = plot_scan(scan, summ, title=f"{name}: stage {key[0]} order {key[1]} {key[2]}")
            fig.savefig(out / f"scan_{name}_stage{key[0]}_order{key[1]}_{key[2]}.png", dpi=110)
    table = pd.DataFrame(rows)
    table.to_csv(out / "metrics.csv", index=False)
    remnants = pd.DataFrame(rem)
    remnants.to_csv(out / "remnants.csv", index=False)
    print(table.to_string(index=False))
    print()
    print(remnants.to_string(index=False))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
