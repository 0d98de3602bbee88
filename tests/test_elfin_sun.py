"""Sun-locked or drifting? The fast part of the sunlit ELFIN passes.

Injected truth for magcal.missions.elfin.diagnostics.sun and the fast-drift correction
(magcal.missions.elfin.harmonic.drifting_harmonic_correction), and the real sunlit
zone 7 of ELFIN-A 2022-01-12 (ELFIN SOC, PI V. Angelopoulos, UCLA; Open Data for
Scientific Use), skipped when ../shared/real-data is absent.
"""

from __future__ import annotations

import numpy as np
import pytest

from magcal.missions.elfin.harmonic import drifting_harmonic_correction
from magcal.missions.elfin.scalar import fast_part, rms
from magcal.missions.elfin.diagnostics.sun import sun_locked_zone
from magcal.spin.despin import spin

SPIN_S = 2.85


def _pass():
    """Despun field turning 40 deg over 360 s; the Sun fixed in the despun frame."""
    t = np.arange(0.0, 360.0, 0.1)
    T = 2 * t / t[-1] - 1
    ang = np.radians(-30 - 40 * (T + 1) / 2)
    ref = np.column_stack([45000 * np.cos(ang), 45000 * np.sin(ang), 2000 - 700 * T])
    phase = 2 * np.pi * t / SPIN_S
    sun = np.tile([np.cos(0.5), np.sin(0.5), 0.3], (t.size, 1))
    return t, spin(ref, phase), spin(sun, phase)


def test_a_sun_locked_field_is_told_from_the_control_and_a_drift_is_not():
    rng = np.random.default_rng(31)
    t, body, sun = _pass()
    mag = np.linalg.norm(body, axis=1)
    chi = np.arctan2(sun[:, 1], sun[:, 0])
    # a solar-array field along body x, 25 nT when the Sun faces the panel
    array_field = np.column_stack([25 * np.cos(chi) + 10 * np.cos(2 * chi), 0 * t, 0 * t])
    noise = rng.normal(scale=0.5, size=body.shape)
    locked = sun_locked_zone(t, body + array_field + noise, mag, sun)
    assert locked["fast_nT"] > 10.0
    # (fitted to the noise, 0.5 nT; the control, drifting as fast the other way, 2.8)
    assert locked["sun_nT"] < 0.6 and locked["control_nT"] > 4 * locked["sun_nT"]
    # a field-locked 2x term whose sign changes every 2 min: no Sun needed; the Sun and
    # the control do equally (within 10 %), the 60 s spline drift does best
    psi = np.angle(body[:, 0] + 1j * body[:, 1])
    g = 5e-4 * np.cos(2 * np.pi * t / 240)
    drifting = body * np.c_[1 + g, 1 - g, np.ones_like(t)] + noise
    out = sun_locked_zone(t, drifting, mag, sun)
    assert out["fast_nT"] > 10.0 and out["drift_nT"] < 1.0
    assert abs(out["sun_nT"] / out["control_nT"] - 1.0) < 0.1
    assert out["chi_minus_psi_range_deg"] == pytest.approx(40.0, abs=0.5)
    assert np.isfinite(psi).all()


def test_fast_drift_correction_removes_a_minute_scale_gain_ratio_and_keeps_the_slow_part():
    rng = np.random.default_rng(32)
    t, body, _ = _pass()
    T = 2 * t / t[-1] - 1
    g = 5e-4 * np.cos(2 * np.pi * t / 150)                 # gain ratio, 150 s period
    slow = 1 + 1e-3 * T ** 2                                # isotropic: not a harmonic
    bad = body * np.c_[(1 + g) * slow, (1 - g) * slow, np.ones_like(t)]
    bad += rng.normal(scale=0.3, size=bad.shape)
    fixed, info = drifting_harmonic_correction(t, bad, np.linalg.norm(body, axis=1))
    assert info["scalar_fast_before_nT"] > 10.0 and info["scalar_fast_after_nT"] < 0.5
    # the gain-ratio wobble is gone from the vectors; the slow isotropic gain is kept
    wanted = body * np.c_[slow, slow, np.ones_like(t)]
    assert rms(np.linalg.norm(fixed - wanted, axis=1)) < 1.0
    r = np.linalg.norm(fixed, axis=1) - np.linalg.norm(body, axis=1)
    assert rms(r - fast_part(t, r)) > 10.0


@pytest.mark.realdata
def test_real_sunlit_zone7_is_a_drift_not_a_sun_locked_term():
    from conftest import real_data_path
    from magcal.missions.elfin.linear import calibrate_elfin
    from magcal.missions.elfin.harmonic import correct_elfin_calibration, correct_fast_drift
    from magcal.missions.elfin.drift import correct_gain_drift
    from magcal.missions.elfin.files import read_elfin_fgs, read_elfin_state
    from magcal.missions.elfin.joint import score_field
    from magcal.missions.elfin.diagnostics.sun import sun_locked_test
    from magcal.missions.elfin.vector import correct_vector

    folder = real_data_path("elfin")
    fgs = read_elfin_fgs(folder / "ela_l1_fgs_20220112_v01.cdf")
    state = read_elfin_state(folder / "ela_l1_state_defn_20220112_v01.cdf")
    cal = calibrate_elfin(fgs, state, zones=[6, 7])          # eclipse and sunlit dawn
    cal, _ = correct_gain_drift(correct_elfin_calibration(cal)[0])
    cal, _ = correct_vector(cal, knot_s=30.0)
    tab = sun_locked_test(cal, state).set_index("zone")
    assert tab.loc[7, "sun_fraction"] == 1.0 and tab.loc[6, "sun_fraction"] == 0.0
    # measured zone 7: fast 16.8 nT; Sun-locked 10.62, control 10.67, field-locked 16.4,
    # 60 s field-locked drift 9.8: the Sun is not singled out (an injected Sun-locked
    # field would leave the control 4x the Sun's, test above)
    z7 = tab.loc[7]
    assert z7["fast_nT"] > 15.0
    assert abs(z7["sun_nT"] / z7["control_nT"] - 1.0) < 0.05
    assert z7["drift_nT"] < 0.65 * z7["fast_nT"] and z7["field_nT"] > 0.9 * z7["fast_nT"]
    # the fast-drift correction takes it under issue 15's 10 nT (measured 8.8)
    fixed, _ = correct_fast_drift(cal)
    score = score_field(fixed.field).set_index("zone")
    assert score.loc[7, "scalar_fast_nT"] < 10.0
    assert score.loc[6, "scalar_fast_nT"] < 7.0             # measured 5.1 (6.0 before)
