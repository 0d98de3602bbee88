"""The OU + white alignment's covariance from the residual's own spectrum
(:mod:`magcal.alignment.sandwich`, issue 21): right where the noise model is right,
and no longer 1.2x too wide on power-law noise.

Truth: :mod:`magcal.alignment.families` draws with a known rotation and the exact
Cramer-Rao bound of the true noise covariance.
"""

from __future__ import annotations

import numpy as np
import pytest

from magcal.alignment.families import draw
from magcal.alignment.gls import fit_alignment
from magcal.alignment.sandwich import spectral_sandwich


def _draws(family, n):
    out = []
    for s in range(n):
        dr = draw(family, np.random.default_rng(5000 + s))
        res = fit_alignment(dr["times_s"], dr["data"], dr["ref"], noise_model="ou+white")
        ci = np.asarray(res.ci95_deg)
        truth = dr["truth_deg"]
        out.append((res.std_deg / dr["crb_std_deg"],
                    (ci[:, 0] <= truth) & (truth <= ci[:, 1])))
    ratio = np.array([o[0] for o in out])
    inside = np.array([o[1] for o in out])
    return ratio, inside


@pytest.mark.slow
def test_power_law_noise_std_near_the_bound_and_intervals_hold():
    """1/f noise (2 min to 20 days), 20 draws: the model-based std was 1.19-1.25x the
    bound (median); the sandwich states 1.04-1.07x (50 draws). 60 intervals at 95 %:
    52 or more hold the truth unless the coverage is below nominal (P < 0.3 %)."""
    ratio, inside = _draws("power-law@1", 20)
    assert np.all(np.median(ratio, axis=0) <= 1.15)
    assert inside.sum() >= 52


@pytest.mark.slow
def test_right_noise_model_keeps_the_std_at_the_bound():
    """OU noise, the model's own family: the sandwich changes nothing beyond its noise
    (median 0.97-0.98x the bound over 50 draws) and the intervals hold."""
    ratio, inside = _draws("ou", 20)
    med = np.median(ratio, axis=0)
    assert np.all((med > 0.85) & (med < 1.15))
    assert inside.sum() >= 52


def test_short_or_singular_input_falls_back():
    x = np.ones((10, 2))
    assert spectral_sandwich([np.zeros(10)], [x], np.eye(2)) is None     # too short
    assert spectral_sandwich([np.zeros(100)], [np.ones((100, 2))],
                             np.full((2, 2), np.nan)) is None            # no covariance


def test_a_red_residual_widens_the_covariance_of_a_slow_regressor():
    """A residual twice as strong at low frequencies as the model says: a regressor
    living at low frequencies gets about twice the variance, a fast one about none."""
    rng = np.random.default_rng(3)
    n = 8000
    t = np.arange(n)
    slow = np.cos(2 * np.pi * 5 * t / n)            # 5 cycles per record
    fast = np.cos(2 * np.pi * 1500 * t / n)
    x = np.stack([slow, fast], axis=1)
    spec = np.fft.rfft(rng.normal(size=n))
    freq = np.fft.rfftfreq(n)
    spec *= np.where(freq < 0.02, np.sqrt(2.0), 1.0)   # low-frequency power x2
    y = np.fft.irfft(spec, n)
    a_inv = np.linalg.inv(x.T @ x)
    cov, dof = spectral_sandwich([y], [x], a_inv)
    ratio = np.diag(cov) / np.diag(a_inv)
    assert abs(ratio[0] - 2.0) < 3 * 2.0 * np.sqrt(2 / dof[0])
    assert abs(ratio[1] - 1.0) < 3 * np.sqrt(2 / dof[1])
