"""Archive runs of ``magcal run`` on Dask: throughput, scaling, memory, incremental reruns.

Generates a simulated archive of 4-sensor daily CSV files (one day simulated and
written at a time: the archive is never in memory), holds back the last month, then
measures in the same run:

* the whole chain on 1 and on 2 local workers (samples per second, ratio);
* the same on a ``dask.distributed`` LocalCluster (2 workers): products identical to
  the local run, overhead against it;
* peak memory (largest single process; each run is a ``magcal run`` subprocess);
* the rerun with nothing changed, and the rerun after adding the held-back month,
  against the first run;
* a GOES-like sample (``--goes-days`` days of 10 Hz two-sensor data): the chain's
  seconds per day, where a partition's and a corrected day's time go, and the year
  extrapolated from them;
* the floor of this machine: the same kind of work (reading daily files) in one process
  and split over two, so the chain's ratio can be read against what the VM allows;
* the IRBEM fork pool of :func:`magcal.models.field.model_field_hpen` (``n_jobs=2``)
  against the same request split into Dask tasks on two local workers, and the model's
  share of a partition (is it worth turning the fork pool into Dask tasks?).

Every figure comes with the load average of the machine (other jobs share the cores).

Usage::

    python benchmarks/bench_archive.py [--days 365] [--cadence 1] [--month 30] [--keep DIR]
                                       [--goes-days 2] [--skip-archive]

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


def load() -> str:
    """The 1-minute load average (other jobs on the cores skew every timing)."""
    return f"load {os.getloadavg()[0]:.1f}"


def run(config: Path, out: Path, workers: int | None = None, scheduler: str | None = None
        ) -> tuple[float, float, float]:
    """``magcal run`` in a subprocess: (seconds, peak RSS of its largest process in MB,
    CPU seconds of the run and its workers)."""
    cmd = [sys.executable, "-m", "magcal", "run", str(config), "-o", str(out), "--quiet"]
    cmd += ["--workers", str(workers)] if workers else []
    cmd += ["--scheduler", scheduler] if scheduler else []
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=BASE_ENV)
    seconds = time.perf_counter() - start
    if proc.returncode not in (0, 3):
        raise SystemExit(f"magcal run failed ({proc.returncode}):\n{proc.stderr[-2000:]}")
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime + after.ru_stime) - (usage.ru_utime + usage.ru_stime)
    return seconds, max(after.ru_maxrss, usage.ru_maxrss) / 1024.0, cpu


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


def archive_figures(args, work: Path) -> None:
    """The archive runs: throughput, scaling, LocalCluster, memory, reruns."""
    work.mkdir(parents=True, exist_ok=True)
    window = 28 if args.days >= 60 else max(2, args.days // 4)
    (work / "PLAN.toml").write_text(PLAN)
    (work / "CHAIN.toml").write_text(CHAIN.format(window=window, step=max(1, window // 4)))
    t0 = time.perf_counter()
    n_all = generate(work, args.days, args.cadence)
    print(f"generated {args.days} daily files, {n_all} samples x 4 sensors at "
          f"{args.cadence:g} s in {time.perf_counter() - t0:.0f} s -> {work}", flush=True)
    held = sorted((work / "raw").glob("day_*.csv"))[args.days - args.month:]
    hold = work / "held"
    hold.mkdir(exist_ok=True)
    for p in held:
        shutil.move(p, hold / p.name)
    n = n_all * (args.days - args.month) // args.days
    cfg = work / "CHAIN.toml"
    l1 = load()
    t1, m1, c1 = run(cfg, work / "out1", workers=1)
    l2 = load()
    t2, m2, c2 = run(cfg, work / "out2", workers=2)
    same_w = differing(products(work / "out1"), products(work / "out2"))
    print(f"  1 worker: {stage_seconds(work / 'out1')}; 2 workers: "
          f"{stage_seconds(work / 'out2')}")
    print(f"first run over {args.days - args.month} days ({n} samples): 1 worker "
          f"{t1:.1f} s ({n / t1:,.0f} samples/s, {c1:.0f} CPU s, {l1} before), 2 workers "
          f"{t2:.1f} s ({n / t2:,.0f} samples/s, {c2:.0f} CPU s, {l2} before): ratio "
          f"{t1 / t2:.2f}; products {same_w}", flush=True)
    f1, f2 = parallel_floor(sorted((work / "raw").glob("day_*.csv"))[:12])
    print(f"floor of this machine for the same kind of work (reading 12 of the daily files "
          f"with magcal.io.formats.read_any, no magcal run): 1 process {f1:.1f} s, 2 "
          f"processes {f2:.1f} s, ratio {f1 / f2:.2f} ({load()}); magcal's ratio is "
          f"{(t1 / t2) / (f1 / f2):.2f} of it", flush=True)
    from distributed import LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=None) as cluster:
        l3 = load()
        t3, m3, _ = run(cfg, work / "out3", scheduler=cluster.scheduler_address)
    same_d = differing(products(work / "out3"), products(work / "out2"))
    print(f"LocalCluster (2 workers): {t3:.1f} s, {t3 / t2:.2f}x the local scheduler's time "
          f"({l3} before); products {same_d}")
    print(f"peak memory of the largest process: {max(m1, m2, m3):.0f} MB "
          "(driver or one worker; the local run holds the driver and 2 workers)")
    t4, _, _ = run(cfg, work / "out2", workers=2)
    print(f"rerun, nothing changed: {t4:.1f} s = {100 * t4 / t2:.1f}% of the first run "
          f"({load()})")
    for p in held:
        shutil.move(hold / p.name, work / "raw" / p.name)
    t5, _, _ = run(cfg, work / "out2", workers=2)
    print(f"rerun after adding {args.month} days: {t5:.1f} s = {100 * t5 / t2:.1f}% of the "
          f"first run ({load()}); {stage_seconds(work / 'out2')}", flush=True)


def _read_files(paths) -> int:
    from magcal.io.formats import read_any

    return sum(len(read_any(p)) for p in paths)


def parallel_floor(files) -> tuple[float, float]:
    """Seconds to read ``files`` in one process, and split over two spawned processes:
    the speed-up any parallel code can reach on this machine for partition-like work
    (both vCPUs of a shared VM do not always run two processes at full speed)."""
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    ctx = mp.get_context("spawn")
    with ProcessPoolExecutor(1, mp_context=ctx) as ex:
        ex.submit(_read_files, files[:1]).result()  # start-up and imports outside the timing
        t0 = time.perf_counter()
        ex.submit(_read_files, files).result()
        one = time.perf_counter() - t0
    with ProcessPoolExecutor(2, mp_context=ctx) as ex:
        list(ex.map(_read_files, [files[:1], files[1:2]]))
        t0 = time.perf_counter()
        list(ex.map(_read_files, [files[0::2], files[1::2]]))
        two = time.perf_counter() - t0
    return one, two


#: Functions whose cumulative time tells where a partition's or corrected day's time goes.
PROFILE_PARTS = {"read": "read_any", "frames and PiCoG upload": "apply_upload",
                 "1-min averages": "average_to_cadence", "model field": "model_field_hpen",
                 "write partition": "write_partition", "write corrected CSV": "write_day_csv",
                 "apply offsets": "apply_offsets"}


def profile_parts(func, arg) -> tuple[float, dict]:
    """``func(arg)`` under cProfile: (seconds, {part: cumulative seconds})."""
    import cProfile
    import pstats

    prof = cProfile.Profile()
    start = time.perf_counter()
    prof.runcall(func, arg)
    seconds = time.perf_counter() - start
    stats = pstats.Stats(prof).stats
    parts = {}
    for part, name in PROFILE_PARTS.items():
        cum = [v[3] for (_, _, fn), v in stats.items() if fn == name]
        if cum:
            parts[part] = max(cum)
    return seconds, parts


def goes_figures(days: int, work: Path) -> None:
    """A GOES-like sample: ``days`` days of 10 Hz two-sensor data through the chain on
    2 workers; seconds per day and the year extrapolated; where a day's time goes."""
    import json

    import pandas as pd

    from magcal.chain import read_chain_config
    from magcal.chain.archive import DayTask, write_corrected_day
    from magcal.chain.partition import FrameApply, PartitionTask, run_partition
    from magcal.indices.kp import write_kp_csv
    from magcal.io.csv import write_csv_frame
    from magcal.offsets import read_offsets_csv
    from magcal.simulate.archive import ArchiveConfig, simulate_archive

    raw = work / "raw"
    raw.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(2025)
    t0 = time.perf_counter()
    kps = []
    for k, r in enumerate(rng.spawn(days)):
        day = pd.Timestamp("2019-03-01") + pd.Timedelta(days=k)
        res = simulate_archive(ArchiveConfig(start=day.isoformat(), n_days=1, cadence_s=0.1,
                                             step_time="2019-07-01"), rng=r)
        index = pd.DatetimeIndex(res.times, name="time").tz_localize("UTC")
        table = pd.DataFrame(np.hstack([res.outboard, res.inboard]), index=index,
                             columns=[f"{s}_{c}" for s in ("fgmo", "fgmi") for c in "xyz"])
        write_csv_frame(raw / f"day_{day:%Y%m%d}.csv", table, float_format="%.3f")
        kps.append(res.kp_3h)
        del res, table
    write_kp_csv(raw / "kp.csv", pd.concat(kps))
    (work / "PLAN.toml").write_text(PLAN)
    (work / "CHAIN.toml").write_text(CHAIN.format(window=1, step=1).replace(
        "min_used = 100", "min_used = 10"))
    n = days * 864_000
    print(f"GOES-like sample: {days} day(s) of 10 Hz two-sensor data ({n} samples per "
          f"sensor) generated in {time.perf_counter() - t0:.0f} s", flush=True)
    before = load()
    seconds, peak, cpu = run(work / "CHAIN.toml", work / "out", workers=2)
    doc = json.loads((work / "out" / "MANIFEST.json").read_text())
    stages = {s["stage"]: s["seconds"] for s in doc["stages"]}
    part_s = doc["partitions"]["seconds"]
    corr_s = stages.get("corrected", 0.0)
    fixed = seconds - part_s - corr_s
    per_day = (part_s + corr_s) / days
    print(f"  chain on 2 workers: {seconds:.0f} s ({cpu:.0f} CPU s, peak {peak:.0f} MB, "
          f"{before} before): partitions {part_s:.0f} s, corrected {corr_s:.0f} s, the rest "
          f"(fit on the first days, offsets, alignment, discovery, start-up) {fixed:.0f} s")
    print(f"  a year of 10 Hz two-sensor data on this machine: about {365 * per_day / 3600:.1f}"
          f" h of partitions and corrected days (2 workers, {per_day:.0f} s per day) plus the"
          f" once-per-run stages (~{fixed:.0f} s here; discovery and alignment grow with the "
          f"span but run on means or the 1-min record)", flush=True)
    # where one day's time goes (in this process, one worker's view)
    cfg = read_chain_config(work / "CHAIN.toml")
    fit_doc = json.loads(next((work / "out" / ".partitions").glob("fit-*.json")).read_text())
    f = fit_doc["fit"]
    fit = FrameApply(key=f["key"], sensors=tuple(f["sensors"]), target=f["target"],
                     transforms={s: (np.asarray(m), np.asarray(o)) for s, (m, o) in
                                 f["transforms"].items()},
                     to_hpen=np.asarray(f["to_hpen"]), upload=f["upload"])
    day_file = sorted(raw.glob("day_*.csv"))[0]
    task = PartitionTask(config=cfg, file=str(day_file), sha256="-", key="-",
                         result=str(work / "profile.npz"), fit=fit)
    p_s, p_parts = profile_parts(run_partition, task)
    table = read_offsets_csv(work / "out" / "offsets" / "OFFSETS.csv")
    day = day_file.stem.split("_")[1]
    c_s, c_parts = profile_parts(write_corrected_day, DayTask(
        f"{day[:4]}-{day[4:6]}-{day[6:]}", (str(work / "profile.npz"),), table,
        str(work / "profile.csv"), {}))
    print("  one day, profiled in one process: partition {:.1f} s ({}); corrected day "
          "{:.1f} s ({})".format(p_s, ", ".join(f"{k} {v:.1f}" for k, v in p_parts.items()),
                                 c_s, ", ".join(f"{k} {v:.1f}" for k, v in c_parts.items())))
    model_share = p_parts.get("model field", 0.0) / max(p_s + c_s, 1e-9)
    print(f"  the model field is {100 * model_share:.1f}% of a day's partition + corrected "
          "time at 10 Hz (evaluated at 60 s, interpolated)", flush=True)


