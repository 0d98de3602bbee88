"""Spinning-spacecraft simulator: sampling, truth consistency, flipper, gaps, drift."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from numpy.testing import assert_allclose

from magcal.simulate.spinning import (FLIP_MATRIX, SpinningConfig, simulate_spinning)
from magcal.spin.despin import despin


def _t(res):
    return res.truth.t_s


def test_galileo_like_sampling_and_columns(rng):
    res = simulate_spinning(SpinningConfig.galileo_like(), rng=rng)
    assert list(res.data.columns) == ["b1", "b2", "b3", "phase", "flip"]
    assert len(res.data) == 81000                      # 5 h at 4.5 vectors/s
    steps = np.diff(_t(res))[:6]
    assert_allclose(steps, [7 / 30, 7 / 30, 6 / 30] * 2, atol=1e-9)
    # index carries the same times as the truth, in UTC
    secs = (res.data.index - res.data.index[0]).total_seconds().to_numpy()
    assert_allclose(secs, _t(res), atol=1e-6)
    assert str(res.data.index.tz) == "UTC"
    # one spin every 20 s
    assert_allclose(res.data["phase"].iloc[-1] - res.data["phase"].iloc[0],
                    2 * np.pi * _t(res)[-1] / 20.0, rtol=1e-12)


def test_truth_consistency(rng):
    cfg = SpinningConfig.galileo_like(duration_s=600.0, noise_nT=0.0)
    res = simulate_spinning(cfg, rng=rng)
    b = res.data[["b1", "b2", "b3"]].to_numpy()
    tr = res.truth
    calibrated = (b - tr.offsets_nT) @ tr.coupling.T        # B = C (b - O)
    assert_allclose(calibrated, tr.b_sc, atol=1e-9)
    assert_allclose(despin(tr.b_sc, tr.phase_rad), tr.b_despun, atol=1e-9)


def test_noise_level(rng):
    cfg = SpinningConfig.galileo_like(duration_s=600.0, noise_nT=0.05)
    res = simulate_spinning(cfg, rng=rng)
    tr = res.truth
    seen = tr.b_sc @ np.linalg.inv(tr.coupling).T + tr.offsets_nT
    resid = res.data[["b1", "b2", "b3"]].to_numpy() - seen
    assert_allclose(resid.std(axis=0), 0.05, rtol=0.05)


def test_same_seed_same_data():
    cfg = SpinningConfig.galileo_like(duration_s=100.0)
    a = simulate_spinning(cfg, rng=np.random.default_rng(5))
    b = simulate_spinning(cfg, rng=np.random.default_rng(5))
    assert_allclose(a.data.to_numpy(), b.data.to_numpy())


def test_flipper_interval_puts_sensor3_in_spin_plane(rng):
    cfg = SpinningConfig.galileo_like(duration_s=1200.0, noise_nT=0.0, turbulence_rms_nT=0.0,
                                      waves=(), slow_amplitude_nT=(0, 0, 0),
                                      coupling=tuple(map(tuple, np.eye(3))),
                                      flip_intervals_s=((400.0, 800.0),))
    res = simulate_spinning(cfg, rng=rng)
    d = res.data
    flipped = d[d["flip"] == 1]
    assert_allclose(res.truth.t_s[d["flip"].to_numpy() == 1][[0, -1]], [400.0, 800.0 - 6 / 30],
                    atol=1e-9)
    # sensor 3 now reads Bx + O3: its mean over whole spins is O3 (0.45 nT)
    n = len(flipped) // 90 * 90                           # whole 20 s spins
    assert_allclose(flipped["b3"].to_numpy()[:n].mean(), 0.45, atol=0.02)
    # sensor 1 reads -Bz + O1 = -35 + 0.8
    assert_allclose(flipped["b1"].to_numpy(), -35.0 + 0.8, atol=1e-9)
    assert_allclose(FLIP_MATRIX @ [1.0, 2.0, 3.0], [-3.0, 2.0, 1.0])


def test_gaps_and_drift(rng):
    cfg = SpinningConfig.galileo_like(duration_s=3600.0, gaps_s=((100.0, 107.0),),
                                      spin_period_drift_s_per_h=0.5)
    res = simulate_spinning(cfg, rng=rng)
    t = res.truth.t_s
    assert not np.any((t >= 100.0) & (t < 107.0))
    assert_allclose(res.truth.spin_period_s[[0, -1]], [20.0, 20.0 + 0.5 * t[-1] / 3600], rtol=1e-12)
    # phase rate matches the instantaneous period
    rate = np.gradient(res.data["phase"].to_numpy(), t)
    assert_allclose(rate[-10:], 2 * np.pi / res.truth.spin_period_s[-10:], rtol=1e-6)


def test_calcoil_square_wave(rng):
    cfg = SpinningConfig.galileo_like(duration_s=120.0, calcoil_amplitude_nT=4.5,
                                      calcoil_frequency_hz=0.5, calcoil_intervals_s=((10.0, 50.0),))
    res = simulate_spinning(cfg, rng=rng)
    coil = res.truth.calcoil_nT
    t = res.truth.t_s
    on = coil[:, 1] > 0
    assert set(np.unique(coil[:, 1])) == {0.0, 4.5}
    assert_allclose(coil[:, [0, 2]], 0.0)
    assert not np.any(on & ((t < 10.0) | (t >= 50.0)))
    # on during the first second of each 2 s period
    assert np.all(((t[on] - 10.0) % 2.0) < 1.0)


def test_elfin_like(rng):
    res = simulate_spinning(SpinningConfig.elfin_like(), rng=rng)
    assert len(res.data) == 3600
    assert_allclose(np.diff(res.truth.t_s), 0.1, atol=1e-9)
    assert res.config.spin_period_s == pytest.approx(2.9)


def test_default_phases_unchanged():
    """Without ``random_phases`` a seed gives the record it gave before the option existed
    (values from that code, seed 11): data_samples and the seeded tests keep their data,
    and a wave's fourth element 0.3 is the default phase."""
    a = simulate_spinning(SpinningConfig.galileo_like(duration_s=600.0),
                          rng=np.random.default_rng(11))
    assert len(a.data) == 2700
    assert_allclose(a.data[["b1", "b2", "b3", "phase"]].to_numpy()[[0, 1000, 2699]],
                    [[25.52275564268082, -16.531163520291233, 35.42374973033252, 0.0],
                     [11.12248867780171, -28.664808872808074, 37.27270677937551,
                      69.81666073827716],
                     [28.215194031156546, -12.282820127958676, 41.59591533727721,
                      188.43272736231577]], rtol=0, atol=1e-11)
    e = simulate_spinning(SpinningConfig.elfin_like(), rng=np.random.default_rng(11))
    assert_allclose(e.data[["b1", "b2", "b3"]].to_numpy()[[0, 1800, 3599]],
                    [[18089.427086964413, -8598.956582521472, 29988.510011546936],
                     [15083.685467724874, -15037.73476457036, 32317.284774632895],
                     [10952.46769449395, -17488.01533718854, 33002.90577036122]],
                    rtol=0, atol=1e-9)
    base = SpinningConfig.galileo_like(duration_s=600.0)
    explicit = dataclasses.replace(base, waves=tuple((*w, 0.3) for w in base.waves))
    same = simulate_spinning(explicit, rng=np.random.default_rng(11))
    assert np.array_equal(same.data.to_numpy(), a.data.to_numpy())


