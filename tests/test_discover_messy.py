"""Discovery on messy input: fills, saturated runs, wrong units, covariates with fill
values, holes or no overlap, renamed columns. Each case is a 10-day 1-min record with
known injected effects (an offset, a local-time term of 4 nT peak to peak in Hp, and
where a covariate is the point, a Dst response of 0.3 nT/nT), and each test asserts
the injected truth or the exact count of damaged samples, not the output of a run.
"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose
from test_discover_cli import LON, geostationary_minutes

from magcal.cli import main
from magcal.discover import discover_gap
from magcal.errors import InputError
from magcal.io.csv import write_csv_frame

#: Dst response (nT of Hp per nT of Dst) injected where a test uses the covariate.
DST_COUPLING = 0.3


def _record(days=10, seed=5, dst_response=False):
    """(measured, model, covariates) of a synthetic geostationary record, 1 min."""
    rng = np.random.default_rng(seed)
    t, lt, model, hidden = geostationary_minutes(days)
    day = np.asarray((t - t[0]).total_seconds() / 86400.0)
    # two storms (Dst down to -80 and -60 nT) with a recovery of a day
    dst = np.zeros(t.size)
    for onset, depth in ((3.2, -80.0), (7.5, -60.0)):
        after = day >= onset
        dst[after] += depth * np.exp(-(day[after] - onset) / 1.0)
    if dst_response:
        hidden[:, 0] += DST_COUPLING * dst
    meas = model + hidden + rng.normal(0, 1.0, (t.size, 3)) + np.array([3.0, -1.0, 0.5])
    cov = pd.DataFrame({"kp": np.full(t.size, 1.0), "dst": dst,
                        "lon_deg": np.full(t.size, LON)}, index=t)
    return meas, model, cov


def _dst_coefficient(result) -> float:
    """The fitted Hp response to Dst (nT per nT) of the activity effect."""
    fe = result.effect("activity")
    return float(fe.parameters["values"]["Hp"]["coefficient_nT_per_nT_dst"])


def test_fill_and_saturated_runs_are_left_out_counted_and_the_effects_stay():
    """A 60-sample run of 99999 in He (a fill value the readers do not know) and two
    hours of all components at 65535 (a saturated converter): before, the gap was
    thousands of nT and no effect was beyond chance; now exactly those samples are
    left out, counted as implausible against the model, and the run ends where the
    undamaged record does (offset and diurnal, the 1 nT noise floor)."""
    meas, model, cov = _record()
    meas.iloc[2000:2060, 1] = 99999.0
    meas.iloc[9000:9120, :] = 65535.0
    res = discover_gap(meas, model, cov[["kp"]], longitude_deg=LON)
    assert res.screened["by_test"]["implausible_vs_model"] == 60 + 120
    assert res.screened["samples"] == 180
    assert res.names[:2] == ["offset", "diurnal"]
    d = res.effect("diurnal").parameters["derived"]["Hp"]
    assert_allclose(d["peak_to_peak_nT"], 4.0, atol=0.3)
    assert_allclose(res.gap_final["rms_nT"], 1.0, atol=0.05)
    assert any("implausible vs model 180" in line for line in res.account())


def test_a_clipped_component_is_left_out():
    """Hp clipped at its own maximum for 30 samples (repeated extreme values): the
    saturation test leaves out exactly those samples."""
    meas, model, _ = _record(days=4)
    top = float(meas["Hp"].max()) + 5.0
    meas.iloc[3000:3030, 0] = top
    res = discover_gap(meas, model, longitude_deg=LON, max_effects=0)
    assert res.screened["by_test"]["saturated"] == 30


@pytest.mark.parametrize("factor, which", [(1000.0, "measured"), (1e-3, "model")])
def test_wrong_units_are_refused_naming_both_files(tmp_path, capsys, factor, which):
    """MEASURED in pT (or MODEL in uT) against nT: exit 2 naming the files, where the
    run used to 'discover' an offset of 1e5 nT and go on."""
    meas, model, _ = _record(days=2)
    if which == "measured":
        meas = meas * factor
    else:
        model = model * factor
    m, mo, out = tmp_path / "m.csv", tmp_path / "model.csv", tmp_path / "r.json"
    write_csv_frame(m, meas)
    write_csv_frame(mo, model)
    assert main(["discover", str(m), str(mo), "--longitude", str(LON), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "wrong units" in err and "m.csv" in err and "model.csv" in err
    assert "Traceback" not in err and not out.exists()


def test_dst_fill_values_are_missing_not_data():
    """Dst with 99999 at 30 hours' samples (the Kyoto/OMNI fill): the fills are not
    data. Before, they were taken as Dst values and the activity coefficient was
    wrong by orders of magnitude; now it is the injected 0.3 nT/nT and the report
    counts the 30 values out of range."""
    meas, model, cov = _record(dst_response=True)
    hourly = cov[["dst"]].resample("1h").mean()
    hourly.iloc[np.arange(10, 220, 7), 0] = 99999.0
    res = discover_gap(meas, model, hourly, longitude_deg=LON)
    assert res.covariates["dst"]["out_of_range"] == 30
    assert res.covariates["dst"]["used"]
    assert "activity" in res.names
    assert_allclose(_dst_coefficient(res), DST_COUPLING, atol=0.03)
    assert any("dst: 30 value(s) outside its physical range" in x for x in res.account())


def test_a_covariate_hole_is_not_bridged_and_its_samples_are_counted():
    """Hourly Dst missing over the first storm (days 3.0-4.5): the interpolated line
    across the hole is flat where the storm was. The samples in the hole are left out
    and counted (exactly the minutes from the last value before the hole to the first
    after it, exclusive) and the coefficient is the injected one."""
    meas, model, cov = _record(dst_response=True)
    hourly = cov[["dst"]].resample("1h").mean()
    hole = (hourly.index >= "2019-11-04T00:00Z") & (hourly.index < "2019-11-05T12:00Z")
    hourly.loc[hole, "dst"] = np.nan
    res = discover_gap(meas, model, hourly, longitude_deg=LON)
    last, first = hourly.index[~hole][hourly.index[~hole] < "2019-11-04"][-1], \
        hourly.index[hole][-1] + pd.Timedelta(hours=1)
    inside = int(((meas.index > last) & (meas.index < first)).sum())
    assert res.screened["covariate_unknown"] == inside
    assert_allclose(_dst_coefficient(res), DST_COUPLING, atol=0.03)
    # bridged, the hole's flat Dst left the storm to a step and a drift (none injected)
    assert "step" not in res.names and "drift" not in res.names


def test_covariates_that_do_not_overlap_are_exit_2(tmp_path, capsys):
    """COV.csv a year after the data: every covariate would be held at its first value
    over the whole record (a constant, so no activity can be found). Exit 2 naming
    the covariates file and both spans."""
    meas, model, cov = _record(days=2)
    cov.index = cov.index + pd.Timedelta(days=365)
    paths = [tmp_path / n for n in ("m.csv", "model.csv", "cov.csv")]
    for p, frame in zip(paths, (meas, model, cov)):
        write_csv_frame(p, frame)
    out = tmp_path / "r.json"
    assert main(["discover", *map(str, paths[:2]), "--covariates", str(paths[2]),
                 "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "cov.csv" in err and "2020-11-" in err and "2019-11-01" in err
    assert not out.exists()


def test_kp_given_times_ten_is_a_unit_error():
    """Kp x 10 (0-90, as in some index files): exit-2 error naming the column."""
    meas, model, cov = _record(days=2)
    cov["kp"] = np.r_[np.full(1000, 13.0), np.full(len(cov) - 1000, 30.0)]
    with pytest.raises(InputError, match="kp.*wrong units"):
        discover_gap(meas, model, cov, longitude_deg=LON, max_effects=0)


def test_a_short_covariate_is_not_used_and_said(tmp_path, capsys):
    """Dst for only the first 2 of 10 days: not used (the 8 days without it are not
    left out), and the account says why."""
    meas, model, cov = _record()
    cov2 = cov[["kp", "dst"]].copy()
    cov2.loc[cov2.index >= "2019-11-03", "dst"] = np.nan
    res = discover_gap(meas, model, cov2, longitude_deg=LON, max_effects=1)
    assert not res.covariates["dst"]["used"] and res.covariates["kp"]["used"]
    # two days, and the minute after the last value (within one spacing of it)
    assert res.covariates["dst"]["samples_known"] == 2 * 1440 + 1
    assert "covariate_unknown" not in res.screened
    assert any(line.startswith("covariate dst not used: known at only 2881 of 14400")
               for line in res.account())


def test_columns_left_aside_are_named(tmp_path, capsys):
    """Hp renamed hp in MEASURED: the run uses He and Hn, and REPORT.json and the
    account name the column left aside (it used to go unsaid)."""
    meas, model, cov = _record(days=3)
    paths = [tmp_path / n for n in ("m.csv", "model.csv")]
    write_csv_frame(paths[0], meas.rename(columns={"Hp": "hp"}))
    write_csv_frame(paths[1], model)
    out = tmp_path / "r.json"
    assert main(["discover", *map(str, paths), "--longitude", str(LON), "--max-effects", "1",
                 "-o", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["components"] == ["He", "Hn"]
    assert doc["columns_not_used"] == {"measured": ["hp"], "model": ["Hp"], "all_missing": []}
    assert "measured column(s) hp not in the other file" in capsys.readouterr().err


def test_a_constant_kp_does_not_hide_a_dst_response():
    """Kp at one value over the record (a quiet stretch, or a Kp file of one value)
    beside a varying Dst: the Kp column, referred to its mean, is all zeros. It made the
    activity term singular and the injected 0.3 nT/nT Dst response was never named
    (only an offset, 3.4 nT left); now the term takes Dst alone."""
    meas, model, cov = _record(dst_response=True)
    assert cov["kp"].nunique() == 1
    res = discover_gap(meas, model, cov[["kp", "dst"]], longitude_deg=LON)
    assert "activity" in res.names
    assert res.effect("activity").parameters["indices"] == ["dst"]
    assert_allclose(_dst_coefficient(res), DST_COUPLING, atol=0.03)


def test_cli_says_what_the_reader_repaired(tmp_path, capsys):
    """-1e31 fills in MEASURED become NaN in the reader (those samples drop out of the
    fit): the verb says how many per column and records them in the provenance."""
    meas, model, _ = _record(days=2)
    meas.iloc[100:140, 2] = -1e31
    paths = [tmp_path / n for n in ("m.csv", "model.csv")]
    write_csv_frame(paths[0], meas)
    write_csv_frame(paths[1], model)
    out = tmp_path / "r.json"
    assert main(["discover", *map(str, paths), "--longitude", str(LON), "--max-effects", "0",
                 "-o", str(out)]) == 0
    assert "m.csv: fill value replaced by NaN in Hn (40)" in capsys.readouterr().err
    doc = json.loads(out.read_text())
    (done,) = doc["provenance"]["parameters"]["input_repairs"].values()
    assert done == [{"what": "fill value replaced by NaN", "column": "Hn", "count": 40}]


def test_rows_at_times_the_other_file_lacks_are_counted():
    """A model at 5 min beside 1-min data: the discovery runs on the common times, and
    the 4 of every 5 measured rows it leaves out are counted (they were dropped unsaid)."""
    meas, model, _ = _record(days=2)
    res = discover_gap(meas, model.iloc[::5], longitude_deg=LON, max_effects=0)
    assert res.screened["no_common_time"] == {"measured": 2 * 1440 * 4 // 5, "model": 0}
    assert any("left out 2304 measured and 0 model row(s)" in x for x in res.account())


def test_a_covariate_for_two_weeks_of_a_month_is_used_on_them():
    """Dst for the first 15 days of 30 (half of the samples, but two weeks of data): it is
    used, the 15 days without it are left out and counted, and its coefficient is the
    injected one; not used, the storm field would have no regressor."""
    meas, model, cov = _record(days=30, dst_response=True)
    hourly = cov[["dst"]].resample("1h").mean().iloc[: 15 * 24]
    res = discover_gap(meas, model, hourly, longitude_deg=LON, max_effects=3)
    assert res.covariates["dst"]["used"]
    # the last hourly value (day 15 minus 1 h) covers its hour: day 15 00:00 is known
    assert res.screened["covariate_unknown"] == 15 * 1440 - 1
    assert_allclose(_dst_coefficient(res), DST_COUPLING, atol=0.03)
