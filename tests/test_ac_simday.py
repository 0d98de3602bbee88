"""Issue-3 numbers on the simulated GK-2A-like day (truth known)."""

import numpy as np
import pytest
from numpy.testing import assert_allclose

from magcal.ac.chain import Order, Plan, Stage, apply_weights, run_chain
from magcal.ac.metrics import band_reduction, disturbance_power_ratio

pytestmark = pytest.mark.slow

SENSORS = ("fgmo", "fgmi", "amr1", "amr2")
#: linearly polarised disturbers large enough to matter at the outboard sensor
PICOG_TYPE = ("midnight", "spikes", "hf_noise", "steps")


@pytest.fixture(scope="module")
def day():
    from magcal.simulate.geostationary import GeostationaryConfig, simulate_geostationary

    res = simulate_geostationary(GeostationaryConfig.gk2a_like(),
                                 rng=np.random.default_rng(20190304))
    t_s = (res.times - res.times[0]).total_seconds().to_numpy()
    return res, t_s, {s: res.sensor(s) for s in SENSORS}


def _per_disturber(truth, M):
    return {d: disturbance_power_ratio(per["fgmo"], apply_weights({k: per[k] for k in M}, M))
            for d, per in truth.disturbances.items()}


def test_regression_gradiometer_day(day):
    res, t_s, data = day
    truth = res.truth
    plan = Plan("fgmo", (Stage("regression", ("fgmo",), references=("fgmi", "amr1", "amr2"),
                               orders=(Order(detrend_s=3600.0),)),))
    r = run_chain(data, t_s, plan)
    assert r.identity_error < 1e-12
    assert np.max(np.abs(apply_weights(data, r.M) - r.corrected)) < 1e-9
    clean = truth.clean("fgmo")
    overall = disturbance_power_ratio(data["fgmo"] - clean, r.corrected - clean)
    assert overall > 20, overall                      # issue target: >= 20x
    per = _per_disturber(truth, r.M)
    for name in PICOG_TYPE:
        assert per[name] > 10, (name, per[name])       # issue target: >= 10x each
    bands = band_reduction(data["fgmo"], r.corrected, 1.0)
    assert bands[0]["mean_ratio"] > 1 and bands[1]["mean_ratio"] > 1


def test_paper_plan_day(day):
    """The paper's chain (AMR1 first order on the midnight disturbance, then the boom
    pair with 100/700/16000 s windows): exact upload matrices, and the midnight and
    high-frequency disturbers removed."""
    res, t_s, data = day
    truth = res.truth
    md = (truth.events["midnight"][0] - res.times[0]).total_seconds()
    plan = Plan("fgmo", (
        Stage("reference", ("fgmo", "fgmi"), reference="amr1",
              orders=(Order(interval=(md + 600.0, md + 4500.0)),)),
        Stage("pair", ("fgmo", "fgmi"), orders=(Order(window_s=100.0), Order(window_s=700.0),
                                                Order(window_s=16000.0)))))
    r = run_chain(data, t_s, plan)
    assert r.identity_error < 1e-12
    assert np.max(np.abs(apply_weights(data, r.M) - r.corrected)) < 1e-9
    assert_allclose(r.G, data["fgmo"].mean(0) - r.corrected.mean(0), atol=1e-9)
    per = _per_disturber(truth, r.M)
    assert per["midnight"] > 20, per
    assert per["hf_noise"] > 100, per
