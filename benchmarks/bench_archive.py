"""Archive runs of ``magcal run`` on Dask: throughput, scaling, memory, incremental reruns.

Generates a simulated archive of 4-sensor daily CSV files (one day simulated and
written at a time: the archive is never in memory), holds back the last month, then
measures in the same run:

* the whole chain on 1 and on 2 local workers (samples per second, ratio);
* the same on a ``dask.distributed`` LocalCluster (2 workers): products identical to
  the local run, overhead against it;
* peak memory (largest single process; each run is a ``magcal run`` subprocess);
* the rerun with nothing changed, and the rerun after adding the held-back month,
  against the first run.

Usage::

    python benchmarks/bench_archive.py [--days 365] [--cadence 1] [--month 30] [--keep DIR]

The defaults are the full year at 1 s (about 31.5 million samples per sensor: long on
a shared 2-core machine); ``--days 20 --month 5`` is a quick check.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

#: The environment before any LocalCluster: creating one sets OMP/OPENBLAS_NUM_THREADS=1
#: in this process, which the magcal subprocesses would inherit (and discovery's BLAS
#: sums differ in the last bits with the thread count).
BASE_ENV = dict(os.environ, MPLBACKEND="Agg")

PLAN = """target = "fgmo"
direction = "coherent"
highpass_s = 1800
[[stage]]
pair = ["fgmo", "fgmi"]
orders = [ { window_s = 3600 }, { window_s = 36000 } ]
"""

CHAIN = """[input]
files = ["raw/day_*.csv"]
target = "fgmo"
sensors = ["fgmo", "fgmi"]
[position]
longitude_deg = 128.2
[kp]
file = "raw/kp.csv"
[picog]
plan = "PLAN.toml"
[offsets]
window_days = {window}
step_days = {step}
min_used = 100
[alignment]
mcmc = false
[discover]
max_effects = 4
[report]
enabled = false
"""


def generate(folder: Path, days: int, cadence_s: float, seed: int = 2024) -> int:
    """Write ``days`` daily 4-sensor files (fgmo, fgmi and two more fluxgates on the
    boom: same ambient field, other offsets and disturber gains) and the Kp file."""
    import pandas as pd

    from magcal.indices.kp import write_kp_csv
    from magcal.io.csv import write_csv_frame
    from magcal.simulate.archive import ArchiveConfig, simulate_archive

    raw = folder / "raw"
    raw.mkdir(parents=True, exist_ok=True)
    rngs = np.random.default_rng(seed).spawn(days)
    kps, n = [], 0
    start = pd.Timestamp("2019-01-01")
    for k in range(days):
        day = start + pd.Timedelta(days=k)
        res = simulate_archive(ArchiveConfig(start=day.isoformat(), n_days=1,
                                             cadence_s=cadence_s, step_time="2019-07-01",
                                             offset_start_nT=(14.8 + 0.04 * k,
                                                              38.4 - 0.03 * k,
                                                              -89.8 + 0.02 * k)), rng=rngs[k])
        dist = res.outboard - res.clean_outboard
        extra = [res.clean_outboard + np.asarray(d) + g * dist
                 for d, g in (((2.0, -3.0, 5.0), 2.0), ((-4.0, 1.0, 3.0), 0.5))]
        index = pd.DatetimeIndex(res.times, name="time").tz_localize("UTC")
        table = pd.DataFrame(np.hstack([res.outboard, res.inboard] + extra), index=index,
                             columns=[f"{s}_{c}" for s in ("fgmo", "fgmi", "fgm3", "fgm4")
                                      for c in "xyz"])
        write_csv_frame(raw / f"day_{day:%Y%m%d}.csv", table, float_format="%.3f")
        kps.append(res.kp_3h)
        n += len(table)
    write_kp_csv(raw / "kp.csv", pd.concat(kps))
    return n


def run(config: Path, out: Path, workers: int | None = None, scheduler: str | None = None
        ) -> tuple[float, float]:
    """``magcal run`` in a subprocess: (seconds, peak RSS of its largest process in MB)."""
    cmd = [sys.executable, "-m", "magcal", "run", str(config), "-o", str(out), "--quiet"]
    cmd += ["--workers", str(workers)] if workers else []
    cmd += ["--scheduler", scheduler] if scheduler else []
    before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    start = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=BASE_ENV)
    seconds = time.perf_counter() - start
    if proc.returncode not in (0, 3):
        raise SystemExit(f"magcal run failed ({proc.returncode}):\n{proc.stderr[-2000:]}")
    peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    return seconds, max(peak, before) / 1024.0


def differing(a: dict, b: dict) -> str:
    """``identical`` or the product files that differ."""
    names = sorted(k for k in set(a) | set(b) if a.get(k) != b.get(k))
    return "identical" if not names else "DIFFER: " + ", ".join(names)


def stage_seconds(out: Path) -> str:
    """Where the time of the last run into ``out`` went (from its MANIFEST.json)."""
    import json

    doc = json.loads((out / "MANIFEST.json").read_text())
    parts = [f"partitions {doc['partitions']['seconds']:.1f}"]
    parts += [f"{s['stage']} {s['seconds']:.1f}" for s in doc["stages"] if s["seconds"] >= 0.5]
    return ", ".join(parts) + " s"


def products(out: Path) -> dict:
    skip = (".partitions", "previous")
    return {p.relative_to(out).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(out.rglob("*")) if p.is_file() and p.name != "MANIFEST.json"
            and not any(s in p.relative_to(out).parts for s in skip)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--days", type=int, default=365)
    ap.add_argument("--cadence", type=float, default=1.0)
    ap.add_argument("--month", type=int, default=30, help="days held back, then added")
    ap.add_argument("--keep", default=None, help="work folder (kept); default a temp dir")
    args = ap.parse_args(argv)
    work = Path(args.keep or tempfile.mkdtemp(prefix="bench-archive-"))
    work.mkdir(parents=True, exist_ok=True)
    window = 28 if args.days >= 60 else max(2, args.days // 4)
    (work / "PLAN.toml").write_text(PLAN)
    (work / "CHAIN.toml").write_text(CHAIN.format(window=window, step=max(1, window // 4)))
    t0 = time.perf_counter()
    n_all = generate(work, args.days, args.cadence)
    print(f"generated {args.days} daily files, {n_all} samples x 4 sensors at "
          f"{args.cadence:g} s in {time.perf_counter() - t0:.0f} s -> {work}")
    held = sorted((work / "raw").glob("day_*.csv"))[args.days - args.month:]
    hold = work / "held"
    hold.mkdir(exist_ok=True)
    for p in held:
        shutil.move(p, hold / p.name)
    n = n_all * (args.days - args.month) // args.days
    cfg = work / "CHAIN.toml"
    t1, m1 = run(cfg, work / "out1", workers=1)
    t2, m2 = run(cfg, work / "out2", workers=2)
    same_w = differing(products(work / "out1"), products(work / "out2"))
    print(f"  1 worker: {stage_seconds(work / 'out1')}; 2 workers: "
          f"{stage_seconds(work / 'out2')}")
    print(f"first run over {args.days - args.month} days ({n} samples): 1 worker "
          f"{t1:.1f} s ({n / t1:,.0f} samples/s), 2 workers {t2:.1f} s "
          f"({n / t2:,.0f} samples/s): ratio {t1 / t2:.2f}; products {same_w}")
    from distributed import LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=None) as cluster:
        t3, m3 = run(cfg, work / "out3", scheduler=cluster.scheduler_address)
    same_d = differing(products(work / "out3"), products(work / "out2"))
    print(f"LocalCluster (2 workers): {t3:.1f} s, {t3 / t2:.2f}x the local scheduler's time; "
          f"products {same_d}")
    print(f"peak memory of the largest process: {max(m1, m2, m3):.0f} MB "
          "(driver or one worker; the local run holds the driver and 2 workers)")
    t4, _ = run(cfg, work / "out2", workers=2)
    print(f"rerun, nothing changed: {t4:.1f} s = {100 * t4 / t2:.1f}% of the first run")
    for p in held:
        shutil.move(hold / p.name, work / "raw" / p.name)
    t5, _ = run(cfg, work / "out2", workers=2)
    print(f"rerun after adding {args.month} days: {t5:.1f} s = {100 * t5 / t2:.1f}% of the "
          "first run")
    if not args.keep:
        shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
