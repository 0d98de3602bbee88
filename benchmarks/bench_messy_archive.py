"""Benchmark: the products of a 35-day archive with bad samples against the clean run's.

The done-when case of issue 20: a 35-day archive of raw two-sensor files at 30 s
(simulated, seed 7, no rotation between data and model: the true angles are 0), run
through ``magcal run`` clean, with spikes (one component at 1e6 nT every 97th sample
of one day) and with saturation (every component of the target at 65535 nT for 400
samples). For each faulty run it prints, against the clean run measured here:

* the alignment: each angle's distance from the truth in its stated std (target
  within 3) and its std over the clean run's (target within 10 %);
* the offsets: the spread (std over the windows, per component) over the clean run's
  (target within 10 %);
* the injected bad samples that carry a quality flag (target at least 95 %).

Run: ``python benchmarks/bench_messy_archive.py [--folder DIR]`` (about 5 minutes on
2 cores; the folder keeps the runs for inspection).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

from magcal.cli import main as magcal
from magcal.simulate.archive import ArchiveConfig, simulate_archive, write_archive_files
from magcal.simulate.faults import Fault, inject_faults

CHAIN = """
[input]
files = ["raw/day_*"]
target = "fgmo"
sensors = ["fgmo", "fgmi"]
frame = "hpen"
[position]
longitude_deg = 128.2
[kp]
file = "raw/kp.csv"
[picog]
plan = "auto"
[alignment]
reference = "model"
[discover]
covariates = "raw/dst.csv"
[truth]
file = "raw/truth.csv"
"""
HPEN = ("Hp", "He", "Hn")


def run(folder: Path) -> tuple[int, float]:
    (folder / "CHAIN.toml").write_text(CHAIN)
    tic = time.perf_counter()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        status = magcal(["run", str(folder / "CHAIN.toml"), "-o", str(folder / "out"),
                         "--quiet"])
    return status, time.perf_counter() - tic


def products(folder: Path) -> dict:
    out = folder / "out"
    align = json.loads((out / "alignment" / "ALIGN.json").read_text())
    offsets = pd.read_csv(out / "offsets" / "OFFSETS.csv")
    quality = pd.concat([pd.read_csv(p, usecols=["time", "quality"])
                         for p in sorted((out / "corrected").glob("CORRECTED_*.csv"))])
    return {"angles": align["angles_deg"], "std": align["std_deg"],
            "spread": {c: float(offsets[c].std(ddof=1)) for c in HPEN},
            "quality": quality.set_index("time")["quality"]}


def bad_times(raw_clean: Path, raw_faulty: Path, day: str) -> pd.Index:
    """Times of the samples the fault changed (compared with the clean file)."""
    name = f"day_{day.replace('-', '')}.csv"
    a = pd.read_csv(raw_clean / name, index_col="time")
    b = pd.read_csv(raw_faulty / name, index_col="time")
    changed = ~np.isclose(a.to_numpy(), b.reindex(a.index).to_numpy(), equal_nan=True)
    return a.index[changed.any(axis=1)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--folder", type=Path, default=None)
    args = ap.parse_args()
    root = args.folder or Path(tempfile.mkdtemp(prefix="messy-"))
    clean = root / "clean"
    shutil.rmtree(clean, ignore_errors=True)
    res = simulate_archive(ArchiveConfig(n_days=35, cadence_s=30.0), rng=np.random.default_rng(7))
    write_archive_files(res, clean / "raw")
    status, seconds = run(clean)
    ref = products(clean)
    print(f"clean: exit {status}, {seconds:.0f} s; angles "
          + ", ".join(f"{c} {ref['angles'][c]:+.3f}+-{ref['std'][c]:.3f}" for c in HPEN)
          + " deg; offset spread " + ", ".join(f"{ref['spread'][c]:.3f}" for c in HPEN) + " nT")
    ok_all = status == 0
    for kind in ("spikes", "saturation"):
        folder = root / kind
        shutil.rmtree(folder, ignore_errors=True)
        shutil.copytree(clean / "raw", folder / "raw")
        done = inject_faults(folder / "raw", [Fault(kind, day=12)], rng=np.random.default_rng(3))
        status, seconds = run(folder)
        got = products(folder)
        bad = bad_times(clean / "raw", folder / "raw", done[0].days[0])
        q = got["quality"]
        flagged = float(np.mean(q.reindex(bad.str.replace("Z", "")).fillna(0)
                                .to_numpy().astype(int) & 47 != 0)) if len(bad) else 1.0
        z = {c: abs(got["angles"][c]) / got["std"][c] for c in HPEN}
        sr = {c: got["std"][c] / ref["std"][c] for c in HPEN}
        spr = {c: got["spread"][c] / ref["spread"][c] for c in HPEN}
        ok = (status == 0 and max(z.values()) <= 3 and all(abs(v - 1) <= 0.1 for v in sr.values())
              and all(abs(v - 1) <= 0.1 for v in spr.values()) and flagged >= 0.95)
        ok_all &= ok
        print(f"{kind}: exit {status}, {seconds:.0f} s, {len(bad)} bad samples, "
              f"{flagged:.1%} flagged (target >= 95 %)")
        print("  |angle - truth| / std: " + ", ".join(f"{c} {z[c]:.2f}" for c in HPEN)
              + " (target <= 3)")
        print("  std / clean std:       " + ", ".join(f"{c} {sr[c]:.3f}" for c in HPEN)
              + " (target 0.9-1.1)")
        print("  offset spread / clean: " + ", ".join(f"{c} {spr[c]:.3f}" for c in HPEN)
              + " (target 0.9-1.1)")
        print(f"  {'met' if ok else 'MISSED'}")
    print(f"all targets {'met' if ok_all else 'MISSED'}; runs in {root}")


if __name__ == "__main__":
    main()
