"""Issue 13 cases 4-7 on real two-sensor data (Venus Express 128 Hz, the MST benchmark).

Truth here is read off the files by routes independent of the fit: the time stamps
(pandas), the outboard magnitude column ``BOST`` of the VEX file, the ambient field
``Bam_*`` of the MST benchmark, and a hand plan (regression, ``detrend_s = 1``) whose
tone reduction is measured with scipy's Welch directly. Sources: Venus Express MAG (ESA
PSA via MAGPRIME, CC BY-NC 4.0), MST gradiometry benchmark supplement.
"""

import json

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose
from scipy import signal

from magcal.ac.chain import Order, Plan, Stage, run_chain
from magcal.cli import main

pytestmark = pytest.mark.realdata

TONE_HZ = (33.0, 37.0)   # the spacecraft tone in the VEX difference (issue 13 case 5)


def _vex_csv(real_data, tmp_path):
    v = pd.read_csv(real_data("multi-sensor", "VEX128.txt"), sep=r"\s+")
    out = pd.DataFrame({"time": v["TIME_UTC"]})
    for name, col in (("bos", "BOS"), ("bis", "BIS")):
        for c in "xyz":
            out[f"{name}_{c}"] = v[col + c.upper()]
    path = tmp_path / "vex.csv"
    out.to_csv(path, index=False)
    return path, v


def _band_ratio(raw, clean, band, fs=128.0, nperseg=1024):
    f, p_raw = signal.welch(raw, fs=fs, nperseg=nperseg, axis=0)
    _, p_cln = signal.welch(clean, fs=fs, nperseg=nperseg, axis=0)
    sel = (f >= band[0]) & (f < band[1])
    return p_raw[sel].mean(axis=0) / p_cln[sel].mean(axis=0)


@pytest.fixture
def vex(real_data, tmp_path):
    return _vex_csv(real_data, tmp_path)


def test_case4_millisecond_stamps_fit_a_128hz_grid(vex, tmp_path):
    path, v = vex
    t = pd.to_datetime(v["TIME_UTC"])
    span_s = (t.iloc[-1] - t.iloc[0]).total_seconds()
    plan = tmp_path / "plan.toml"
    plan.write_text('target = "bos"\n[[stage]]\nregression = ["bos"]\nreferences = ["bis"]\n'
                    'orders = [ { detrend_s = 1 } ]\n')
    params = tmp_path / "p.json"
    assert main(["picog", "fit", str(path), "--plan", str(plan), "-o", str(params)]) == 0
    grid = json.loads(params.read_text())["time_grid"]
    # every row is one sample: the spacing is the span over the intervals
    assert grid["n_missing"] == 0 and grid["n_grid"] == len(v)
    assert_allclose(grid["dt_s"], span_s / (len(v) - 1), rtol=2e-6)
    assert abs(grid["rate_hz"] - 128.0) < 0.01
    # stamps rounded to 1 ms: jitter about uniform in +-0.5 ms (rms 0.29 ms)
    assert grid["stamp_resolution_s"] == 1e-3
    assert 0.0005 <= grid["jitter_max_s"] <= grid["tolerance_s"]
    assert_allclose(grid["jitter_rms_s"], 1e-3 / np.sqrt(12), rtol=0.1)


def test_case5_auto_scales_to_the_record_and_reports_bands(vex, tmp_path, capsys):
    path, v = vex
    raw = v[["BOSX", "BOSY", "BOSZ"]].to_numpy()
    b_in = v[["BISX", "BISY", "BISZ"]].to_numpy()
    t = np.arange(len(v)) / 128.0
    hand = run_chain({"bos": raw, "bis": b_in}, t, Plan("bos", (Stage(
        "regression", ("bos",), references=("bis",), orders=(Order(detrend_s=1.0),)),)))
    hand_tone = _band_ratio(raw, hand.corrected, TONE_HZ)
    assert np.all(hand_tone > 9)                      # issue 13: the hand plan, 10-35x

    params, clean = tmp_path / "auto.json", tmp_path / "clean.csv"
    assert main(["picog", "fit", str(path), "--target", "bos", "--auto",
                 "-o", str(params)]) == 0
    out, err = capsys.readouterr()
    assert "filters scaled to the 118.4 s record" in out and "power reduction" in out
    doc = json.loads(params.read_text())
    assert doc["auto"]["highpass_s"] < 10 and doc["auto"]["fit_highpass_s"] < 10
    # worse_than_raw describes the on-board product (the top-level M and G)
    assert main(["picog", "apply", str(path), "--params", str(params), "--on-board",
                 "-o", str(clean)]) == 0
    cleaned = pd.read_csv(clean)[["x", "y", "z"]].to_numpy()
    auto_tone = _band_ratio(raw, cleaned, TONE_HZ)
    assert np.all(auto_tone > 0.5 * hand_tone), (auto_tone, hand_tone)   # was 0.49x in x

    # the worse-than-raw entries are exactly the bands where an independent Welch
    # estimate of the same definition shows more cleaned than raw power
    check = doc["band_check"]
    nper = len(v) // 8
    f, p_raw = signal.welch(raw, fs=128.0, nperseg=nper, axis=0)
    _, p_cln = signal.welch(cleaned, fs=128.0, nperseg=nper, axis=0)
    expect = set()
    for lo, hi in check["bands_hz"]:
        sel = (f >= lo) & ((f < hi) if hi < f[-1] else (f <= hi))
        ratio = p_raw[sel].mean(axis=0) / p_cln[sel].mean(axis=0)
        expect |= {(lo, "xyz"[k]) for k in range(3) if ratio[k] * 1.1 < 1.0}
    got = {(w["band_hz"][0], w["component"]) for w in doc["worse_than_raw"]}
    assert got == expect
    assert bool(got) == ("worse than raw" in err)