def _model_chunk(job):
    """One chunk of a model request (a Dask task)."""
    from magcal.models.field import model_field_hpen

    times, kp = job
    return model_field_hpen(times, 128.2, 0.0, 6.6, "T89", kp=kp, cadence_s=None,
                            n_jobs=1).b_hpen_nT


def irbem_figures(n_points: int = 525_600) -> None:
    """The IRBEM fork pool (n_jobs=2) against the same request as 2 Dask tasks (a year
    of 1-min points by default)."""
    from magcal.chain.engine import Engine
    from magcal.models.field import model_field_hpen

    times = (np.datetime64("2019-03-01", "ns")
             + np.arange(n_points) * np.timedelta64(60, "s"))
    kp = np.full(n_points, 1.0)

    def timed(func):
        start = time.perf_counter()
        out = func()
        return time.perf_counter() - start, out

    before = load()
    t1, b1 = timed(lambda: model_field_hpen(times, 128.2, 0.0, 6.6, "T89", kp=kp,
                                            cadence_s=None, n_jobs=1).b_hpen_nT)
    t2, b2 = timed(lambda: model_field_hpen(times, 128.2, 0.0, 6.6, "T89", kp=kp,
                                            cadence_s=None, n_jobs=2).b_hpen_nT)
    half = n_points // 2
    jobs = [(times[:half], kp[:half]), (times[half:], kp[half:])]
    with Engine(workers=2) as engine:
        engine.map(_model_chunk, jobs[:1], "warm-up")  # spawn the pool outside the timing
        t3, b3 = timed(lambda: np.vstack(engine.map(_model_chunk, jobs, "model")))
    same = np.array_equal(b1, b2) and np.array_equal(b1, b3)
    print(f"IRBEM T89 at {n_points} points ({before}): in-process {t1:.1f} s, fork pool "
          f"n_jobs=2 {t2:.1f} s ({t1 / t2:.2f}x), 2 Dask tasks on 2 local workers "
          f"{t3:.1f} s ({t1 / t3:.2f}x); fields {'identical' if same else 'DIFFER'}",
          flush=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--days", type=int, default=365)
    ap.add_argument("--cadence", type=float, default=1.0)
    ap.add_argument("--month", type=int, default=30, help="days held back, then added")
    ap.add_argument("--keep", default=None, help="work folder (kept); default a temp dir")
    ap.add_argument("--goes-days", type=int, default=2,
                    help="days of the 10 Hz GOES-like sample (0: skip)")
    ap.add_argument("--skip-archive", action="store_true",
                    help="only the GOES sample and the IRBEM figures")
    args = ap.parse_args(argv)
    work = Path(args.keep or tempfile.mkdtemp(prefix="bench-archive-"))
    work.mkdir(parents=True, exist_ok=True)
    if not args.skip_archive:
        archive_figures(args, work / "archive")
    if args.goes_days:
        goes_figures(args.goes_days, work / "goes")
    irbem_figures()
    if not args.keep:
        shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
