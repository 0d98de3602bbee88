"""spincal refuses input that breaks its model, and handles units and spin sense.

Issue 13 case 9: on ELFIN science-zone counts with ``--spin-period`` spincal returned
coupling terms of 17.8 and -9.1 and a spin tone of 2.6e6 "nT" with exit 0: counts were
taken as nT and all three sensors see the spin.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from numpy.testing import assert_allclose

from magcal.cli import main
from magcal.errors import InputError
from magcal.io.csv import write_csv_frame
from magcal.simulate.spinning import SpinningConfig, simulate_spinning
from magcal.spin.despin import spin
from magcal.spin.inputs import (MAX_AXIS_TILT_DEG, SENSE_FLIP, check_spin_assumptions,
                                measure_spin_assumptions)

R = SENSE_FLIP


@pytest.fixture(scope="module")
def sim():
    cfg = SpinningConfig.galileo_like(duration_s=1800.0)
    return simulate_spinning(cfg, rng=np.random.default_rng(0))


@pytest.fixture(scope="module")
def files(sim, tmp_path_factory):
    d = tmp_path_factory.mktemp("spinsense")
    data = sim.data.drop(columns=["phase", "flip"])
    write_csv_frame(d / "pos.csv", data, float_format=None)
    # the same record from a triad turned 180 deg about sensor 1: it spins negatively
    # about its sensor 3, and its true C and O are R C R and R O
    neg = data.copy()
    neg[["b2", "b3"]] *= -1.0
    write_csv_frame(d / "neg.csv", neg, float_format=None)
    counts = data * 1.0e5
    write_csv_frame(d / "counts.csv", counts, float_format=None)
    tr = sim.truth
    c0 = np.eye(3)
    c0[0] = tr.coupling[0]
    c0[2, 2] = tr.coupling[2, 2]
    o0 = np.array([0.0, 0.0, tr.offsets_nT[2]])
    for name, c, o in (("prior_pos.json", c0, o0), ("prior_neg.json", R @ c0 @ R, R @ o0)):
        (d / name).write_text(json.dumps({"schema_version": 1, "coupling": c.tolist(),
                                          "offsets": o.tolist()}))
    return d


def _run(*argv) -> int:
    return main([str(a) for a in argv])


@pytest.fixture(scope="module")
def cal_pos(files):
    """``magcal spincal`` of the positive-sense record (in nT) with its prior: the
    reference of the tests that read it (each may run in its own test process)."""
    pos = files / "CAL_pos.json"
    assert _run("spincal", files / "pos.csv", "--spin-period", 20, "--prior",
                files / "prior_pos.json", "-o", pos) == 0
    return pos


def test_measure_tilted_triad():
    """A triad whose spin axis lies 30 deg from sensor 3 in the b1-b3 plane."""
    p = np.linspace(0, 30 * 2 * np.pi, 3000, endpoint=False)
    b_sc = spin(np.tile([20.0, 0.0, 5.0], (p.size, 1)), p)
    tilt = np.radians(30.0)
    turn = np.array([[np.cos(tilt), 0, np.sin(tilt)], [0, 1, 0], [-np.sin(tilt), 0, np.cos(tilt)]])
    found = measure_spin_assumptions(p, b_sc @ turn.T, p)
    assert_allclose(found.axis_tilt_deg, 30.0, atol=1e-6)
    assert_allclose(found.spin_axis, turn[:, 2], atol=1e-9)
    # sensor tones: b1 cos(30) * 20, b2 20, b3 sin(30) * 20
    assert_allclose(found.tone_nT, [20 * np.cos(tilt), 20.0, 20 * np.sin(tilt)], atol=1e-9)
    assert MAX_AXIS_TILT_DEG < 30.0
    with pytest.raises(InputError, match="spin axis lies 30 deg from sensor 3"):
        check_spin_assumptions(found)


def test_negative_sense_recovers_the_turned_truth(files, sim, cal_pos):
    tr = sim.truth
    pos, neg = cal_pos, files / "CAL_neg.json"
    assert _run("spincal", files / "neg.csv", "--spin-period", 20, "--spin-sense", "auto",
                "--prior", files / "prior_neg.json", "-o", neg) == 0
    jp, jn = json.loads(pos.read_text()), json.loads(neg.read_text())
    assert jp["spin_phase"]["sense"] == "positive" and jn["spin_phase"]["sense"] == "negative"
    # truth, as in the ripple fit's own docstring example (30 min, 0.05 nT)
    assert_allclose(jp["offsets"], tr.offsets_nT, atol=0.05)
    assert_allclose(jn["offsets"], R @ tr.offsets_nT, atol=0.05)
    assert_allclose(jn["coupling"], R @ np.asarray(jp["coupling"]) @ R, atol=1e-9)
    assert_allclose(jn["coupling"], R @ tr.coupling @ R, atol=5e-3)
    assert max(jn["spin_tone_after_nT"]["BX"]) < 0.05
    # the waves' bias record is turned into the file's frame like the parameters
    from magcal.spin.product import _PARAM_SIGN
    from magcal.spin.ripple import PARAM_NAMES

    sign = dict(zip(PARAM_NAMES, _PARAM_SIGN))
    for key in ("bias_estimate", "bias_correction"):
        assert jn[key].keys() == jp[key].keys()
        assert_allclose([jn[key][n] for n in jp[key]],
                        [sign[n] * jp[key][n] for n in jp[key]], rtol=1e-6, atol=1e-12)


def test_wrong_sense_is_refused(files, tmp_path, capsys):
    out = tmp_path / "x.json"
    assert _run("spincal", files / "neg.csv", "--spin-period", 20, "-o", out) == 2
    err = capsys.readouterr().err
    assert "neg.csv" in err and "opposite to --spin-sense positive" in err
    assert "give --spin-sense negative or auto" in err and not out.exists()
    assert _run("spincal", files / "pos.csv", "--spin-period", 20, "--spin-sense", "negative",
                "-o", out) == 2
    assert "give --spin-sense positive or auto" in capsys.readouterr().err
    assert not out.exists()


def test_counts_need_a_scale(files, cal_pos, tmp_path, capsys):
    out = tmp_path / "x.json"
    assert _run("spincal", files / "counts.csv", "--spin-period", 20, "-o", out) == 2
    err = capsys.readouterr().err
    assert "implausible for nT" in err and "--scale" in err and not out.exists()
    assert _run("spincal", files / "counts.csv", "--spin-period", 20, "--scale", 1e-5,
                "--prior", files / "prior_pos.json", "-o", out) == 0
    ref = json.loads(cal_pos.read_text())
    got = json.loads(out.read_text())
    assert got["spin_phase"]["input_scale_nT_per_unit"] == 1e-5
    assert_allclose(got["offsets"], ref["offsets"], atol=1e-6)
    assert_allclose(got["coupling"], ref["coupling"], atol=1e-9)


def _elfin_zone(tmp_path):
    from conftest import real_data_path

    from magcal.missions.elfin.files import read_elfin_fgs
    from magcal.missions.elfin.phase import split_zones

    fgs = read_elfin_fgs(real_data_path("elfin", "ela_l1_fgs_20220112_v01.cdf"))
    t = (fgs.index - fgs.index[0]).total_seconds().to_numpy()
    a, b = split_zones(t)[0]
    path = tmp_path / "ELFIN_ZONE1.csv"
    write_csv_frame(path, fgs.iloc[a:b], float_format=None)
    return path, t[a:b] - t[a], fgs.iloc[a:b].to_numpy()


@pytest.mark.realdata
def test_elfin_counts_refused_with_the_reason(tmp_path, capsys):
    path, t, counts = _elfin_zone(tmp_path)
    # independent route: every sensor carries a strong line near the 2.9 s spin
    # (periodogram of the detrended counts, 0.3-0.4 Hz)
    x = counts - np.array([np.polyval(np.polyfit(t, c, 3), t) for c in counts.T]).T
    spec = np.abs(np.fft.rfft(x * np.hanning(t.size)[:, None], axis=0))
    f = np.fft.rfftfreq(t.size, d=np.median(np.diff(t)))
    band = (f > 0.3) & (f < 0.4)
    peak = spec[band].max(axis=0)
    assert np.all(peak / peak.max() > 0.3), peak / peak.max()
    assert np.median(np.linalg.norm(counts, axis=1)) > 1e6           # counts, not nT

    out = tmp_path / "CAL.json"
    assert _run("spincal", path, "--spin-period", 2.9, "-o", out) == 2
    err = capsys.readouterr().err
    assert "implausible for nT" in err and "give --scale" in err and not out.exists()
    assert _run("spincal", path, "--spin-period", 2.9, "--scale", 0.01, "--spin-sense",
                "auto", "-o", out) == 2
    err = capsys.readouterr().err
    assert "ELFIN_ZONE1.csv" in err and "not confined to the spin plane" in err
    assert "deg from sensor 3 (b3)" in err and not out.exists()
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err


def test_malformed_calibration_json_is_exit_2(files, tmp_path, capsys):
    bad = tmp_path / "BAD.json"
    bad.write_text(json.dumps({"schema_version": 1, "coupling": [[1, 2], [3]],
                               "offsets": [0, 0, 0]}))
    out = tmp_path / "x.json"
    assert _run("spincal", files / "pos.csv", "--spin-period", 20, "--prior", bad,
                "-o", out) == 2
    err = capsys.readouterr().err
    assert "BAD.json: column coupling: coupling must be 3 x 3 finite numbers" in err
    assert not out.exists()
