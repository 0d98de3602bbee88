"""Instrument files detected by content, read into one frame layout, and converted."""

import gzip
import struct

import numpy as np
import pandas as pd
import pytest

from magcal.cli import main
from magcal.errors import InputError
from magcal.io.formats import detect_format, read_any, write_any
from conftest import real_data_path


def _frame(n=5):
    t = pd.date_range("2019-03-04", periods=n, freq="1s", tz="UTC", name="time")
    return pd.DataFrame({"fgmo_x": np.arange(n, dtype=float), "fgmo_y": 2.0, "fgmo_z": -1.5,
                         "Hp": 1.0, "He": 2.0, "Hn": np.r_[3.0, np.nan, 3.0, 3.0, 3.0][:n],
                         "lon_deg": 128.2}, index=t)


def test_detection_ignores_the_file_name(tmp_path):
    csv = tmp_path / "data.nc"
    write_any(csv, _frame(), "csv")
    assert detect_format(csv) == "csv"
    gz = tmp_path / "data.bin"
    gz.write_bytes(gzip.compress(csv.read_bytes()))
    assert detect_format(gz) == "csv"
    cdf = tmp_path / "data.csv"
    write_any(cdf, _frame(), "cdf")
    assert detect_format(cdf) == "cdf"


@pytest.mark.parametrize("content, message", [
    (b"", "empty file"),
    (b"\x00\x01\x02binary garbage\xff" * 10, "binary content"),
    (b"CDF\x01" + b"\x00" * 40, "netCDF-3"),
    (b"TIME_UTC BISX BISY\n2006-06-09T01:43:18 1 2\n", "not a CSV header"),
])
def test_unsupported_content_names_the_file_and_the_formats(tmp_path, content, message):
    path = tmp_path / "bad.dat"
    path.write_bytes(content)
    with pytest.raises(InputError, match=message) as exc:
        read_any(path)
    assert "bad.dat" in str(exc.value) and "GOES-R MAG L2" in str(exc.value)


def test_hdf5_without_goes_variables_is_refused(tmp_path):
    import h5py

    path = tmp_path / "other.h5"
    with h5py.File(path, "w") as f:
        f["x"] = np.arange(3)
    with pytest.raises(InputError, match="without GOES-R MAG L2 variables"):
        read_any(path)


def test_csv_cdf_round_trip_keeps_values_nan_and_times(tmp_path):
    src = _frame()
    cdf = write_any(tmp_path / "a.cdf", src, "cdf")
    back = read_any(cdf)
    assert back.attrs["format"] == "cdf"
    np.testing.assert_array_equal(back.index.as_unit("ns").asi8, src.index.as_unit("ns").asi8)
    np.testing.assert_array_equal(back[src.columns].to_numpy(), src.to_numpy())


def test_convert_cli_joins_goes_files_and_round_trips(tmp_path):
    folder = real_data_path("goes16", "l2_hires_5min")
    files = sorted(str(p) for p in folder.glob("*.nc"))
    cdf, csv = tmp_path / "g.cdf", tmp_path / "g.csv"
    assert main(["convert", *files, "-o", str(cdf)]) == 0
    assert main(["convert", str(cdf), "-o", str(csv)]) == 0
    direct = read_any(files[0])
    back = read_any(csv)
    assert len(back) == 4200  # 7 one-minute files at 10 Hz
    # the first sample as stored in the netCDF file (float32), read by the GOES reader
    np.testing.assert_allclose(back.iloc[0][["Hp", "He", "Hn", "brf_x"]].to_numpy(dtype=float),
                               direct.iloc[0][["Hp", "He", "Hn", "brf_x"]].to_numpy(dtype=float),
                               atol=1e-4)


def test_convert_cli_refuses_an_unsupported_file_with_exit_2(tmp_path, capsys):
    vex = real_data_path("multi-sensor", "VEX128.txt")
    assert main(["convert", str(vex), "-o", str(tmp_path / "v.csv")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "VEX128.txt" in err[0] and "supported" in err[0]
    assert not (tmp_path / "v.csv").exists()


def test_real_files_are_detected(real_data):
    assert detect_format(real_data("elfin", "ela_l1_fgs_20220112_v01.cdf")) == "cdf"
    goes = sorted(real_data("goes16", "l2_hires_gap").glob("*.nc"))[0]
    assert detect_format(goes) == "goes-netcdf"
    fgs = read_any(real_data("elfin", "ela_l1_fgs_20220112_v01.cdf"))
    assert list(fgs.columns) == ["b1", "b2", "b3"]


def test_cdf_reader_keeps_values_of_an_istp_file(tmp_path):
    # struct check that the CDF writer's magic is what detection expects
    path = write_any(tmp_path / "m.cdf", _frame(), "cdf")
    assert struct.unpack(">I", path.read_bytes()[:4])[0] in (0xCDF30001, 0xCCCC0001)
