"""Binary in, binary out (issue 23): GOES-format 10 Hz two-sensor netCDF days through
``magcal run`` to netCDF products, against this machine's floor measured in the same run.

Generates ``--days`` simulated days of 10 Hz two-sensor data written as GOES-R MAG L2
netCDF4 files (``b_ob_sensor``, ``b_ib_sensor``, ``b_epn``, ``b_gse``, ``b_gsm``,
``orbit_llr_geo``, float32 as GOES writes them; one day simulated and written at a time),
then prints:

* **floor**: reading one input day's bytes with h5py alone, and writing the product's
  bytes (time, Hp, He, Hn, offset_flag, quality; the same compression) with h5py alone and
  with cdflib alone; magcal's reader and writers of the same day against it, and CSV for comparison;
* **where a day's time goes**: one partition and one corrected day profiled in one
  process (cProfile: read, frames/PiCoG upload, 1-min averages, model, writes);
* **per day per worker**: partition + corrected of one day in one process (target
  <= 1.5 s);
* **the chain** on 1 and on 2 workers (``magcal run`` subprocesses): wall seconds, per
  day, the 1 -> 2 ratio (target >= 1.8x on 120 days) against the floor's ratio (the same
  files read in one process and split over two), peak memory (target <= 1.5 GB), the
  year extrapolated on 2 workers (target <= 15 min);
* **fixed cost per run** (``--fixed-days``, 30 s cadence, target <= 3 s at 35 days):
  the wall time not spent in partitions and corrected days.

Usage::

    python benchmarks/bench_formats.py [--days 120] [--fixed-days 35] [--keep DIR]
                                       [--skip-chain]

The full figures need an idle machine: ``--days 120 --fixed-days 35`` (about 12 min of
generation and runs). ``--days 3 --fixed-days 5`` is a quick check.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

# one BLAS thread, as the chain's workers run (engine.py): the in-process profile of a
# day then sees what a worker sees (threaded BLAS on (n, 3) @ (3, 3) is 10x slower here)
_USER_ENV = dict(os.environ, MPLBACKEND="Agg")  # what the magcal run subprocesses get
for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_archive  # noqa: E402
from bench_archive import load, parallel_floor, profile_parts, run  # noqa: E402

bench_archive.BASE_ENV = _USER_ENV

# the allocator settings of the chain's workers (engine.keep_freed_memory, their pool's
# initializer), so the in-process day and the floor see what a worker sees
from magcal.chain.engine import keep_freed_memory  # noqa: E402
from timing import best  # noqa: E402  (this folder, run as a script)

keep_freed_memory()

CHAIN = """[input]
files = ["raw/*.nc"]
target = "ob"
sensors = ["ob", "ib"]
[frames]
# the simulated sensors are already in Hpen: the identity, given as a matrix
to_common = {{ ob = [[1, 0, 0], [0, 1, 0], [0, 0, 1]], ib = [[1, 0, 0], [0, 1, 0], [0, 0, 1]] }}
to_hpen = "identity"
[position]
columns = true
[kp]
file = "raw/kp.csv"
[picog]
plan = "none"
fit_days = 1
[offsets]
window_days = {window}
step_days = {step}
min_used = 10
[alignment]
enabled = false
[discover]
enabled = false
[report]
enabled = false
[output]
format = "netcdf"
"""

#: J2000 epoch of GOES-R time variables.
_GOES_EPOCH = np.datetime64("2000-01-01T12:00:00", "ns")

#: Parts of a day's time (function names in the profile).
PARTS = {"read GOES netCDF": "read_any", "frames and PiCoG upload": "apply_frame",
         "1-min averages": "average_to_cadence", "model field": "model_field_hpen",
         "write partition": "write_partition", "apply offsets": "apply_offsets",
         "quality control (magcal.qc)": "quality_control",
         "write corrected netCDF": "write_day_product"}


def write_goes_day(path: Path, times: np.ndarray, ob: np.ndarray, ib: np.ndarray,
                   lon_deg: float) -> None:
    """One day as a GOES-R MAG L2 hires file (sensor frames = Hpen here)."""
    import h5netcdf

    n = len(times)
    comp = {"compression": "gzip", "compression_opts": 1, "shuffle": True,
            "chunks": (min(n, 86_400), 3)}
    with h5netcdf.File(path, "w") as f:
        f.dimensions = {"time": n, "coordinate": 3}
        t = f.create_variable("time", ("time",), float, fillvalue=-9999.0,
                              chunks=(min(n, 86_400),), compression="gzip",
                              compression_opts=1)
        t[:] = (times.astype("datetime64[ns]") - _GOES_EPOCH).astype(np.int64) / 1e9
        t.attrs["units"] = "seconds since 2000-01-01 12:00:00"
        epn = ob[:, [1, 0, 2]]  # EPN order: He (E), Hp (P), Hn (N)
        for name, values in (("b_ob_sensor", ob), ("b_ib_sensor", ib), ("b_epn", epn),
                             ("b_gse", ob), ("b_gsm", ob)):
            v = f.create_variable(name, ("time", "coordinate"), np.float32,
                                  fillvalue=-9999.0, **comp)
            v[:] = values.astype(np.float32)
        o = f.create_variable("orbit_llr_geo", ("time", "coordinate"), np.float32,
                              fillvalue=-9999.0, **comp)
        o[:] = np.tile(np.array([0.0, lon_deg, 42164e3], np.float32), (n, 1))
        o.attrs["units"] = "'degrees, degrees, meters'"
        b = f.create_variable("b_total", ("time",), np.float32, fillvalue=-9999.0,
                              chunks=(min(n, 86_400),), compression="gzip",
                              compression_opts=1)
        b[:] = np.linalg.norm(ob, axis=1).astype(np.float32)


def generate(folder: Path, days: int, cadence_s: float, seed: int = 2025) -> int:
    """``days`` GOES-format daily files and a Kp CSV in ``folder``; samples per sensor."""
    import pandas as pd

    from magcal.indices.kp import write_kp_csv
    from magcal.simulate.archive import ArchiveConfig, simulate_archive

    folder.mkdir(parents=True, exist_ok=True)
    kps, n = [], 0
    for k, r in enumerate(np.random.default_rng(seed).spawn(days)):
        day = pd.Timestamp("2019-03-01") + pd.Timedelta(days=k)
        res = simulate_archive(ArchiveConfig(start=day.isoformat(), n_days=1,
                                             cadence_s=cadence_s, step_time="2019-07-01"),
                               rng=r)
        write_goes_day(folder / f"goes_{day:%Y%m%d}.nc", np.asarray(res.times),
                       res.outboard, res.inboard, lon_deg=-75.2)
        kps.append(res.kp_3h)
        n += len(res.times)
        del res
    write_kp_csv(folder / "kp.csv", pd.concat(kps))
    return n


# ------------------------------------------------------------------------------ floor
def floor_figures(day_file: Path, work: Path) -> dict:
    """The bytes of one day read and written with h5py / cdflib alone, and magcal's
    reader and writers of the same day."""
    import h5py
    import pandas as pd

    from magcal.chain.daily_csv import write_day_csv
    from magcal.chain.output import write_day_product
    from magcal.io.cdf import datetime64_to_tt2000
    from magcal.io.formats import read_any

    def h5_read():
        with h5py.File(day_file, "r") as f:
            return {k: f[k][()] for k in f.keys() if isinstance(f[k], h5py.Dataset)}

    floor_read, raw = best(h5_read)
    frame = read_any(day_file)
    n = len(frame)
    t_ns = frame.index.tz_localize(None).as_unit("ns").asi8
    hpen = frame[["Hp", "He", "Hn"]].to_numpy(float) + 0.123456789
    flag = np.zeros(n, np.int8)
    quality = np.zeros(n, np.uint16)  # the QC bit flags, written as int32 (CF flag masks)
    comp = {"compression": "gzip", "compression_opts": 1, "shuffle": True,
            "chunks": (min(n, 262_144),)}

    def h5_write():
        with h5py.File(work / "floor.h5", "w") as f:
            f.create_dataset("time", data=t_ns, **comp)
            for j, c in enumerate(("Hp", "He", "Hn")):
                f.create_dataset(c, data=np.ascontiguousarray(hpen[:, j]), **comp)
            f.create_dataset("offset_flag", data=flag, **comp)
            f.create_dataset("quality", data=quality.astype(np.int32), **comp)

    def cdf_write():
        import cdflib

        path = work / "floor.cdf"
        path.unlink(missing_ok=True)
        w = cdflib.cdfwrite.CDF(str(path), cdf_spec={"Majority": "Row_major"}, delete=True)
        spec = {"Rec_Vary": True, "Dim_Sizes": [], "Var_Type": "zVariable",
                "Num_Elements": 1, "Compress": 0}  # as magcal's products
        w.write_var({**spec, "Variable": "Epoch", "Data_Type": 33}, var_attrs={},
                    var_data=datetime64_to_tt2000(t_ns.astype("datetime64[ns]")))
        for j, c in enumerate(("Hp", "He", "Hn")):
            w.write_var({**spec, "Variable": c, "Data_Type": 45}, var_attrs={},
                        var_data=np.ascontiguousarray(hpen[:, j]))
        w.write_var({**spec, "Variable": "offset_flag", "Data_Type": 1}, var_attrs={},
                    var_data=flag)
        w.write_var({**spec, "Variable": "quality", "Data_Type": 4}, var_attrs={},
                    var_data=quality.astype(np.int32))
        w.close()

    floor_write, _ = best(h5_write)
    floor_cdf, _ = best(cdf_write)
    times = pd.DatetimeIndex(t_ns.astype("datetime64[ns]")).tz_localize("UTC")
    cols = {"Hp": hpen[:, 0], "He": hpen[:, 1], "Hn": hpen[:, 2], "offset_flag": flag,
            "quality": quality}
    read_s, _ = best(lambda: read_any(day_file))
    nc_s, _ = best(lambda: write_day_product(work / "day.nc", "netcdf", times, cols, {}))
    cdf_s, _ = best(lambda: write_day_product(work / "day.cdf", "cdf", times, cols, {}))
    csv_s, _ = best(lambda: write_day_csv(work / "day.csv", times, hpen, ("Hp", "He", "Hn"),
                                          flag, extra={"quality": quality}, provenance={}),
                      repeat=1)
    from magcal.io.products import read_product

    back_nc, _ = best(lambda: read_product(work / "day.nc"))
    back_cdf, _ = best(lambda: read_product(work / "day.cdf"))
    back_csv, _ = best(lambda: read_product(work / "day.csv"), repeat=1)
    mb = {s: (work / f"day.{s}").stat().st_size / 1e6 for s in ("nc", "cdf", "csv")}
    print(f"floor, one {n}-sample day ({load()}): h5py read of the GOES file "
          f"{floor_read:.2f} s; h5py write of the product's bytes {floor_write:.2f} s; "
          f"cdflib write {floor_cdf:.2f} s")
    print(f"  magcal read_any (GOES netCDF) {read_s:.2f} s = {read_s / floor_read:.1f}x floor")
    print(f"  write corrected day: netCDF {nc_s:.2f} s = {nc_s / floor_write:.1f}x h5py floor "
          f"({mb['nc']:.1f} MB); CDF {cdf_s:.2f} s = {cdf_s / floor_cdf:.1f}x cdflib floor "
          f"({mb['cdf']:.1f} MB); CSV {csv_s:.2f} s ({mb['csv']:.1f} MB)")
    print(f"  read the product back: netCDF {back_nc:.2f} s, CDF {back_cdf:.2f} s, CSV "
          f"{back_csv:.2f} s", flush=True)
    return {"read": (read_s, floor_read), "write_nc": (nc_s, floor_write),
            "write_cdf": (cdf_s, floor_cdf), "write_csv": csv_s}


# ------------------------------------------------------------------------------ chain
def per_day_figures(work: Path, day_file: Path) -> float:
    """One partition + one corrected day in this process, profiled; seconds."""
    import json

    from magcal.chain import read_chain_config
    from magcal.chain.archive import DayTask, write_corrected_day
    from magcal.chain.partition import FrameApply, PartitionTask, run_partition
    from magcal.offsets import read_offsets_csv

    cfg = read_chain_config(work / "CHAIN.toml")
    fit_doc = json.loads(next((work / "out2" / ".partitions").glob("fit-*.json")).read_text())
    f = fit_doc["fit"]
    fit = FrameApply(key=f["key"], sensors=tuple(f["sensors"]), target=f["target"],
                     transforms={s: (np.asarray(m), np.asarray(o)) for s, (m, o) in
                                 f["transforms"].items()},
                     to_hpen=np.asarray(f["to_hpen"]), upload=f["upload"])
    task = PartitionTask(config=cfg, file=str(day_file), sha256="-", key="-",
                         result=str(work / "profile.npz"), fit=fit)
    run_partition(task)  # imports and caches outside the timing
    table = read_offsets_csv(work / "out2" / "offsets" / "OFFSETS.csv")
    day = day_file.stem.split("_")[1]
    day_task = DayTask(f"{day[:4]}-{day[4:6]}-{day[6:]}", (str(work / "profile.npz"),),
                       table, str(work / "profile.nc"), {}, "netcdf")
    # the figure: best of three, unprofiled (cProfile adds 10-20 % to this code)
    p_s, _ = best(lambda: run_partition(task))
    c_s, _ = best(lambda: write_corrected_day(day_task))
    # where the time goes: one profiled pass
    _, p_parts = profile_parts_named(run_partition, task)
    _, c_parts = profile_parts_named(write_corrected_day, day_task)
    parts = {**p_parts, **c_parts}
    print(f"one day in one process (best of 3, {load()}): partition {p_s:.2f} s + corrected "
          f"{c_s:.2f} s = {p_s + c_s:.2f} s per day per worker (target <= 1.5 s); "
          "profiled: " + ", ".join(f"{k} {v:.2f}" for k, v in parts.items()), flush=True)
    return p_s + c_s


def profile_parts_named(func, arg):
    import bench_archive

    saved = bench_archive.PROFILE_PARTS
    bench_archive.PROFILE_PARTS = PARTS
    try:
        return profile_parts(func, arg)
    finally:
        bench_archive.PROFILE_PARTS = saved


def chain_figures(work: Path, days: int) -> dict:
    import json

    (work / "CHAIN.toml").write_text(CHAIN.format(window=1, step=1))
    results = {}
    for workers in (1, 2):
        out = work / f"out{workers}"
        shutil.rmtree(out, ignore_errors=True)
        before = load()
        seconds, peak, cpu = run(work / "CHAIN.toml", out, workers=workers)
        doc = json.loads((out / "MANIFEST.json").read_text())
        stages = {s["stage"]: s["seconds"] for s in doc["stages"]}
        busy = doc["partitions"]["seconds"] + stages.get("corrected", 0.0)
        results[workers] = (seconds, peak, busy)
        print(f"chain on {workers} worker(s), {days} GOES-format days to netCDF ({before}): "
              f"{seconds:.1f} s wall ({cpu:.0f} CPU s), partitions + corrected {busy:.1f} s "
              f"({busy / days:.2f} s per day), the rest {seconds - busy:.1f} s; peak "
              f"{peak:.0f} MB (target <= 1536 MB)", flush=True)
    one, two = results[1][0], results[2][0]
    files = sorted((work / "raw").glob("*.nc"))
    f1, f2 = parallel_floor(files[: max(2, min(len(files), 8))])
    year_s = 365 * results[2][2] / days + (results[2][0] - results[2][2])
    print(f"  1 -> 2 workers: {one / two:.2f}x (target >= 1.8x on 120 days); the floor "
          f"(reading the same files in 1 and 2 processes): {f1 / f2:.2f}x")
    print(f"  a year of such days on 2 workers: {year_s / 60:.1f} min (target <= 15 min)",
          flush=True)
    return {"speedup": one / two, "floor_speedup": f1 / f2, "year_min": year_s / 60,
            "peak_mb": max(results[1][1], results[2][1]),
            "per_day_1w": results[1][2] / days}


def fixed_figures(work: Path, days: int) -> float:
    """A ``days``-day 30 s archive: wall time not in partitions and corrected days."""
    import json

    generate(work / "raw", days, 30.0, seed=7)
    (work / "CHAIN.toml").write_text(CHAIN.format(window=7, step=7))
    seconds, peak, _ = run(work / "CHAIN.toml", work / "out", workers=2)
    doc = json.loads((work / "MANIFEST.json" if False else work / "out" / "MANIFEST.json"
                      ).read_text())
    stages = {s["stage"]: s["seconds"] for s in doc["stages"]}
    busy = doc["partitions"]["seconds"] + stages.get("corrected", 0.0)
    print(f"fixed cost per run, {days}-day 30 s archive on 2 workers ({load()}): "
          f"{seconds:.1f} s wall, partitions + corrected {busy:.1f} s, fixed "
          f"{seconds - busy:.1f} s (target <= 3 s); stages: "
          + ", ".join(f"{k} {v:.1f}" for k, v in stages.items()), flush=True)
    return seconds - busy


def summary(days: int, fixed_days: int, floor: dict, per_day: float | None,
            chain: dict | None, fixed: float | None) -> None:
    """Every figure of issue 23 part 3 with its target, in one block."""
    rows = [("read a GOES 10 Hz day (read_any)",
             f"{floor['read'][0]:.2f} s = {floor['read'][0] / floor['read'][1]:.1f}x "
             f"h5py floor ({floor['read'][1]:.2f} s)", "", None),
            ("write a corrected day, netCDF",
             f"{floor['write_nc'][0]:.2f} s = {floor['write_nc'][0] / floor['write_nc'][1]:.1f}x "
             f"h5py floor ({floor['write_nc'][1]:.2f} s); CSV {floor['write_csv']:.2f} s",
             "", None),
            ("write a corrected day, CDF",
             f"{floor['write_cdf'][0]:.2f} s = "
             f"{floor['write_cdf'][0] / floor['write_cdf'][1]:.1f}x cdflib floor "
             f"({floor['write_cdf'][1]:.2f} s)", "", None)]
    if per_day is not None:
        rows.append(("one day per worker (partition + corrected, one process)",
                     f"{per_day:.2f} s (chain on 1 worker: {chain['per_day_1w']:.2f} s/day)",
                     "<= 1.5 s", per_day <= 1.5))
        rows.append(("a year on 2 workers (extrapolated)", f"{chain['year_min']:.1f} min",
                     "<= 15 min", chain["year_min"] <= 15))
        rows.append((f"1 -> 2 workers on {days} days", f"{chain['speedup']:.2f}x (floor "
                     f"{chain['floor_speedup']:.2f}x)", ">= 1.8x on 120 days",
                     chain["speedup"] >= 1.8))
        rows.append(("peak memory", f"{chain['peak_mb']:.0f} MB", "<= 1536 MB",
                     chain["peak_mb"] <= 1536))
    if fixed is not None:
        rows.append((f"fixed cost per run ({fixed_days}-day 30 s archive)", f"{fixed:.1f} s",
                     "<= 3 s on 35 days", fixed <= 3.0))
    print(f"\nissue 23 part 3 figures ({load()}):")
    for name, value, target, ok in rows:
        verdict = "" if ok is None else ("met" if ok else "NOT met")
        print(f"  {name:<58} {value:<48} {target:<20} {verdict}")
    if days < 120 or (fixed is not None and fixed_days < 35):
        print("  (smaller than the issue's 120 / 35 days: a quick check, not the figures)")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--days", type=int, default=120, help="10 Hz GOES-format days")
    ap.add_argument("--fixed-days", type=int, default=35,
                    help="days of the 30 s archive for the fixed cost (0: skip)")
    ap.add_argument("--keep", type=Path, default=None, help="work folder kept after")
    ap.add_argument("--skip-chain", action="store_true", help="floor figures only")
    args = ap.parse_args(argv)
    work = args.keep or Path(tempfile.mkdtemp(prefix="bench_formats_"))
    try:
        t0 = time.perf_counter()
        n = generate(work / "goes" / "raw", args.days, 0.1)
        print(f"{args.days} GOES-format 10 Hz two-sensor days ({n} samples per sensor) "
              f"generated in {time.perf_counter() - t0:.0f} s", flush=True)
        day_file = sorted((work / "goes" / "raw").glob("*.nc"))[0]
        floor = floor_figures(day_file, work)
        per_day = chain = fixed = None
        if not args.skip_chain:
            chain = chain_figures(work / "goes", args.days)
            per_day = per_day_figures(work / "goes", day_file)
            if args.fixed_days:
                fixed = fixed_figures(work / "fixed", args.fixed_days)
        summary(args.days, args.fixed_days, floor, per_day, chain, fixed)
    finally:
        if args.keep is None:
            shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
