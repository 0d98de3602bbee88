"""Level steps of the spin-axis field across left-out intervals (magcal.missions.elfin.levels).

Closed-form cases with known truth (a sheet is a step, a pulse or a disturbance flagged
in part is not), a false-step rate over seeded noise, and on the real day: the zones
where an earlier gate stepped real disturbances get no step, and their product is the
default one.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pandas as pd
import pytest

from conftest import real_data_path
from magcal.alignment.noise import simulate_ou
from magcal.missions.elfin.levels import (
    judge_level_steps,
    level_change_candidates,
    level_step_rows,
    level_steps_wanted,
    step_columns,
    trial_sheet,
)

FGS = "ela_l1_fgs_20220112_v01.cdf"
STATE = "ela_l1_state_defn_20220112_v01.cdf"

T = np.arange(0.0, 370.0, 0.2)          # one ELFIN zone at 5 Hz


def _sheet(t0=180.0, size=300.0):
    return size / (1.0 + np.exp(-(T - t0) / 4.5))            # 10-90 % rise in 20 s


@pytest.mark.parametrize("step", [250.0, -250.0])
def test_a_trial_sheet_changes_the_spin_axis_level_with_the_kept_step_s_sign(step):
    """Truth: a polar orbit in the GEI x-z plane (orbit normal -y), the spin axis 2 deg
    from the opposite of the orbit normal, as on 2022-01-12. A kept step of +-250 nT
    gets a trial sheet along the orbit normal whose spin-axis component after its rise
    is the step times cos 2 deg (the calibration treats the two signs differently, so
    a trial of the other sign would measure another sheet), and which is 250 nT along
    the returned unit vectors."""
    idx = pd.date_range("2022-01-12", periods=T.size, freq="200ms", tz="UTC")
    w = 2 * np.pi / 5700.0                                      # 95 min orbit
    ts = np.arange(-60.0, 430.0, 1.0)
    r, v = 6900.0, 6900.0 * w
    state = pd.DataFrame({"pos_gei_x": r * np.cos(w * ts), "pos_gei_y": 0.0,
                          "pos_gei_z": r * np.sin(w * ts), "vel_gei_x": -v * np.sin(w * ts),
                          "vel_gei_y": 0.0, "vel_gei_z": v * np.cos(w * ts)},
                         index=idx[0] + pd.to_timedelta(ts, unit="s"))
    tilt = np.radians(2.0)
    axis = np.array([np.sin(tilt), 1.0 * np.cos(tilt), 0.0])    # orbit normal is -y
    zone = pd.DataFrame({"igrf_x_gei": 30000.0, "igrf_y_gei": 2000.0,
                         "igrf_z_gei": -35000.0,
                         **{f"spin_axis_gei_{c}": a for c, a in zip("xyz", axis)}},
                        index=idx)
    sig, u = trial_sheet(zone, state, step, T, 180.0)
    after = T > 300.0
    assert np.allclose(sig[after] @ axis, step * np.cos(tilt), rtol=1e-3)
    assert np.allclose(np.sum(sig[after] * u[after], axis=1), abs(step), rtol=1e-3)
    assert np.abs(sig[T < 100.0]).max() < 1e-3 * abs(step)
    none, _ = trial_sheet(zone, state, float("nan"), T, 180.0)
    assert not none.any()


def test_the_level_error_a_row_carries_adds_the_zone_s_steps_in_quadrature():
    """Truth: the level after two kept steps is their sum, so its stated error is
    sqrt(e1^2 + e2^2) (60 and 108 nT -> 123.5 nT); the other zone's step does not
    count, and rows before the zone's first step carry none."""
    from types import SimpleNamespace

    from magcal.missions.elfin.pipeline import ElfinDay

    zone = np.repeat([0, 1], 10)
    level = np.zeros(20, int)
    level[[2, 3, 6, 14]] = 1
    idx = pd.date_range("2022-01-12", periods=20, freq="1s", tz="UTC")
    field = pd.DataFrame({"zone": zone, "level_step": level}, index=idx)
    trials = pd.DataFrame({"zone": [0, 0, 1], "step_error_nT": [60.0, 108.0, 30.0]})
    day = SimpleNamespace(calibration=SimpleNamespace(field=field),
                          steps={"level_trials": trials})
    col = ElfinDay.level_error_column(day)
    assert np.isnan(col[[0, 1, 10, 11, 12, 13]]).all()
    assert np.all(col[2:6] == 60.0)
    assert np.allclose(col[6:10], np.hypot(60.0, 108.0))
    assert np.all(col[14:] == 30.0)


