"""Archive runs of ``magcal run`` (issue 12): partitioned by file on Dask, incremental,
resumable, one bad file failing only its partition.

The archives are small simulations (``simulate_archive``, 1-min cadence, a few days) so
each run takes seconds. What the numbers are checked against:

* the partitioned 1-min record must equal the whole record processed in one piece by
  the stage functions (``load_series -> run_frames -> run_ac -> run_model``): an
  independent route through the same physics;
* the offset product must follow the offsets injected by the simulator;
* reruns, added files, killed runs, other worker counts and the distributed scheduler
  must all give products byte-identical to one uninterrupted local run.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from magcal.chain import read_chain_config, run_chain
from magcal.cli import main
from magcal.errors import InputError
from magcal.provenance import file_sha256

# one test process for the whole module (pyproject runs pytest with --dist loadgroup):
# its module fixtures (simulated archives and their runs) are then computed once instead
# of once per process
pytestmark = pytest.mark.xdist_group("chain_archive")

CHAIN = """
[input]
files = ["raw/day_*.csv"]
target = "fgmo"
sensors = ["fgmo", "fgmi"]
[position]
longitude_deg = 128.2
[kp]
file = "raw/kp.csv"
[picog]
plan = "{plan}"
fit_days = 3
[offsets]
window_days = 4
step_days = 2
min_used = 100
[alignment]
enabled = false
[discover]
enabled = false
[report]
enabled = false
"""

PLAN = """
target = "fgmo"
direction = "coherent"
highpass_s = 1800
[[stage]]
pair = ["fgmo", "fgmi"]
orders = [ { window_s = 3600 }, { window_s = 36000 } ]
"""


def _archive(folder: Path, n_days: int = 12, cadence_s: float = 60.0, seed: int = 5,
             plan: str = "none", stages: bool = False) -> Path:
    """Simulated raw daily files, Kp and truth in ``folder/raw``; the CHAIN.toml path.
    ``stages`` also runs the alignment and discovery (tasks on a worker)."""
    from magcal.simulate.archive import ArchiveConfig, simulate_archive, write_archive_files

    res = simulate_archive(ArchiveConfig(n_days=n_days, cadence_s=cadence_s,
                                         step_time="2019-11-07"),
                           rng=np.random.default_rng(seed))
    write_archive_files(res, folder / "raw")
    cfg = folder / "CHAIN.toml"
    text = CHAIN.format(plan=plan)
    if stages:
        text = text.replace("[alignment]\nenabled = false", "[alignment]\nenabled = true")
        text = text.replace("[discover]\nenabled = false",
                            "[discover]\nenabled = true\nmax_effects = 2")
    cfg.write_text(text)
    return cfg


def _products(out: Path) -> dict:
    """SHA-256 of every product file (not the manifest, the partition state, or the
    previous versions of OFFSETS.csv)."""
    skip = (".partitions", "previous")
    return {p.relative_to(out).as_posix(): file_sha256(p) for p in sorted(out.rglob("*"))
            if p.is_file() and p.name != "MANIFEST.json"
            and not any(part in skip for part in p.relative_to(out).parts)}


#: The environment before any engine of this module set its workers' BLAS threads: a
#: ``magcal run`` subprocess gets it, so its driver runs BLAS as this process's does.
_ENV = dict(os.environ)


@pytest.fixture(scope="module")
def engines():
    """A pool of one and a pool of two local worker processes shared by the module's
    runs (``run_chain(engine=...)``): a run on its own pool spends a second or more
    spawning its workers and importing the library in them."""
    from magcal.chain.engine import Engine

    with Engine(1) as one, Engine(2) as two:
        yield {1: one, 2: two}


@pytest.fixture(scope="module")
def archive(tmp_path_factory, engines):
    """One 12-day archive run with two local workers, alignment and discovery included."""
    tmp = tmp_path_factory.mktemp("archive")
    cfg = _archive(tmp, stages=True)
    out = tmp / "out"
    result = run_chain(cfg, out, engine=engines[2])
    return tmp, cfg, out, result


def test_partitioned_record_equals_the_whole_record_in_one_piece(archive):
    from magcal.chain import prepare

    _, cfg_path, out, result = archive
    assert not result.failed and len(result.partitions.done) == 12
    cfg = read_chain_config(cfg_path)
    files = cfg.input_files()
    series = prepare.load_series(cfg, files)
    common, _ = prepare.run_frames(series, cfg)
    cleaned, _ = prepare.run_ac(common, cfg)
    whole, _ = prepare.run_model(series, cleaned, cfg)
    table = pd.read_csv(out / "model" / "DATA_HPEN.csv", comment="#")
    model = pd.read_csv(out / "model" / "MODEL.csv", comment="#")
    assert len(table) == len(whole.times) == 12 * 1440
    np.testing.assert_allclose(table[["Hp", "He", "Hn"]].to_numpy(), whole.hpen, atol=2e-6)
    np.testing.assert_allclose(model[["Hp", "He", "Hn"]].to_numpy(), whole.model, atol=2e-6)
    # the corrected daily files hold every input sample once
    n_raw = sum(len(pd.read_csv(p, usecols=["time"])) for p in files)
    corrected = sorted((out / "corrected").glob("CORRECTED_*.csv"))
    assert len(corrected) == 12
    assert sum(len(pd.read_csv(p, comment="#")) for p in corrected) == n_raw


def test_offset_product_follows_the_injected_offsets(archive):
    from magcal.offsets import read_offsets_csv

    tmp, _, out, _ = archive
    table = read_offsets_csv(out / "offsets" / "OFFSETS.csv")
    truth = pd.read_csv(tmp / "raw" / "truth.csv", comment="#", index_col="time",
                        parse_dates=True)
    true = truth[[f"offset_{c}" for c in ("Hp", "He", "Hn")]]
    true.index = pd.DatetimeIndex(true.index).tz_localize(None).as_unit("ns")
    centers = pd.DatetimeIndex(table.center)
    assert list(centers.strftime("%m-%d")) == ["11-03", "11-05", "11-07", "11-09", "11-11"]
    at = true.reindex(centers, method="nearest").to_numpy()
    # 4-day windows clear of the step (the local-time field T89 lacks is sampled over
    # 4 days only, heater and tone left in with plan none) stay within 2 nT of the
    # injected offset, the one straddling it within the step; the change across the
    # step (windows 11-05 and 11-09 are clear of it) follows the injected 3/-2/1.5 nT
    # plus 4 days of drift within 0.5 nT
    clear = [0, 1, 3, 4]
    assert np.abs(table.offset_nT[clear] - at[clear]).max() < 2.0
    assert np.abs(table.offset_nT[2] - at[2]).max() < 3.0
    jump = table.offset_nT[3] - table.offset_nT[1]
    np.testing.assert_allclose(jump, at[3] - at[1], atol=0.5)
    np.testing.assert_allclose(at[3] - at[1], [3.16, -2.12, 1.58], atol=0.01)


def test_rerun_skips_every_partition_and_leaves_identical_products(archive, engines):
    _, cfg, out, _ = archive
    before = _products(out)
    again = run_chain(cfg, out, engine=engines[2])
    assert again.partitions.done == () and len(again.partitions.skipped) == 12
    skipped = {r.stage for r in again.records if r.skipped}
    assert {"frames", "ac", "read", "model", "alignment", "discover"} <= skipped
    assert _products(out) == before
    assert not (out / "offsets" / "previous").exists()  # OFFSETS.csv unchanged


def test_other_worker_counts_give_byte_identical_products(archive, engines, tmp_path):
    _, cfg, out, _ = archive
    one = run_chain(cfg, tmp_path / "one", engine=engines[1])
    assert not one.failed
    assert _products(tmp_path / "one") == _products(out)


def test_added_files_recompute_only_their_partitions(tmp_path, engines):
    cfg = _archive(tmp_path, n_days=12)
    raw = tmp_path / "raw"
    later = sorted(raw.glob("day_*.csv"))[8:]
    hold = tmp_path / "later"
    hold.mkdir()
    for p in later:
        shutil.move(p, hold / p.name)
    out = tmp_path / "out"
    first = run_chain(cfg, out, engine=engines[2])
    assert len(first.partitions.done) == 8
    early = out / "corrected" / "CORRECTED_20191101.csv"
    stamp = early.stat().st_mtime_ns
    old_offsets = (out / "offsets" / "OFFSETS.csv").read_bytes()
    for p in later:
        shutil.move(hold / p.name, raw / p.name)
    update = run_chain(cfg, out, engine=engines[2])
    assert sorted(Path(f).name for f in update.partitions.done) == [p.name for p in later]
    assert len(update.partitions.skipped) == 8
    # a day far from the new files keeps its file (its offset windows did not change)
    assert early.stat().st_mtime_ns == stamp
    # the monthly product was replaced, the previous version kept
    assert (out / "offsets" / "previous" / "OFFSETS.1.csv").read_bytes() == old_offsets
    fresh = run_chain(cfg, tmp_path / "fresh", engine=engines[2])
    assert _products(out) == _products(tmp_path / "fresh")
    assert not fresh.failed


def test_a_corrupt_day_fails_only_its_partition(tmp_path, capsys):
    cfg = _archive(tmp_path, n_days=12)
    bad = tmp_path / "raw" / "day_20191107.csv"
    bad.write_bytes(b"time,fgmo_x\n\x00\x01\x02 not a day of data\n")
    out = tmp_path / "out"
    assert main(["run", str(cfg), "-o", str(out), "--quiet", "--workers", "2"]) == 3
    err = capsys.readouterr().err
    assert "day_20191107.csv" in err and "Traceback" not in err
    manifest = json.loads((out / "MANIFEST.json").read_text())
    failed = [f for f in manifest["failed"] if f["stage"] == "partition"]
    assert len(failed) == 1 and failed[0]["partition"].endswith("day_20191107.csv")
    assert failed[0]["reason"]
    corrected = sorted(p.name for p in (out / "corrected").glob("CORRECTED_*.csv"))
    assert len(corrected) == 11 and "CORRECTED_20191107.csv" not in corrected
    table = pd.read_csv(out / "offsets" / "OFFSETS.csv", keep_default_na=False)
    touches = (pd.to_datetime(table["start"]) < "2019-11-08") & (
        pd.to_datetime(table["end"]) > "2019-11-07")
    named = table["reason"].str.contains("day_20191107.csv failed")
    assert touches.any() and (named == touches).all()


def test_a_missing_day_fails_as_its_own_partition(tmp_path, capsys):
    cfg = _archive(tmp_path, n_days=12)
    (tmp_path / "raw" / "day_20191107.csv").unlink()  # a hole in the daily sequence
    out = tmp_path / "out"
    assert main(["run", str(cfg), "-o", str(out), "--quiet", "--workers", "2"]) == 3
    captured = capsys.readouterr()
    assert "failed 2019-11-07: no input file covers this day" in captured.out  # summary
    assert "2019-11-07" in captured.err and "Traceback" not in captured.err
    manifest = json.loads((out / "MANIFEST.json").read_text())
    failed = [f for f in manifest["failed"] if f["stage"] == "partition"]
    assert [f["partition"] for f in failed] == ["2019-11-07"]
    assert "day_20191106.csv and day_20191108.csv" in failed[0]["reason"]
    assert len(manifest["partitions"]["done"]) == 11
    table = pd.read_csv(out / "offsets" / "OFFSETS.csv", keep_default_na=False)
    touches = (pd.to_datetime(table["start"]) < "2019-11-08") & (
        pd.to_datetime(table["end"]) > "2019-11-07")
    named = table["reason"].str.contains("no input file for 2019-11-07")
    assert touches.any() and (named == touches).all()


def test_missing_days_are_the_uncovered_days_no_failed_file_explains():
    from magcal.chain.archive import missing_days

    ok = [{"file": f"d/day_{d}.csv", "days": [f"2019-11-{d}"]} for d in ("01", "02", "05",
                                                                         "08")]
    got = missing_days(ok, ())
    assert [m["partition"] for m in got] == ["2019-11-03", "2019-11-04", "2019-11-06",
                                            "2019-11-07"]
    # a corrupt file between 05 and 08 is named for that gap instead
    corrupt = ({"partition": "d/day_06.csv", "stage": "partition", "reason": "bad"},)
    assert [m["day"] for m in missing_days(ok, corrupt)] == ["2019-11-03", "2019-11-04"]


@pytest.mark.loopback
def test_an_unreachable_scheduler_is_exit_2_with_one_line(tmp_path, capsys, monkeypatch):
    import socket

    from magcal.chain import engine

    monkeypatch.setattr(engine, "CONNECT_TIMEOUT_S", 1.0)
    with socket.socket() as sock:  # a port nobody listens on once closed
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    cfg = _archive(tmp_path, n_days=2)
    start = time.monotonic()
    status = main(["run", str(cfg), "-o", str(tmp_path / "out"), "--quiet",
                   "--scheduler", f"tcp://127.0.0.1:{port}"])
    assert status == 2 and time.monotonic() - start < 10
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"cannot reach the dask scheduler tcp://127.0.0.1:{port}" in err[0]


def test_killed_run_resumes_to_the_uninterrupted_products(tmp_path, engines):
    cfg = _archive(tmp_path, n_days=16, cadence_s=10.0)
    whole = run_chain(cfg, tmp_path / "whole", engine=engines[2])
    assert not whole.failed
    out = tmp_path / "out"
    env = dict(_ENV, MPLBACKEND="Agg")
    cmd = [sys.executable, "-m", "magcal", "run", str(cfg), "-o", str(out), "--quiet",
           "--workers", "2"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            env=env, start_new_session=True)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        if len(list((out / ".partitions").glob("day_*.npz"))) >= 3:
            break
        time.sleep(0.05)
    killed = proc.poll() is None
    if killed:
        os.killpg(proc.pid, signal.SIGKILL)
    proc.wait(timeout=30)
    assert killed, "the run ended before it could be killed"
    resumed = run_chain(cfg, out, engine=engines[2])
    assert not resumed.failed and len(resumed.partitions.skipped) >= 3
    assert _products(out) == _products(tmp_path / "whole")
    assert not [p for p in out.rglob(".*") if p.is_file() and ".part" in p.name]


def test_fit_days_is_checked():
    from magcal.chain import parse_chain_config

    text = CHAIN.format(plan="none").replace("fit_days = 3", "fit_days = 0")
    with pytest.raises(InputError, match="fit_days must be positive"):
        parse_chain_config(text, "CHAIN.toml")
    text = CHAIN.format(plan="none").replace("fit_days = 3", "fit_days = 3\nfit_max_samples = 0")
    with pytest.raises(InputError, match="fit_max_samples must be at least 1"):
        parse_chain_config(text, "CHAIN.toml")


def test_the_fit_stops_at_fit_max_samples_and_says_so(tmp_path, engines):
    # 1440 samples a day: 3000 samples hold two whole days of the three fit_days allow
    cfg = _archive(tmp_path, n_days=4)
    cfg.write_text(cfg.read_text().replace("fit_days = 3", "fit_days = 3\nfit_max_samples = 3000"))
    out = tmp_path / "out"
    assert not run_chain(cfg, out, engine=engines[2]).failed
    ac = json.loads((out / "ac" / "AC.json").read_text())
    assert [Path(f).name for f in ac["fit_files"]] == ["day_20191101.csv", "day_20191102.csv"]
    assert ac["fit_samples"] == 2 * 1440 and ac["fit_capped_by_samples"] is True
    manifest = json.loads((out / "MANIFEST.json").read_text())
    assert len(manifest["partitions"]["done"]) == 4  # every day is still calibrated


def test_picog_is_fitted_on_the_first_days_and_applied_to_every_partition(tmp_path, engines):
    cfg = _archive(tmp_path, n_days=6, plan="PLAN.toml")
    (tmp_path / "PLAN.toml").write_text(PLAN)
    out = tmp_path / "out"
    result = run_chain(cfg, out, engine=engines[2])
    assert not result.failed
    ac = json.loads((out / "ac" / "AC.json").read_text())
    assert ac["delivered"] == "cleaned" and len(ac["fit_files"]) == 3
    # the disturbers are 4x stronger at the inboard sensor: the exact gradiometer
    # removes them from the outboard sensor on every day, not only the fitted ones
    truth = pd.read_csv(tmp_path / "raw" / "truth.csv", comment="#", index_col="time",
                        parse_dates=True)
    for day in ("20191102", "20191106"):
        got = pd.read_csv(out / "corrected" / f"CORRECTED_{day}.csv", comment="#",
                          index_col="time", parse_dates=True)
        both = got.join(truth, how="inner")
        resid = both[["Hp", "He", "Hn"]].to_numpy() - both[
            ["clean_Hp", "clean_He", "clean_Hn"]].to_numpy()
        resid -= resid.mean(axis=0)  # the offset and its drift over a day
        assert np.sqrt(np.mean(resid ** 2)) < 0.15  # raw disturbance rms is ~0.6 nT


@pytest.mark.loopback
def test_distributed_scheduler_gives_the_local_products(archive, tmp_path):
    distributed = pytest.importorskip("distributed")
    _, cfg, out, _ = archive
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  host="127.0.0.1", dashboard_address="127.0.0.1:0") as cluster:
        res = run_chain(cfg, tmp_path / "dist", scheduler=cluster.scheduler_address)
    assert not res.failed and "distributed" in res.manifest["engine"]
    assert _products(tmp_path / "dist") == _products(out)


def test_kp_records_invalidate_only_the_partitions_they_cover(tmp_path, engines):
    cfg = _archive(tmp_path, n_days=6)
    out = tmp_path / "out"
    run_chain(cfg, out, engine=engines[2])
    kp_path = tmp_path / "raw" / "kp.csv"
    lines = kp_path.read_text().splitlines()
    # a month of Kp appended after the archive's end: every partition stays valid
    last = pd.Timestamp(lines[-1].split(",")[0])
    extra = [f"{(last + pd.Timedelta(hours=3 * k)).isoformat()},1.0" for k in range(1, 240)]
    kp_path.write_text("\n".join(lines + extra) + "\n")
    again = run_chain(cfg, out, engine=engines[2])
    assert again.partitions.done == () and len(again.partitions.skipped) == 6
    # one Kp value changed at noon of 2019-11-04: only that day's partition is redone
    k = next(i for i, line in enumerate(lines) if line.startswith("2019-11-04T12:00:00"))
    lines[k] = "2019-11-04T12:00:00,7.0"
    kp_path.write_text("\n".join(lines + extra) + "\n")
    changed = run_chain(cfg, out, engine=engines[2])
    assert [Path(f).name for f in changed.partitions.done] == ["day_20191104.csv"]
    fresh = run_chain(cfg, tmp_path / "fresh", engine=engines[2])
    assert _products(out) == _products(tmp_path / "fresh") and not fresh.failed


def test_results_of_changed_or_removed_files_are_pruned(tmp_path, engines):
    cfg = _archive(tmp_path, n_days=6)
    out = tmp_path / "out"
    run_chain(cfg, out, engine=engines[2])
    state = out / ".partitions"
    assert len(list(state.glob("*.npz"))) == 6
    raw = sorted((tmp_path / "raw").glob("day_*.csv"))
    raw[-1].unlink()  # a day leaves the archive
    text = raw[3].read_text().splitlines()  # after the 3 days the fit uses
    raw[3].write_text("\n".join(text[:-1]) + "\n")  # a day changes (its last sample cut)
    again = run_chain(cfg, out, engine=engines[2])
    assert [Path(f).name for f in again.partitions.done] == [raw[3].name]
    names = sorted(p.name.rsplit("-", 1)[0] for p in state.glob("*.npz"))
    assert names == sorted(p.stem for p in raw[:-1])  # one result per file still there
    assert len(list(state.glob("fit-*.json"))) == 1


def test_discovery_is_given_means_of_a_long_record():
    from dataclasses import replace

    from magcal.chain.calibrate import discovery_interval, mean_record
    from magcal.chain.prepare import MinuteData

    def record(days):
        t = (np.datetime64("2019-01-01T00:00:30", "ns")
             + np.arange(int(days * 1440)) * np.timedelta64(60, "s"))
        x = np.arange(len(t), dtype=float)
        ramp = np.column_stack([x, 2 * x, -x])
        one = np.ones(len(t))
        return MinuteData(t, ramp, 0.5 * ramp, 0.1 * x, 128.0 * one, 0 * one, 6.6 * one)

    # at most 50,000 samples: the 1-min record up to 34 days, 10-min means for 335 days
    assert discovery_interval(record(30), 60.0) == 60.0
    assert discovery_interval(record(335), 60.0) == 600.0
    short = record(2)
    assert mean_record(short, 60.0, 60.0) is short
    hpen = short.hpen.copy()
    hpen[10:16] = np.nan  # 4 of the 10 minutes of the second bin left: under half
    means = mean_record(replace(short, hpen=hpen), 600.0, 60.0)
    assert len(means.times) == 2 * 144 - 1
    assert str(means.times[0]) == "2019-01-01T00:05:00.000000000"  # the bin's centre
    # a linear ramp's mean is its value at the bin's centre: minute 4.5, 24.5, ...
    np.testing.assert_allclose(means.hpen[:2, 0], [4.5, 24.5])
    np.testing.assert_allclose(means.model[:2, 1], [4.5, 24.5])
    np.testing.assert_allclose(means.kp[:2], [0.45, 2.45])
    np.testing.assert_allclose(means.r_re, 6.6)


@pytest.mark.parametrize("cadence", ["1s", "100ms"])
def test_corrected_day_writer_writes_the_bytes_of_write_csv_frame(tmp_path, cadence):
    # the fast writer of the corrected days must not change the product: the reference
    # is the library's CSV writer on the same frame
    from magcal.chain.daily_csv import write_day_csv
    from magcal.io.csv import write_csv_frame

    rng = np.random.default_rng(12)
    n = 5000
    times = pd.date_range("2019-11-01", periods=n, freq=cadence, tz="UTC")
    values = rng.normal(0.0, 100.0, (n, 3)) * rng.choice([1e-9, 1.0, 1e4], (n, 3))
    values[::7, 0] = -0.0
    flags = rng.integers(0, 4, n)
    prov = {"step": "offsets apply", "when": pd.Timestamp("2019-11-01")}
    frame = pd.DataFrame(values, index=times, columns=["Hp", "He", "Hn"])
    frame["offset_flag"] = flags
    for case, vals in (("finite", values), ("nan", np.where(values > 150, np.nan, values)),
                       ("inf", np.where(values > 150, np.inf, values))):
        frame[["Hp", "He", "Hn"]] = vals
        ref = write_csv_frame(tmp_path / f"ref_{case}.csv", frame, float_format="%.6f",
                              provenance=prov)
        got = write_day_csv(tmp_path / f"got_{case}.csv", times, vals, ("Hp", "He", "Hn"),
                            flags, provenance=prov)
        assert got.read_bytes() == ref.read_bytes(), case
        assert (Path(f"{got}.provenance.json").read_bytes()
                == Path(f"{ref}.provenance.json").read_bytes())
