"""``magcal align`` command (CONTRACTS §3)."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from magcal.alignment.synthetic import synthetic_pair
from magcal.cli import main
from magcal.io.csv import write_csv_frame


@pytest.fixture
def pair_files(tmp_path):
    case = synthetic_pair(np.random.default_rng(21), n=2000, cadence_s=300.0,
                          rotvec_deg=(3.0, -1.0, 0.5), offset_nT=(2.0, 0.0, -1.0),
                          noise_tau_s=(1800.0,) * 3)
    idx = pd.DatetimeIndex(case.times, name="time")
    data = pd.DataFrame(case.data, index=idx, columns=["Hp", "He", "Hn"])
    ref = pd.DataFrame(case.ref, index=idx, columns=["Hp", "He", "Hn"])
    write_csv_frame(tmp_path / "data.csv", data)
    write_csv_frame(tmp_path / "ref.csv", ref.iloc[100:])  # reference starts later
    return tmp_path, case


def test_align_closed_form_contract_keys(pair_files):
    path, case = pair_files
    out = path / "align.json"
    assert main([ "align", str(path / "data.csv"), "--reference", str(path / "ref.csv"),
                  "-o", str(out)]) == 0
    doc = json.loads(out.read_text())
    for key in ("schema_version", "magcal_version", "angles_deg", "std_deg", "ci95_deg",
                "n_used", "method", "provenance"):
        assert key in doc
    assert doc["n_used"] == 1900
    for k, c in enumerate(("Hp", "He", "Hn")):
        lo, hi = doc["ci95_deg"][c]
        assert lo < doc["angles_deg"][c] < hi
        assert abs(doc["angles_deg"][c] - case.rotvec_deg[k]) < 4 * doc["std_deg"][c]
    assert "converged" not in doc


def test_align_mcmc_reports_convergence(pair_files):
    path, _ = pair_files
    out = path / "align.json"
    assert main(["align", str(path / "data.csv"), "--reference", str(path / "ref.csv"),
                 "--mcmc", "--seed", "3", "-o", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["method"] == "emcee"
    assert isinstance(doc["converged"], bool) and doc["converged"]
    assert doc["autocorr_steps"] > 0
    assert doc["mcmc"]["n_steps"] > 50 * doc["autocorr_steps"]


def test_align_bad_input_exit_2_and_no_output(pair_files, tmp_path, capsys):
    path, _ = pair_files
    bad = tmp_path / "bad.csv"
    bad.write_text("time,Hp,He\n2019-03-01T00:00:00,1,2\n")
    out = tmp_path / "never.json"
    assert main(["align", str(path / "data.csv"), "--reference", str(bad), "-o", str(out)]) == 2
    assert not out.exists()
    assert "bad.csv" in capsys.readouterr().err