def test_a_step_in_a_zone_whose_spin_axis_field_hardly_changes_says_so():
    """The listing states each step's zone's spin-axis field change and whether its row
    was drawn to the day's: zone 1 of the prior (992 nT, not drawn), zone 3 (74 nT,
    drawn, under 500 nT: the level trades with the spin-axis gain)."""
    from types import SimpleNamespace

    from magcal.missions.elfin.pipeline import ElfinDay

    steps = [{"zone": 3, "start": "a", "end": "b", "step_nT": 250.0},
             {"zone": 1, "start": "c", "end": "d", "step_nT": -90.0}]
    prior = {"zones": [1], "axis_field_std_nT": [992.0, 74.0]}
    linear = SimpleNamespace(parameters={"axis_prior": prior}, field=None,
                             zone_numbers=[1, 3])
    day = SimpleNamespace(linear=linear, steps={}, level_step_intervals=lambda: steps)
    day._with_trials = lambda key, plain: ElfinDay._with_trials(day, key, plain)
    listed = ElfinDay.level_step_listing(day)
    assert [(x["zone"], x["axis_field_std_nT"], x["axis_field_small"], x["axis_row_prior"])
            for x in listed] == [(3, 74.0, True, True), (1, 992.0, False, False)]
    assert [x["step_nT"] for x in listed] == [250.0, -90.0]
    # without a prior (axis_prior_weight = 0) the change is read off the field's model
    bz = np.r_[np.linspace(-4450.0, -3050.0, 50), np.zeros(50)]
    linear.parameters, linear.field = {}, pd.DataFrame(
        {"zone": np.repeat([3, 1], 50), "used": 1, "igrf_z_despun": bz})
    (three, _) = ElfinDay.level_step_listing(day)
    assert three["axis_field_std_nT"] == pytest.approx(np.std(bz[:50]))     # 409 nT
    assert three["axis_field_small"] is True and three["axis_row_prior"] is False


def test_at_most_max_steps_are_kept_strongest_first():
    """Truth: a 300 nT sheet after one gap and a 100 nT one after another; with
    ``max_steps = 1`` only the larger is kept, without it both."""
    sheets = 300.0 / (1.0 + np.exp(-(T - 250.0) / 4.5)) \
        + 100.0 / (1.0 + np.exp(-(T - 110.0) / 4.5))
    fit = ~(((T > 235) & (T < 265)) | ((T > 95) & (T < 125)))
    assert level_steps_wanted(T, sheets, fit).tolist() == [True, True]
    assert level_steps_wanted(T, sheets, fit, max_steps=1).tolist() == [False, True]


def test_step_columns_turn_on_after_each_run():
    marked = np.zeros(10, bool)
    marked[2:4] = marked[7] = True
    cols = step_columns(marked)
    assert cols.shape == (10, 2)
    assert cols[:, 0].tolist() == [0, 0, 0, 0, 1, 1, 1, 1, 1, 1]
    assert cols[:, 1].tolist() == [0] * 8 + [1, 1]
    assert step_columns(np.zeros(5, bool)).shape == (5, 0)


def test_a_sheet_behind_a_tilt_trend_gets_its_step_and_the_quiet_gap_none():
    """The product without steps shows a sheet as a step plus the trend its slow
    terms took (here -0.8 nT/s); a second, quiet gap earlier must not be stepped."""
    r = _sheet() - 0.8 * T + 3.0 * np.sin(2 * np.pi * T / 3.0)
    fit = ~(((T > 160) & (T < 240)) | ((T > 50) & (T < 80)))
    assert level_steps_wanted(T, r, fit).tolist() == [False, True]


def test_a_pulse_left_out_is_not_a_step():
    r = 200.0 * np.exp(-0.5 * ((T - 180.0) / 17.0) ** 2) - 0.3 * T
    fit = ~((T > 140) & (T < 220))
    assert level_steps_wanted(T, r, fit).tolist() == [False]


