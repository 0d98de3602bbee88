"""PARAMS.json keeps the plan: plan_from_json must invert plan_to_dict exactly."""

from magcal.ac.chain import Order, Plan, Stage
from magcal.ac.plan import plan_from_json, plan_to_dict


def test_every_stage_kind_and_option_round_trips():
    kw = {"direction": "coherent", "highpass_s": 1800.0}
    plan = Plan("fgmo", (
        Stage("reference", ("fgmo", "fgmi"), reference="amr1",
              orders=(Order(interval=(600.0, 4500.0), cone_deg=3.0, **kw),)),
        Stage("pair", ("fgmo", "fgmi"), joint=True, events="interval", min_snr=4.0,
              event_half_s=90.0, pulse_min_snr=3.0,
              orders=(Order(window_s=100.0, **kw), Order(band_hz=(0.1664, 0.1669), **kw))),
        Stage("pair", ("fgmo", "fgmi"), orders=(Order(window_s=700.0),)),
        Stage("regression", ("fgmo",), references=("fgmi", "amr1"),
              orders=(Order(detrend_s=3600.0),)),
    ))
    assert plan_from_json(plan_to_dict(plan)) == plan
    moved = plan_from_json(plan_to_dict(plan), shift_s=86400.0)
    assert moved.stages[0].orders[0].interval == (87000.0, 90900.0)
    assert moved.stages[1] == plan.stages[1]
