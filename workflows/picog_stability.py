"""Parameter stability over a simulated year (Table-1 style, §4.2).

Refits the paper's plan on every 7th simulated GK-2A-like day, then reports the std of
the maximum-variance directions (deg) and of alpha per step, and Bmaxdev: the largest
change of the corrected field on the first day for parameter changes of one std (each
parameter alone, and all at once).

``--plan coherent`` or ``--plan joint`` refit the variants of ``workflows/picog_day.py``
instead; for every plan the spread of the product is also given as the largest change
of the corrected first day between any two refits' upload matrices.

Run: ``python workflows/picog_stability.py [OUTDIR] [--n-days 52] [--seed N] [--plan P]``
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from magcal.ac.chain import _wcombine
from magcal.ac.core import correction_matrix
from magcal.ac.metrics import bmaxdev
from magcal.io.jsonio import write_json
from magcal.offline import configure_offline
from magcal.provenance import make_provenance

SENSORS = ("fgmo", "fgmi", "amr1")


def rebuild_paper_M(steps: list[dict]) -> dict:
    """Upload matrices of the paper's chain from PARAMS-style steps (Eqs. 28-30)."""
    eye = np.eye(3)
    w = {s: {s: eye} for s in SENSORS}
    A = {(s["stage"], s["order"], s["i"]): correction_matrix(s["alpha"], s["direction_i"],
                                                             s["direction_ij"]) for s in steps}
    for s in ("fgmo", "fgmi"):
        w[s] = _wcombine(w[s], w["amr1"], A[(1, 1, s)])
    orders = sorted({k[1] for k in A if k[0] == 2})
    for n in orders:
        a_ij, a_ji = A[(2, n, "fgmo")], A[(2, n, "fgmi")]
        w["fgmo"], w["fgmi"] = _wcombine(w["fgmo"], w["fgmi"], a_ij), \
            _wcombine(w["fgmi"], w["fgmo"], a_ji)
    return w["fgmo"]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("outdir", nargs="?", default="picog-stability")
    ap.add_argument("--n-days", type=int, default=52)
    ap.add_argument("--seed", type=int, default=2019)
    ap.add_argument("--plan", choices=("paper", "coherent", "joint"), default="paper",
                    help="the paper's plan, its coherent variant, or the joint pair stage "
                         "(see workflows/picog_day.py)")
    args = ap.parse_args(argv)
    configure_offline()
    from tqdm import tqdm

    from magcal.ac.chain import run_chain
    from magcal.ac.stability import stability
    from magcal.simulate.geostationary import GeostationaryConfig, simulate_geostationary
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from picog_day import coherent_plan, joint_plan, paper_plan

    make_plan = {"paper": paper_plan, "coherent": coherent_plan, "joint": joint_plan}[args.plan]
    out = Path(args.outdir)
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(args.seed)
    start = pd.Timestamp("2019-01-06T00:00:00")
    refits, first = [], None
    for k in tqdm(range(args.n_days), desc=f"refits ({args.plan} plan), one day each",
                  unit="day"):
        day = start + pd.Timedelta(days=7 * k)
        sim = simulate_geostationary(GeostationaryConfig.gk2a_like(
            start=day.isoformat(), ambient_model="dipole"), rng=rng)
        t_s = (sim.times - sim.times[0]).total_seconds().to_numpy()
        data = {s: sim.sensor(s) for s in SENSORS}
        md0 = (sim.truth.events["midnight"][0] - sim.times[0]).total_seconds()
        res = run_chain(data, t_s, make_plan(md0))
        refits.append({"day": str(day.date()), "steps": [s.to_dict() for s in res.steps],
                       "M": res.M})
        if first is None:
            first = data
    # every refit's upload matrices applied to the first day: the spread of the product
    frame = pd.DataFrame({f"{s}_{c}": v[:, i] for s, v in first.items()
                          for i, c in enumerate("xyz")})
    table = stability(frame, refits)
    payload = {"plan": args.plan, "n_days": args.n_days, "steps": table["steps"],
               "bmaxdev_refits_nT": table["bmaxdev_nT"],
               "bmaxdev_refits_ac_nT": table["bmaxdev_ac_nT"]}
    if args.plan == "paper":  # Table 1 of the paper: one-std parameter deviations
        stab = [{k: v for k, v in row.items() if k != "kind"} for row in table["steps"]]
        payload["bmaxdev_one_std"] = bmaxdev(first, refits[0]["steps"], stab,
                                             rebuild_paper_M)
    pd.DataFrame(table["steps"]).to_csv(out / "stability.csv", index=False)
    write_json(out / "stability.json", {**payload, "provenance": make_provenance(
        "workflows/picog_stability", vars(args))})
    print(pd.DataFrame(table["steps"]).to_string(index=False))
    print(f"largest change of the corrected first day between two refits: "
          f"{table['bmaxdev_nT']:.3f} nT ({table['bmaxdev_ac_nT']:.3f} nT without the mean)")
    if args.plan == "paper":
        print(f"Bmaxdev (all one-std deviations at once): "
              f"{payload['bmaxdev_one_std']['all']:.3f} nT (paper: 0.186 nT)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