def test_the_judgement_states_each_interval_s_tests_with_the_kept_step_s_size():
    """Closed form: a 300 nT sheet behind a -0.8 nT/s trend, a quiet gap before it.
    The sheet's interval is kept with its step within 5 nT of 300 (the trend is fitted
    with it), nearly all of its excursion and the level beside it; the quiet gap is
    judged too, not kept, and says which tests it fails (a step of a few nT)."""
    r = _sheet() - 0.8 * T
    fit = ~(((T > 160) & (T < 240)) | ((T > 50) & (T < 80)))
    tab = judge_level_steps(T, r, fit)
    assert tab["kept"].tolist() == [False, True]
    sheet = tab.iloc[1]
    assert sheet["step_nT"] == pytest.approx(300.0, abs=5.0)
    assert sheet["share"] >= 0.95 and sheet["gain"] >= 3.0 and sheet["why"] == ""
    assert sheet["start_s"] == pytest.approx(160.2, abs=0.3)
    quiet = tab.iloc[0]
    assert abs(quiet["step_nT"]) < 5.0
    assert quiet["why"].startswith("gain under 3") and "under 30 nT" in quiet["why"]
    # the choice is level_steps_wanted's
    assert level_steps_wanted(T, r, fit).tolist() == tab["kept"].tolist()


def test_a_disturbance_flagged_in_part_is_not_a_step():
    """A 120 nT bump (60 s sigma) whose rise is fitted and whose tail is left out:
    the trend bends to its fitted side, the level next to the gap hardly changes."""
    r = 120.0 * np.exp(-0.5 * ((T - 90.0) / 30.0) ** 2)
    fit = ~((T > 60) & (T < 170))
    assert level_steps_wanted(T, r, fit).tolist() == [False]


def test_no_false_steps_over_seeded_correlated_noise():
    """40 draws of a 10 nT OU wander (30 s) plus 5 nT white noise on a quiet zone with
    two gaps: no step (truth: none)."""
    rng = np.random.default_rng(20261127)
    fit = ~(((T > 100) & (T < 170)) | ((T > 250) & (T < 290)))
    hits = 0
    for _ in range(40):
        r = simulate_ou(rng, T, 10.0, 30.0) + rng.normal(0.0, 5.0, T.size)
        hits += int(level_steps_wanted(T, r, fit).any())
    assert hits == 0


def test_sheets_over_seeded_noise_are_all_found():
    """The same noise with a 300 nT sheet inside the second gap: found every time."""
    rng = np.random.default_rng(7)
    fit = ~(((T > 100) & (T < 140)) | ((T > 160) & (T < 240)))
    for _ in range(20):
        r = _sheet() + simulate_ou(rng, T, 10.0, 30.0) + rng.normal(0.0, 5.0, T.size)
        assert level_steps_wanted(T, r, fit).tolist() == [False, True]


def test_level_step_rows_marks_the_stepped_interval_of_each_zone():
    idx = pd.date_range("2022-01-12", periods=2 * T.size, freq="200ms", tz="UTC")
    zone = np.repeat([0, 1], T.size)
    fit = np.tile(~((T > 160) & (T < 240)), 2)
    bz = np.concatenate([_sheet(), 200.0 * np.exp(-0.5 * ((T - 200.0) / 17.0) ** 2)])
    field = pd.DataFrame({"zone": zone, "used": 1, "fit": fit.astype(int),
                          "bz_despun": 1000.0 + bz, "igrf_z_despun": 1000.0}, index=idx)
    rows = level_step_rows(field)
    assert rows[:T.size].tolist() == (~fit[:T.size] & (T > 0)).tolist()   # zone 0: the gap
    assert not rows[T.size:].any()                                      # zone 1: a pulse


def _field(bz, fit):
    idx = pd.date_range("2022-01-12", periods=T.size, freq="200ms", tz="UTC")
    return pd.DataFrame({"zone": 0, "used": 1, "fit": np.asarray(fit).astype(int),
                         "bz_despun": 1000.0 + bz, "igrf_z_despun": 1000.0}, index=idx)


def test_a_sheet_the_detector_missed_is_found_on_the_fitted_samples():
    """No interval left out, a 300 nT sheet rising at 180 s (10-90 % over 171-189 s)
    behind a trend: the candidate covers the rise and becomes a level step."""
    r = _sheet() - 0.5 * T
    fit = np.ones(T.size, bool)
    cand = level_change_candidates(T, r, fit)
    assert T[cand].min() <= 171.0 and T[cand].max() >= 189.0
    assert T[cand].max() - T[cand].min() <= 60.0
    rows = level_step_rows(_field(r, fit))
    assert rows.any() and T[rows].min() <= 171.0 and T[rows].max() >= 189.0
    assert not level_step_rows(_field(r, fit), candidates=False).any()


