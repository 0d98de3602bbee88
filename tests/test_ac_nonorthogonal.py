"""Non-orthogonal disturbers far apart: plain PiCoG leaves a remnant, the regression
gradiometer removes it (the case the paper leaves for future examination, §5)."""

import numpy as np
from numpy.testing import assert_allclose

from magcal.ac.chain import Order, Plan, Stage, apply_weights, run_chain
from magcal.ac.metrics import disturbance_power_ratio


def _unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def _case(rng, n=20000):
    """Four disturbers with the same timescale, polarisations 30-50 deg apart, each with
    its own scaling factor between sensors (sources far apart), three sensors."""
    t = np.arange(n, dtype=float)
    amb = np.c_[0.5 * np.sin(t / 3000), 0.4 * np.cos(t / 2000), 0.3 * np.sin(t / 1000)]
    s = rng.normal(size=(4, n, 1))
    u = [_unit([1, 0, 0]), _unit([np.cos(0.7), np.sin(0.7), 0]),
         _unit([0.6, 0.3, 0.75]), _unit([0.2, 0.9, 0.4])]
    gains = {"o": (1.0, 1.0, 0.6, 0.8), "i": (3.0, 1.5, 2.5, 1.1), "b": (1.5, 6.0, 0.9, 4.0)}
    data = {k: amb + sum(g[q] * s[q] * u[q] for q in range(4)) + 0.01 * rng.normal(size=(n, 3))
            for k, g in gains.items()}
    return t, data, amb


def test_regression_removes_what_picog_leaves(rng):
    t, data, amb = _case(rng)
    picog = run_chain(data, t, Plan("o", (
        Stage("pair", ("o", "i"), orders=(Order(), Order(), Order())),)))
    reg2 = run_chain(data, t, Plan("o", (Stage("regression", ("o",), references=("i",)),)))
    reg3 = run_chain(data, t, Plan("o", (Stage("regression", ("o",), references=("i", "b")),)))
    r_picog = disturbance_power_ratio(data["o"] - amb, picog.corrected - amb)
    r_reg2 = disturbance_power_ratio(data["o"] - amb, reg2.corrected - amb)
    r_reg3 = disturbance_power_ratio(data["o"] - amb, reg3.corrected - amb)
    # plain PiCoG: a large remnant (measured about 2-4x reduction only)
    assert r_picog < 10, r_picog
    # two sensors give 3 difference channels: 4 disturbers cannot all be separated
    assert r_reg2 < 30, r_reg2
    # three sensors: 6 channels for 4 disturbers -> removed down to the sensor noise
    assert r_reg3 > 1000, r_reg3
    assert reg3.identity_error < 1e-12
    assert np.max(np.abs(apply_weights(data, reg3.M) - reg3.corrected)) < 1e-9


def test_two_sensor_three_disturbers_exact(rng):
    # up to three non-orthogonal disturbers with independent difference directions are
    # solvable with two sensors: the residual reaches the noise floor
    n = 10000
    s = rng.normal(size=(3, n, 1))
    u = [_unit([1, 0, 0]), _unit([1, 1, 0]), _unit([1, 0.3, 1])]   # 45 deg and less apart
    b_o = sum(g * s[q] * u[q] for q, g in enumerate((1.0, 0.8, 0.5)))
    b_i = sum(g * s[q] * u[q] for q, g in enumerate((4.0, 1.3, 2.0)))
    res = run_chain({"o": b_o, "i": b_i}, np.arange(n, dtype=float),
                    Plan("o", (Stage("regression", ("o",), references=("i",)),)))
    assert_allclose(res.corrected, 0.0, atol=1e-9)
