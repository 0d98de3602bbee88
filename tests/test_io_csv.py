"""CSV reader/writer against CONTRACTS §0, with line-numbered errors."""

import numpy as np
import pandas as pd
import pytest

from magcal.errors import InputError
from magcal.io.csv import format_times, read_csv_frame, write_csv_frame


def _write(tmp_path, text, name="in.csv"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_round_trip_values_and_times(tmp_path):
    t = pd.date_range("2019-03-04T15:10:00", periods=5, freq="250ms", tz="UTC")
    df = pd.DataFrame({"fgmo_x": [1.25, np.nan, -3.5, 4.0, 1e-4],
                       "fgmo_y": np.arange(5.0), "fgmo_z": -np.arange(5.0)}, index=t)
    path = write_csv_frame(tmp_path / "out.csv", df)
    back = read_csv_frame(path)
    assert back.index.equals(t.as_unit("ns").rename("time"))
    np.testing.assert_allclose(back.to_numpy(), df.to_numpy(), atol=5e-5, equal_nan=True)
    lines = path.read_text().splitlines()
    assert lines[1] == "2019-03-04T15:10:00.000,1.2500,0.0000,-0.0000"  # -0.0 kept
    assert lines[2].split(",")[1] == "NaN"


def test_whole_second_times_written_without_fraction(tmp_path):
    t = pd.date_range("2019-03-04", periods=2, freq="1s", tz="UTC")
    path = write_csv_frame(tmp_path / "o.csv", pd.DataFrame({"Hp": [1.0, 2.0]}, index=t))
    assert path.read_text().splitlines()[1].startswith("2019-03-04T00:00:00,")


def test_z_suffix_fractional_seconds_and_missing_cells(tmp_path):
    path = _write(tmp_path, "time,Hp,He,Hn\n2019-03-04T15:10:00Z,1,,3\n"
                            "2019-03-04T15:10:00.5Z,NaN,2,3\n")
    df = read_csv_frame(path, required=["Hp", "He", "Hn"])
    assert df.index[1] == pd.Timestamp("2019-03-04T15:10:00.5", tz="UTC")
    assert np.isnan(df["He"].iloc[0]) and np.isnan(df["Hp"].iloc[1])
    assert df.attrs["n_missing"] == {"Hp": 1, "He": 1, "Hn": 0}


def test_fill_values_become_nan_and_are_counted(tmp_path):
    path = _write(tmp_path, "time,x\n2019-01-01T00:00:00,-1e31\n2019-01-01T00:00:01,-9999\n"
                            "2019-01-01T00:00:02,-9998\n")
    df = read_csv_frame(path)
    assert df["x"].isna().tolist() == [True, True, False]
    assert df.attrs["repairs"] == [{"what": "fill value replaced by NaN", "column": "x",
                                    "count": 2}]


@pytest.mark.parametrize("body, line, column, words", [
    ("2019-01-01T00:00:01,1\n2019-01-01T00:00:00,2\n", 3, "time", "backwards"),
    ("2019-01-01T00:00:00,1\n2019-01-01T00:00:00,2\n", 3, "time", "duplicate"),
    ("2019-01-01T00:00:00,1\nyesterday,2\n", 3, "time", "cannot parse"),
    ("2019-01-01T00:00:00,1\n2019-01-01T00:00:01,1.2.3\n", 3, "x", "not a number"),
])
def test_errors_name_file_line_and_column(tmp_path, body, line, column, words):
    path = _write(tmp_path, "time,x\n" + body)
    with pytest.raises(InputError) as err:
        read_csv_frame(path)
    assert err.value.row == line and err.value.column == column
    assert words in str(err.value) and str(path) in str(err.value)


def test_header_problems(tmp_path):
    with pytest.raises(InputError, match="first column must be 'time'"):
        read_csv_frame(_write(tmp_path, "t,x\n2019-01-01,1\n"))
    with pytest.raises(InputError, match="missing required column"):
        read_csv_frame(_write(tmp_path, "time,Hp\n2019-01-01,1\n"), required=["Hp", "He"])
    with pytest.raises(InputError, match="no data rows"):
        read_csv_frame(_write(tmp_path, "time,Hp\n"))
    with pytest.raises(InputError, match="file is empty"):
        read_csv_frame(_write(tmp_path, ""))
    with pytest.raises(InputError, match="file not found"):
        read_csv_frame(tmp_path / "nope.csv")


def test_failed_write_leaves_no_file(tmp_path):
    t = pd.DatetimeIndex(["2019-01-01T00:00:01", "2019-01-01T00:00:00"], tz="UTC")
    with pytest.raises(InputError):
        write_csv_frame(tmp_path / "bad.csv", pd.DataFrame({"x": [1.0, 2.0]}, index=t))
    assert list(tmp_path.iterdir()) == []


def test_provenance_sidecar(tmp_path):
    t = pd.date_range("2019-01-01", periods=2, freq="1s", tz="UTC")
    path = write_csv_frame(tmp_path / "p.csv", pd.DataFrame({"x": [1.0, 2.0]}, index=t),
                           provenance={"step": "test"})
    assert path == tmp_path / "p.csv"
    assert (tmp_path / "p.csv.provenance.json").read_text().count('"step": "test"') == 1


def test_compressed_output_is_really_compressed(tmp_path):
    t = pd.date_range("2019-01-01", periods=500, freq="1s", tz="UTC")
    df = pd.DataFrame({"x": np.zeros(500)}, index=t)
    path = write_csv_frame(tmp_path / "z.csv.gz", df)
    assert path.read_bytes()[:2] == b"\x1f\x8b"  # gzip magic
    np.testing.assert_array_equal(read_csv_frame(path)["x"].to_numpy(), np.zeros(500))
    assert oct(path.stat().st_mode & 0o777) != oct(0o600)  # not left private by mkstemp


@pytest.mark.parametrize("raw, values, what", [
    (b"time,x\r\n2019-01-01T00:00:00,1\r\n2019-01-01T00:00:01,2\r\n", [1.0, 2.0], None),
    (b"\xef\xbb\xbftime,x\n2019-01-01T00:00:00,1\n", [1.0], None),
    (b"time,x\n2019-01-01T00:00:00,1\n   \n\n2019-01-01T00:00:01,2\n", [1.0, 2.0], None),
    (b"time,x,\n2019-01-01T00:00:00,1,\n", [1.0], "unnamed empty last column dropped"),
    (b"time,x\n2019-01-01T00:00:00,1\n2019-01-01T00:00:01,2", [1.0, 2.0], "no line break"),
])
def test_harmless_variants_read_or_are_repaired_and_counted(tmp_path, raw, values, what):
    path = tmp_path / "v.csv"
    path.write_bytes(raw)
    df = read_csv_frame(path)
    assert df["x"].tolist() == values
    repairs = [r["what"] for r in df.attrs["repairs"]]
    if what is None:
        assert repairs == []
    else:
        assert len(repairs) == 1 and what in repairs[0]


@pytest.mark.parametrize("raw, line, column, words", [
    # blank lines do not shift the line named
    (b"time,x\n\n2019-01-01T00:00:00,1\n\n2019-01-01T00:00:01,y\n", 5, "x", "not a number"),
    (b"time,x\n2019-01-01T00:00:00,1\n2019-01-01T00:00:01\n", 3, None, "1 fields where"),
    (b"time,x\n2019-01-01T00:00:00,1,2\n", 2, None, "3 fields where the header has 2"),
    (b'time,x,n\n2019-01-01T00:00:00,1,"a,b"\n2019-01-01T00:00:01,2\n', 3, None,
     "2 fields where the header has 3"),
    (b"time,x,\n2019-01-01T00:00:00,1,5\n", 1, None, "column 3 of the header has no name"),
    (b"time,x,x\n2019-01-01T00:00:00,1,5\n", 1, "x", "duplicate column 'x'"),
    (b"time,x\n2019-01-01T00:00:00,\xff\n", 2, None, "byte 0xff is not UTF-8"),
    (b"time,x\n2016-12-31T23:59:60,1\n", 2, "time", "leap second"),
    (b"time,x\n2019-01-01T00:00:00+01:00,1\n", 2, "time", "UTC offset +01:00"),
    (b"time,x\n2529,1\n", 2, "time", "outside 1677-2262"),
])
def test_damage_names_the_line(tmp_path, raw, line, column, words):
    path = tmp_path / "d.csv"
    path.write_bytes(raw)
    with pytest.raises(InputError) as err:
        read_csv_frame(path)
    assert err.value.row == line and err.value.column == column, str(err.value)
    assert words in str(err.value) and str(path) in str(err.value)


def test_fast_writer_writes_the_bytes_pandas_writes(tmp_path):
    """write_csv_frame formats plain float/integer tables itself; the truth is pandas'
    own ``to_csv`` with the same format: NaN, +-inf, -0.0, float32, int8/uint16 columns
    and a column name holding "nan" come out byte for byte alike."""
    rng = np.random.default_rng(3)
    n = 1000
    index = pd.date_range("2019-11-01", periods=n, freq="1s", tz="UTC")
    frame = pd.DataFrame({"nanoT": rng.normal(0, 100, n), "small": rng.normal(0, 1e-5, n),
                          "f32": rng.normal(size=n).astype(np.float32),
                          "quality": rng.integers(0, 64, n).astype(np.int8),
                          "count": rng.integers(0, 9, n).astype(np.uint16)}, index=index)
    frame.iloc[::97, 0] = np.nan
    frame.iloc[3, 0], frame.iloc[4, 0], frame.iloc[5, 1] = np.inf, -np.inf, -0.0
    for fmt in ("%.4f", "%.3e"):
        path = write_csv_frame(tmp_path / "fast.csv", frame, float_format=fmt)
        ref = frame.copy()
        ref.index = pd.Index(format_times(index), name="time")
        ref.to_csv(tmp_path / "pandas.csv", float_format=fmt, na_rep="NaN",
                   index_label="time")
        assert path.read_bytes() == (tmp_path / "pandas.csv").read_bytes(), fmt
