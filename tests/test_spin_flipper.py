"""Flipper: O3 from the spin average of the flipped sensor, and completion of C, O."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose

from magcal.errors import InputError
from magcal.simulate.spinning import SpinningConfig, simulate_spinning
from magcal.spin.flipper import complete_with_flipper, flipper_offset
from magcal.spin.ripple import fit_spin_ripple


def _cols(res):
    d = res.data
    return (res.truth.t_s, d[["b1", "b2", "b3"]].to_numpy(), d["phase"].to_numpy(),
            d["flip"].to_numpy())


@pytest.fixture(scope="module")
def flipped():
    # sensor 3 tilted by 0.23 deg towards sensor 1: 0.14 nT of the 35 nT Bz leaks in
    c = np.array([[1.0012, 0.0, 0.0021], [0.0017, 0.9981, -0.0013], [0.004, -0.0024, 0.9993]])
    cfg = SpinningConfig.galileo_like(duration_s=4 * 3600.0, coupling=tuple(map(tuple, c)),
                                      flip_intervals_s=((10800.0, 14400.0),))
    return simulate_spinning(cfg, rng=np.random.default_rng(77))


def test_o3_with_tilt_correction(flipped):
    t, b, p, f = _cols(flipped)
    tr = flipped.truth
    res = flipper_offset(t, b, p, f, coupling=tr.coupling, offsets=tr.offsets_nT)
    assert abs(res.O3 - 0.45) < 0.05
    assert abs(res.O3 - 0.45) < 4 * res.O3_std
    assert 0 < res.O3_std < 0.05
    assert_allclose(res.tilt_correction_nT, 0.004 * 35.0, atol=0.03)   # ~ c31 <Bz>
    plain = flipper_offset(t, b, p, f)
    assert plain.tilt_correction_nT == 0.0
    assert abs(plain.O3 - 0.45) > 0.08          # the leak biases the plain average
    assert res.n_spins_flipped == 180 and res.n_spins_unflipped >= 530


def test_complete_twelve_parameters(flipped):
    t, b, p, f = _cols(flipped)
    tr = flipped.truth
    on0 = f == 0
    c0 = np.eye(3)
    c0[0] = tr.coupling[0]
    c0[2, 2] = tr.coupling[2, 2]
    cal = fit_spin_ripple(t[on0], b[on0], p[on0], coupling0=c0, offsets0=[0, 0, 0])  # O3 prior 0
    res = flipper_offset(t, b, p, f, coupling=cal.coupling, offsets=cal.offsets_nT)
    full = complete_with_flipper(cal, res)
    assert "O3" in full.determined and "O3" not in full.fixed
    assert len(full.determined) == 9
    assert_allclose(full.offsets_nT, tr.offsets_nT, atol=0.05)
    # spin-plane calibration unchanged by the completion
    assert_allclose(full.calibrate(b[:100])[:, :2], cal.calibrate(b[:100])[:, :2], atol=1e-9)
    # absolute BZ now right (was off by c33 * 0.45 nT)
    bz_err = full.calibrate(b[on0])[:, 2] - tr.b_sc[on0][:, 2]
    assert abs(bz_err.mean()) < 0.05


def test_flipper_bad_input(flipped):
    t, b, p, f = _cols(flipped)
    with pytest.raises(InputError, match="no flipper intervals"):
        flipper_offset(t, b, p, np.zeros_like(f))
    with pytest.raises(InputError, match="flip = 0"):
        flipper_offset(t, b, p, np.ones_like(f))
    with pytest.raises(InputError, match="whole spins with flip = 1"):
        g = f.copy()
        g[:] = 0
        g[1000:1050] = 1
        flipper_offset(t, b, p, g)
    with pytest.raises(InputError, match="0 or 1"):
        flipper_offset(t, b, p, f * 2)
