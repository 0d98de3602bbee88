"""The disturbed-interval detector's parts on synthetic fields with known truth
(magcal.missions.elfin.detect, .disturbed); on the real day: test_elfin_injection."""

import numpy as np
import pandas as pd
import pytest

from magcal.missions.elfin.detect import DetectSettings, flag_excursions, robust_baseline
from magcal.missions.elfin.disturbed import bridge_check, spin_split

PERIOD_S = 2.85


def _zone(t, b, zone=0):
    idx = pd.Timestamp("2022-01-12T12:00:00", tz="UTC") + pd.to_timedelta(t, unit="s")
    return pd.DataFrame({"zone": zone, "bx_despun": b[:, 0], "by_despun": b[:, 1],
                         "bz_despun": b[:, 2], "phase": 2 * np.pi * t / PERIOD_S},
                        index=pd.DatetimeIndex(idx, name="time"))


def test_spin_split_puts_a_spin_tone_in_tone_and_a_slow_field_in_slow():
    t = np.arange(0.0, 300.0, 0.1)
    slow = np.column_stack([1000 + 0.5 * t, -200 + 0 * t, 50 * np.sin(t / 40)])
    tone = np.column_stack([30 * np.cos(2 * np.pi * t / PERIOD_S), 0 * t,
                            10 * np.sin(4 * np.pi * t / PERIOD_S)])
    s, r = spin_split(_zone(t, slow + tone))
    inner = (t > 5) & (t < 295)
    # a running mean over one spin (29 samples of 0.1 s for 2.85 s): the tones leave
    # at most a 2 % remainder, the slow field's curvature a few hundredths of nT
    assert np.abs(s - slow)[inner].max() < 0.05 * 30
    assert np.abs(r - tone)[inner].max() < 0.05 * 30


def test_bridge_check_keeps_a_slow_change_and_drops_a_tone_change():
    t = np.arange(0.0, 300.0, 0.1)
    base = np.column_stack([1000 + 0 * t, 0 * t, 0 * t])
    plain = _zone(t, base)
    run = (t >= 100) & (t < 160)
    bump = np.zeros_like(base)
    bump[run, 2] = 80.0 * np.sin(np.pi * (t[run] - 100) / 60)          # a slow field
    ripple = np.zeros_like(base)
    ripple[run, 0] = 80.0 * np.cos(2 * np.pi * t[run] / PERIOD_S)      # a spin tone
    kept = bridge_check(_zone(t, base + bump), plain, run)
    dropped = bridge_check(_zone(t, base + ripple), plain, run)
    assert len(kept) == len(dropped) == 1
    assert bool(kept["kept"].iloc[0]) and not bool(dropped["kept"].iloc[0])
    # closed form: RMS of 80 sin over a half period is 80 / sqrt(2)
    assert kept["slow_change_nT"].iloc[0] == pytest.approx(80 / np.sqrt(2), rel=0.05)
    assert dropped["tone_change_nT"].iloc[0] == pytest.approx(80 / np.sqrt(2), rel=0.05)
    assert kept["start_s"].iloc[0] == pytest.approx(100.0)
    assert kept["end_s"].iloc[0] == pytest.approx(159.9)


def test_a_run_near_a_zone_edge_is_not_flagged():
    t = np.arange(0.0, 300.0, 0.1)
    z = np.zeros((t.size, 1))
    z[(t > 100) & (t < 120), 0] = 9.0
    z[(t > 8) & (t < 25), 0] = 9.0                 # within edge_s (20 s) of the start
    s = DetectSettings(pad_s=1.0)
    f = flag_excursions(t, z, 100 * z, t >= 0, s)
    assert f[(t > 100) & (t < 120)].all()
    assert not f[t < 50].any()
    assert flag_excursions(t, z, 100 * z, t >= 0, DetectSettings(pad_s=1.0, edge_s=0.0))[
        (t > 8) & (t < 25)].all()


