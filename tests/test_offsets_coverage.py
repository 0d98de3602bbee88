"""Offsets say when the record is far shorter than the window and refuse thin windows.

Issue 13 case 8: on the GOES-16 minutes ``offsets fit`` answered only that no sample had
Kp <= 1, and loosened it wrote a "28-day" offset from 7 one-minute samples with exit 0.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from magcal.cli import main
from magcal.errors import InputError
from magcal.offsets import OffsetEstimator, window_coverage
from magcal.offsets.estimator import MIN_DAY_COVERAGE, MIN_LT_COVERAGE, short_record_warning
from magcal.offsets.windows import DAY_NS, thin_coverage_reason

MINUTE = np.timedelta64(60, "s")


def _minutes(start: str, n: int, every: int = 1) -> np.ndarray:
    return np.datetime64(start, "ns") + np.arange(n) * every * MINUTE


def test_window_coverage_counts_days_and_local_time_hours():
    # 3 samples on day 0 (LT 1.0, 1.5, 13.0 h), one on day 2 that is not selected
    t = np.array([0, 60, 2 * 3600, 2 * 86400], dtype=np.int64) * 10**9
    cov = window_coverage(t, [True, True, True, False], [0, DAY_NS], [28 * DAY_NS, 29 * DAY_NS],
                          local_time_h=[1.0, 1.5, 13.0, 5.0])
    assert_array_equal(cov["days_covered"], [1, 0])
    assert_array_equal(cov["lt_hours_covered"], [2, 0])
    assert_allclose(cov["window_days"], [28.0, 28.0])
    assert_array_equal(window_coverage(t, np.ones(4, bool), [0], [DAY_NS])["lt_hours_covered"],
                       [-1])


def test_thin_coverage_thresholds_are_the_documented_ones():
    assert MIN_DAY_COVERAGE == 0.25 and MIN_LT_COVERAGE == 0.5
    # 7 of 28 days and 12 of 24 hours are enough; one less is not
    assert thin_coverage_reason(7, 28.0, 12, MIN_DAY_COVERAGE, MIN_LT_COVERAGE) == ""
    assert "6 of 28 days" in thin_coverage_reason(6, 28.0, 12, 0.25, 0.5)
    assert "11 of 24 local-time hours" in thin_coverage_reason(7, 28.0, 11, 0.25, 0.5)


def test_short_record_warning_names_the_span():
    assert short_record_warning(7 / 1440, 28) == ("record spans 7 min, far shorter than the "
                                                 "28-day window")
    assert "5.0 h" in short_record_warning(5 / 24, 28)
    assert short_record_warning(6.9, 28) != "" and short_record_warning(7.0, 28) == ""


def test_thin_window_is_nan_with_reason_and_loosened_is_cautioned():
    # 3 days of quiet 1-min data, all in the first 6 local-time hours of each day
    t = np.concatenate([_minutes(f"2019-11-0{d}T00:00", 360) for d in (1, 2, 3)])
    offset = np.array([3.0, -2.0, 1.0])
    data = np.tile(offset, (t.size, 1))
    model = np.zeros_like(data)
    est = OffsetEstimator(min_used=10).fit(t, data, model, np.zeros(t.size), lon_deg=0.0)
    tab = est.table_
    assert len(tab) == 1 and not tab.valid[0]
    assert tab.days_covered[0] == 3 and tab.lt_hours_covered[0] == 6
    assert tab.reason[0].startswith("coverage too thin to trust: used samples on 3 of 28 days")
    assert "record spans 2.2 days, far shorter than the 28-day window" in tab.reason[0]
    assert est.warnings_ == tab.warnings and len(tab.warnings) == 1
    # statistics of the thin window stay in the table for the reader to judge
    assert tab.n_used[0] == t.size and np.all(np.isfinite(tab.mad_nT[0]))
    loose = OffsetEstimator(min_used=10, min_day_fraction=0.0, min_lt_fraction=0.0).fit(
        t, data, model, np.zeros(t.size), lon_deg=0.0).table_
    assert loose.valid[0]
    assert_allclose(loose.offset_nT[0], offset, atol=1e-12)
    assert loose.reason[0].startswith("caution: record spans 2.2 days")


def test_well_covered_month_has_no_caution():
    t = _minutes("2019-11-01T00:00", 30 * 1440)
    data = np.tile([1.0, 2.0, 3.0], (t.size, 1))
    tab = OffsetEstimator().fit(t, data, np.zeros_like(data), np.zeros(t.size),
                                lon_deg=128.2).table_
    assert tab.valid.all() and tab.reason == ("", "") and tab.warnings == ()
    # the second window [Nov 8, Dec 6) holds Nov 8..30: 23 days, all 24 hours
    assert_array_equal(tab.days_covered, [28, 23])
    assert_array_equal(tab.lt_hours_covered, [24, 24])


def test_fit_offsets_frame_checks_its_parameters():
    from magcal.models.inputs import ModelInputs
    from magcal.offsets import fit_offsets_frame

    frame = pd.DataFrame({"Hp": [1.0]}, index=pd.DatetimeIndex(["2019-11-01"], tz="UTC"))
    inp = ModelInputs(lon_deg=128.2, lat_deg=0.0, r_re=6.6, kp=pd.Series(dtype=float),
                      drivers=None, model="T89")
    with pytest.raises(InputError, match="kp_max 10"):
        fit_offsets_frame(frame, inp, kp_max=10)
    with pytest.raises(InputError, match="min_lt_fraction 2"):
        fit_offsets_frame(frame, inp, min_lt_fraction=2)
    with pytest.raises(InputError, match="missing column"):
        fit_offsets_frame(frame, inp)


@pytest.fixture(scope="module")
def goes_minutes(tmp_path_factory, request):
    """The 7 GOES-16 one-minute files as a CONTRACTS CSV with the file's position."""
    from conftest import real_data_path

    from magcal.io.csv import write_csv_frame
    from magcal.missions.goes import read_goes_mag

    files = sorted(real_data_path("goes16", "l2_hires_5min").glob("*.nc"))
    kp = real_data_path("indices", "celestrak_SW_2017-2023_subset.txt")
    frame = read_goes_mag(files)
    path = tmp_path_factory.mktemp("goes") / "GOES.csv"
    write_csv_frame(path, frame[["Hp", "He", "Hn", "lon_deg", "lat_deg", "r_re"]])
    return path, kp, frame


