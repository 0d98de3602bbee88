"""Pulse events of the joint pair stage (magcal.ac.joint): masks around other events,
ambient waves interpolated from the flanks, the matched-filter pulse selection and
pooling, against injected truth."""

import re

import numpy as np
from numpy.testing import assert_allclose

from magcal.ac.chain import Order
from magcal.ac.events import event_masks
from magcal.ac.joint import (
    Selection,
    fit_joint,
    flank_ambient,
    flank_ambient_error,
    pool_pulses,
    pulse_selection,
    selections,
)


def triangle(t, centre, half=90.0):
    return np.maximum(0.0, 1.0 - np.abs(t - centre) / half)


def test_event_masks_mask_other_spike_instead_of_dropping(rng):
    t = np.arange(20000.0)
    d = rng.normal(0, 0.05, (20000, 3))
    d[5000:15000, 2] += 20.0          # two large ramps (midnight-like)
    d[15080:15086, 1] += 3.0          # a 6 s spike 80 s after the second ramp
    m1, m2 = event_masks(d, t, half_s=120.0, guard_s=15.0)
    assert m1.sum() == 241 and m1[4880] and m1[5120]
    # the second interval keeps everything but the spike and its guard
    assert not m2[15075:15092].any()
    assert m2[15000] and m2[15060] and m2[15110] and m2[15120]
    assert 241 - 40 <= m2.sum() <= 241 - 30      # 6 s spike + 2 x 15 s guard


def test_flank_ambient_interpolates_a_wave_across_the_pulse(rng):
    t = np.arange(4000.0)
    wave = (2.0 * np.cos(2 * np.pi * (t - 2000) / 300.0)[:, None] * [1.0, 0.3, -0.5]
            + 1e-3 * (t - 2000)[:, None])
    pulse = triangle(t, 2000.0)[:, None] * [0.0, 0.5, 2.0]
    amb = flank_ambient(wave + pulse, t, 2000.0)
    core = np.abs(t - 2000) <= 100
    # the basis holds the wave exactly, and the pulse is only in the core
    assert_allclose(amb[core], wave[core], atol=1e-6)
    assert np.isnan(amb[np.abs(t - 2000) > 600]).all()
    e_mod, e_raw = flank_ambient_error(wave, t, 2000.0)
    assert e_mod < 1e-6 * e_raw
    # white noise does not interpolate: the check says so
    noise = rng.normal(0, 1.0, (4000, 3))
    e_mod, e_raw = flank_ambient_error(noise, t, 2000.0)
    assert e_mod > e_raw


def _pulse_pair(rng, n=8000, centres=(3000.0, 5700.0), period_s=330.0):
    t = np.arange(float(n))
    e_i, e_j = np.array([0.3, -0.2, 2.0]), np.array([0.5, -0.6, 5.0])
    h = sum(triangle(t, c) for c in centres)[:, None]
    # a Pc5 wave symmetric about the first pulse: its chance correlation with the
    # pulse is as large as it gets
    amb = 1.5 * np.cos(2 * np.pi * (t - centres[0]) / period_s)[:, None] * [0.6, 0.2, 0.8]
    x = amb + h * e_i + rng.normal(0, 0.03, (n, 3))
    y = amb + h * e_j + rng.normal(0, 0.03, (n, 3))
    return t, x, y, e_i, e_j


def remnant(K, e_i, e_j):
    return np.linalg.norm(e_i + K @ (e_i - e_j)) / np.linalg.norm(e_i)


def test_pulse_selection_with_ambient_removal_beats_the_interval_regression(rng):
    t, x, y, e_i, e_j = _pulse_pair(rng)
    c = 3000.0
    m = np.abs(t - c) <= 120
    plain = fit_joint([Selection("interval", x, y, m)], 1.0, min_snr=0.0)
    pulse = pulse_selection("e", x, y, t, c, m, ambient=True)
    fit = fit_joint([pulse], 1.0)
    # truth: e_i + K (e_i - e_j) = 0 along the pulse; measured remnants 1.15 (the
    # wave dominates the interval) and 0.07 (330 s wave fitted with the 320/340 s grid)
    assert remnant(plain.K, e_i, e_j) > 0.5
    assert remnant(fit.K, e_i, e_j) < 0.1
    # the wave runs through the record: without removal the chance level says so
    bare = pulse_selection("e", x, y, t, c, m, ambient=False)
    snr_bare = fit_joint([bare], 1.0, pulse_min_snr=0.0).snr["e pulse"]
    assert remnant(fit_joint([bare], 1.0, pulse_min_snr=0.0).K, e_i, e_j) > 0.5
    assert fit.snr["e pulse"] > 5 * snr_bare          # measured 52 vs 6.1
    # swapping the sensors swaps the chance levels
    assert pulse.chance is not None and len(pulse.chance) == 2


