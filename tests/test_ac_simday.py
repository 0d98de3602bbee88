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


def _coherent_plan(md, n_orders=3):
    kw = {"direction": "coherent", "highpass_s": 1800.0}
    return Plan("fgmo", (
        Stage("reference", ("fgmo", "fgmi"), reference="amr1",
              orders=(Order(interval=(md + 600.0, md + 4500.0), **kw),)),
        Stage("pair", ("fgmo", "fgmi"), orders=tuple(
            Order(window_s=w, **kw) for w in (100.0, 700.0, 16000.0)[:n_orders]))))


@pytest.fixture(scope="module")
def coherent_fit(day):
    res, t_s, data = day
    md = (res.truth.events["midnight"][0] - res.times[0]).total_seconds()
    return run_chain(data, t_s, _coherent_plan(md))


def test_coherent_paper_plan_day(day, coherent_fit):
    """The paper's stages and windows with ambient-free directions and a 30 min
    high-pass, under ULF waves and a 25 nT substorm (measured: 289x overall; midnight
    6e4, spikes 870, hf 4200, steps 68; PSD ratios 12.3 and 8.3)."""
    res, t_s, data = day
    truth = res.truth
    r = coherent_fit
    assert r.identity_error < 1e-12
    assert np.max(np.abs(apply_weights(data, r.M) - r.corrected)) < 1e-9
    clean = truth.clean("fgmo")
    overall = disturbance_power_ratio(data["fgmo"] - clean, r.corrected - clean)
    assert overall > 200, overall                          # issue target: >= 20x
    per = _per_disturber(truth, r.M)
    for name in PICOG_TYPE:
        assert per[name] > 50, (name, per[name])           # issue target: >= 10x each
    assert per["md_edge"] > 10, per["md_edge"]             # this seed (4-16x over seeds)
    # the 6 s tone: its fgmi/fgmo scaling differs from the spike/step/noise cluster, and
    # the pair's three orders are spent on that cluster (measured 3.9x)
    assert 2 < per["tone_6s"] < 10, per["tone_6s"]
    bands = band_reduction(data["fgmo"], r.corrected, 1.0)
    assert bands[0]["mean_ratio"] > 7.8 and bands[1]["mean_ratio"] > 3.9   # the paper's
    steps = [s for s in r.steps if s.scan]
    assert all(s.direction_method == "coherent" and s.highpass_s == 1800.0 for s in steps)
    assert sum(s.scan["n_ill_defined"] for s in steps) < 1000


def test_coherent_day_table2_remnants(day, coherent_fit):
    """Table-2 magnitudes at the simulator's event times (the paper's GK-2A values in
    the comments): measured midnight ramps 0.15/0.20 nT, steps 0.82, spikes 0.32, hf
    peak-to-peak 0.015 nT in the cleaned data."""
    from magcal.ac.metrics import hf_peak_to_peak, ramp_sizes, spike_heights

    res, t_s, data = day
    ev = {k: (v - res.times[0]).total_seconds().to_numpy() for k, v in res.truth.events.items()}
    ev["midnight_up"], ev["midnight_down"] = ev["midnight"][0::3], ev["midnight"][1::3]
    spikes = np.sort(ev["spikes"])
    after = spikes[spikes > ev["hf_noise"][1]]
    # quiet etalon: the first off interval of the noise; disturbed: between two spikes
    quiet = (ev["hf_noise"][0] + 5.0, ev["hf_noise"][1] - 5.0)
    disturbed = (after[0] + 30.0, after[1] - 30.0)
    b = coherent_fit.corrected
    raw = data["fgmo"]

    def mag(x):
        return float(np.mean(np.linalg.norm(x, axis=1)))

    assert_allclose(mag(ramp_sizes(raw, t_s, ev["midnight_up"])), 34.0, atol=0.5)
    assert mag(ramp_sizes(b, t_s, ev["midnight_up"])) < 0.5      # paper: < 2 nT
    assert mag(ramp_sizes(b, t_s, ev["midnight_down"])) < 0.5    # paper: ~1 nT
    assert mag(ramp_sizes(b, t_s, ev["steps"])) < 1.3            # paper: 2.5 -> 1.3 nT
    assert_allclose(mag(spike_heights(raw, t_s, ev["spikes"])), 4.9, atol=0.2)
    assert mag(spike_heights(b, t_s, ev["spikes"])) < 0.5        # paper: 4.9 -> 0.3 nT
    p2p = hf_peak_to_peak(b, t_s, quiet, disturbed)
    assert np.linalg.norm(p2p) < 0.1                             # paper: < 0.1 nT


def test_auto_on_simulated_day(day):
    """--auto on the day: fitted incrementally (about 25 s here with the joint pair
    fit), every choice reported."""
    from magcal.ac.estimator import PiCoG

    res, t_s, data = day
    truth = res.truth
    m = PiCoG(target="fgmo", auto=True).fit(res.measurements)
    rep = m.auto_report_
    assert rep["choices"] and rep["method"] in ("picog", "regression")
    assert {r["reference"] for r in rep["reference_candidates"]} == {"fgmi", "amr1", "amr2"}
    assert all(len(o["tried"]) >= 2 for o in rep["pair_orders"])
    clean = truth.clean("fgmo")
    overall = disturbance_power_ratio(data["fgmo"] - clean, apply_weights(data, m.M_) - clean)
    assert overall > 100, overall                # measured 317x (258x before the joint fit)
