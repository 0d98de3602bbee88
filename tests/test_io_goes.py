"""GOES-R MAG L2 reader: values read by hand from the files, ordering, gaps, fills."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from magcal.errors import InputError
from magcal.missions.goes import EARTH_RADIUS_KM, read_goes_mag

CORE = ["ib_x", "ib_y", "ib_z", "ob_x", "ob_y", "ob_z", "Hp", "He", "Hn",
        "gse_x", "gse_y", "gse_z", "gsm_x", "gsm_y", "gsm_z", "b_total",
        "lon_deg", "lat_deg", "r_re"]


def test_five_minute_folder_matches_hand_read_values(real_data):
    df = read_goes_mag(real_data("goes16", "l2_hires_5min"))
    assert len(df) == 7 * 600
    assert df.index.name == "time" and str(df.index.tz) == "UTC"
    assert df.index.is_monotonic_increasing and df.index.is_unique
    # first sample, read with h5netcdf: time 541951739.90094 s after 2000-01-01T12:00,
    # b_epn = (E, P, N) = (102.9403, 67.66329, -6.975276), b_ob_sensor, b_ib_sensor, b_gse
    assert df.index[0] == pd.Timestamp("2017-03-05T02:08:59.900942Z")
    assert df.index[-1] == pd.Timestamp("2017-03-05T02:15:59.800592Z")
    first = df.iloc[0]
    assert_allclose(first[["Hp", "He", "Hn"]].to_numpy(float), [67.66329, 102.9403, -6.975276],
                    rtol=0, atol=1e-4)
    assert_allclose(first[["ob_x", "ob_y", "ob_z"]].to_numpy(float),
                    [106.6512, 28.24721, 8.425425], rtol=0, atol=1e-4)
    assert_allclose(first[["ib_x", "ib_y", "ib_z"]].to_numpy(float),
                    [101.6043, -52.7966, -66.75101], rtol=0, atol=1e-4)
    assert_allclose(first[["gse_x", "gse_y", "gse_z"]].to_numpy(float),
                    [49.65119, -51.05814, 100.7586], rtol=0, atol=1e-4)
    assert_allclose(first["b_total"], 123.3843, rtol=0, atol=1e-4)
    # orbit_llr_geo = (lat, lon, radius m) = (0, -89.5, 4.2164e7) on every sample
    assert_allclose(df["lon_deg"], -89.5)
    assert_allclose(df["lat_deg"], 0.0)
    assert_allclose(df["r_re"], 42164.0 / EARTH_RADIUS_KM, rtol=1e-6)
    assert not df[CORE].isna().any().any()
    assert df.attrs["repairs"] == []
    assert df.attrs["all_fill"] == ["b_ib_epn", "b_ob_epn"]
    assert "ib_Hp" not in df.columns
    assert df.attrs["platform"] == ["g16"] and len(df.attrs["source"]) == 7
    steps = np.diff(df.index.asi8) / 1e9
    assert 0.098 < steps.min() and steps.max() < 0.102  # 10 Hz, no gap between files


def test_gap_folder_sorted_and_gap_kept(real_data):
    folder = real_data("goes16", "l2_hires_gap")
    df = read_goes_mag(folder)
    assert len(df) == 6 * 600
    assert df.index.is_monotonic_increasing and df.index.is_unique
    # the dn files store 1-s blocks out of order (e.g. rows 250..259 of the first file
    # hold 19:24:00.0..19:24:00.9 after 19:24:01.x): 420 rows move when sorted
    assert df.attrs["repairs"] == [{"what": "rows reordered by time", "column": "time",
                                    "count": 420}]
    steps = np.diff(df.index.asi8) / 1e9
    big = np.flatnonzero(steps > 0.2)
    assert big.size == 1
    # last time of the 19:26 file 545470019.800518 s, first of the 20:28 file 545473679.900871 s
    assert df.index[big[0]] == pd.Timestamp("2017-04-14T19:26:59.800518Z")
    assert df.index[big[0] + 1] == pd.Timestamp("2017-04-14T20:27:59.900871Z")
    assert_allclose(steps[big[0]], 3660.100353, atol=1e-5)
    assert ((df.index > "2017-04-14T19:27:00Z") & (df.index < "2017-04-14T20:27:59Z")).sum() == 0
    # earliest sample (row 0 of the first file): b_epn (E, P, N) = (36.76719, 99.76964, 0.8382491)
    assert_allclose(df.iloc[0][["Hp", "He", "Hn"]].to_numpy(float),
                    [99.76964, 36.76719, 0.8382491], rtol=0, atol=1e-4)
    assert_allclose(df.iloc[0][["ob_x", "ob_y", "ob_z"]].to_numpy(float),
                    [103.0392, 19.44871, 17.95491], rtol=0, atol=1e-4)
    assert df.attrs["all_fill"] == ["b_ib_epn", "b_ob_epn"]
    assert not df[CORE].isna().any().any()


def test_gap_folder_rows_match_h5netcdf(real_data):
    """Every row of the first dn file appears unchanged (EPN reordered) at its own time."""
    import h5netcdf

    folder = real_data("goes16", "l2_hires_gap")
    path = sorted(folder.glob("*.nc"))[0]
    with h5netcdf.File(path, "r") as f:
        t = f["time"][:]
        epn = f["b_epn"][:].astype(float)
        ib = f["b_ib_sensor"][:].astype(float)
        gsm = f["b_gsm"][:].astype(float)
    df = read_goes_mag(path)
    times = (pd.Timestamp("2000-01-01T12:00:00Z")
             + pd.to_timedelta(np.round(t * 1e6).astype(np.int64), unit="us"))
    sub = df.loc[times]
    assert_array_equal(sub[["Hp", "He", "Hn"]].to_numpy(), epn[:, [1, 0, 2]])
    assert_array_equal(sub[["ib_x", "ib_y", "ib_z"]].to_numpy(), ib)
    assert_array_equal(sub[["gsm_x", "gsm_y", "gsm_z"]].to_numpy(), gsm)


def _write_small_file(path, t, epn, orbit, orbit_on_time=True):
    import h5netcdf

    n = len(t)
    with h5netcdf.File(path, "w") as f:
        f.dimensions = {"time": n, "coordinate": 3}
        v = f.create_variable("time", ("time",), float, fillvalue=-9999.0)
        v[:] = t
        v.attrs["units"] = "seconds since 2000-01-01 12:00:00"
        for name in ("b_ib_sensor", "b_ob_sensor", "b_gse", "b_gsm", "b_ib_epn"):
            w = f.create_variable(name, ("time", "coordinate"), np.float32, fillvalue=-9999.0)
            w[:] = np.full((n, 3), -9999.0 if name == "b_ib_epn" else 1.0)
        w = f.create_variable("b_epn", ("time", "coordinate"), np.float32, fillvalue=-9999.0)
        w.attrs["valid_min"] = np.int32(-1024)
        w.attrs["valid_max"] = np.int32(1024)
        w[:] = epn
        w = f.create_variable("b_total", ("time",), np.float32, fillvalue=-9999.0)
        w[:] = np.full(n, 2.0)
        if orbit_on_time:
            o = f.create_variable("orbit_llr_geo", ("time", "coordinate"), float,
                                  fillvalue=-1e31)
            o[:] = orbit
        else:
            f.dimensions["time_orbit"] = len(orbit)
            o = f.create_variable("orbit_llr_geo", ("time_orbit", "coordinate"), np.float32,
                                  fillvalue=-9999.0)
            o[:] = orbit
            o.attrs["units"] = "'degrees, degrees, meters'"
            to = f.create_variable("time_orbit", ("time_orbit",), float, fillvalue=-9999.0)
            to[:] = np.arange(len(orbit), dtype=float) * 2.0 + t[0]
            to.attrs["units"] = "seconds since 2000-01-01 12:00:00"


def test_fills_duplicates_and_bad_times_are_counted(tmp_path):
    t = np.array([100.0, 100.1, -9999.0, 100.3, 100.2, 100.3])
    epn = np.array([[1, 2, 3], [-9999, -9999, -9999], [1, 1, 1], [4, 5, 6], [7, 8, 2000],
                    [9, 9, 9]], dtype=float)
    orbit = np.array([[0.0, -75.0, 4.2e7]] * 6)
    orbit[1] = -1e31
    path = tmp_path / "a.nc"
    _write_small_file(path, t, epn, orbit)
    df = read_goes_mag(path)
    # rows: 100.0, 100.1, 100.2, 100.3 (first of the two 100.3 kept), bad time dropped
    expected_t = pd.Timestamp("2000-01-01T12:00:00Z") + pd.to_timedelta([100.0, 100.1, 100.2,
                                                                         100.3], unit="s")
    assert_array_equal(df.index, expected_t)
    assert_allclose(df[["Hp", "He", "Hn"]].to_numpy(),
                    [[2, 1, 3], [np.nan] * 3, [8, 7, np.nan], [5, 4, 6]])
    assert_allclose(df["lon_deg"].to_numpy(), [-75.0, np.nan, -75.0, -75.0])
    repairs = {(r["what"], r["column"]): r["count"] for r in df.attrs["repairs"]}
    assert repairs == {
        ("rows without a valid time dropped", "time"): 1,
        ("rows reordered by time", "time"): 2,
        ("duplicate time dropped (first kept)", "time"): 1,
        ("fill value replaced by NaN", "b_epn"): 3,
        ("value outside valid_min/valid_max replaced by NaN", "b_epn"): 1,
        ("fill value replaced by NaN", "orbit_llr_geo"): 3,
    }
    assert df.attrs["all_fill"] == ["b_ib_epn"]
    assert df.attrs["n_missing"]["Hp"] == 1 and df.attrs["n_missing"]["Hn"] == 2


def test_orbit_on_its_own_time_axis_is_interpolated(tmp_path):
    t = 1000.0 + np.arange(5) * 1.0
    orbit = np.array([[0.0, -75.0, 4.2e7], [0.2, -74.0, 4.3e7], [0.4, -73.0, 4.4e7]])
    path = tmp_path / "b.nc"
    _write_small_file(path, t, np.ones((5, 3)), orbit, orbit_on_time=False)
    df = read_goes_mag(path)  # orbit at t0, t0+2, t0+4
    assert_allclose(df["lat_deg"], [0.0, 0.1, 0.2, 0.3, 0.4], atol=1e-7)
    assert_allclose(df["lon_deg"], [-75.0, -74.5, -74.0, -73.5, -73.0], atol=1e-5)
    assert_allclose(df["r_re"] * EARTH_RADIUS_KM, [42000, 42500, 43000, 43500, 44000])


def test_errors_name_the_file_and_variable(tmp_path):
    with pytest.raises(InputError, match="file not found"):
        read_goes_mag(tmp_path / "missing.nc")
    with pytest.raises(InputError, match="no .nc files"):
        read_goes_mag(tmp_path)
    bad = tmp_path / "bad.nc"
    bad.write_text("not netcdf")
    with pytest.raises(InputError, match="bad.nc: not a readable"):
        read_goes_mag(bad)
    import h5netcdf

    path = tmp_path / "short.nc"
    with h5netcdf.File(path, "w") as f:
        f.dimensions = {"time": 2}
        v = f.create_variable("time", ("time",), float)
        v[:] = [0.0, 0.1]
        v.attrs["units"] = "seconds since 2000-01-01 12:00:00"
    with pytest.raises(InputError, match="short.nc: column b_ib_sensor: variable missing"):
        read_goes_mag(path)
