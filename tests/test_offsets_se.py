"""Offset standard errors (issue 21): coverage against truth on correlated model misses."""

import numpy as np

from magcal.alignment.noise import simulate_ou
from magcal.offsets.windows import DAY_NS, batch_standard_error, window_statistics


def _window_draws(n_draws, days=28, cadence_s=300.0, seed=0, tau_s=6 * 3600.0):
    """Median offsets and standard errors of windows whose model misses an AR(1) field
    (3 nT, tau ``tau_s``, 6 h by default) plus 0.5 nT white noise; truth offset
    (4, -2, 1) nT."""
    truth = np.array([4.0, -2.0, 1.0])
    t_s = np.arange(int(days * 86400 / cadence_s)) * cadence_s
    t_ns = (t_s * 1e9).astype(np.int64)
    rng = np.random.default_rng(seed)
    inside, ratio = [], []
    for _ in range(n_draws):
        miss = np.stack([simulate_ou(rng, t_s, 3.0, tau_s) for _ in range(3)], axis=1)
        diff = truth + miss + 0.5 * rng.standard_normal(miss.shape)
        quiet = rng.random(t_s.size) > 0.3  # Kp selection leaves 70 %
        st = window_statistics(t_ns, diff, quiet, [0], [t_ns[-1] + 1], min_used=100)
        err = st["median"][0] - truth
        inside.append(np.abs(err) <= 1.96 * st["se"][0])
        ratio.append(st["se"][0] / st["std"][0])
    return np.array(inside), np.array(ratio)


def test_offset_standard_error_covers_truth_under_ar1_model_miss():
    inside, ratio = _window_draws(120)
    # >= 90 % of 95 % intervals hold the true offset (issue 21); 360 intervals, so a
    # coverage below 0.90 would be detected
    assert inside.mean() >= 0.90
    # and not wildly conservative either (a standard error is not the spread)
    assert inside.mean() <= 0.995
    assert np.median(ratio) < 0.5


def test_offset_standard_error_covers_truth_when_the_miss_lasts_days():
    """A model miss correlated over two days (a slow ring-current change the model
    lacks): consecutive days' values follow each other beyond the first lag. The first
    lag's factor alone held the truth in 74 % of these 600 intervals (200 windows); the
    AR(1) factor with the lag's small-sample bias holds it in 90 % (binomial sd 1.2 %;
    the rest is the normal quantile on about 20 batches)."""
    inside, ratio = _window_draws(200, seed=5, tau_s=2 * 86400.0)
    assert inside.mean() >= 0.87, inside.mean()
    assert inside.mean() <= 0.99


def test_batch_standard_error_white_noise_matches_sigma_over_root_n():
    rng = np.random.default_rng(3)
    t = np.arange(40 * 144) * (DAY_NS // 144)
    x = rng.standard_normal((t.size, 1))
    se = batch_standard_error(t, x)[0]
    # median of each day: sd 1.2533 / sqrt(144); mean of 40 days
    expected = 1.2533 / np.sqrt(144 * 40)
    assert 0.7 * expected < se < 1.45 * expected


def test_batch_standard_error_needs_three_days():
    t = np.arange(2 * 144) * (DAY_NS // 144)
    assert np.isnan(batch_standard_error(t, np.ones((t.size, 2)))).all()
