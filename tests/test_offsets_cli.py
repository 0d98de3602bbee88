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
    assert "2 windows (2 valid)" in err


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
