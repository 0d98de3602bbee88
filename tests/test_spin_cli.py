"""``magcal spincal`` and ``magcal flipper`` end to end on simulated CSV files."""

from __future__ import annotations

import json

import numpy as np
import pytest
from numpy.testing import assert_allclose

from magcal.cli import main
from magcal.io.csv import write_csv_frame
from magcal.simulate.spinning import SpinningConfig, simulate_spinning


@pytest.fixture(scope="module")
def sim():
    cfg = SpinningConfig.galileo_like(duration_s=3600.0, flip_intervals_s=((2400.0, 3600.0),))
    return simulate_spinning(cfg, rng=np.random.default_rng(11))


@pytest.fixture(scope="module")
def files(sim, tmp_path_factory):
    d = tmp_path_factory.mktemp("spin")
    write_csv_frame(d / "with_phase.csv", sim.data, float_format=None)
    write_csv_frame(d / "no_phase.csv", sim.data.drop(columns=["phase"]), float_format=None)
    write_csv_frame(d / "no_flip.csv", sim.data.drop(columns=["flip"]), float_format=None)
    return d


def test_spincal_and_flipper(files, sim, capsys):
    out = files / "CAL.json"
    assert main(["spincal", str(files / "with_phase.csv"), "-o", str(out)]) == 0
    cal = json.loads(out.read_text())
    for key in ("coupling", "offsets", "determined", "fixed", "spin_tone_before_nT",
                "spin_tone_after_nT", "schema_version", "magcal_version", "provenance"):
        assert key in cal
    assert sorted(cal["fixed"]) == ["O3", "c11", "c12", "c33"]
    # identity priors: offsets right up to the turn and gain nobody can see
    assert cal["spin_tone_before_nT"]["BX"][0] > 1.0
    assert cal["spin_tone_after_nT"]["BX"][0] < 0.01
    flip = files / "FLIP.json"
    full = files / "CAL_full.json"
    assert main(["flipper", str(files / "with_phase.csv"), "--cal", str(out),
                 "--complete", str(full), "-o", str(flip)]) == 0
    fl = json.loads(flip.read_text())
    assert abs(fl["O3"] - 0.45) < 0.05 and fl["O3_std"] > 0
    # CAL.json's covariance reaches O3's error: the two parts in quadrature
    assert fl["O3_std_calibration"] > 0 and fl["O3_std_data"] > 0
    assert_allclose(fl["O3_std"], np.hypot(fl["O3_std_data"], fl["O3_std_calibration"]))
    done = json.loads(full.read_text())
    assert "O3" in done["determined"] and done["offsets"][2] == fl["O3"]


def test_phase_from_period_and_from_data(files, sim):
    ref = json.loads((files / "CAL.json").read_text()) if (files / "CAL.json").exists() else None
    a = files / "a.json"
    b = files / "b.json"
    assert main(["spincal", str(files / "no_phase.csv"), "--spin-period", "20", "-o", str(a)]) == 0
    assert main(["spincal", str(files / "no_phase.csv"), "-o", str(b)]) == 0
    ja, jb = json.loads(a.read_text()), json.loads(b.read_text())
    assert ja["spin_phase"]["source"] == "spin period 20 s"
    assert jb["spin_phase"]["source"].startswith("derived")
    assert_allclose(jb["spin_phase"]["spin_period_s"], 20.0, atol=0.02)
    for doc in (ja, jb):
        assert doc["spin_tone_after_nT"]["BX"][0] < 0.01
    if ref is not None:
        assert_allclose(ja["offsets"], ref["offsets"], atol=1e-6)


def test_bad_input_messages(files, tmp_path, capsys):
    out = tmp_path / "x.json"
    assert main(["spincal", str(files / "no_phase.csv"), "--spin-period", "20.3",
                 "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "no_phase.csv" in err and "spin period 20.3 s does not fit the data" in err
    assert not out.exists()
    assert main(["flipper", str(files / "no_flip.csv"), "-o", str(out)]) == 2
    assert "flipper intervals missing" in capsys.readouterr().err
    short = tmp_path / "short.csv"
    res = simulate_spinning(SpinningConfig.galileo_like(duration_s=90.0),
                            rng=np.random.default_rng(1))
    write_csv_frame(short, res.data, float_format=None)
    assert main(["spincal", str(short), "-o", str(out)]) == 2
    assert "complete spins usable" in capsys.readouterr().err
    assert not out.exists()
