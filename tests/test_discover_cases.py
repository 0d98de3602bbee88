"""Test months for the discovery loop: model + hidden effects + benign variability.

Built on :func:`magcal.simulate.gaps.make_background` (a
:func:`magcal.simulate.month.simulate_month` month: T89 model field, Kp, Dst, boom
temperature, local time, ULF waves and white noise). The benign variability that no
vocabulary term should explain is: the simulator's ULF waves (stronger at high Kp) and
white noise, bipolar substorm signatures on the night side at high Kp (growth-phase dip
then dipolarisation overshoot, zero mean) or, with ``simulator_substorms=True``, the
simulator's own one-sided dips, and a slowly varying red "model error"
(Ornstein-Uhlenbeck, 2 h correlation). The hidden effects are added from their exact
truth, so the noise floor (RMS of the residual left when the truth is removed) is known.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from magcal.simulate.gaps import COMPONENTS, LON_DEG, base_month, make_background, spin_phase


@dataclass(frozen=True)
class Case:
    measured: pd.DataFrame
    model: pd.DataFrame
    covariates: pd.DataFrame
    truth: np.ndarray        # hidden effects (n, 3), excluding the offset
    offset_nT: np.ndarray    # constant offset (3,)
    benign: np.ndarray       # what no effect should explain (n, 3)
    month: object

    @property
    def noise_floor_nT(self) -> float:
        return float(np.sqrt(np.nanmean(self.benign ** 2)))


def make_case(hidden: dict | None = None, *, seed: int = 7, offset_nT=(4.0, -3.0, 2.0),
              red_std_nT: float = 2.0, phase: bool = False, temperature_C=None,
              n_days: float = 30.0, simulator_substorms: bool = False) -> Case:
    """A month with the hidden effects ``hidden`` (name -> (n, 3) array or callable).

    ``simulator_substorms``: the benign substorms are the simulator's own one-sided dips
    (``MonthResult.disturbed_nT``; storm coupling is off, so that is substorms only)
    instead of the zero-mean bipolar signatures.
    """
    bg = make_background(seed, n_days=n_days, red_std_nT=red_std_nT,
                         simulator_substorms=simulator_substorms)
    m, benign, t_s = bg.month, bg.benign, bg.t_s
    n = m.times.size
    truth = np.zeros((n, 3))
    for value in (hidden or {}).values():
        truth += value
    meas = m.model_nT + np.asarray(offset_nT)[None, :] + truth + benign
    index = pd.DatetimeIndex(m.times, name="time").tz_localize("UTC")
    cov = {"temperature": m.temperature_C if temperature_C is None else temperature_C,
           "kp": m.kp, "dst": m.dst}
    if phase:
        cov["phase"] = spin_phase(t_s)
    return Case(measured=pd.DataFrame(meas, index=index, columns=list(COMPONENTS)),
                model=pd.DataFrame(m.model_nT, index=index, columns=list(COMPONENTS)),
                covariates=pd.DataFrame(cov, index=index), truth=truth,
                offset_nT=np.asarray(offset_nT, dtype=float), benign=benign, month=m)


def lt_of(case: Case) -> np.ndarray:
    return case.month.local_time_h


# ------------------------------------------------------------------------- the tests
import pytest  # noqa: E402
from numpy.testing import assert_allclose  # noqa: E402

from magcal.discover import discover_gap  # noqa: E402


def _axes():
    m = base_month()
    n = m.times.size
    t_s = np.arange(n) * 60.0
    return m, t_s, t_s / 86400.0, 2 * np.pi * m.local_time_h / 24.0


def _run(case: Case, keep=None):
    """Discovery on ``case`` (on the rows ``keep`` only, if given)."""
    rows = slice(None) if keep is None else keep
    return discover_gap(case.measured[rows], case.model[rows], case.covariates[rows],
                        longitude_deg=LON_DEG)


def _first_new(res, skip=("offset",)):
    names = [n for n in res.names if n not in skip]
    return names[0] if names else None


def _signal_error(res, case: Case, name: str) -> float:
    """RMS of (fitted contribution of ``name`` - hidden truth), demeaned per component."""
    from magcal.discover.inputs import build_inputs

    inputs, _ = build_inputs(case.measured.index, case.model, COMPONENTS, case.covariates, LON_DEG)
    fit = sum(e.effect.evaluate(inputs, e.beta) for e in res.effects if e.name == name)
    d = (fit - case.truth)
    d = d - d.mean(axis=0)
    return float(np.sqrt(np.mean(d ** 2)))


def _check_floor(res, case: Case):
    floor = case.noise_floor_nT
    assert abs(res.gap_final["rms_nT"] / floor - 1) < 0.2, (res.gap_final["rms_nT"], floor)


def test_hidden_effects_are_small_against_raw_residual():
    m, t_s, day, phi = _axes()
    case = make_case({"d": np.column_stack([-1.5 * np.cos(phi), 1.0 * np.cos(phi), 0 * phi])})
    raw = (case.measured - case.model).to_numpy()
    assert np.var(case.truth[:, 0]) < 0.2 * np.var(raw[:, 0])  # under a fifth of the variance


def test_no_hidden_effect_adds_only_offset():
    case = make_case()
    res = _run(case)
    assert res.names == ["offset"], res.account()
    assert_allclose([res.effects[0].parameters["values"][c]["offset_nT"] for c in COMPONENTS],
                    case.offset_nT, atol=0.6)
    # the level in red noise: far fewer independent samples than the 129,600 values
    # (the residual's correlation time is hours at 1-min cadence)
    assert res.effects[0].evidence["n_eff"] < 0.02 * case.truth.size
    # the report's interval: value -+ t_0.975(dof) * std; a level in 30 full days has
    # the jackknife's n_blocks - 1 degrees of freedom exactly
    from scipy.stats import t as student_t

    par = res.effects[0].parameters
    n_blocks = res.effects[0].evidence["n_blocks"]
    for c in COMPONENTS:
        v, s, dof = (par[k][c]["offset_nT"] for k in ("values", "std", "dof"))
        assert dof == pytest.approx(n_blocks - 1, rel=1e-6)
        q = student_t.ppf(0.975, dof)
        assert_allclose(par["ci95"][c]["offset_nT"], [v - q * s, v + q * s], rtol=1e-12)
    _check_floor(res, case)


@pytest.mark.slow
def test_no_hidden_effect_false_additions_at_most_1_in_20():
    """20 seeded short months (10 days, 3 storm days: noisier than the month above)."""
    false = {}
    for seed in range(100, 120):
        case = make_case(seed=seed, n_days=10.0)
        res = _run(case)
        if res.names != ["offset"]:
            false[seed] = res.names
    assert len(false) <= 1, false


def test_benign_simulator_substorms_and_ulf_with_hidden_drift():
    """The simulator's own substorm dips (one-sided, night side, Kp >= 3) and ULF waves as
    the benign background, with a hidden drift. The dips have a non-zero mean that grows
    with Kp, so the model truly lacks a Kp-correlated field: ``activity`` may take part
    of it, but nothing else may be added, and the drift is named first and recovered.
    (With a hidden local-time field instead, the night-side dips and T89's own Kp and
    local-time dependence make ``scale`` compete with ``diurnal``: reported ambiguous.)"""
    m, t_s, day, phi = _axes()
    case = make_case({"drift": np.outer(day - 15, [0.25, -0.15, 0.0])},
                     simulator_substorms=True)
    assert np.min(case.benign[:, 0]) < -20.0  # deep one-sided dips are in there
    assert np.mean(case.benign[:, 0]) < -0.1  # and they do not average out
    res = _run(case)
    assert _first_new(res) == "drift", res.account()
    assert set(res.names) <= {"offset", "drift", "activity"}, res.account()
    v = res.effect("drift").parameters["values"]
    assert_allclose([v["Hp"]["rate_nT_per_day"], v["He"]["rate_nT_per_day"]], [0.25, -0.15],
                    atol=0.06)
    _check_floor(res, case)


def test_offset_recovered():
    case = make_case(offset_nT=(5.0, -3.0, 2.0))
    res = _run(case)
    assert res.names[0] == "offset"
    assert_allclose([res.effects[0].parameters["values"][c]["offset_nT"] for c in COMPONENTS],
                    [5.0, -3.0, 2.0], atol=0.6)
    _check_floor(res, case)


def test_drift():
    m, t_s, day, phi = _axes()
    case = make_case({"drift": np.outer(day - 15, [0.25, -0.15, 0.0])})
    res = _run(case)
    assert _first_new(res) == "drift", res.account()
    v = res.effect("drift").parameters["values"]
    assert_allclose([v["Hp"]["rate_nT_per_day"], v["He"]["rate_nT_per_day"]], [0.25, -0.15],
                    atol=0.06)
    _check_floor(res, case)


def test_diurnal_sosmag_like():
    m, t_s, day, phi = _axes()
    hidden = np.column_stack([-1.5 * np.cos(phi), 1.0 * np.cos(phi - 2 * np.pi * 23 / 24),
                              0 * phi])
    case = make_case({"diurnal": hidden})
    res = _run(case)
    assert _first_new(res) == "diurnal", res.account()
    d = res.effect("diurnal").parameters["derived"]
    assert_allclose(d["Hp"]["peak_to_peak_nT"], 3.0, atol=0.6)
    assert abs(d["Hp"]["peak_lt_h"] - 12.0) < 2.0
    assert_allclose(d["He"]["peak_to_peak_nT"], 2.0, atol=0.6)
    assert _signal_error(res, case, "diurnal") < 0.35
    _check_floor(res, case)
    assert any("peak-to-peak local-time variation" in line for line in res.account())


def test_temperature_told_apart_from_diurnal():
    """Confounded case 1: temperature follows the day but also varies from day to day."""
    m, t_s, day, phi = _axes()
    temp = m.temperature_C + 20 * np.sin(2 * np.pi * day / 9.3)
    case = make_case({"t": np.outer(temp - temp.mean(), [0.03, 0.0, -0.02])},
                     temperature_C=temp)
    res = _run(case)
    assert _first_new(res) == "temperature", res.account()
    eff = res.effect("temperature")
    v = eff.parameters["values"]
    assert_allclose(v["Hp"]["coefficient_nT_per_degC"], 0.03, atol=0.006)
    assert_allclose(v["Hn"]["coefficient_nT_per_degC"], -0.02, atol=0.006)
    assert not eff.evidence["ambiguous"]
    assert "diurnal" in eff.evidence["preferred_over"]
    assert "diurnal" not in res.names
    _check_floor(res, case)


def test_temperature_locked_to_local_time_is_ambiguous():
    """Confounded case 2: temperature is a function of local time only."""
    m, t_s, day, phi = _axes()
    temp = 20.0 + 15.0 * np.cos(phi - 2 * np.pi * 14 / 24)
    case = make_case({"t": np.outer(temp - 20.0, [0.12, 0.0, 0.0])}, temperature_C=temp)
    res = _run(case)
    first = _first_new(res)
    assert first in ("temperature", "diurnal"), res.account()
    ev = res.effect(first).evidence
    other = "diurnal" if first == "temperature" else "temperature"
    assert ev["ambiguous"] and other in ev["ambiguous_with"], ev
    assert any("ambiguous" in line for line in res.account())
    assert _signal_error(res, case, first) < 0.35
    _check_floor(res, case)


def test_scale():
    m, t_s, day, phi = _axes()
    case = make_case({"scale": m.model_nT * np.array([0.08, 0.08, 0.0])})
    res = _run(case)
    assert _first_new(res) == "scale", res.account()
    v = res.effect("scale").parameters["values"]
    assert_allclose([v["Hp"]["scale"], v["He"]["scale"]], [0.08, 0.08], atol=0.015)
    _check_floor(res, case)


def test_a_scale_beyond_the_plausible_bound_is_not_named_scale():
    # a signature proportional to the model field but 80 % of it: no working fluxgate
    # has that scale error, so the loop must not name it (it says why in its rounds)
    m, t_s, day, phi = _axes()
    case = make_case({"big": m.model_nT * np.array([0.0, 0.8, 0.0])})
    res = _run(case)
    assert "scale" not in res.names, res.account()
    flagged = [c for r in res.rounds for c in r["candidates"]
               if c["name"] == "scale" and "implausible" in c]
    assert flagged and "0.8" in flagged[0]["implausible"]


def test_storm_field_without_dst_is_not_named_rotation_or_scale():
    # the demo's failure: a storm-time field (Burton Dst coupled 0.7/0.1/0.05) and a
    # local-time field, with Kp but no Dst among the covariates. A rotation and a scale
    # fit early stand in for them and reach implausible values once the activity and
    # diurnal terms are in: they must be dropped (and said), not delivered.
    from magcal.simulate.month import local_time_field

    m, t_s, day, phi = _axes()
    case = make_case({"storm": np.outer(m.dst, [0.7, 0.1, 0.05]),
                      "lt": local_time_field(m.local_time_h, (8.0, 5.0, 1.5))})
    res = discover_gap(case.measured, case.model, case.covariates.drop(columns=["dst"]),
                       longitude_deg=LON_DEG)
    assert set(res.names) <= {"offset", "activity", "diurnal"}, res.account()
    assert {"activity", "diurnal"} <= set(res.names), res.account()
    assert not {"rotation", "scale"} & set(res.names)


def test_rotation():
    m, t_s, day, phi = _axes()
    w = np.deg2rad([0.0, 3.0, -3.0])
    case = make_case({"rot": np.cross(w, m.model_nT)})
    res = _run(case)
    assert _first_new(res) == "rotation", res.account()
    a = res.effect("rotation").parameters["angles_deg"]
    # Hp is nearly along the field: only the He and Hn angles are well determined
    assert_allclose([a["He"], a["Hn"]], [3.0, -3.0], atol=1.0)
    _check_floor(res, case)


def test_activity():
    m, t_s, day, phi = _axes()
    case = make_case({"act": np.outer(m.dst, [0.15, 0.05, 0.0])})
    res = _run(case)
    assert _first_new(res) == "activity", res.account()
    truth_rms = np.sqrt(np.mean((case.truth - case.truth.mean(axis=0)) ** 2))
    assert _signal_error(res, case, "activity") < 0.3 * truth_rms
    _check_floor(res, case)


def test_spin_tone():
    m, t_s, day, phi = _axes()
    p = spin_phase(t_s)
    hidden = np.column_stack([0 * p, np.cos(p), 0.5 * np.sin(2 * p)])
    case = make_case({"spin": hidden}, phase=True)
    res = _run(case)
    assert _first_new(res) == "spin_tone", res.account()
    d = res.effect("spin_tone").parameters["derived"]
    assert_allclose(d["He"]["amplitude1_nT"], 1.0, atol=0.05)
    assert_allclose(d["Hn"]["amplitude2_nT"], 0.5, atol=0.05)
    _check_floor(res, case)


def test_step():
    m, t_s, day, phi = _axes()
    case = make_case({"step": np.outer(day >= 17.3, [3.0, -2.0, 0.0])})
    res = _run(case)
    assert _first_new(res) == "step", res.account()
    p = res.effect("step").parameters
    t_true = pd.Timestamp("2019-11-01T00:00:00Z") + pd.Timedelta(days=17.3)
    assert abs(pd.Timestamp(p["time"]) - t_true) < pd.Timedelta(hours=6)
    assert_allclose([p["values"]["Hp"]["size_nT"], p["values"]["He"]["size_nT"]], [3.0, -2.0],
                    atol=0.7)
    _check_floor(res, case)


@pytest.mark.slow
def test_a_step_shared_by_components_is_one_step_with_all_of_them():
    """A 2 nT step in every component (6 seeded months, red noise of 2 nT; in three of
    them a week is missing around the step). Each month names one step holding all three
    components, near the true time (for the week's gap: near the gap, where the data
    place it), and the sizes' 95 % intervals hold the truth. Tried only in the
    components whose own change point fell within 3 h of it, such a step was named whole
    in one of these six months and a drift was named instead in the other five. The
    step time's 95 % interval holds the true time (inside the gap where a week is
    missing)."""
    m, t_s, day, phi = _axes()
    t0 = pd.Timestamp("2019-11-01T00:00:00Z")
    off_h, inside, when = [], [], []
    for seed in range(6):
        case = make_case({"step": np.outer(day >= 17.3, [2.0, 2.0, 2.0])}, seed=seed)
        if seed < 3:
            keep = np.ones(day.size, dtype=bool)
            lo, hi = (t0 + pd.Timedelta(days=17.3),) * 2
        else:
            keep = (day < 14.0) | (day >= 21.0)
            lo, hi = t0 + pd.Timedelta(days=14.0), t0 + pd.Timedelta(days=21.0)
        res = _run(case, keep)
        steps = [e for e in res.effects if e.name == "step"]
        assert [e.components for e in steps] == [("Hp", "He", "Hn")], (seed, res.account())
        # the runner-up is another effect, not this step at another of the tried times
        assert steps[0].evidence["runner_up"]["name"] != "step", steps[0].evidence
        p = steps[0].parameters
        t = pd.Timestamp(p["time"])
        off_h.append(max((lo - t).total_seconds(), (t - hi).total_seconds(), 0.0) / 3600.0)
        inside += [lo_ <= 2.0 <= hi_ for lo_, hi_ in
                   (p["ci95"][c]["size_nT"] for c in ("Hp", "He", "Hn"))]
        # the time's 95 % interval: after its first value, at or before its second
        after, by = (pd.Timestamp(v) for v in p["time_ci95"])
        assert p["time_ci95_s"] == [after.timestamp(), by.timestamp()], p
        assert after < t <= by, p
        when.append(after < t0 + pd.Timedelta(days=17.3) <= by)
    # the time: within 6 h in most months (red noise places a 2 nT step only roughly);
    # the intervals: 18 values at 95 %, at most 2 outside (binomial: 94 % of the time)
    assert np.median(off_h) <= 6.0, off_h
    assert sum(inside) >= 16, inside
    # 6 intervals at 95 %: at most one without the true time (binomial: 97 % of the time)
    assert sum(when) >= 5, when


@pytest.mark.slow
def test_a_drift_rate_change_several_components_share_is_one_drift_with_its_break():
    """A drift-rate change of 0.7 nT/day at day 12.4 in every component (about 1.5x its
    detectability threshold; 5 seeded months, in two of them three days missing around
    the break): each month names one drift holding all three components with a break
    (the hinge), near the true time, and no step. Tried only in the components whose
    own change of slope fell within 3 h, the bend came out in each of these months as a
    drift without a break followed by two or three breaks in parts of the components,
    days apart (and a step in one month). The break time's 95 % interval holds the true
    time."""
    m, t_s, day, phi = _axes()
    t_true = pd.Timestamp("2019-11-01T00:00:00Z") + pd.Timedelta(days=12.4)
    off_h, when = [], []
    for seed in range(5):
        case = make_case({"bend": np.outer(np.maximum(day - 12.4, 0.0), [0.7, 0.7, 0.7])},
                         seed=seed)
        keep = (day < 11.0) | (day >= 14.0) if seed >= 3 else np.ones(day.size, dtype=bool)
        res = _run(case, keep)
        assert "step" not in res.names, (seed, res.account())
        drifts = [e for e in res.effects if e.name == "drift"]
        assert [e.components for e in drifts] == [("Hp", "He", "Hn")], (seed, res.account())
        assert drifts[0].effect.t_break_s is not None, (seed, res.account())
        off_h.append(abs(drifts[0].effect.t_break_s - t_true.timestamp()) / 3600.0)
        # the break's 95 % interval: after its first value, at or before its second
        after, by = drifts[0].time_ci95_s
        when.append(after < t_true.timestamp() <= by)
    # a bend of 0.7 nT/day in red noise of 2 nT is placed to about a day
    assert np.median(off_h) <= 24.0, off_h
    # 5 intervals at 95 %: at most one without the true time (binomial: 97.7 % of the
    # time; seeds 0-19 of this design held it in 20 of 20, 44-109 h wide)
    assert sum(when) >= 4, when


def test_periodic():
    m, t_s, day, phi = _axes()
    hidden = np.outer(np.cos(2 * np.pi * t_s / (7.7 * 3600) + 0.3), [1.0, 0.0, 0.7])
    case = make_case({"per": hidden})
    res = _run(case)
    assert _first_new(res) == "periodic", res.account()
    p = res.effect("periodic").parameters
    assert_allclose(p["period_h"], 7.7, rtol=0.01)
    assert_allclose(p["derived"]["Hp"]["amplitude_nT"], 1.0, atol=0.2)
    assert_allclose(p["derived"]["Hn"]["amplitude_nT"], 0.7, atol=0.2)
    _check_floor(res, case)


def test_two_hidden_effects_and_augmented_model():
    m, t_s, day, phi = _axes()
    hidden_d = np.column_stack([-1.5 * np.cos(phi), 0 * phi, 0 * phi])
    hidden_a = np.outer(m.dst, [0.15, 0.0, 0.0])
    case = make_case({"d": hidden_d, "a": hidden_a})
    res = _run(case)
    assert {"diurnal", "activity"} <= set(res.names), res.account()
    _check_floor(res, case)
    aug = res.augmented_model(case.measured.index, case.model, case.covariates)
    resid = (case.measured - aug).to_numpy()
    assert_allclose(np.sqrt(np.mean(resid ** 2)), res.gap_final["rms_nT"], rtol=1e-9)
    # the augmented model evaluates on new times (the last 5 days only)
    tail = case.measured.index[-7200:]
    aug_tail = res.augmented_model(tail, case.model.loc[tail], case.covariates.loc[tail])
    assert_allclose(aug_tail.to_numpy(), aug.loc[tail].to_numpy(), atol=1e-9)
    doc = res.to_json()
    assert doc["gap_initial"]["rms_nT"] > doc["gap_final"]["rms_nT"]
    assert [e["name"] for e in doc["effects"]] == res.names
    for e in doc["effects"]:
        assert e["rms_after_nT"] <= e["rms_before_nT"]
