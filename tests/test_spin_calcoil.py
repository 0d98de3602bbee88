"""Calibration coil: turn about the spin axis and spin-plane gain from a known square wave."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose

from magcal.errors import InputError
from magcal.simulate.spinning import SpinningConfig, simulate_spinning
from magcal.spin.calcoil import apply_calcoil, calcoil_rotation, square_wave
from magcal.spin.ripple import fit_spin_ripple

ANGLE_TOL = np.radians(0.01)


@pytest.fixture(scope="module")
def sim():
    cfg = SpinningConfig.galileo_like(duration_s=3 * 3600.0, calcoil_amplitude_nT=4.5,
                                      calcoil_frequency_hz=0.5,
                                      calcoil_direction_sc=(0.0, 1.0, 0.0),
                                      calcoil_intervals_s=((9000.0, 10800.0),))
    return simulate_spinning(cfg, rng=np.random.default_rng(31))


def test_ripple_plus_calcoil_gives_spin_plane(sim):
    tr, d = sim.truth, sim.data
    b, p, t = d[["b1", "b2", "b3"]].to_numpy(), d["phase"].to_numpy(), tr.t_s
    quiet = t < 9000.0                        # ripple fit without the coil
    c0 = np.eye(3)
    c0[2, 2] = tr.coupling[2, 2]
    cal = fit_spin_ripple(t[quiet], b[quiet], p[quiet], coupling0=c0,
                          offsets0=[0, 0, tr.offsets_nT[2]])
    # the ripple fit alone cannot see the 0.5 deg turn of the truth
    assert abs(cal.coupling[0, 1] - tr.coupling[0, 1]) > 0.008
    coil = calcoil_rotation(t, cal.calibrate(b), p, frequency_hz=0.5, t_on_s=0.0,
                            direction_sc=(0, 1, 0), amplitude_nT=4.5,
                            intervals_s=((9000.0, 10800.0),))
    # calibrated frame = truth turned by -0.5 deg (c12 = 0 prior), gain 1/1.0012
    assert_allclose(coil.rotation_deg, -0.5, atol=0.01)
    assert abs(coil.rotation_deg + 0.5) < 4 * coil.rotation_std_deg + 1e-4
    assert_allclose(coil.gain_ratio, 1 / 1.0012, rtol=2e-4)
    done = apply_calcoil(cal, coil)
    assert_allclose(done.coupling[:2], tr.coupling[:2], atol=ANGLE_TOL)
    assert {"c11", "c12"} <= set(done.determined)
    assert done.fixed == ("c33", "O3")


def test_square_wave_and_bad_input(sim):
    assert square_wave([0.0, 0.5, 1.0, 1.5], 0.5, 0.0).tolist() == [1.0, 1.0, 0.0, 0.0]
    tr = sim.truth
    with pytest.raises(InputError, match="no calibration-coil signal"):
        calcoil_rotation(tr.t_s, tr.b_sc, tr.phase_rad, frequency_hz=0.5, t_on_s=0.0,
                         direction_sc=(0, 1, 0), amplitude_nT=4.5,
                         intervals_s=((20000.0, 20010.0),))
    with pytest.raises(InputError, match="spin-plane component"):
        calcoil_rotation(tr.t_s, tr.b_sc, tr.phase_rad, frequency_hz=0.5, t_on_s=0.0,
                         direction_sc=(0, 0, 1), amplitude_nT=4.5)
