"""Spinning-spacecraft simulator: sampling, truth consistency, flipper, gaps, drift."""

from __future__ import annotations

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
    a = simulate_spinning(SpinningConfig.galileo_like(duration_s=100.0), rng=np.random.default_rng(5))
    b = simulate_spinning(SpinningConfig.galileo_like(duration_s=100.0), rng=np.random.default_rng(5))
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
