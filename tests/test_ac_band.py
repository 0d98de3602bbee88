"""Band-limited PiCoG orders (band_hz): a weak spectral line under a strong broadband
disturber with a different sensor ratio."""

import numpy as np
import pytest
from numpy.testing import assert_allclose

from magcal.ac.chain import Order, Plan, Stage, apply_weights, run_chain
from magcal.ac.filters import bandpass
from magcal.ac.plan import plan_from_dict
from magcal.errors import InputError


def _pair(rng, n=20000):
    t = np.arange(n, dtype=float)
    tone = 0.05 * np.sin(2 * np.pi * t / 6.0)
    noise = np.convolve(rng.normal(size=n), np.ones(5) / 5, mode="same")  # broadband
    u_t, u_n = np.array([0.0, 0.6, 0.8]), np.array([0.8, 0.0, 0.6])
    amb = np.array([100.0, -20.0, 40.0])
    # tone: fgmi/fgmo = 2.8, noise: 2.5 (the GK-2A-like ratios)
    o = amb + tone[:, None] * u_t + noise[:, None] * u_n + 0.001 * rng.normal(size=(n, 3))
    i = amb + 2.8 * tone[:, None] * u_t + 2.5 * noise[:, None] * u_n \
        + 0.001 * rng.normal(size=(n, 3))
    return t, {"o": o, "i": i}, tone[:, None] * u_t


def test_band_order_removes_weak_line(rng):
    t, data, tone_o = _pair(rng)
    plan = Plan("o", (Stage("reference", ("o",), reference="i",
                            orders=(Order(band_hz=(0.165, 0.168), direction="coherent"),)),))
    r = run_chain(data, t, plan)
    assert r.identity_error < 1e-12
    # the line's fgmo part: 0.05 nT amplitude -> remnant of the tone at o
    rem = apply_weights({"o": tone_o, "i": 2.8 * tone_o}, r.M)
    ratio = np.sum(tone_o.var(0)) / np.sum(rem.var(0))
    assert ratio > 1e3, ratio
    # o + A (o - i) with o - i = (1 - a) s u: alpha = -1 / (a - 1), a = 2.8 (Eq. 19 form)
    assert_allclose(r.steps[0].alpha, -1 / 1.8, rtol=1e-2)
    assert r.steps[0].to_dict()["band_hz"] == [0.165, 0.168]
    # without the band the broadband disturber sets the fit (ratio 2.5, not 2.8)
    r2 = run_chain(data, t, Plan("o", (Stage("reference", ("o",), reference="i",
                                             orders=(Order(direction="coherent"),)),)))
    assert_allclose(r2.steps[0].alpha, -1 / 1.5, rtol=1e-2)


def test_bandpass_keeps_nan_rows_and_rejects_bad_bands():
    x = np.sin(2 * np.pi * np.arange(600.0) / 6)
    x[10] = np.nan
    y = bandpass(x, (0.1, 0.2), 1.0)
    assert np.isnan(y[10]) and np.isfinite(y[11])
    with pytest.raises(InputError):
        bandpass(x, (0.2, 0.1), 1.0)
    with pytest.raises(InputError):
        bandpass(x, (0.9, 1.0), 1.0)   # above Nyquist: no bin


def test_plan_band_hz_parsed_and_validated():
    plan, _ = plan_from_dict({"target": "fgmo", "stage": [
        {"pair": ["fgmo", "fgmi"], "orders": [{"window_s": 100}, {"band_hz": [0.15, 0.18]}]}]})
    assert plan.stages[0].orders[1].band_hz == (0.15, 0.18)
    assert plan.stages[0].orders[0].band_hz is None
    with pytest.raises(InputError, match="band_hz"):
        plan_from_dict({"target": "fgmo", "stage": [
            {"pair": ["fgmo", "fgmi"], "orders": [{"band_hz": [0.18, 0.15]}]}]})
