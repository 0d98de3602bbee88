"""CDF reading (ELFIN, hand-checked against cdflib) and ISTP product round trips."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from magcal.errors import InputError
from magcal.io.cdf import (
    ISTP_DATA_ATTRIBUTES,
    ISTP_GLOBAL_ATTRIBUTES,
    REQUIRED_GLOBAL_INPUTS,
    datetime64_to_tt2000,
    read_cdf,
    write_cdf_product,
)
from magcal.missions.elfin.files import read_elfin_fgs, read_elfin_state

GLOBALS = {"Project": "ISTP>International Solar-Terrestrial Physics",
           "Source_name": "GK2A>Geo-KOMPSAT-2A", "Data_type": "L2>Level 2",
           "Descriptor": "SOSMAG>Service Oriented Spacecraft Magnetometer",
           "Logical_source_description": "Calibrated magnetic field in Hpen",
           "PI_name": "n/a", "PI_affiliation": "n/a", "Mission_group": "GK2A",
           "TEXT": "Test product written by the magcal test suite."}


def _product(tmp_path, name="prod.cdf"):
    times = np.array(["2016-12-31T23:59:59.123456789", "2017-01-01T00:00:00.000000001",
                      "2017-01-01T00:00:01", "2017-01-01T00:00:01.5"], dtype="datetime64[ns]")
    b = np.array([[1.0, 2.0, 3.0], [np.nan, 5.0, 6.0], [7.0, np.nan, 9.0], [10.0, 11.0, 12.25]])
    scalar = np.array([0.5, -0.25, np.nan, 1e-9])
    variables = {
        "B_hpen": (b, {"UNITS": "nT", "CATDESC": "Magnetic field, Hpen",
                       "labels": ["Hp", "He", "Hn"],
                       "VALIDMIN": -1e5, "VALIDMAX": 1e5}),
        "offset": (scalar, {"UNITS": "nT"}),
        "quality": (np.array([0, 1, 2, 3], dtype=np.int32), {"UNITS": " "}),
    }
    prov = {"step": "test", "parameters": {"window_days": 28}, "inputs": []}
    path = write_cdf_product(tmp_path / name, times, variables, GLOBALS, provenance=prov)
    return path, times, b, scalar, prov


def test_round_trip_values_fill_times(tmp_path):
    path, times, b, scalar, prov = _product(tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["prod.cdf"]   # no temp leftovers
    data = read_cdf(path)
    assert_array_equal(data["Epoch"], times)                            # to the nanosecond
    assert_array_equal(data["B_hpen"], b)                                # NaN where written
    assert_array_equal(data["offset"], scalar)
    assert data.fill_counts["B_hpen"] == 2 and data.fill_counts["offset"] == 1
    assert_array_equal(data["quality"], [0, 1, 2, 3])
    assert data["quality"].dtype == np.int32
    assert list(data["B_hpen_labl"]) == ["Hp", "He", "Hn"]


def test_tt2000_values_and_leap_second(tmp_path):
    import cdflib

    path, times, *_ = _product(tmp_path)
    raw = cdflib.CDF(str(path)).varget("Epoch")
    assert cdflib.CDF(str(path)).varinq("Epoch").Data_Type_Description == "CDF_TIME_TT2000"
    expected = cdflib.cdfepoch.compute_tt2000([[2016, 12, 31, 23, 59, 59, 123, 456, 789],
                                               [2017, 1, 1, 0, 0, 0, 0, 0, 1]])
    assert_array_equal(raw[:2], expected)
    # the 2016-12-31 leap second: 0.876543212 s of UTC apart are 1.876543212 s of TT
    assert int(raw[1] - raw[0]) == 1_876_543_212
    # J2000 epoch: 2000-01-01T12:00:00 TT = 11:58:55.816 UTC
    assert datetime64_to_tt2000(np.array(["2000-01-01T11:58:55.816"], "datetime64[ns]"))[0] == 0


def test_istp_attributes_present(tmp_path):
    path, *_ , prov = _product(tmp_path)
    data = read_cdf(path)
    g = data.global_attrs
    for key in ISTP_GLOBAL_ATTRIBUTES:
        assert g.get(key) not in (None, ""), key
    assert g["Discipline"] == "Space Physics>Magnetospheric Science"
    assert g["Instrument_type"] == "Magnetic Fields (space)"
    assert g["Logical_source"] == "gk2a_l2_sosmag"
    assert g["Logical_file_id"] == "prod"
    assert g["magcal_version"]
    assert json.loads(g["Provenance"]) == prov
    epoch = data.var_attrs["Epoch"]
    assert epoch["VAR_TYPE"] == "support_data"
    for name in ("B_hpen", "offset", "quality"):
        attrs = data.var_attrs[name]
        for key in ISTP_DATA_ATTRIBUTES:
            assert key in attrs, (name, key)
        assert attrs["DEPEND_0"] == "Epoch" and attrs["VAR_TYPE"] == "data"
        assert attrs["DISPLAY_TYPE"] == "time_series"
    assert data.var_attrs["B_hpen"]["LABL_PTR_1"] == "B_hpen_labl"
    assert data.var_attrs["offset"]["LABLAXIS"] == "offset"
    assert_allclose(data.var_attrs["B_hpen"]["FILLVAL"], -1e31)
    assert_allclose([data.var_attrs["B_hpen"]["VALIDMIN"], data.var_attrs["B_hpen"]["VALIDMAX"]],
                    [-1e5, 1e5])
    assert data.var_attrs["B_hpen_labl"]["VAR_TYPE"] == "metadata"


def test_writer_errors_leave_nothing(tmp_path):
    times = np.array(["2020-01-01T00:00:00"], dtype="datetime64[ns]")
    incomplete = {k: v for k, v in GLOBALS.items() if k != "PI_name"}
    with pytest.raises(ValueError, match="PI_name"):
        write_cdf_product(tmp_path / "a.cdf", times, {"x": (np.ones(1), {})}, incomplete)
    with pytest.raises(ValueError, match="shape"):
        write_cdf_product(tmp_path / "b.cdf", times, {"x": (np.ones(2), {})}, GLOBALS)
    assert list(tmp_path.iterdir()) == []
    assert set(REQUIRED_GLOBAL_INPUTS) <= set(GLOBALS)


def test_non_cdf_suffix_and_overwrite(tmp_path):
    times = pd.date_range("2020-01-01", periods=3, freq="1s", tz="UTC")
    target = tmp_path / "product.bin"
    for scale in (1.0, 2.0):
        write_cdf_product(target, times, {"x": (scale * np.arange(3.0), {"UNITS": "nT"})}, GLOBALS)
    data = read_cdf(target)
    assert_array_equal(data["x"], [0.0, 2.0, 4.0])
    assert_array_equal(data["Epoch"], times.tz_localize(None).to_numpy())
    assert sorted(p.name for p in tmp_path.iterdir()) == ["product.bin"]


def test_read_errors(tmp_path):
    with pytest.raises(InputError, match="file not found"):
        read_cdf(tmp_path / "none.cdf")
    junk = tmp_path / "junk.cdf"
    junk.write_bytes(b"not a cdf at all" * 10)
    with pytest.raises(InputError, match="not a readable CDF"):
        read_cdf(junk)
    path, *_ = _product(tmp_path)
    with pytest.raises(InputError, match="nope"):
        read_cdf(path, variables=["nope"])


# ------------------------------------------------------------------ ELFIN (real files)
def test_elfin_fgs(real_data):
    # read by hand with cdflib: 43594 records, first time 2022-01-12T04:54:09.896225,
    # first vector (-848884, -3474967, -2517006), last (-1193889, -3475191, -4081822)
    fgs = read_elfin_fgs(real_data("elfin", "ela_l1_fgs_20220112_v01.cdf"))
    assert len(fgs) == 43594
    assert list(fgs.columns) == ["b1", "b2", "b3"]
    assert fgs.index[0] == pd.Timestamp("2022-01-12T04:54:09.896225", tz="UTC")
    assert_array_equal(fgs.iloc[0].to_numpy(), [-848884, -3474967, -2517006])
    assert_array_equal(fgs.iloc[-1].to_numpy(), [-1193889, -3475191, -4081822])
    assert fgs.attrs["units"] == "counts" and fgs.attrs["n_fill"] == 0
    assert fgs.index.is_monotonic_increasing
    # 10 Hz inside the science zones: the median step is 0.1 s
    assert_allclose(np.median(np.diff(fgs.index.asi8)) / 1e9, 0.1, atol=2e-3)


def test_elfin_state(real_data):
    # by hand: 86400 records at 1 s from 2022-01-12T00:00:00; first position
    # (5548.668, 3833.0857, -841.84) km, velocity (1.014651, 0.195763, 7.589338) km/s,
    # first attitude (-0.58215225, 0.8104529, 0.06530594); 71236 records in sunlight
    state = read_elfin_state(real_data("elfin", "ela_l1_state_defn_20220112_v01.cdf"))
    assert len(state) == 86400
    assert state.index[0] == pd.Timestamp("2022-01-12T00:00:00", tz="UTC")
    assert state.index[-1] == pd.Timestamp("2022-01-12T23:59:59", tz="UTC")
    first = state.iloc[0]
    assert_allclose(first[["pos_gei_x", "pos_gei_y", "pos_gei_z"]].to_numpy(float),
                    [5548.668, 3833.0857, -841.84], rtol=0, atol=1e-3)
    assert_allclose(first[["vel_gei_x", "vel_gei_y", "vel_gei_z"]].to_numpy(float),
                    [1.014651, 0.195763, 7.589338], rtol=0, atol=1e-6)
    axis_cols = ["spin_axis_gei_x", "spin_axis_gei_y", "spin_axis_gei_z"]
    assert_allclose(first[axis_cols].to_numpy(float),
                    [-0.58215225, 0.8104529, 0.06530594], rtol=0, atol=1e-6)
    assert int(state["sun"].sum()) == 71236
    r = np.linalg.norm(state[["pos_gei_x", "pos_gei_y", "pos_gei_z"]].to_numpy(), axis=1)
    assert 6700 < r.min() and r.max() < 6900                            # low Earth orbit
    axis = state[["spin_axis_gei_x", "spin_axis_gei_y", "spin_axis_gei_z"]].to_numpy()
    ok = np.isfinite(axis).all(axis=1)
    assert_allclose(np.linalg.norm(axis[ok], axis=1), 1.0, atol=1e-9)
    # attitude solutions end at 23:59:00: the last minute is outside them
    assert ok.sum() == 86400 - 59
