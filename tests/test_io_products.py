"""Products in CF-1.8 netCDF4 and ISTP CDF (issue 23), checked with independent readers:
xarray with CF decoding for netCDF, cdflib for CDF. The truth is the frame written (or
the CSV product of the same frame, read back at its written precision)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from magcal.io.products import read_product, write_product
from magcal.qc import flags as qcflags

N = 5000  # above the 4096 samples from which netCDF variables are compressed


def _frame(seed: int = 3) -> pd.DataFrame:
    """A 10 Hz day fragment with gaps (NaN), every quality bit, the offset flag."""
    rng = np.random.default_rng(seed)
    t = pd.date_range("2019-11-01T23:59:50", periods=N, freq="100ms", tz="UTC", name="time")
    f = pd.DataFrame({"Hp": 90 + rng.normal(0, 3, N), "He": -20 + rng.normal(0, 3, N),
                      "Hn": rng.normal(0, 3, N),
                      "offset_flag": rng.integers(0, 4, N).astype(np.int8),
                      "quality": rng.integers(0, 64, N).astype(np.uint16)}, index=t)
    f.iloc[7:19, 1] = np.nan  # a gap in one component
    f.iloc[0, :3] = np.nan
    return f


def _offsets() -> pd.DataFrame:
    center = pd.DatetimeIndex(pd.date_range("2019-11-03", periods=4, freq="7D", tz="UTC"),
                              name="center")
    return pd.DataFrame({"start": center - pd.Timedelta(days=14),
                         "end": center + pd.Timedelta(days=14),
                         "Hp": [1.25, np.nan, -0.5, 2.0], "Hp_se": [0.1, np.nan, 0.2, 0.3],
                         "n_used": [800, 0, 900, 1000],
                         "reason": ["", "too few samples", "", "caution: short"],
                         "days_covered": pd.array([10, None, 12, 14], dtype="Int64")},
                        index=center)


def _assert_flags_decode(values, masks, meanings) -> None:
    """The bits named by a file's masks/meanings are those magcal.qc set."""
    names = dict(zip((int(m) for m in masks), meanings.split()))
    for v in np.unique(values):
        assert [n for m, n in names.items() if int(v) & m] == qcflags.describe(int(v))
    assert {int(v) & int(qcflags.IMPLAUSIBLE) for v in values} == {0, 32}


def test_netcdf_is_cf_with_flag_variable_and_provenance(tmp_path):
    xr = pytest.importorskip("xarray")
    f = _frame()
    path = write_product(tmp_path / "CORRECTED_20191101.nc", f,
                         provenance={"stage": "offsets apply", "seed": 1})
    with xr.open_dataset(path, engine="h5netcdf") as ds:  # CF decoding on
        assert ds.attrs["Conventions"] == "CF-1.8"
        assert '"stage": "offsets apply"' in ds.attrs["provenance"]
        assert "magcal_version" in ds.attrs and ds.attrs["title"]
        # CF time, exact to the nanosecond
        assert ds["time"].dtype == np.dtype("datetime64[ns]")
        np.testing.assert_array_equal(ds["time"].values,
                                      f.index.tz_localize(None).to_numpy())
        assert ds["time"].attrs["standard_name"] == "time"
        for c in ("Hp", "He", "Hn"):
            assert ds[c].attrs["units"] == "nT" and ds[c].attrs["long_name"]
            assert ds[c].encoding["zlib"] and ds[c].encoding["shuffle"]  # compressed
            np.testing.assert_array_equal(ds[c].values, f[c].to_numpy())  # NaN where NaN
        q = ds["quality"]
        assert q.attrs["standard_name"] == "quality_flag"
        # the bits of magcal.qc (CONTRACTS 7.1, magcal's implausible-vs-model and
        # offset-bridged, across-a-level-change and near-a-level-change bits)
        assert list(q.attrs["flag_masks"]) == [1, 2, 4, 8, 16, 32, 64, 128, 256]
        assert q.attrs["flag_meanings"].split() == list(qcflags.FLAG_NAMES.values())
        _assert_flags_decode(q.values, q.attrs["flag_masks"], q.attrs["flag_meanings"])
        assert q.attrs["flag_masks"].dtype == q.dtype
        np.testing.assert_array_equal(q.values, f["quality"].to_numpy())
        np.testing.assert_array_equal(ds["offset_flag"].values, f["offset_flag"].to_numpy())
        o = ds["offset_flag"]  # a CF flag variable of values (codes 0-3, and 4 bridged)
        assert list(o.attrs["flag_values"]) == [0, 1, 2, 3, 4]
        assert o.attrs["flag_values"].dtype == o.dtype
        assert len(o.attrs["flag_meanings"].split()) == 5