@pytest.mark.realdata
def test_goes_minutes_offsets_say_what_minutes_cannot_give(goes_minutes, tmp_path, capsys):
    path, kp, frame = goes_minutes
    # the record as read off the file: 02:08:59.9 to 02:15:59.8 UTC at 10 Hz
    assert frame.index[0].strftime("%H:%M:%S") == "02:08:59"
    assert frame.index[-1].strftime("%H:%M:%S") == "02:15:59"
    out = tmp_path / "OFFSETS.csv"
    base = ["offsets", "fit", str(path), "--kp", str(kp), "--jobs", "1", "-o", str(out)]
    assert main(base) == 0
    err = capsys.readouterr().err
    assert "warning: record spans 7 min, far shorter than the 28-day window" in err
    off = pd.read_csv(out, keep_default_na=False)
    assert len(off) == 1 and off.loc[0, "Hp"] == "NaN"
    # Kp on 2017-03-05 00-03 UT is 27 (x10) in the CelesTrak file: nothing is quiet
    assert off.loc[0, "reason"].startswith("too few quiet samples: n_used=0")
    assert "record spans 7 min" in off.loc[0, "reason"]

    # loosened Kp and sample count: 7 whole minutes remain (02:09..02:15; the lone
    # 0.1 s sample of 02:08 does not fill a minute), on 1 day, all at local time
    # 02:09 UT - 89.5/15 h = 20.2 h: one local-time hour
    assert main(base + ["--kp-max", "9", "--min-used", "1"]) == 0
    err = capsys.readouterr().err
    assert "1 with coverage too thin to trust" in err and "record spans 7 min" in err
    off = pd.read_csv(out, keep_default_na=False)
    assert off.loc[0, "Hp"] == "NaN" and int(off.loc[0, "n_used"]) == 7
    assert int(off.loc[0, "days_covered"]) == 1 and int(off.loc[0, "lt_hours_covered"]) == 1
    assert off.loc[0, "reason"].startswith(
        "coverage too thin to trust: used samples on 1 of 28 days (< 25%) and in 1 of 24 "
        "local-time hours (< 50%)")

    # with every threshold switched off the number comes out, still marked
    assert main(base + ["--kp-max", "9", "--min-used", "1", "--min-day-coverage", "0",
                        "--min-lt-coverage", "0"]) == 0
    off = pd.read_csv(out, keep_default_na=False)
    assert off.loc[0, "Hp"] != "NaN"
    assert off.loc[0, "reason"] == "caution: record spans 7 min, far shorter than the 28-day window"
    assert "warning: record spans 7 min" in capsys.readouterr().err


@pytest.mark.realdata
def test_goes_netcdf_file_read_directly(tmp_path, capsys):
    """One GOES-16 one-minute file given as it is: one minute of a 28-day window."""
    from conftest import real_data_path

    nc = sorted(real_data_path("goes16", "l2_hires_5min").glob("*.nc"))[0]
    kp = real_data_path("indices", "celestrak_SW_2017-2023_subset.txt")
    out = tmp_path / "OFFSETS.csv"
    assert main(["offsets", "fit", str(nc), "--kp", str(kp), "--jobs", "1", "-o", str(out)]) == 0
    assert "warning: record spans 1 min, far shorter than the 28-day window" in (
        capsys.readouterr().err)
    off = pd.read_csv(out, keep_default_na=False)
    assert off.loc[0, "Hp"] == "NaN" and "record spans 1 min" in off.loc[0, "reason"]


@pytest.mark.realdata
def test_apply_says_when_samples_lie_in_no_valid_window(goes_minutes, tmp_path, capsys):
    """The 2017-03-05 window [Mar 5, Apr 2) applied to the 2017-04-14 files, and to itself."""
    from conftest import real_data_path

    path, kp, _ = goes_minutes
    table = tmp_path / "OFFSETS.csv"
    assert main(["offsets", "fit", str(path), "--kp", str(kp), "--jobs", "1", "--kp-max", "9",
                 "--min-used", "1", "--min-day-coverage", "0", "--min-lt-coverage", "0",
                 "-o", str(table)]) == 0
    capsys.readouterr()
    later = sorted(real_data_path("goes16", "l2_hires_gap").glob("*.nc"))[0]
    out = tmp_path / "CORRECTED.csv"
    assert main(["offsets", "apply", str(later), "--offsets", str(table), "-o", str(out)]) == 0
    # 10 Hz for one minute, twelve days after the window's end
    assert "warning: 600 of 600 samples lie in no valid window" in capsys.readouterr().err
    assert main(["offsets", "apply", str(path), "--offsets", str(table), "-o", str(out)]) == 0
    assert "no valid window" not in capsys.readouterr().err
