"""model_field_hpen: Hpen rotation, cadence grid, parallel == serial, disk cache."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from magcal.frames.hpen import geo_to_hpen
from magcal.models import irbem
from magcal.models.field import model_field_hpen


def _minutes(n, start="2019-11-01T00:00"):
    return np.datetime64(start, "ns") + np.arange(n) * np.timedelta64(60, "s")


def test_hpen_matches_direct_geo_evaluation():
    t = _minutes(5)
    kp = np.array([0.0, 1.0, 2.0, 4 / 3, 5 / 3])
    res = model_field_hpen(t, 128.2, 0.0, 6.6, "T89", kp=kp, n_jobs=1)
    xyz = irbem.geo_position_re(128.2, 0.0, 6.6)[0]
    direct = geo_to_hpen(irbem.field_geo(t, xyz, "T89", {"Kp": kp}), 128.2, 0.0)
    assert_allclose(res.b_hpen_nT, direct, atol=1e-12)
    # at geostationary orbit the field is mostly northward: Hp ~ 100 nT, |He|,|Hn| small
    assert np.all((res.b_hpen_nT[:, 0] > 80) & (res.b_hpen_nT[:, 0] < 140))
    assert res.n_invalid == 0 and res.n_evaluated == 5 and res.cache_hits == 0


def test_cadence_grid_interpolates_dense_times():
    t = np.datetime64("2019-11-01T00:00:07", "ns") + np.arange(900) * np.timedelta64(4, "s")
    coarse = model_field_hpen(t, 128.2, 0.0, 6.6, "T89", kp=1.0, cadence_s=60, n_jobs=1)
    exact = model_field_hpen(t, 128.2, 0.0, 6.6, "T89", kp=1.0, cadence_s=None, n_jobs=1)
    # 00:00:07 .. 01:00:03 needs the minutes 00:00 .. 01:01
    assert coarse.n_evaluated == 62 and exact.n_evaluated == 900
    assert_allclose(coarse.b_hpen_nT, exact.b_hpen_nT, atol=1e-3)


def test_parallel_equals_serial_and_kp_series_is_a_step_function():
    t = _minutes(30_000)
    kp_series = pd.Series([1.0, 2.0, 9.5, 0.0] * 70,
                          index=pd.date_range("2019-11-01", periods=280, freq="3h"))
    par = model_field_hpen(t, 128.2, 0.0, 6.6, "T89", kp=kp_series, n_jobs=2)
    ser = model_field_hpen(t, 128.2, 0.0, 6.6, "T89", kp=kp_series, n_jobs=1)
    assert_array_equal(par.b_hpen_nT, ser.b_hpen_nT)
    # the 9.5 intervals (every 4th 3-hour block, 180 minutes each) are NaN and counted
    n_bad = sum(1 for m in range(30_000) if (m // 180) % 4 == 2)
    assert par.n_invalid == n_bad
    assert par.reasons == {"Kp outside [0, 9] (T89)": n_bad}
    assert np.all(np.isnan(par.b_hpen_nT[par.invalid]))


def test_disk_cache_hit_is_identical_and_keyed_on_inputs(tmp_path):
    t = _minutes(600)
    first = model_field_hpen(t, 128.2, 0.0, 6.6, "T89", kp=1.0, n_jobs=1, cache_dir=tmp_path)
    again = model_field_hpen(t, 128.2, 0.0, 6.6, "T89", kp=1.0, n_jobs=1, cache_dir=tmp_path)
    assert (first.cache_misses, first.cache_hits) == (1, 0)
    assert (again.cache_misses, again.cache_hits, again.n_evaluated) == (0, 1, 0)
    assert_array_equal(first.b_hpen_nT, again.b_hpen_nT)
    other = model_field_hpen(t, 128.2, 0.0, 6.6, "T89", kp=2.0, n_jobs=1, cache_dir=tmp_path)
    moved = model_field_hpen(t, 128.3, 0.0, 6.6, "T89", kp=1.0, n_jobs=1, cache_dir=tmp_path)
    assert other.cache_hits == 0 and moved.cache_hits == 0
    assert len(list(tmp_path.glob("T89-*.json"))) == 3  # one entry per distinct request


def test_drivers_dataframe_for_t96_and_missing_inputs():
    t = _minutes(120)
    drivers = pd.DataFrame({"Dst": [-10.0, -150.0], "Pdyn": [2.0, 2.0], "ByIMF": [1.0, 1.0],
                            "BzIMF": [-1.0, -1.0]},
                           index=pd.DatetimeIndex(["2019-11-01T00:00", "2019-11-01T01:00"]))
    res = model_field_hpen(t, 128.2, 0.0, 6.6, "T96", drivers=drivers, n_jobs=1)
    assert_array_equal(res.invalid, np.arange(120) >= 60)
    assert res.reasons == {"Dst outside [-100, 20] (T96)": 60}
    with pytest.raises(irbem.InputError, match="needs drivers with"):
        model_field_hpen(t, 128.2, 0.0, 6.6, "T96", kp=1.0)
    with pytest.raises(irbem.InputError, match="needs kp"):
        model_field_hpen(t, 128.2, 0.0, 6.6, "T89")
