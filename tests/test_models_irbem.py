"""IRBEM fast path against spacepy's get_Bfield, ranges, Kp rounding."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from magcal.models import irbem


def _orbit(n, seed=7):
    gen = np.random.default_rng(seed)
    t = (np.datetime64("2019-11-01T00:00", "ns")
         + (np.arange(n) * 3_600 * 7 + 13).astype("timedelta64[s]"))
    lon = gen.uniform(-180, 180, n)
    lat = gen.uniform(-20, 20, n)
    r = gen.uniform(4.0, 8.0, n)
    return t, irbem.geo_position_re(lon, lat, r)


DRIVERS = {"Kp": 2.0, "Dst": -20.0, "dens": 5.0, "velo": 400.0, "Pdyn": 2.0, "ByIMF": 1.5,
           "BzIMF": -2.0, "G1": 3.0, "G2": 4.0, "G3": 5.0, "W1": 0.5, "W2": 0.4,
           "W3": 0.6, "W4": 0.3, "W5": 0.7, "W6": 0.8}


@pytest.mark.parametrize("model", ["IGRF", "T89", "T96", "T01", "T04"])
def test_ctypes_path_equals_get_bfield(model):
    t, xyz = _orbit(12)
    kp = np.array([0.0, 1 / 3, 2 / 3, 1.0, 4 / 3, 5 / 3, 2.0, 3.0, 4.0, 5.0, 6.0, 9.0])
    inputs = dict(DRIVERS, Kp=kp)
    fast = irbem.evaluate_geo(t, xyz, model, inputs)
    slow = irbem.evaluate_geo(t, xyz, model, inputs, backend="get_Bfield")
    assert fast.backend == "ctypes" and slow.backend == "get_Bfield"
    assert fast.n_invalid == 0
    assert_allclose(fast.b_geo_nT, slow.b_geo_nT, rtol=0, atol=1e-6)
    # sanity: field magnitude at 4-8 RE is a dipole-like 50-500 nT
    mag = np.linalg.norm(fast.b_geo_nT, axis=1)
    assert np.all((mag > 40) & (mag < 600))


def test_kp_thirds_land_in_the_omni_level():
    """Kp = 5/3 (2-) must give the same T89 field as Kp = 1.7 (OMNI 17) and 2.0 (level 3)."""
    t = np.array(["2019-11-01T06:00"] * 3, dtype="datetime64[ns]")
    xyz = irbem.geo_position_re(128.2, 0.0, 6.6)[0]
    b = irbem.field_geo(t, xyz, "T89", {"Kp": [5 / 3, 1.7, 2.0]})
    assert_allclose(b[0], b[1], atol=0)
    assert_allclose(b[0], b[2], atol=0)  # 2- and 2o share T89 level 3
    b1 = irbem.field_geo(t[:2], xyz, "T89", {"Kp": [4 / 3, 1.6]})  # 1+ and 1.6: level 2
    assert_allclose(b1[0], b1[1], atol=0)
    assert np.max(np.abs(b1[0] - b[0])) > 0.1
    assert_array_equal(irbem.kp_to_irbem([1 / 3, 2 / 3, 4 / 3, 5 / 3]), [3, 7, 13, 17])


def test_out_of_range_become_nan_with_counted_reasons():
    t, xyz = _orbit(6)
    inputs = dict(DRIVERS, Dst=[-20, -150, -20, -20, np.nan, -20],
                  Pdyn=[2, 2, 20, 2, 2, 2])
    res = irbem.evaluate_geo(t, xyz, "T96", inputs)
    assert_array_equal(res.invalid, [False, True, True, False, True, False])
    assert np.all(np.isnan(res.b_geo_nT[res.invalid]))
    assert np.all(np.isfinite(res.b_geo_nT[~res.invalid]))
    assert res.reasons == {"Dst missing": 1, "Dst outside [-100, 20] (T96)": 1,
                           "Pdyn outside [0.5, 10] (T96)": 1}
    # T04 (TS05) has no range check: the same inputs, minus the NaN, all evaluate
    inputs["Dst"][4] = -20
    assert irbem.evaluate_geo(t, xyz, "T04", inputs).n_invalid == 0


def test_t89_kp_above_9_is_nan_and_warned():
    t, xyz = _orbit(3)
    with pytest.warns(irbem.ModelRangeWarning, match="1 of 3 T89 samples"):
        b = irbem.field_geo(t, xyz, "T89", {"Kp": [1.0, 9.0, 9.5]})
    assert np.all(np.isfinite(b[:2])) and np.all(np.isnan(b[2]))
    # fill must never leak through as numbers, even if the pre-check missed it
    res = irbem.evaluate_geo(t, xyz, "T89", {"Kp": [1.0, 9.0, 9.5]})
    assert res.reasons["Kp outside [0, 9] (T89)"] == 1
    assert not np.any(np.abs(np.nan_to_num(res.b_geo_nT)) > 1e5)


def test_chunking_over_ntime_max(monkeypatch):
    monkeypatch.setattr(irbem, "NTIME_MAX", 5)
    t, xyz = _orbit(13)
    chunked = irbem.field_geo(t, xyz, "T89", {"Kp": 2.0})
    monkeypatch.setattr(irbem, "NTIME_MAX", 100_000)
    whole = irbem.field_geo(t, xyz, "T89", {"Kp": 2.0})
    assert_allclose(chunked, whole, atol=0)


def test_igrf_dipole_strength_and_bad_usage():
    t = np.array(["2019-11-01T00:00"], dtype="datetime64[ns]")
    # At 6.6 RE on the equator IGRF is close to a dipole: ~ 30000 nT / 6.6^3 = 104 nT
    b = irbem.field_geo(t, irbem.geo_position_re(128.2, 0, 6.6)[0], "IGRF")
    assert 95 < np.linalg.norm(b) < 115
    with pytest.raises(irbem.InputError, match="needs input 'Pdyn'"):
        irbem.field_geo(t, [6.6, 0, 0], "T96", {"Dst": -10})
    with pytest.raises(irbem.InputError, match="unknown model"):
        irbem.field_geo(t, [6.6, 0, 0], "T77")
    with pytest.raises(irbem.InputError, match="unknown IRBEM input"):
        irbem.field_geo(t, [6.6, 0, 0], "T89", {"kp": 1.0})
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        irbem.field_geo(t, [6.6, 0, 0], "T89", {"Kp": 1.0})