def test_robust_cubic_passes_under_a_pulse_that_drags_least_squares():
    """A 200 nT 40 s pulse in a 6 min zone on a cubic trend: the least-squares start of
    the biweights would be pulled tens of nT; the L1 start is not."""
    t = np.arange(0.0, 370.0, 0.1)
    trend = 40 * ((t - 185) / 185) ** 3 - 30 * ((t - 185) / 185)
    rng = np.random.default_rng(2024)
    y = trend + rng.normal(0, 2, t.size) - 200 * np.exp(-4 * np.log(2) * (t - 185) ** 2 / 40 ** 2)
    base, sigma = robust_baseline(t, y, t >= 0, degree=3)
    assert np.abs(base - trend).max() < 3.0
    # the noise is 2 nT; the median absolute departure also counts the pulse's flanks
    # (measured 3.2 nT), and the pulse still departs by more than 40 of them
    assert 2.0 <= sigma <= 4.0
    assert (base - y).max() > 40 * sigma
    ols, _ = robust_baseline(t, y, t >= 0, degree=3, l1_iter=0, n_iter=1)
    assert np.abs(ols - trend).max() > 20.0


def _field(t, dz, level=None):
    """A zone whose despun field departs from the model by ``dz`` along the spin axis,
    across B (ELFIN's spin axis is near east-west: such a field leaves ``|B|`` alone to
    first order)."""
    ref = np.column_stack([45000.0 + 0 * t, 0 * t, 0 * t])
    cols = {"zone": 7, "used": 1}
    for i, c in enumerate("xyz"):
        cols[f"b{c}_despun"] = ref[:, i] + (dz if c == "z" else 0.0)
        cols[f"igrf_{c}_despun"] = ref[:, i]
    f = _zone(t, ref).assign(**cols)
    return f if level is None else f.assign(level_step=np.asarray(level, int))


def _quiet_axis(t):
    """3 nT of smoothed white noise on a 10 nT wobble, seeded."""
    rng = np.random.default_rng(7)
    return np.convolve(rng.normal(0, 4, t.size), np.ones(5) / 5, mode="same") \
        + 10 * np.sin(t / 50)


def test_a_kept_level_step_keeps_the_disturbance_beside_it_flagged():
    """A 120 nT disturbance at 80 s and a 300 nT current sheet rising at 185 s: about a
    baseline that cannot follow the sheet's plateau the robust sigma grows sixfold and
    the disturbance goes unflagged; with the sheet's level step in the baseline the
    disturbance is flagged as on the day without the sheet."""
    from magcal.missions.elfin.detect import detect_in_field

    t = np.arange(0.0, 370.0, 0.2)
    disturbance = 120 * np.exp(-0.5 * ((t - 80) / 12) ** 2)
    sheet = -150 * (1 + np.tanh((t - 185) / 4.5))
    level = (t > 170) & (t < 200)
    clean, clean_tab = detect_in_field(_field(t, _quiet_axis(t) + disturbance))
    blind, blind_tab = detect_in_field(_field(t, _quiet_axis(t) + disturbance + sheet))
    kept, kept_tab = detect_in_field(_field(t, _quiet_axis(t) + disturbance + sheet, level))
    core = (t > 70) & (t < 90)
    assert clean[core, 0].all()
    assert not blind[core, 0].all()                 # what the level step is for
    assert blind_tab["sigma_z_nT"].iloc[0] > 3 * clean_tab["sigma_z_nT"].iloc[0]
    before = t < 150
    assert kept[core, 0].all()
    # the same interval, its ends within a second (the sigma is 3 % apart)
    assert np.count_nonzero(kept[before] != clean[before]) <= 10
    assert kept[level, 0].all()                     # the rise itself is disturbed
    assert kept_tab["sigma_z_nT"].iloc[0] == pytest.approx(
        clean_tab["sigma_z_nT"].iloc[0], rel=0.1)


def test_a_level_step_the_data_do_not_demand_changes_no_flag():
    """Level rows where the level does not change: the step would not lower the robust
    sigma by LEVEL_BASELINE_GAIN, and the flags are those without the level column."""
    from magcal.missions.elfin.detect import detect_in_field

    t = np.arange(0.0, 370.0, 0.2)
    dz = _quiet_axis(t) + 120 * np.exp(-0.5 * ((t - 80) / 12) ** 2)
    plain, _ = detect_in_field(_field(t, dz))
    marked, _ = detect_in_field(_field(t, dz, (t > 170) & (t < 200)))
    np.testing.assert_array_equal(marked, plain)