def test_cdf_is_istp_with_tt2000_and_support_data(tmp_path):
    cdflib = pytest.importorskip("cdflib")
    f = _frame()
    path = write_product(tmp_path / "CORRECTED_20191101.cdf", f, provenance={"seed": 1})
    cdf = cdflib.CDF(str(path))
    assert cdf.varinq("Epoch").Data_Type_Description == "CDF_TIME_TT2000"
    epoch = cdflib.cdfepoch.to_datetime(cdf.varget("Epoch"))
    np.testing.assert_array_equal(np.asarray(epoch, dtype="datetime64[ns]"),
                                  f.index.tz_localize(None).to_numpy())
    # TT2000 = UTC since 2000-01-01T12:00 + TAI-UTC (37 s in 2019) + 32.184 s
    assert cdf.varget("Epoch")[0] == (f.index[0] - pd.Timestamp("2000-01-01T12:00", tz="UTC")
                                      ).value + 37_000_000_000 + 32_184_000_000
    required = ("VAR_TYPE", "DEPEND_0", "FILLVAL", "VALIDMIN", "VALIDMAX", "UNITS", "CATDESC",
                "FIELDNAM", "LABLAXIS", "DISPLAY_TYPE")
    for name in ("Hp", "He", "Hn", "quality", "offset_flag"):
        attrs = cdf.varattsget(name)
        missing = [a for a in required if a not in attrs]
        assert not missing, (name, missing)
        assert attrs["DEPEND_0"] == "Epoch" and attrs["FIELDNAM"] == name
    assert cdf.varattsget("Hp")["VAR_TYPE"] == "data"
    assert cdf.varattsget("Hp")["UNITS"] == "nT"
    assert cdf.varattsget("quality")["VAR_TYPE"] == "support_data"
    assert cdf.varattsget("offset_flag")["VAR_TYPE"] == "support_data"
    qa = cdf.varattsget("quality")
    assert qa["VALIDMIN"] == 0 and qa["VALIDMAX"] == 511  # the sum of the bits
    assert list(qa["FLAG_MASKS"]) == [1, 2, 4, 8, 16, 32, 64, 128, 256]
    assert qa["FLAG_MEANINGS"].split() == list(qcflags.FLAG_NAMES.values())
    assert "32 implausible vs model" in qa["VAR_NOTES"]
    _assert_flags_decode(cdf.varget("quality"), qa["FLAG_MASKS"], qa["FLAG_MEANINGS"])
    raw = cdf.varget("He")
    fill = cdf.varattsget("He")["FILLVAL"]
    assert (raw == fill).sum() == f["He"].isna().sum()
    ok = f["He"].notna().to_numpy()
    np.testing.assert_array_equal(raw[ok], f["He"].to_numpy()[ok])
    np.testing.assert_array_equal(cdf.varget("quality"), f["quality"].to_numpy())
    g = cdf.globalattsget()
    for key in ("Project", "Source_name", "Discipline", "Data_type", "Descriptor",
                "Logical_source", "Logical_file_id", "PI_name", "TEXT", "Provenance"):
        assert key in g, key


@pytest.mark.parametrize("suffix", [".nc", ".cdf"])
def test_binary_equals_csv_product_at_written_precision(tmp_path, suffix):
    f = _frame()
    csv = read_product(write_product(tmp_path / "a.csv", f))
    back = read_product(write_product(tmp_path / f"a{suffix}", f))
    assert list(back.columns) == list(f.columns)
    assert back.index.equals(csv.index)
    for c in ("Hp", "He", "Hn"):  # CSV keeps 6 decimals: 5e-7 nT
        np.testing.assert_allclose(back[c], csv[c], atol=5.1e-7, rtol=0)
        assert (back[c].isna() == csv[c].isna()).all()
    for c in ("quality", "offset_flag"):
        np.testing.assert_array_equal(back[c].to_numpy(), csv[c].to_numpy())


@pytest.mark.parametrize("suffix", [".nc", ".cdf"])
def test_offsets_table_round_trip_any_columns(tmp_path, suffix):
    o = _offsets()
    back = read_product(write_product(tmp_path / f"OFFSETS{suffix}", o))
    assert back.index.equals(o.index)
    assert list(back.columns) == list(o.columns)
    for c in ("start", "end"):
        assert pd.DatetimeIndex(back[c]).equals(pd.DatetimeIndex(o[c]))
    np.testing.assert_array_equal(back["Hp_se"], o["Hp_se"])
    assert back["reason"].tolist() == o["reason"].tolist()
    assert back["n_used"].tolist() == o["n_used"].tolist()
    assert back["days_covered"].isna().tolist() == [False, True, False, False]


@pytest.mark.parametrize("name", ["a.nc", "a.cdf", "OFFSETS.nc", "OFFSETS.cdf"])
def test_bytes_repeat(tmp_path, name):
    """No time of writing in the file (HDF5 object times, gzip headers): a rerun leaves
    byte-identical products (a CDF's Generation_date is the day only)."""
    import time

    f = _offsets() if name.startswith("OFFSETS") else _frame()
    a = write_product(tmp_path / name, f, provenance={"x": 1}).read_bytes()
    time.sleep(1.1)  # gzip and HDF5 stamps have a resolution of one second
    b = write_product(tmp_path / name, f, provenance={"x": 1}).read_bytes()
    assert a == b


def test_unknown_suffix_and_format_are_input_errors(tmp_path):
    from magcal.errors import InputError

    with pytest.raises(InputError, match="suffix"):
        write_product(tmp_path / "a.txt", _frame())
    with pytest.raises(InputError, match="unknown product format"):
        write_product(tmp_path / "a.nc", _frame(), "hdf")