def test_random_phases_drawn_per_seed():
    """With ``random_phases`` each seed draws its own wave, slow-field and spin phases
    (seeded: the same seed, the same record); amplitudes and periods stay."""
    quiet = SpinningConfig.galileo_like(duration_s=600.0, turbulence_rms_nT=0.0,
                                        noise_nT=0.0, random_phases=True)
    r1 = simulate_spinning(quiet, rng=np.random.default_rng(11))
    r1b = simulate_spinning(quiet, rng=np.random.default_rng(11))
    r2 = simulate_spinning(quiet, rng=np.random.default_rng(12))
    assert np.array_equal(r1.data.to_numpy(), r1b.data.to_numpy())
    p1, p2 = r1.data["phase"].iloc[0], r2.data["phase"].iloc[0]
    assert 0.0 <= p1 < 2 * np.pi and 0.0 <= p2 < 2 * np.pi and p1 != p2
    assert_allclose(np.diff(r1.data["phase"].to_numpy()), 2 * np.pi * np.diff(r1.truth.t_s) / 20)
    # noise-free, so the despun field is background + slow + waves: recover each phase
    t = r1.truth.t_s
    phases = []
    for res in (r1, r2):
        f = res.truth.b_despun - np.asarray(quiet.background_nT)
        cols = [np.ones_like(t)]
        for per in quiet.slow_period_s:
            cols += [np.sin(2 * np.pi * t / per), np.cos(2 * np.pi * t / per)]
        for _, freq, _ in quiet.waves:
            cols += [np.sin(2 * np.pi * freq * t), np.cos(2 * np.pi * freq * t)]
        coef, *_ = np.linalg.lstsq(np.column_stack(cols), f, rcond=None)
        # slow field of component k: amplitude A_k, any phase (600 s of a 4-6 h sine:
        # the fit tells it from the constant to 1e-6 only)
        for k, amp in enumerate(quiet.slow_amplitude_nT):
            assert_allclose(np.hypot(*coef[1 + 2 * k:3 + 2 * k, k]), amp, rtol=1e-4)
        # wave 1 (0.6 nT along (0.6, 0.8, 0)) seen in Y
        w1 = coef[7:9, 1]
        assert_allclose(np.hypot(*w1), 0.6 * 0.8, rtol=1e-6)
        # a sin(wt + phi) = a cos(phi) sin(wt) + a sin(phi) cos(wt)
        phases.append(np.arctan2(w1[1], w1[0]))
    assert abs(np.angle(np.exp(1j * (phases[0] - phases[1])))) > 0.01
    assert abs(np.angle(np.exp(1j * (phases[0] - 0.3)))) > 0.01