def test_fitted_pulses_and_level_changes_next_to_a_gap_give_no_step():
    """A 200 nT pulse on fitted samples has two abrupt changes and comes back: no
    step. A sheet rising 10 s after a left-out interval is no candidate (the falling
    edge of a disturbance whose top is left out looks the same)."""
    pulse = 200.0 * np.exp(-0.5 * ((T - 180.0) / 17.0) ** 2)
    assert not level_step_rows(_field(pulse, np.ones(T.size, bool))).any()
    fit = ~((T > 100) & (T < 160))
    assert not level_change_candidates(T, _sheet(), fit).any()


@pytest.fixture(scope="module")
def zones_2_7_8():
    from magcal.missions.elfin.files import read_elfin_fgs, read_elfin_state
    from magcal.missions.elfin.injection import select_zones

    fgs = read_elfin_fgs(real_data_path("elfin", FGS))
    state = read_elfin_state(real_data_path("elfin", STATE))
    return select_zones(fgs, [2, 7, 8]), state


def test_real_disturbances_flagged_in_part_get_no_step(zones_2_7_8):
    """2022-01-12 zones 2, 7 and 8: real disturbances the detector flags in part. The
    earlier in-fit gate stepped zones 2 and 8 (zone 2 vector 14.5 -> 18.3 nT), level
    changes next to a left-out run taken as candidates stepped zones 7 and 8 (vector
    28 -> 56 nT). Decided on the product, no step, and the product is the one without
    level steps."""
    from magcal.missions.elfin.pipeline import ElfinSettings, calibrate_elfin_day

    fgs, state = zones_2_7_8
    cols = ["bx_gei", "by_gei", "bz_gei"]
    on = calibrate_elfin_day(fgs, state, ElfinSettings(level_steps=True, bridge_trials=0),
                             diagnostics=False)
    off = calibrate_elfin_day(fgs, state, ElfinSettings(level_steps=False, bridge_trials=0),
                              diagnostics=False)
    f = on.calibration.field
    assert ((f["used"] == 1) & (f["fit"] == 0)).any()      # there are left-out runs
    assert f["level_step"].sum() == 0
    assert np.abs(f[cols].to_numpy() - off.calibration.field[cols].to_numpy()).max() < 1e-9
    # each was judged and is stated with the tests it fails
    judged = on.to_json()["level_steps"]["judged"]
    assert judged and not any(x["kept"] for x in judged)
    assert all(x["why"] and x["start"] < x["end"] for x in judged)
    assert {x["zone"] for x in judged} <= {0, 1, 2}
    assert on.calibrated_table()["level_step"].eq(0).all()


