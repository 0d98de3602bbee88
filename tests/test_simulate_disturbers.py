"""Disturber physics and time profiles of the geostationary simulator, against closed forms."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose

from magcal.errors import InputError
from magcal.simulate.disturbers import (Disturber, disturber_fields, disturber_patterns,
                                        moment_for_amplitude)
from magcal.simulate.multipoles import dipole_field, quadrupole_field
from magcal.simulate.profiles import (ArrayProfile, BroadbandNoiseProfile, DailyStepProfile,
                                      EdgePulseProfile, ProfileContext, RotatingProfile,
                                      SpikeTrainProfile, SquareWaveProfile, ToggleStepProfile,
                                      ToneProfile)

MU0_4PI_NT = 4e-7 * np.pi / (4 * np.pi) * 1e9  # mu0/(4 pi) in nT m / A = 100


def _ctx(cadence_s=1.0, start="2019-03-04T00:00:00", lon=128.2):
    return ProfileContext(pd.Timestamp(start, tz="UTC"), lon, cadence_s)


# ------------------------------------------------------------------ multipoles

def test_dipole_on_axis_is_twice_equatorial_and_falls_as_r_cubed():
    m = np.array([0.0, 0.0, 2.5])  # A m^2
    r = 0.7
    b = dipole_field(m, [0, 0, 0], [[0, 0, r], [r, 0, 0], [0, 0, 2 * r], [0, -2 * r, 0]])
    assert_allclose(b[0], [0, 0, 2 * MU0_4PI_NT * 2.5 / r**3], rtol=1e-14)
    assert_allclose(b[1], [0, 0, -MU0_4PI_NT * 2.5 / r**3], rtol=1e-14)
    assert_allclose(b[0, 2] / -b[1, 2], 2.0, rtol=1e-14)
    assert_allclose(b[0, 2] / b[2, 2], 8.0, rtol=1e-14)
    assert_allclose(b[1, 2] / b[3, 2], 8.0, rtol=1e-14)


def test_dipole_matches_textbook_formula_for_arbitrary_geometry(rng):
    for _ in range(20):
        m = rng.normal(size=3)
        src = rng.normal(size=3)
        pt = src + rng.normal(size=3) * 2
        r = pt - src
        rn = np.linalg.norm(r)
        expected = MU0_4PI_NT * (3 * (m @ r) * r / rn**5 - m / rn**3)
        assert_allclose(dipole_field(m, src, pt)[0], expected, rtol=1e-12, atol=1e-12)


def test_dipole_refuses_the_source_position():
    with pytest.raises(ValueError):
        dipole_field([0, 0, 1.0], [1, 2, 3], [[1, 2, 3]])


def test_quadrupole_on_axis_matches_point_quadrupole_limit():
    # +m at +s/2, -m at -s/2, m and s along z: b_z = 6 (mu0/4pi) m s / r^4 for s << r
    m, s = 1.5, 0.004
    for r in (0.5, 1.0, 2.0):
        b = quadrupole_field([0, 0, m], [0, 0, 0], [0, 0, s], [0, 0, r])[0]
        assert_allclose(b, [0, 0, 6 * MU0_4PI_NT * m * s / r**4], rtol=2 * (s / r) ** 2 * 10)


def test_quadrupole_falls_as_r_to_the_fourth_in_any_direction(rng):
    d = rng.normal(size=3)
    d /= np.linalg.norm(d)
    b1 = quadrupole_field([0.3, -0.2, 0.9], [0, 0, 0], [0.01, 0.0, 0.0], d * 1.0)
    b2 = quadrupole_field([0.3, -0.2, 0.9], [0, 0, 0], [0.01, 0.0, 0.0], d * 3.0)
    assert_allclose(b1 / b2, 81.0, rtol=1e-3)


def test_moment_for_amplitude_gives_the_requested_field():
    m = moment_for_amplitude("dipole", [0.1, 0.2, 0.3], [1, 1, 0], [1.0, -0.5, 0.2], 34.0)
    assert_allclose(np.linalg.norm(dipole_field(m, [0.1, 0.2, 0.3], [1.0, -0.5, 0.2])), 34.0,
                    rtol=1e-12)
    q = moment_for_amplitude("quadrupole", [0, 0, 0], [0, 0, 1], [0.0, 0.5, 1.0], 0.05,
                             separation_m=[0.1, 0, 0])
    assert_allclose(np.linalg.norm(quadrupole_field(q, [0, 0, 0], [0.1, 0, 0],
                                                    [0.0, 0.5, 1.0])), 0.05, rtol=1e-12)


# ------------------------------------------------------------------ disturbers

def test_linear_disturber_same_direction_at_two_sensors_ratio_from_geometry(rng):
    # collinear source and sensors, moment along the line: ratio (r2/r1)^3 exactly
    d = Disturber("coil", (0.0, 0.0, 0.0), (1.0, 0.0, 0.0), SpikeTrainProfile())
    sensors = np.array([[1.2, 0.0, 0.0], [2.0, 0.0, 0.0]])
    coeffs = d.profile.evaluate(np.arange(3600.0), rng=rng, context=_ctx()).values
    b = disturber_fields(disturber_patterns(d, sensors), coeffs)
    assert_allclose(b[0], (2.0 / 1.2) ** 3 * b[1], rtol=1e-12, atol=1e-15)
    # general geometry: the field at each sensor keeps one direction (up to sign)
    d2 = Disturber("coil2", (0.1, -0.3, 0.2), (0.3, 0.8, -0.5), ToneProfile(6.0))
    pts = np.array([[1.5, 0.4, -0.7], [2.3, 0.4, -0.7]])
    coeffs = d2.profile.evaluate(np.arange(600.0), rng=rng, context=_ctx()).values
    b = disturber_fields(disturber_patterns(d2, pts), coeffs)
    pat = disturber_patterns(d2, pts)[0]
    for j in range(2):
        u = pat[j] / np.linalg.norm(pat[j])
        assert_allclose(np.cross(b[j], u), 0.0, atol=1e-13)
        assert_allclose(np.linalg.norm(b[j], axis=1), np.abs(coeffs[:, 0]) * np.linalg.norm(pat[j]),
                        rtol=1e-12, atol=1e-15)
    assert_allclose(np.std(b[0], axis=0).sum() / np.std(b[1], axis=0).sum(),
                    np.abs(pat[0]).sum() / np.abs(pat[1]).sum(), rtol=1e-9)


def _eig_ratio(b):
    ev = np.linalg.eigvalsh(np.cov(b.T))
    return ev[1] / ev[2], ev[0] / ev[2]


def test_reaction_wheel_is_not_linearly_polarised(rng):
    t = np.arange(3600.0)
    wheel = Disturber("wheel", (-0.9, 0.0, 1.0), (0.05, 0.0, 0.0), RotatingProfile(),
                      kind="rotating", rotation_axis=(0.0, 1.0, 1.0))
    line = Disturber("line", (-0.9, 0.0, 1.0), (0.05, 0.0, 0.0), ToneProfile(9.0))
    pts = np.array([[2.55, -0.8, -1.6]])
    bw = disturber_fields(disturber_patterns(wheel, pts),
                          wheel.profile.evaluate(t, rng=rng, context=_ctx()).values)[0]
    bl = disturber_fields(disturber_patterns(line, pts),
                          line.profile.evaluate(t, rng=rng, context=_ctx()).values)[0]
    mid, low = _eig_ratio(bw)
    assert mid > 0.05          # two significant eigenvalues: elliptical polarisation
    assert low < 1e-12         # still confined to a plane (a rotating dipole)
    assert _eig_ratio(bl)[0] < 1e-12  # the linear one has a single eigenvalue
    # constant moment magnitude: the rotating basis moments are orthogonal, equal length
    u, v = wheel.basis_moments()
    assert_allclose([u @ v, np.linalg.norm(u) - np.linalg.norm(v)], [0.0, 0.0], atol=1e-15)


def test_disturber_validation():
    with pytest.raises(InputError, match="kind"):
        Disturber("x", (0, 0, 0), (1, 0, 0), ToneProfile(), kind="octupole")
    with pytest.raises(InputError, match="component"):
        Disturber("x", (0, 0, 0), (1, 0, 0), RotatingProfile())
    with pytest.raises(InputError, match="separation_m"):
        Disturber("x", (0, 0, 0), (1, 0, 0), ToneProfile(), kind="quadrupole")
    with pytest.raises(InputError, match="along rotation_axis"):
        Disturber("x", (0, 0, 0), (0, 0, 1), RotatingProfile(), kind="rotating",
                  rotation_axis=(0, 0, 2))


# ------------------------------------------------------------------ profiles

def test_daily_step_timing_levels_and_overshoot():
    ctx = _ctx()
    t = np.arange(0.0, 86400.0)
    prof = DailyStepProfile()
    s = prof.evaluate(t, rng=np.random.default_rng(0), context=ctx)
    onset = (23.8 - 128.2 / 15.0) * 3600.0  # 15:15:12 UT
    assert_allclose(s.events_s, [onset, onset + 2700.0, onset + 2700.0 + 14400.0], atol=1e-6)
    v = s.values[:, 0]
    assert_allclose(v[int(onset) - 60], 0.0)
    assert_allclose(v[int(onset) + 600], 1.0)
    assert_allclose(v[int(onset) + 2700 + 600], -0.15)
    assert_allclose(v[int(onset) + 2700 + 14400 + 60], 0.0)
    assert_allclose(v[int(onset)], 0.5, atol=1 / 30.0)  # mid-ramp (30 s ramp)
    edge = EdgePulseProfile(step=prof).evaluate(t, rng=None, context=ctx)
    assert_allclose(edge.values[int(round(onset)), 0], 1.0, atol=1 / 90.0)
    assert_allclose(edge.values[int(onset) + 200, 0], 0.0)


def test_spike_train_period_and_shape(rng):
    t = np.arange(0.0, 7200.0)
    s = SpikeTrainProfile(period_s=600.0, width_s=6.0, phase_s=100.0, jitter_s=0.0,
                          height_spread=0.0).evaluate(t, rng=rng, context=_ctx())
    assert_allclose(s.events_s, 100.0 + 600.0 * np.arange(12), atol=1e-9)
    v = s.values[:, 0]
    assert_allclose(v[[100, 700, 6700]], 1.0, atol=1e-12)
    assert_allclose(v[103], 0.5, rtol=1e-9)  # half maximum 3 s from the peak
    assert v[400] < 1e-100


def test_toggle_steps_interval_range(rng):
    t = np.arange(0.0, 86400.0)
    s = ToggleStepProfile().evaluate(t, rng=rng, context=_ctx())
    gaps = np.diff(s.events_s)
    assert len(gaps) >= 14
    assert gaps.min() >= 4800.0 and gaps.max() <= 5400.0
    v = s.values[:, 0]
    assert set(np.round(v[(v < 0.001) | (v > 0.999)])) <= {0.0, 1.0}
    # level alternates across the events
    probe = (s.events_s[:-1] + s.events_s[1:]) / 2
    levels = v[probe.astype(int)]
    assert_allclose(np.abs(np.diff(levels)), 1.0)


def test_broadband_noise_band_level_and_gaps(rng):
    t = np.arange(0.0, 86400.0)
    prof = BroadbandNoiseProfile(level=7.0, n_off=2, off_s=600.0)
    s = prof.evaluate(t, rng=rng, context=_ctx())
    v = s.values[:, 0]
    off = v == 0.0
    assert 1150 <= off.sum() <= 1200  # two 600 s off intervals (may overlap a little)
    on = v[~off]
    assert_allclose(on.mean(), 7.0, atol=0.02)
    assert_allclose(on.std(), 1.0, rtol=0.03)
    # no power at periods longer than 60 s in the noise itself
    noise = np.where(off, 0.0, v - 7.0)
    spec = np.abs(np.fft.rfft(noise)) ** 2
    f = np.fft.rfftfreq(len(noise), 1.0)
    low = spec[(f > 0) & (f < 1 / 120.0)].mean()
    high = spec[(f > 1 / 60.0)].mean()
    assert low < 0.05 * high


def test_tone_and_square_wave(rng):
    t = np.arange(0.0, 600.0, 0.5)
    v = ToneProfile(6.0, phase_rad=0.0).evaluate(t, rng=rng, context=_ctx(0.5)).values[:, 0]
    assert_allclose(v, np.sin(2 * np.pi * t / 6.0), atol=1e-12)
    sq = SquareWaveProfile(period_s=100.0, duty=0.3, ramp_s=2.0, phase_s=10.0)
    v = sq.evaluate(np.arange(0.0, 1000.0), rng=rng, context=_ctx()).values[:, 0]
    assert_allclose(v[[20, 120, 920]], 1.0)
    assert_allclose(v[[50, 150, 990]], 0.0)
    assert_allclose(v.mean(), 0.3, atol=0.01)


def test_rotating_profile_frequency(rng):
    t = np.arange(0.0, 4096.0)
    prof = RotatingProfile(frequency_hz=0.11, drift_hz=0.0)
    v = prof.evaluate(t, rng=rng, context=_ctx()).values
    assert_allclose(np.hypot(v[:, 0], v[:, 1]), 1.0, atol=1e-12)
    z = v[:, 0] + 1j * v[:, 1]
    f = np.fft.fftfreq(len(t), 1.0)
    assert_allclose(f[np.argmax(np.abs(np.fft.fft(z)))], 0.11, atol=1 / 4096)


def test_array_profile_length_checked():
    with pytest.raises(InputError, match="rows"):
        ArrayProfile(np.zeros(5)).evaluate(np.arange(4.0), rng=None, context=_ctx())
