"""``magcal run`` on messy configurations and index files: numbers out of range, named
files that do not exist and a Kp file of another year are exit 2 naming the key before
the partitions run; the discovery stage takes its covariate file at the file's own times
(an hourly Dst with fill values and holes) and says what it left out.
"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose

from magcal.chain import parse_chain_config
from magcal.cli import main
from magcal.errors import InputError

MINIMAL = '[input]\nfiles = ["raw/*.csv"]\ntarget = "fgmo"\n[position]\nlongitude_deg = 128.2\n'


@pytest.mark.parametrize("extra, key", [
    ("[offsets]\nkp_max = nan\n", "offsets.kp_max"),
    ("[offsets]\nkp_max = -1\n", "offsets.kp_max"),
    ("[offsets]\nwindow_days = inf\n", "offsets.window_days"),
    ("[offsets]\nmin_used = -5\n", "offsets.min_used"),
    ("[offsets]\ncadence_s = -60\n", "offsets.cadence_s"),
    ("[model]\ncadence_s = 0\n", "model.cadence_s"),
    ("[model]\njobs = 0\n", "model.jobs"),
    ("[alignment]\nkp_max = -2\n", "alignment.kp_max"),
    ("[alignment]\nseed = -3\n", "alignment.seed"),
    ("[alignment]\nlt_harmonics = \"many\"\n", "alignment.lt_harmonics"),
    ("[alignment]\nwindow_days = \"weekly\"\n", "alignment.window_days"),
    ("[discover]\nmax_effects = -1\n", "discover.max_effects"),
])
def test_numbers_out_of_range_name_the_key(extra, key):
    """Each of these ran to exit 0 (a Kp threshold no sample meets, no effect), failed a
    late stage (exit 3) or crashed (exit 1: lt_harmonics, window_days, seed)."""
    with pytest.raises(InputError) as info:
        parse_chain_config(MINIMAL + extra, "CHAIN.toml")
    assert info.value.column == key and info.value.file == "CHAIN.toml"


@pytest.mark.parametrize("text", ["longitude_deg = 500", "longitude_deg = nan"])
def test_a_longitude_out_of_range_is_refused(text):
    with pytest.raises(InputError, match="longitude_deg must be -360 to 360"):
        parse_chain_config(MINIMAL.replace("longitude_deg = 128.2", text), "CHAIN.toml")


def test_the_documented_defaults_pass():
    cfg = parse_chain_config(MINIMAL + "[alignment]\nwindow_days = 0\nlt_harmonics = 2\n",
                             "CHAIN.toml")
    assert cfg["alignment"]["window_days"] == 0 and cfg["discover"]["max_effects"] == 8


@pytest.mark.parametrize("section, key, value", [
    ("discover", "covariates", "raw/nodst.csv"), ("truth", "file", "raw/notruth.csv"),
    ("kp", "file", "raw/nokp.csv"), ("alignment", "reference", "noref.csv"),
    ("picog", "plan", "NOPLAN.toml"), ("discover", "covariates", "raw/empty.csv"),
    ("kp", "file", "raw/empty.csv")])
def test_a_named_file_that_does_not_exist_is_exit_2_before_any_partition(
        tmp_path, capsys, section, key, value):
    """A typo in a path used to fail only its stage (exit 3) after the whole run; so did
    an empty covariate file (``raw/empty.csv``, 0 bytes)."""
    raw = tmp_path / "raw"
    raw.mkdir()
    (raw / "empty.csv").write_text("")
    (raw / "day.csv").write_text("time,fgmo_x,fgmo_y,fgmo_z\n2019-11-01T00:00:00,1,2,3\n")
    cfg = tmp_path / "CHAIN.toml"
    cfg.write_text(MINIMAL + f'[{section}]\n{key} = "{value}"\n')
    assert main(["run", str(cfg), "-o", str(tmp_path / "out"), "--workers", "1",
                 "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"[{section}] {key}" in err[0] and value in err[0]
    assert not (tmp_path / "out" / ".partitions").exists()


@pytest.mark.parametrize("text, says", [
    ("time,dst\n", "no data rows"),
    ("time,Dst\n2019-11-01T00:00:00,-20\n2019-11-01T01:00:00,-21\n",
     "no covariate column")])
def test_a_covariate_file_discovery_cannot_use_is_exit_2_before_any_partition(
        tmp_path, capsys, text, says):
    """A header-only covariate file, or one whose column is ``Dst`` instead of ``dst``,
    used to fail the discovery stage alone (exit 3) after every partition had run."""
    raw = tmp_path / "raw"
    raw.mkdir()
    (raw / "dst.csv").write_text(text)
    (raw / "day.csv").write_text("time,fgmo_x,fgmo_y,fgmo_z\n2019-11-01T00:00:00,1,2,3\n")
    cfg = tmp_path / "CHAIN.toml"
    cfg.write_text(MINIMAL + '[discover]\ncovariates = "raw/dst.csv"\n')
    assert main(["run", str(cfg), "-o", str(tmp_path / "out"), "--workers", "1",
                 "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "[discover] covariates" in err[0] and says in err[0]
    assert "dst.csv" in err[0]
    assert not (tmp_path / "out" / ".partitions").exists()


def test_a_kp_file_of_another_year_is_exit_2_naming_both_spans(tmp_path):
    """Every partition's minutes without Kp: bad input, not a run with no offset, no
    model and exit 3."""
    from magcal.chain.runner import check_kp_coverage

    kp = tmp_path / "kp.csv"
    kp.write_text("time,kp\n2018-11-01T00:00:00,1.0\n2018-11-01T03:00:00,2.0\n")
    cfg = parse_chain_config(MINIMAL + '[kp]\nfile = "kp.csv"\n', tmp_path / "CHAIN.toml")
    records = [{"n_minutes": 1440, "n_no_kp": 1440, "start": "2019-11-01 00:00:00",
                "end": "2019-11-01 23:59:00"}]
    with pytest.raises(InputError, match="covers none of the data") as info:
        check_kp_coverage(cfg, records)
    assert "2018-11-01T00:00" in str(info.value) and "2019-11-01 00:00" in str(info.value)
    assert info.value.column == "kp.file"
    records.append(dict(records[0], n_no_kp=100))  # one day with Kp: the per-file warnings
    check_kp_coverage(cfg, records)


def _minutes(days=10, coupling=0.3, seed=2):
    """A 1-min record whose Hp responds to an hourly Dst by ``coupling`` nT/nT."""
    from magcal.chain.prepare import MinuteData

    rng = np.random.default_rng(seed)
    t = pd.date_range("2019-11-01", periods=days * 1440, freq="1min")
    day = np.asarray((t - t[0]).total_seconds() / 86400.0)
    dst = np.zeros(t.size)
    for onset, depth in ((2.2, -90.0), (6.4, -50.0)):
        after = day >= onset
        dst[after] += depth * np.exp(-(day[after] - onset) / 1.0)
    lt = (t.hour + t.minute / 60 + 128.2 / 15) % 24
    model = np.column_stack([100 + 10 * np.cos(2 * np.pi * (lt - 12) / 24),
                             5 * np.sin(2 * np.pi * lt / 24), -20 + 3 * np.cos(day)])
    hpen = model + rng.normal(0, 1.0, model.shape) + [5.0, -2.0, 1.0]
    hpen[:, 0] += coupling * dst
    n = t.size
    kp = np.repeat(rng.integers(0, 7, n // 180 + 1) / 3.0, 180)[:n]  # 3-hourly, no effect
    minute = MinuteData(t.to_numpy(), hpen, model, kp, np.full(n, 128.2), np.zeros(n),
                        np.full(n, 6.6))
    hourly = pd.Series(dst, index=t.tz_localize("UTC"), name="dst").resample("1h").mean()
    return minute, hourly


def test_chain_discovery_takes_an_hourly_dst_with_fills_at_its_own_times(tmp_path):
    """An hourly Dst file (as the Kyoto WDC publishes it) with 25 hours of 99999: the
    fills are missing values, the holes they make (two adjacent fills and more) are
    left out and counted, and the Dst response is the injected 0.3 nT/nT. Before, the
    fills were interpolated as Dst (the activity was not named: a diurnal twice)."""
    from magcal.chain.calibrate import run_discovery
    from magcal.io.csv import write_csv_frame

    minute, hourly = _minutes()
    fills = np.arange(5, 230, 9)
    hourly.iloc[fills] = 99999.0
    hourly.iloc[100:104] = 99999.0  # one hole of 4 h: not bridged
    write_csv_frame(tmp_path / "dst.csv", hourly.to_frame(), float_format="%.2f")
    cfg = parse_chain_config(MINIMAL + '[discover]\ncovariates = "dst.csv"\n',
                             tmp_path / "CHAIN.toml")
    doc, product = run_discovery(minute, cfg)
    bad = np.unique(np.r_[fills, 100:104])
    cov = doc["covariates"]["dst"]
    assert cov["used"] and cov["out_of_range"] == bad.size
    # a lone fill is a 2 h step between values (interpolated); a run of k >= 2 is a hole
    # of k + 1 hours whose (k + 1) * 60 - 1 inner minutes are left out (here 100-104)
    runs = np.split(bad, np.flatnonzero(np.diff(bad) > 1) + 1)
    inner = sum((r.size + 1) * 60 - 1 for r in runs if r.size >= 2)
    assert inner == 6 * 60 - 1
    assert doc["screened"]["covariate_unknown"] == inner
    act = next(e for e in doc["effects"] if e["name"] == "activity")
    assert_allclose(act["parameters"]["values"]["Hp"]["coefficient_nT_per_nT_dst"], 0.3,
                    atol=0.03)
    assert any("outside its physical range" in w for w in product.warnings)
    assert json.dumps(doc)  # JSON-ready


def test_chain_discovery_refuses_a_covariate_file_without_a_covariate(tmp_path):
    """A Dst column named ``Dst``: the file was silently ignored, now the stage fails
    naming the file and its columns."""
    from magcal.chain.calibrate import run_discovery
    from magcal.io.csv import write_csv_frame

    minute, hourly = _minutes(days=2)
    write_csv_frame(tmp_path / "dst.csv", hourly.rename("Dst").to_frame())
    cfg = parse_chain_config(MINIMAL + '[discover]\ncovariates = "dst.csv"\n',
                             tmp_path / "CHAIN.toml")
    with pytest.raises(InputError, match="no covariate column.*the file has Dst"):
        run_discovery(minute, cfg)