def test_a_sheet_injected_on_the_real_day_is_listed_with_its_level_change_and_error():
    """Zones 1 and 10 with a 300 nT east-west sheet injected at mid-zone 1: one level
    step, in the JSON with its level change within 20 % of the injected field's
    spin-axis component (truth: the signal, 30 s medians either side as the product's).
    Its stated error comes from a sheet of the step's size put into zone 10: the level
    zone 10 keeps is within 25 % of what was put in (truth: the trial's own injection),
    and the error is that level's distance from it."""
    from magcal.missions.elfin.files import read_elfin_fgs, read_elfin_state
    from magcal.missions.elfin.injection import inject_counts, select_zones, signal_gei
    from magcal.missions.elfin.pipeline import ElfinSettings, calibrate_elfin_day

    fgs = select_zones(read_elfin_fgs(real_data_path("elfin", FGS)), [1, 10])
    state = read_elfin_state(real_data_path("elfin", STATE))
    s = ElfinSettings(bridge_trials=0, level_trials=1)
    clean = calibrate_elfin_day(fgs, state, replace(s, level_trials=0), diagnostics=False)
    lf = clean.linear.field
    first = lf["zone"].to_numpy() == 0
    sig = signal_gei("sheet_ew", lf[first], state)
    day = calibrate_elfin_day(inject_counts(fgs, clean.linear, {0: sig}), state, s,
                              diagnostics=False)
    steps = day.level_step_intervals()
    assert len(steps) == 1 and steps[0]["zone"] == 0
    listed = day.to_json()["level_steps"]["intervals"]
    assert [{k: v for k, v in x.items() if k in steps[0]} for x in listed] == steps
    # the zone's spin-axis field over the pass, read off the model (day's zone 1: 605 nT,
    # its own row trusted)
    lin = day.linear.field
    used = (lin["zone"] == 0).to_numpy() & (lin["used"] == 1).to_numpy()
    assert listed[0]["axis_field_std_nT"] == pytest.approx(
        float(np.std(lin["igrf_z_despun"].to_numpy()[used])), rel=0.02)
    assert listed[0]["axis_field_small"] is False and listed[0]["axis_row_prior"] is False
    f = day.calibration.field[first]
    axis = f[["spin_axis_gei_x", "spin_axis_gei_y", "spin_axis_gei_z"]].to_numpy()
    along = np.sum(sig * axis, axis=1)
    ts = (f.index.as_unit("ns").asi8 - f.index.as_unit("ns").asi8[0]) / 1e9
    rows = np.flatnonzero(f["level_step"].to_numpy() == 1)
    a, b = ts[rows[0]], ts[rows[-1]]
    truth = (np.median(along[(ts > b) & (ts <= b + 30)])
             - np.median(along[(ts < a) & (ts >= a - 30)]))
    assert abs(truth) > 250.0
    assert abs(steps[0]["step_nT"] - truth) <= 0.2 * abs(truth)
    size = abs(steps[0]["step_nT"])
    (level,) = listed[0]["trial_levels_nT"]
    assert abs(level - size) <= 0.25 * size
    assert listed[0]["step_error_nT"] == pytest.approx(abs(level - size), rel=1e-9)
    # per row: the error from the step to the zone's end, nothing before it or elsewhere
    column = day.calibrated_table()["level_error_nT"].to_numpy()
    carried = np.zeros(len(column), bool)
    carried[np.flatnonzero(first)[rows[0]]:np.flatnonzero(first)[-1] + 1] = True
    assert np.all(column[carried] == listed[0]["step_error_nT"])
    assert np.isnan(column[~carried]).all()


def test_a_sheet_that_bends_a_real_disturbance_into_a_step_keeps_one_step():
    """2022-01-12 zones 7 and 8, a 300 nT sheet of the opposite polarity (-300 nT east-
    west) injected at 0.65 of zone 8 through the clean calibration. Judged all at once
    on the product without steps, the real disturbance before it also looked like a
    level change (-197 nT) and the level after the sheet kept -26 nT of -300; with the
    strongest step first and the others judged on the product with it, the zone keeps
    one step and the level within 20 % of the truth."""
    from magcal.missions.elfin.files import read_elfin_fgs, read_elfin_state
    from magcal.missions.elfin.injection import (
        directions,
        inject_counts,
        select_zones,
        signal_gei,
    )
    from magcal.missions.elfin.levels import kept_level
    from magcal.missions.elfin.pipeline import ElfinSettings, calibrate_elfin_day

    fgs = select_zones(read_elfin_fgs(real_data_path("elfin", FGS)), [7, 8])
    state = read_elfin_state(real_data_path("elfin", STATE))
    s = ElfinSettings(bridge_trials=0, pulse_trials=0, level_trials=0)
    clean = calibrate_elfin_day(fgs, state, s, diagnostics=False)
    lf = clean.linear.field
    z = (lf["zone"] == 1).to_numpy()
    zf = lf[z]
    sig = -signal_gei("sheet_ew", zf, state, centre=0.65)
    ns = zf.index.as_unit("ns").asi8
    t = (ns - ns[0]) / 1e9
    tu = t[zf["used"].to_numpy() == 1]
    t0 = tu[0] + 0.65 * (tu[-1] - tu[0])
    u = directions(zf.index, state, zf[["igrf_x_gei", "igrf_y_gei",
                                        "igrf_z_gei"]].to_numpy(float))["ew"]
    day = calibrate_elfin_day(inject_counts(fgs, clean.linear, {1: sig}), state, s,
                              diagnostics=False)
    steps = [x for x in day.level_step_intervals() if x["zone"] == 1]
    assert len(steps) == 1
    level = kept_level(day.calibration.field[z], clean.calibration.field[z], u, t, t0)
    assert level == pytest.approx(-300.0, rel=0.2)
