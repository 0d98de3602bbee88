"""Write ``data_samples/`` with magcal's own simulators and fixed seeds.

Usage::

    python workflows/make_data_samples.py [--out data_samples]

Every file is regenerated bit for bit from the seeds below (same magcal version and
library versions). Large tables are gzip-compressed CSV (pandas and ``magcal`` read
``.csv.gz`` directly); the folder must stay under 30 MB.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pandas as pd

from magcal import __version__
from magcal.io.csv import write_csv_frame
from magcal.io.jsonio import write_json
from magcal.offline import configure_offline
from magcal.provenance import make_provenance
from magcal.simulate.geostationary import GeostationaryConfig, simulate_geostationary
from magcal.simulate.month import MonthConfig, simulate_month
from magcal.simulate.spinning import SpinningConfig, simulate_spinning

SEEDS = {"geostationary": 20190304, "month": 20191101, "spinning": 19891031}
GEO_DAYS = 3


def _frame(times, columns: dict) -> pd.DataFrame:
    index = pd.DatetimeIndex(times, name="time")
    if index.tz is None:
        index = index.tz_localize("UTC")
    return pd.DataFrame(columns, index=index)


def make_geostationary(out: Path) -> dict:
    config = GeostationaryConfig.gk2a_like(duration_s=GEO_DAYS * 86400.0)
    sim = simulate_geostationary(config, rng=np.random.default_rng(SEEDS["geostationary"]))
    write_csv_frame(out / "geostationary_3days_1s.csv.gz", sim.measurements, float_format="%.2f")
    clean = sim.truth.clean("fgmo")
    truth = _frame(sim.measurements.index, {
        "fgmo_x": clean[:, 0], "fgmo_y": clean[:, 1], "fgmo_z": clean[:, 2],
        "Hp": sim.truth.ambient_hpen[:, 0], "He": sim.truth.ambient_hpen[:, 1],
        "Hn": sim.truth.ambient_hpen[:, 2]})
    write_csv_frame(out / "geostationary_3days_truth.csv.gz", truth, float_format="%.3f")
    return {"seed": SEEDS["geostationary"], "config": config.summary(),
            "ambient_model": sim.truth.ambient_model}


def make_month(out: Path) -> dict:
    config = MonthConfig()
    sim = simulate_month(config, rng=np.random.default_rng(SEEDS["month"]))
    write_csv_frame(out / "month_1min_hpen.csv.gz", sim.to_frame(), float_format="%.3f")
    write_csv_frame(out / "month_kp.csv", sim.kp_frame(), float_format="%.4f")
    write_csv_frame(out / "month_covariates.csv.gz", sim.covariates_frame(), float_format="%.3f")
    cols = {}
    for name, arr in (("offset", sim.offset_nT), ("local_time", sim.local_time_nT)):
        for k, comp in enumerate(("Hp", "He", "Hn")):
            cols[f"{name}_{comp}"] = arr[:, k]
    write_csv_frame(out / "month_truth.csv.gz", _frame(sim.times, cols), float_format="%.4f")
    return {"seed": SEEDS["month"], "config": {k: getattr(config, k) for k in
                                                config.__dataclass_fields__}}


def make_spinning(out: Path) -> dict:
    config = SpinningConfig.galileo_like(flip_intervals_s=((3.5 * 3600, 5 * 3600),))
    sim = simulate_spinning(config, rng=np.random.default_rng(SEEDS["spinning"]))
    write_csv_frame(out / "spinning_galileo_5h.csv.gz", sim.data, float_format="%.4f")
    write_json(out / "spinning_galileo_truth.json", {
        "coupling": sim.truth.coupling, "offsets": sim.truth.offsets_nT,
        "spin_period_s": config.spin_period_s, "seed": SEEDS["spinning"]})
    return {"seed": SEEDS["spinning"], "flip_intervals_s": config.flip_intervals_s}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(Path(__file__).resolve().parents[1] / "data_samples"))
    args = parser.parse_args(argv)
    configure_offline()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    record = {}
    for name, func in (("geostationary", make_geostationary), ("month", make_month),
                       ("spinning", make_spinning)):
        print(f"writing {name} ...", flush=True)
        record[name] = func(out)
    write_json(out / "provenance.json", {
        "made_by": "workflows/make_data_samples.py", "samples": record,
        "provenance": make_provenance("make_data_samples", {"seeds": SEEDS})})
    total = sum(p.stat().st_size for p in out.iterdir() if p.is_file())
    print(f"data_samples: {total / 1e6:.1f} MB (limit 30 MB), magcal {__version__}")
    if total > 30e6:
        raise SystemExit("data_samples/ exceeds 30 MB")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