def test_pool_pulses_weights_events_by_their_chance_level(rng):
    t, x, y, e_i, e_j = _pulse_pair(rng)
    good = pulse_selection("b", x, y, t, 5700.0, np.abs(t - 5700) <= 120, ambient=True)
    bad = pulse_selection("a", x, y, t, 3000.0, np.abs(t - 3000) <= 120, ambient=False)
    assert bad.chance[0] > 10 * good.chance[0]        # measured 31x
    pooled = pool_pulses([bad, good])
    assert pooled.mask.sum() == 482
    fit = fit_joint([pooled], 1.0)
    assert remnant(fit.K, e_i, e_j) < 0.05
    # unweighted pooling would follow the bad event much more
    raw = Selection("raw", bad.b_i + good.b_i, bad.b_j + good.b_j, bad.mask | good.mask,
                    lag_null=False)
    assert remnant(fit_joint([raw], 1.0, min_snr=0.0).K, e_i, e_j) > 3 * remnant(fit.K, e_i, e_j)


def test_selections_pulse_mode_pools_events_and_interval_mode_keeps_them(rng):
    t, x, y, e_i, e_j = _pulse_pair(rng)
    # the events are found as steps of the (raw) difference: two ramps in it
    ramp = np.clip((t - 3000) / 30 + 0.5, 0, 1) - np.clip((t - 5700) / 30 + 0.5, 0, 1)
    raw_d = x - y + 20.0 * ramp[:, None] * [0.0, 0.0, 1.0]
    orders = (Order(window_s=500.0, direction="coherent"),)
    pulse = selections(x, y, t, orders, 1.0, event_difference=raw_d)
    names = [s.name for s in pulse]
    assert len(pulse) == 2 and names[0] == "window 500 s"
    # both events found (the pulses in the difference shift the ramp centres by < 15 s)
    # and both taken with the wave removed
    spans = [tuple(map(float, r)) for r in re.findall(r"event (\d+)-(\d+) s", names[1])]
    assert_allclose([0.5 * (a + b) for a, b in spans], [3000.0, 5700.0], atol=15.0)
    assert names[1].count("(ambient removed)") == 2
    fit = fit_joint(pulse[1:], 1.0)
    assert remnant(fit.K, e_i, e_j) < 0.1
    inter = selections(x, y, t, orders, 1.0, events="interval", event_difference=raw_d)
    assert [s.name for s in inter[1:]] == ["event 2888-3127 s", "event 5573-5812 s"]
    assert all(s.chance is None and s.lag_null for s in inter)


def test_pulse_events_mask_a_spike_on_the_ramp_and_model_a_step_in_the_window(rng):
    # a spike 12 s before the first ramp (inside its detection signals in the raw
    # difference) and a step 67 s after the second, both with other signatures
    # the wave's period is on the grid of flank_ambient: spike and step are the only
    # error sources
    t, x, y, e_i, e_j = _pulse_pair(rng, period_s=320.0)
    spike = np.exp(-0.5 * ((t - 2988.0) / 2.5) ** 2)[:, None]
    step = (t >= 5767.0)[:, None].astype(float)
    x = x + spike * [5.0, 3.0, 1.0] + step * [0.0, 2.0, -2.0]
    y = y + spike * [14.0, 8.0, 3.0] + step * [0.0, 5.0, -5.0]
    ramp = np.clip((t - 3000) / 30 + 0.5, 0, 1) - np.clip((t - 5700) / 30 + 0.5, 0, 1)
    raw_d = x - y + 20.0 * ramp[:, None] * [0.0, 0.0, 1.0]
    sels = selections(x, y, t, (Order(window_s=500.0, direction="coherent"),), 1.0,
                      event_difference=raw_d)
    pooled = sels[-1]
    assert not pooled.mask[2980:2997].any()           # the spike and its guard
    fit = fit_joint([pooled], 1.0)
    # measured 0.01-0.02 (0.79 when neither is masked nor modelled)
    assert remnant(fit.K, e_i, e_j) < 0.05


def test_step_events_pool_one_disturbers_steps_and_recover_its_signature(rng):
    from magcal.ac.joint import fit_joint, pool_pulses, step_group, step_selection

    # a unit toggling at 4 times (signature 2 at x, 5 at y along Y) under a slow
    # ambient wave; one step of another unit (along X) must not join the group
    t = np.arange(20000.0)
    amb = 3.0 * np.sin(2 * np.pi * t / 700.0)[:, None] * [1.0, 0.7, 0.2]
    amb = amb + rng.normal(0, 0.03, (20000, 3))
    lev = np.zeros(20000)
    for c in (3000.0, 7000.0, 11000.0, 15000.0):
        lev += np.clip((t - c) / 20 + 0.5, 0, 1) * (1 if c in (3000.0, 11000.0) else -1)
    other = np.clip((t - 18000) / 20 + 0.5, 0, 1)
    x = amb + lev[:, None] * [0.0, 2.0, 0.0] + other[:, None] * [1.0, 0.0, 0.0]
    y = amb + lev[:, None] * [0.0, 5.0, 0.0] + other[:, None] * [4.0, 0.0, 0.0]
    keep = np.ones(20000, bool)
    sels = [step_selection(f"{c:g}", x, y, t, c, keep)
            for c in (3000.0, 7000.0, 11000.0, 15000.0, 18000.0)]
    group = step_group(sels)
    assert [s.name for s in group] == ["3000 step", "7000 step", "11000 step", "15000 step"]
    fit = fit_joint([pool_pulses(group)], 1.0)
    # x + K (x - y) nulls the unit's signature: K_yy = -2 / (2 - 5)
    assert_allclose(fit.K[1, 1], 2.0 / 3.0, atol=0.01)
