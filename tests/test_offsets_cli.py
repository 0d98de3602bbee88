"""magcal model / offsets fit / offsets apply on a simulated month (CONTRACTS §2)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose

from magcal.cli import main


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    from magcal.indices import write_kp_csv
    from magcal.io.csv import write_csv_frame
    from magcal.simulate.month import MonthConfig, simulate_month

    d = tmp_path_factory.mktemp("cli")
    res = simulate_month(MonthConfig(n_days=30, n_jobs=1), rng=np.random.default_rng(4))
    write_csv_frame(d / "DATA.csv", res.to_frame())
    write_kp_csv(d / "KP.csv", res.kp_3h, thirds=True)
    return d, res


def test_model_fit_apply_chain(files, capsys):
    d, res = files
    assert main([
        "model", str(d / "DATA.csv"), "--kp", str(d / "KP.csv"), "--longitude", "128.2",
        "--jobs", "1", "-o", str(d / "MODEL.csv")]) == 0
    model = pd.read_csv(d / "MODEL.csv")
    assert model.columns.tolist() == ["time", "Hp", "He", "Hn"]
    assert_allclose(model[["Hp", "He", "Hn"]].to_numpy(), res.model_nT, atol=1e-4)
    assert main([
        "offsets", "fit", str(d / "DATA.csv"), "--kp", str(d / "KP.csv"), "--longitude",
        "128.2", "--jobs", "1", "-o", str(d / "OFFSETS.csv")]) == 0
    off = pd.read_csv(d / "OFFSETS.csv", keep_default_na=False)
    assert off.columns.tolist()[:11] == ["center", "start", "end", "Hp", "He", "Hn", "Hp_std",
                                         "He_std", "Hn_std", "n_used", "fraction_used"]
    assert off["center"].tolist() == ["2019-11-15T00:00:00", "2019-11-22T00:00:00"]
    # the contract's offset: median of data minus model over Kp <= 1 in [start, end)
    q = res.kp <= 1.0 + 1e-9
    m = q & (res.times < np.datetime64("2019-11-29", "ns"))
    expect = np.median((res.measured_nT - res.model_nT)[m], axis=0)
    assert_allclose(off.loc[0, ["Hp", "He", "Hn"]].to_numpy(float), expect, atol=2e-4)
    assert off.loc[0, "n_used"] == m.sum()
    assert main(["offsets", "apply", str(d / "DATA.csv"), "--offsets", str(d / "OFFSETS.csv"),
                 "-o", str(d / "CORRECTED.csv")]) == 0
    corr = pd.read_csv(d / "CORRECTED.csv")
    assert corr.columns.tolist() == ["time", "Hp", "He", "Hn", "offset_flag"]
    assert set(corr["offset_flag"]) == {0, 1, 2}
    err = "\n".join(capsys.readouterr().err.splitlines())
    # a month holds too few days to look for level changes of the offset: said, not silent
    assert "2 windows (2 valid; record too short to look for level changes)" in err


def test_bad_input_exit_2_and_no_output(files, capsys):
    d, _ = files
    out = d / "never.csv"
    assert main(["offsets", "fit", str(d / "DATA.csv"), "--kp", str(d / "KP.csv"),
                 "-o", str(out)]) == 2
    assert "lon_deg" in capsys.readouterr().err and not out.exists()
    assert main(["model", str(d / "DATA.csv"), "--kp", str(d / "KP.csv"), "--model", "T96",
                 "--longitude", "128.2", "-o", str(out)]) == 2
    assert "needs --drivers" in capsys.readouterr().err and not out.exists()
    bad = d / "OFF_BAD.csv"
    bad.write_text("center,start\n")
    assert main(["offsets", "apply", str(d / "DATA.csv"), "--offsets", str(bad),
                 "-o", str(out)]) == 2
    assert "missing column" in capsys.readouterr().err and not out.exists()


@pytest.mark.slow
def test_monthly_offsets_workflow(tmp_path):
    import importlib.util
    import json
    from pathlib import Path

    script = Path(__file__).resolve().parents[1] / "workflows" / "monthly_offsets.py"
    spec = importlib.util.spec_from_file_location("monthly_offsets", script)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    assert mod.main(["--simulate-days", "30", "--seed", "4", "-o", str(tmp_path)]) == 0
    for name in ("OFFSETS.csv", "OFFSETS.cdf", "CORRECTED.csv", "summary.json",
                 "fig19_residual_local_time.png", "fig20_offsets.png"):
        assert (tmp_path / name).stat().st_size > 0, name
    summary = json.loads((tmp_path / "summary.json").read_text())
    # the simulated local-time field: 8 / 5 / 1.5 nT peak-to-peak, seen in the residuals
    assert_allclose(summary["local_time_peak_to_peak_nT"]["Hp"][0], 8.0, atol=1.0)
    assert_allclose(summary["local_time_peak_to_peak_nT"]["He"][0], 5.0, atol=1.0)
    import cdflib

    cdf = cdflib.CDF(str(tmp_path / "OFFSETS.cdf"))
    off = pd.read_csv(tmp_path / "OFFSETS.csv")
    assert_allclose(cdf.varget("offset_hpen"), off[["Hp", "He", "Hn"]].to_numpy(), atol=1e-4)
    assert "Provenance" in cdf.globalattsget()


def _offsets_csv(path, hp, he):
    """A 4-window OFFSETS.csv (daily centres, Hn 0) with the given Hp and He cells."""
    centres = pd.date_range("2019-11-02", periods=4, freq="1D")
    frame = pd.DataFrame({
        "center": centres.strftime("%Y-%m-%dT%H:%M:%S"),
        "start": (centres - pd.Timedelta("12h")).strftime("%Y-%m-%dT%H:%M:%S"),
        "end": (centres + pd.Timedelta("12h")).strftime("%Y-%m-%dT%H:%M:%S"),
        "Hp": hp, "He": he, "Hn": ["0"] * 4, "Hp_std": ["1"] * 4, "He_std": ["1"] * 4,
        "Hn_std": ["1"] * 4, "n_used": ["900"] * 4, "fraction_used": ["0.6"] * 4})
    frame.to_csv(path, index=False)
    return path


def test_apply_treats_fill_and_nonfinite_offsets_as_missing_windows(tmp_path, capsys):
    # sweep D5: a -1e31 Hp in OFFSETS.csv was applied (Hp ~ 1e31 on 8639 rows, exit 0)
    times = pd.date_range("2019-11-01T12:00", "2019-11-05T12:00", freq="1h")
    data = pd.DataFrame({"time": times.strftime("%Y-%m-%dT%H:%M:%S"), "Hp": 100.0,
                         "He": 50.0, "Hn": -80.0})
    data.to_csv(tmp_path / "DATA.csv", index=False)
    fill = _offsets_csv(tmp_path / "OFF_FILL.csv", ["10", "-1e31", "30", "40"],
                        ["1", "2", "inf", "4"])
    nan = _offsets_csv(tmp_path / "OFF_NAN.csv", ["10", "NaN", "30", "40"],
                       ["1", "2", "NaN", "4"])
    for name, table in (("FILL", fill), ("NAN", nan)):
        assert main(["offsets", "apply", str(tmp_path / "DATA.csv"), "--offsets", str(table),
                     "-o", str(tmp_path / f"CORR_{name}.csv")]) == 0
    err = capsys.readouterr().err
    assert "2 of 4 windows without a valid offset" in err
    assert "2019-11-03T00:00:00" in err and "2019-11-04T00:00:00" in err
    got = pd.read_csv(tmp_path / "CORR_FILL.csv")
    want = pd.read_csv(tmp_path / "CORR_NAN.csv")
    vals = got[["Hp", "He", "Hn"]].to_numpy()
    assert np.isfinite(vals).all() and np.abs(vals).max() < 200
    # the fill windows are skipped exactly like NaN windows: Hp interpolated 10 -> 40
    # between the valid centres of Nov 2 and Nov 5
    assert_allclose(vals, want[["Hp", "He", "Hn"]].to_numpy())
    mid = got["time"] == "2019-11-03T12:00:00"
    assert_allclose(got.loc[mid, "Hp"], 100.0 - 25.0)
    assert got["offset_flag"].tolist() == want["offset_flag"].tolist()
    # and every sample between those centres says its offset bridged the skipped ones
    t = pd.to_datetime(got["time"])
    inner = (t > "2019-11-02") & (t < "2019-11-05")
    assert (got.loc[inner, "offset_flag"] == 4).all()
    assert not (got.loc[~inner, "offset_flag"] == 4).any()
    assert f"bridged over a window without an offset {int(inner.sum())}" in err
    from magcal.offsets import read_offsets_csv

    table = read_offsets_csv(fill)
    assert table.valid.tolist() == [True, False, False, True]
    assert "Hp is a fill value" in table.reason[1] and "He is a fill value" in table.reason[2]