def test_case6_unsupported_plan_keys_are_refused(vex, tmp_path, capsys):
    path, _ = vex
    out = tmp_path / "p.json"
    cases = {
        'target = "bos"\n[[stage]]\nregression = ["bos"]\nreferences = ["bis"]\n'
        'orders = [ { detrend_s = 1, band_hz = [33, 37] } ]\n': ("band_hz", "stage 1"),
        'target = "bos"\n[[stage]]\npair = ["bos", "bis"]\nmin_snr = 3\n':
            ("min_snr", "stage 1"),
        'target = "bos"\n[[stage]]\nreference = "bis"\nsensors = ["bos"]\n'
        '[[stage]]\npair = ["bos", "bis"]\norders = [ { windows_s = 1 } ]\n':
            ("windows_s", "stage 2"),
        'target = "bos"\nhighpass = 3\n[[stage]]\nreference = "bis"\nsensors = ["bos"]\n':
            ("highpass", "plan"),
    }
    for text, (key, stage) in cases.items():
        plan = tmp_path / "plan.toml"
        plan.write_text(text)
        assert main(["picog", "fit", str(path), "--plan", str(plan), "-o", str(out)]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1
        assert f"'{key}'" in err and stage in err and "plan.toml" in err, err
        assert not out.exists()


def test_case7_default_product_keeps_the_outboard_field(vex, tmp_path, capsys):
    path, v = vex
    plan = tmp_path / "plan.toml"
    plan.write_text('target = "bos"\n[[stage]]\nregression = ["bos"]\nreferences = ["bis"]\n'
                    'orders = [ { detrend_s = 1 } ]\n')
    params = tmp_path / "p.json"
    assert main(["picog", "fit", str(path), "--plan", str(plan), "-o", str(params)]) == 0
    assert "|G|" in capsys.readouterr().err        # |G| ~ 420 nT against ~175 nT
    outs = {}
    for flag in ("", "--pure-ac", "--keep-correction-offset"):
        o = tmp_path / f"clean{flag}.csv"
        assert main(["picog", "apply", str(path), "--params", str(params), "-o", str(o)]
                    + ([flag] if flag else [])) == 0
        outs[flag] = pd.read_csv(o)[["x", "y", "z"]].to_numpy()
    assert "|G|" in capsys.readouterr().err
    # the file's own outboard magnitude column BOST (read independently) is the truth
    bost = v["BOST"].to_numpy()
    assert_allclose(np.mean(np.linalg.norm(outs[""], axis=1)), bost.mean(), atol=0.5)
    assert_allclose(np.linalg.norm(outs[""], axis=1), bost, atol=6.0)
    assert_allclose(outs["--pure-ac"], outs[""], atol=2e-6)
    G = np.array(json.loads(params.read_text())["G"])
    assert np.linalg.norm(G) > 2 * bost.mean()
    assert_allclose(outs[""] - outs["--keep-correction-offset"], np.tile(G, (len(v), 1)),
                    atol=2e-6)
    with pytest.raises(SystemExit) as exc:     # argparse: mutually exclusive options
        main(["picog", "apply", str(path), "--params", str(params), "--pure-ac",
              "--keep-correction-offset", "-o", str(tmp_path / "x.csv")])
    assert exc.value.code == 2


def test_mst_auto_product_is_closer_to_the_ambient_truth(real_data, tmp_path):
    df = pd.read_csv(real_data("multi-sensor", "mstac2e2esupp1.csv"))
    t0 = pd.Timestamp("2020-01-01T00:00:00")
    out = pd.DataFrame({"time": (t0 + pd.to_timedelta(df["timestep"], unit="s"))
                        .dt.strftime("%Y-%m-%dT%H:%M:%S.%f")})
    for name, col in (("bout", "Bout"), ("bin", "Bin")):
        for c in "xyz":
            out[f"{name}_{c}"] = df[f"{col}_{c}"]
    path = tmp_path / "mst.csv"
    out.to_csv(path, index=False)
    params, clean = tmp_path / "p.json", tmp_path / "c.csv"
    assert main(["picog", "fit", str(path), "--target", "bout", "--auto",
                 "-o", str(params)]) == 0
    assert main(["picog", "apply", str(path), "--params", str(params), "-o", str(clean)]) == 0
    cleaned = pd.read_csv(clean)[["x", "y", "z"]].to_numpy()
    amb = df[["Bam_x", "Bam_y", "Bam_z"]].to_numpy()
    raw = df[["Bout_x", "Bout_y", "Bout_z"]].to_numpy()

    def rms(x):
        return np.sqrt(np.mean(x ** 2, axis=0))

    # the default product keeps the DC level: errors against the truth, mean included
    assert np.all(rms(cleaned - amb) < rms(raw - amb))
    assert np.mean(rms(cleaned - amb) / rms(raw - amb)) < 0.95
