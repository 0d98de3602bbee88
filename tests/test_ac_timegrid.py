"""Uniform grid fitted to sample times (issue 13 case 4) and plan keys refused (case 6)."""

import numpy as np
import pytest
from numpy.testing import assert_allclose

from magcal.ac.estimator import fit_time_grid, uniform_grid
from magcal.ac.plan import plan_from_dict
from magcal.errors import InputError


def test_rounded_stamps_with_gaps_fit_the_true_rate():
    k = np.arange(40000)
    keep = np.ones(k.size, bool)
    keep[[5000, 5001, 5002]] = False                 # a 3-sample gap
    keep[20000:20400] = False                        # a 400-sample gap
    t = 1.5e9 + 0.25 + k[keep] / 128.0
    t = np.round(t * 1e3) / 1e3                      # millisecond stamps
    g = fit_time_grid(t)
    assert_allclose(g.dt_s, 1 / 128.0, rtol=1e-7)
    assert g.n_grid == 40000 and g.n_missing == 403
    assert np.array_equal(g.slots, k[keep])
    assert g.resolution_s == 1e-3 and g.jitter_max_s <= 0.5e-3 + 1e-6
    assert_allclose(g.times_s[g.slots] - t, 0.0, atol=g.jitter_max_s + 1e-9)
    # the median of rounded spacings (8 ms) would be 1.6 s off after 40000 samples
    assert abs(np.median(np.diff(t)) - 1 / 128) * 40000 > 1.0
    assert uniform_grid(t)[1] == 40000


def test_a_sample_off_the_grid_is_refused_by_index():
    t = np.arange(2000) / 128.0
    t[1234] += 3e-3                                  # beyond 0 + 0.05 * 7.8 ms
    with pytest.raises(InputError, match="sample 1234 is 0.003 s off"):
        fit_time_grid(t)
    t[1234] -= 2.7e-3                                 # 0.3 ms: within the tolerance
    assert_allclose(fit_time_grid(t).jitter_max_s, 3e-4, atol=2e-5)


@pytest.mark.parametrize("stage, key", [
    ({"regression": ["a"], "references": ["b"], "orders": [{"band_hz": [1, 2]}]}, "band_hz"),
    ({"regression": ["a"], "references": ["b"], "orders": [{"window_s": 10}]}, "window_s"),
    ({"pair": ["a", "b"], "orders": [{"detrend_s": 10}]}, "detrend_s"),
    ({"pair": ["a", "b"], "events": "pulse"}, "events"),
    ({"reference": "b", "sensors": ["a"], "sensor": ["a"]}, "sensor"),
])
def test_plan_keys_a_stage_does_not_use_are_refused(stage, key):
    with pytest.raises(InputError, match=rf"stage 1 .*'{key}'"):
        plan_from_dict({"target": "a", "stage": [stage]})
    assert plan_from_dict({"target": "a", "stage": [
        {"pair": ["a", "b"], "joint": True, "events": "pulse"}]})[0].stages[0].joint
