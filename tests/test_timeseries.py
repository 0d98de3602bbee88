"""The VectorSeries container: validation, counted repairs, gaps, resampling."""

import numpy as np
import pandas as pd
import pytest

from magcal.errors import InputError
from magcal.timeseries import VectorSeries, validate_frame


def _times(n, freq="1s"):
    return pd.date_range("2019-03-04", periods=n, freq=freq, tz="UTC")


def test_flat_multisensor_columns_are_grouped(tmp_path):
    t = _times(4)
    df = pd.DataFrame({f"{s}_{c}": np.arange(4.0) + k for k, (s, c) in enumerate(
        [(s, c) for s in ("fgmo", "amr1") for c in "xyz"])}, index=t)
    df["temperature"] = 20.0
    vs = VectorSeries.from_frame(df, frame_name="OSRF")
    assert vs.sensors == ("fgmo", "amr1") and vs.components == ("x", "y", "z")
    np.testing.assert_array_equal(vs["amr1"][:, 2], np.arange(4.0) + 5)
    assert list(vs.aux.columns) == ["temperature"]
    assert list(vs.to_frame().columns) == list(df.columns)


def test_hpen_single_vector_and_csv(tmp_path):
    path = tmp_path / "h.csv"
    path.write_text("time,Hp,He,Hn\n2019-03-04T00:00:00,1,2,3\n2019-03-04T00:01:00,4,5,6\n")
    vs = VectorSeries.read_csv(path)
    assert vs.sensors == ("",) and vs.components == ("Hp", "He", "Hn")
    np.testing.assert_array_equal(vs.vector(), [[1, 2, 3], [4, 5, 6]])
    assert vs.cadence_s == 60.0
    assert vs.provenance[0]["step"] == "read_csv"


def test_repairs_are_counted_not_silent():
    t = pd.DatetimeIndex(["2019-03-04T00:00:02", "2019-03-04T00:00:00", "2019-03-04T00:00:01",
                          "2019-03-04T00:00:01"], tz="UTC")
    df = pd.DataFrame({"x": [3.0, 1.0, 2.0, 2.0], "y": [-9999.0, 0, 0, 0]}, index=t)
    with pytest.raises(InputError, match="backwards"):
        validate_frame(df)
    with pytest.raises(InputError, match="duplicate"):
        validate_frame(df, on_unsorted="sort")
    clean, rep = validate_frame(df, on_unsorted="sort", on_duplicate="drop")
    assert clean["x"].tolist() == [1.0, 2.0, 3.0]
    what = {r.what: r.count for r in rep.repairs}
    assert what == {"sorted out-of-order samples": 4, "dropped exact duplicate samples": 1,
                    "fill value replaced by NaN": 1}
    assert rep.n_rows_in == 4 and rep.n_rows_out == 3


def test_conflicting_duplicates_always_error():
    t = pd.DatetimeIndex(["2019-03-04T00:00:00", "2019-03-04T00:00:00"], tz="UTC")
    with pytest.raises(InputError, match="duplicate"):
        validate_frame(pd.DataFrame({"x": [1.0, 2.0]}, index=t), on_duplicate="drop")


def test_mixed_cadence_detected_but_gaps_allowed():
    base = _times(10).as_unit("ns")
    gap = base.delete([4, 5])  # a 3 s gap: a multiple of the cadence, fine
    clean, rep = validate_frame(pd.DataFrame({"x": np.ones(8)}, index=gap))
    assert rep.cadence_s == 1.0 and rep.repairs == ()
    mixed = base.append(pd.date_range(base[-1] + pd.Timedelta("1.5s"), periods=3, freq="1.5s"))
    with pytest.raises(InputError, match="mixed cadence"):
        validate_frame(pd.DataFrame({"x": np.ones(13)}, index=mixed))
    _, rep = validate_frame(pd.DataFrame({"x": np.ones(13)}, index=mixed), mixed_cadence="allow")
    assert rep.repairs[0].count == 3


def test_wrong_shapes_and_names():
    with pytest.raises(InputError, match=r"expected shape \(3, 3\)"):
        VectorSeries.from_arrays(_times(3), {"a": np.ones((3, 2))})
    with pytest.raises(InputError, match="no vector columns"):
        VectorSeries.from_frame(pd.DataFrame({"foo": [1.0]}, index=_times(1)))
    with pytest.raises(InputError, match="not in data"):
        VectorSeries.from_arrays(_times(3), {"a": np.ones((3, 3))})["b"]


def test_gaps_lists_missing_samples_and_nan_runs():
    t = _times(20).delete(range(5, 10))
    v = np.ones((15, 3))
    v[10:12, 1] = np.nan
    vs = VectorSeries.from_arrays(t, {"a": v})
    gaps = vs.gaps()
    assert gaps["kind"].tolist() == ["missing samples", "NaN"]
    assert gaps["duration_s"].tolist() == [6.0, 3.0]


def test_resample_never_bridges_long_gaps():
    t = _times(100).delete(range(40, 60))  # 21 s gap
    x = np.arange(100.0)[np.r_[0:40, 60:100]]
    vs = VectorSeries.from_arrays(t, {"a": np.column_stack([x, x, x])})
    grid = vs.resample(1.0, max_gap_s=10.0, method="interp")
    a = grid["a"][:, 0]
    assert len(grid) == 100 and np.isnan(a[40:60]).all()
    np.testing.assert_allclose(a[:40], np.arange(40.0))
    bridged = vs.resample(1.0, max_gap_s=30.0, method="interp")["a"][:, 0]
    np.testing.assert_allclose(bridged, np.arange(100.0))  # linear data: exact
    assert grid.provenance[-1]["step"] == "resample"


def test_resample_mean_bins_and_empty_cells():
    t = _times(180).delete(range(60, 120))
    kept = np.arange(180.0)[np.r_[0:60, 120:180], None]
    vs = VectorSeries.from_arrays(t, {"a": np.tile(kept, 3)})
    m = vs.resample(60, max_gap_s=0)["a"][:, 0]
    assert m[0] == 29.5 and np.isnan(m[1]) and m[2] == 149.5
