"""Joint pair stage (magcal.ac.joint): one constant 3x3 per sensor over several
selections, against injected truth."""

import numpy as np
import pytest
from numpy.testing import assert_allclose

from magcal.ac.chain import Order, Plan, Stage, apply_weights, run_chain
from magcal.ac.events import event_intervals
from magcal.ac.joint import Selection, fit_joint
from magcal.ac.metrics import disturbance_power_ratio
from magcal.ac.plan import plan_from_dict, plan_to_dict
from magcal.errors import InputError

LINEAR = ("midnight", "md_edge", "spikes", "hf_noise", "steps", "tone_6s")


def test_joint_fit_recovers_two_disturbers_seen_in_different_selections(rng):
    # disturber 1 only in the first half, disturber 2 only in the second: each half
    # alone fixes K on one direction; jointly K maps both differences to -signature
    n = 40000
    amb = rng.normal(0, 1.0, (n, 3))
    s = np.zeros((n, 2))
    s[: n // 2, 0] = rng.normal(0, 3.0, n // 2)
    s[n // 2:, 1] = rng.normal(0, 3.0, n // 2)
    po, pi = np.array([[0.0, 0.6, 0.8], [1.0, 0.2, 0.0]]), np.array([[0.0, 0.1, 0.2],
                                                                      [0.1, 0.5, 0.0]])
    bi = amb + s @ po + rng.normal(0, 0.01, (n, 3))
    bj = amb + s @ pi + rng.normal(0, 0.01, (n, 3))
    half = np.arange(n) < n // 2
    fit = fit_joint([Selection("a", bi, bj, half), Selection("b", bi, bj, ~half)], 1.0)
    for k in range(2):
        remnant = po[k] + fit.K @ (po[k] - pi[k])
        assert np.linalg.norm(remnant) < 0.02 * np.linalg.norm(po[k])
    assert min(fit.reduction.values()) > 100
    # a selection with no disturbance in it (pure chance correlation) is dropped
    quiet = Selection("quiet", amb[:2000] + rng.normal(0, 0.01, (2000, 3)),
                      amb[:2000] + rng.normal(0, 0.01, (2000, 3)), np.ones(2000, bool))
    with pytest.raises(InputError, match="chance level"):
        fit_joint([quiet], 1.0, min_snr=5.0)


def test_event_intervals_keep_only_clean_large_steps(rng):
    t = np.arange(20000.0)
    d = rng.normal(0, 0.05, (20000, 3))
    d[5000:15000, 2] += 20.0          # two large ramps (midnight-like)
    d[8000:, 0] += 1.0                # a small step: not an event itself
    d[15060:15066, 1] += 3.0          # a 6 s spike 60 s after the second ramp
    iv = event_intervals(d, t, half_s=120.0)
    assert len(iv) == 1
    assert_allclose(np.mean(iv[0]), 5000, atol=15)
    assert_allclose(iv[0][1] - iv[0][0], 240, atol=2)


def test_plan_joint_parsed_and_validated():
    doc = {"target": "fgmo", "stage": [{"pair": ["fgmo", "fgmi"], "joint": True,
                                        "min_snr": 4, "event_half_s": 0,
                                        "orders": [{"window_s": 100}]}]}
    plan, _ = plan_from_dict(doc)
    st = plan.stages[0]
    assert st.joint and st.min_snr == 4.0 and st.event_half_s is None
    assert plan_to_dict(plan)["stages"][0]["joint"] is True
    assert st.events == "pulse" and st.pulse_min_snr == 2.5      # defaults
    doc["stage"][0].update(events="interval", pulse_min_snr=3)
    st2 = plan_from_dict(doc)[0].stages[0]
    assert st2.events == "interval" and st2.pulse_min_snr == 3.0
    d = plan_to_dict(plan_from_dict(doc)[0])["stages"][0]
    assert d["events"] == "interval" and d["pulse_min_snr"] == 3.0
    with pytest.raises(InputError, match="events must be"):
        plan_from_dict({"target": "fgmo", "stage": [{"pair": ["fgmo", "fgmi"], "joint": True,
                                                     "events": "pulses"}]})
    with pytest.raises(InputError, match="pulse_min_snr must be"):
        plan_from_dict({"target": "fgmo", "stage": [{"pair": ["fgmo", "fgmi"], "joint": True,
                                                     "pulse_min_snr": -1}]})
    with pytest.raises(InputError, match="joint must be"):
        plan_from_dict({"target": "fgmo", "stage": [{"pair": ["fgmo", "fgmi"],
                                                     "joint": "yes"}]})
    with pytest.raises(InputError, match="only for a pair"):
        Stage("reference", ("fgmo",), reference="amr1", joint=True)


def joint_day_plan(md_start_s: float) -> Plan:
    kw = {"direction": "coherent", "highpass_s": 1800.0}
    return Plan("fgmo", (
        Stage("reference", ("fgmo", "fgmi"), reference="amr1",
              orders=(Order(interval=(md_start_s + 600.0, md_start_s + 4500.0), **kw),)),
        Stage("pair", ("fgmo", "fgmi"), joint=True,
              orders=tuple(Order(window_s=w, **kw) for w in (100.0, 700.0, 16000.0))
              + (Order(band_hz=(0.1664, 0.1669), **kw),))))


#: per-disturber power ratios at fgmo (exact by linearity), pinned from the fit with the
#: default pulse events (seed 2: both edge pulses sit in Pc5 waves, the ambient is
#: interpolated from the flanks)
PINNED = {
    20190304: {"midnight": 94137.0, "md_edge": 15.8, "spikes": 14.0, "hf_noise": 13.9,
               "steps": 113.2, "tone_6s": 17.8},
    1: {"midnight": 116935.1, "md_edge": 25.3, "spikes": 13.5, "hf_noise": 12.6,
        "steps": 26.8, "tone_6s": 19.6},
    2: {"midnight": 6420.5, "md_edge": 20.4, "spikes": 17.8, "hf_noise": 16.7,
        "steps": 28.8, "tone_6s": 14.6},
    # a toggle step 7 s after the first midnight ramp; the other toggles carry the
    # steps disturber only as pooled step events (5.5x before them)
    13: {"midnight": 1713340.2, "md_edge": 12.9, "spikes": 16.6, "hf_noise": 17.2,
         "steps": 12.3, "tone_6s": 14.5},
}


@pytest.mark.slow
@pytest.mark.parametrize("seed", sorted(PINNED))
def test_joint_pair_day_every_linear_disturber_10x(seed):
    from magcal.simulate.geostationary import GeostationaryConfig, simulate_geostationary

    sim = simulate_geostationary(GeostationaryConfig.gk2a_like(),
                                 rng=np.random.default_rng(seed))
    truth = sim.truth
    t_s = (sim.times - sim.times[0]).total_seconds().to_numpy()
    data = {s: sim.sensor(s) for s in ("fgmo", "fgmi", "amr1", "amr2")}
    md = (truth.events["midnight"][0] - sim.times[0]).total_seconds()
    res = run_chain(data, t_s, joint_day_plan(md))
    # Eq. 33 and one-step = iteration; the pair is one constant 3x3 per sensor
    assert res.identity_error < 1e-12
    assert np.max(np.abs(apply_weights(data, res.M) - res.corrected)) < 1e-9
    joint = [s for s in res.steps if s.kind == "joint"]
    assert len(joint) == 2 and all(np.asarray(s.A).shape == (3, 3) for s in joint)
    ratios = {d: disturbance_power_ratio(truth.disturbances[d]["fgmo"],
                                         apply_weights({k: truth.disturbances[d][k]
                                                        for k in res.M}, res.M))
              for d in LINEAR}
    assert min(ratios.values()) >= 10.0, ratios
    assert_allclose([ratios[d] for d in LINEAR], [PINNED[seed][d] for d in LINEAR],
                    rtol=0.02)


def test_cli_fit_apply_joint_plan(tmp_path, rng):
    import json

    import pandas as pd

    from magcal.cli import main

    n = 8000
    t = np.arange(n, dtype=float)
    amb = np.c_[3 * np.sin(t / 900), 2 * np.cos(t / 700), np.sin(t / 500)] + [90.0, -5.0, 30.0]
    s = np.zeros((n, 2))
    s[: n // 2, 0] = rng.normal(0, 2.0, n // 2)
    s[n // 2:, 1] = rng.normal(0, 2.0, n // 2)
    po, pi = np.array([[0.0, 0.6, 0.8], [1.0, 0.2, 0.0]]), np.array([[0.0, 0.1, 0.2],
                                                                      [0.1, 0.5, 0.0]])
    sensors = {"fgmo": amb + s @ po, "fgmi": amb + s @ pi}
    df = pd.DataFrame({f"{k}_{c}": b[:, i] for k, b in sensors.items()
                       for i, c in enumerate("xyz")},
                      index=pd.date_range("2019-03-04", periods=n, freq="1s", tz="UTC")
                      .strftime("%Y-%m-%dT%H:%M:%S"))
    df.index.name = "time"
    path = tmp_path / "in.csv"
    df.to_csv(path, float_format="%.9f")
    plan = tmp_path / "plan.toml"
    plan.write_text('target = "fgmo"\ndirection = "coherent"\n[[stage]]\n'
                    'pair = ["fgmo", "fgmi"]\njoint = true\nevent_half_s = 0\n'
                    'orders = [ { interval = ["2019-03-04T00:00", "2019-03-04T01:06:40"] },'
                    ' { interval = ["2019-03-04T01:06:40", "2019-03-04T02:13:20"] } ]\n')
    params = tmp_path / "p.json"
    assert main(["picog", "fit", str(path), "--plan", str(plan), "-o", str(params)]) == 0
    doc = json.loads(params.read_text())
    assert [st["kind"] for st in doc["steps"]] == ["joint", "joint"]
    assert doc["plan"]["stages"][0]["joint"] is True
    assert_allclose(sum(np.array(m) for m in doc["M"].values()), np.eye(3), atol=1e-12)
    out = tmp_path / "clean.csv"
    assert main(["picog", "apply", str(path), "--params", str(params), "--pure-ac",
                 "-o", str(out)]) == 0
    clean = pd.read_csv(out)[["x", "y", "z"]].to_numpy()
    # both disturbers gone (the ambient's chance correlation with them is the remnant)
    assert np.std(clean - amb, axis=0).max() < 0.02 * np.std(s @ po, axis=0).max()


@pytest.mark.slow
def test_joint_pair_day_interval_events_keep_the_earlier_fit():
    # events = "interval" is the earlier behaviour: the numbers pinned before pulse
    # events (seed 20190304); on seed 2 it leaves md_edge at 1.5x
    from dataclasses import replace

    from magcal.simulate.geostationary import GeostationaryConfig, simulate_geostationary

    sim = simulate_geostationary(GeostationaryConfig.gk2a_like(),
                                 rng=np.random.default_rng(20190304))
    truth = sim.truth
    t_s = (sim.times - sim.times[0]).total_seconds().to_numpy()
    data = {s: sim.sensor(s) for s in ("fgmo", "fgmi", "amr1", "amr2")}
    md = (truth.events["midnight"][0] - sim.times[0]).total_seconds()
    plan = joint_day_plan(md)
    plan = replace(plan, stages=(plan.stages[0], replace(plan.stages[1], events="interval")))
    res = run_chain(data, t_s, plan)
    ratios = [disturbance_power_ratio(truth.disturbances[d]["fgmo"],
                                      apply_weights({k: truth.disturbances[d][k]
                                                     for k in res.M}, res.M))
              for d in LINEAR]
    assert_allclose(ratios, [79163.4, 15.5, 14.7, 13.1, 94.5, 17.3], rtol=0.02)
