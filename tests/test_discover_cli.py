"""``magcal discover`` end to end on a two-week synthetic record with a hidden diurnal term."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
from numpy.testing import assert_allclose

from magcal.cli import main
from magcal.io.csv import write_csv_frame

LON = 128.2


def geostationary_minutes(days: int):
    """A synthetic geostationary record at 1 min from 2019-11-01 (UTC): its times, local
    time (h) at :data:`LON`, a model whose Hp and He follow local time and Hn is
    constant, and a hidden 2 nT diurnal term in Hp the model lacks. Shared by the
    discovery tests (CLI, messy input, degenerate candidates)."""
    t = pd.date_range("2019-11-01", periods=days * 1440, freq="1min", tz="UTC", name="time")
    lt = (t.hour + t.minute / 60 + LON / 15) % 24
    model = pd.DataFrame({"Hp": 100 + 10 * np.cos(2 * np.pi * (lt - 12) / 24),
                          "He": 5 * np.sin(2 * np.pi * lt / 24), "Hn": -20.0 + 0 * lt},
                         index=t)
    hidden = np.column_stack([2.0 * np.cos(2 * np.pi * (lt - 13) / 24), 0 * lt, 0 * lt])
    return t, lt, model, hidden


def _files(tmp_path, rng, with_cov=True, days=14):
    t, lt, model, hidden = geostationary_minutes(days)
    noise = rng.normal(0, 1.0, (len(t), 3))
    meas = model + hidden + noise + np.array([3.0, -1.0, 0.5])
    paths = {"m": tmp_path / "measured.csv", "model": tmp_path / "model.csv",
             "cov": tmp_path / "cov.csv"}
    write_csv_frame(paths["m"], meas)
    write_csv_frame(paths["model"], model)
    if with_cov:
        cov = pd.DataFrame({"kp": np.full(len(t), 1.0), "lon_deg": np.full(len(t), LON)},
                           index=t)
        write_csv_frame(paths["cov"], cov)
    return paths


def test_cli_writes_contract_report(tmp_path, rng, capsys):
    p = _files(tmp_path, rng)
    out = tmp_path / "report.json"
    png = tmp_path / "gap.png"
    status = main(["discover", str(p["m"]), str(p["model"]), "--covariates", str(p["cov"]),
                   "--plot", str(png), "-o", str(out)])
    assert status == 0
    doc = json.loads(out.read_text())
    for key in ("schema_version", "magcal_version", "gap_initial", "effects", "gap_final",
                "stopped_because"):
        assert key in doc
    names = [e["name"] for e in doc["effects"]]
    assert names[:2] == ["offset", "diurnal"]
    for e in doc["effects"]:
        assert set(e) >= {"name", "components", "parameters", "rms_before_nT", "rms_after_nT",
                          "evidence"}
    d = doc["effects"][1]["parameters"]["derived"]["Hp"]
    assert_allclose(d["peak_to_peak_nT"], 4.0, atol=0.3)
    assert abs(d["peak_lt_h"] - 13.0) < 1.0
    assert_allclose(doc["gap_final"]["rms_nT"], 1.0, atol=0.05)  # the white-noise floor
    assert doc["effects"][0]["rms_before_nT"] == doc["gap_initial"]["rms_nT"]
    assert png.stat().st_size > 1000
    assert "diurnal" in capsys.readouterr().err


def test_cli_longitude_option_equals_lon_deg_column(tmp_path, rng):
    p = _files(tmp_path, rng, with_cov=False)
    out = tmp_path / "r.json"
    assert main(["discover", str(p["m"]), str(p["model"]), "--longitude", str(LON),
                 "-o", str(out)]) == 0
    names = [e["name"] for e in json.loads(out.read_text())["effects"]]
    assert "diurnal" in names


def test_cli_bad_input_exit_2_and_no_output(tmp_path, rng, capsys):
    p = _files(tmp_path, rng)
    out = tmp_path / "r.json"
    other = tmp_path / "other.csv"
    other.write_text("time,x,y\n2019-11-01T00:00:00,1,2\n2019-11-01T00:01:00,1,2\n")
    assert main(["discover", str(p["m"]), str(other), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "common" in err and "measured.csv" in err
    assert not out.exists()
    assert main(["discover", str(p["m"]), str(tmp_path / "missing.csv"), "-o", str(out)]) == 2
    assert not out.exists()


def test_cli_leaves_out_spikes_and_says_so(tmp_path, rng, capsys):
    """A week with a hidden diurnal term and 0.5 % of the samples spiked by 30-300 nT
    (either sign, every component): the default run leaves out exactly those samples,
    reports them, and reaches the effects and the white-noise floor (1 nT) of a
    spike-free record; with ``--no-screen`` (and no effect added) the spikes stay in
    the gap, several times the floor."""
    p = _files(tmp_path, rng, days=7)
    meas = pd.read_csv(p["m"], index_col=0)
    hit = rng.random(len(meas)) < 0.005
    size = rng.choice([-1.0, 1.0], (hit.sum(), 1)) * rng.uniform(30.0, 300.0, (hit.sum(), 3))
    meas.loc[hit, ["Hp", "He", "Hn"]] += size
    meas.to_csv(p["m"])
    out, raw = tmp_path / "screened.json", tmp_path / "raw.json"
    common = [str(p["m"]), str(p["model"]), "--covariates", str(p["cov"])]
    assert main(["discover", *common, "-o", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["screened"]["samples"] == int(hit.sum())
    first = pd.Timestamp(meas.index[hit][0])
    first = first if first.tz is not None else first.tz_localize("UTC")
    assert pd.Timestamp(doc["screened"]["first"]) == first
    assert [e["name"] for e in doc["effects"]][:2] == ["offset", "diurnal"]
    assert_allclose(doc["gap_final"]["rms_nT"], 1.0, atol=0.05)
    assert f"left out {int(hit.sum())} spike sample(s)" in capsys.readouterr().err
    assert main(["discover", *common, "--no-screen", "--max-effects", "0", "-o", str(raw)]) == 0
    doc = json.loads(raw.read_text())
    assert doc["screened"] == {} and doc["provenance"]["parameters"]["screen"] is False
    assert doc["gap_final"]["rms_nT"] > 3.0
