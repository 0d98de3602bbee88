"""Slow part of the ELFIN scalar residual: spin-plane gain drift and reference screening.

Injected truth on a simulated spinner (magcal.missions.elfin.drift), a closed-form check
of the reference screening (magcal.missions.elfin.diagnostics.reference), and the real ELFIN-A
passes
of 2022-01-12 (ELFIN SOC, PI V. Angelopoulos, UCLA; Open Data for Scientific Use),
skipped when ../shared/real-data is absent.
"""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose

from magcal.missions.elfin.drift import drift_shape_agreement, fit_gain_drift
from magcal.missions.elfin.diagnostics.reference import screen_slow_part
from magcal.missions.elfin.scalar import fast_part, rms
from magcal.spin.despin import despin, spin

SPIN_S = 2.85


def _pass():
    """A 360 s pass at 10 Hz: the field turns 40 deg in inertial space and |B| changes."""
    t = np.arange(0.0, 360.0, 0.1)
    T = 2 * t / t[-1] - 1
    ang = np.radians(-30 - 40 * (T + 1) / 2)
    perp = 45000 + 2500 * T
    inertial = np.column_stack([perp * np.cos(ang), perp * np.sin(ang), 2000 - 700 * T])
    return t, T, spin(inertial, 2 * np.pi * t / SPIN_S)


def test_injected_isotropic_gain_drift_is_recovered():
    rng = np.random.default_rng(5)
    t, T, truth = _pass()
    g = 4e-4 + 1.5e-3 * T - 2.5e-3 * T ** 2 + 6e-4 * T ** 3       # 0.45 % p-p, ELFIN-like
    measured = truth * np.c_[1 + g, 1 + g, np.ones_like(t)]
    measured += rng.normal(scale=0.3, size=measured.shape)
    fixed, info = fit_gain_drift(t, measured, np.linalg.norm(truth, axis=1))
    # the drift is recovered to 1e-5 (0.45 nT at 45000 nT) ...
    np.testing.assert_allclose(info["gain_coefficients"], [4e-4, 1.5e-3, -2.5e-3, 6e-4],
                               atol=1e-5)
    np.testing.assert_allclose(info["gain_drift_pp"], np.ptp(g), rtol=0.01)
    # ... and the vectors come back to the noise
    assert info["scalar_slow_before_nT"] > 50.0
    assert info["scalar_slow_after_nT"] < 0.5
    assert rms(fixed - truth) < 0.5


def test_pulse_along_b_is_a_gain_drift_to_a_cubic_and_kept_by_the_robust_fit():
    """What |B| alone cannot tell apart, in closed form: a 100 nT pulse along B of 90 s
    FWHM in a 360 s pass projects mostly onto a cubic gain drift; a fit weighted by the
    residual the reference-free (2x-spin) shape leaves keeps most of it."""
    rng = np.random.default_rng(7)
    t, T, truth = _pass()
    mag = np.linalg.norm(truth, axis=1)
    pulse = 100.0 * np.exp(-4 * np.log(2) * (t - t.mean()) ** 2 / 90.0 ** 2)
    g = 1e-3 * (0.5 * T + T ** 3)
    measured = truth * (1 + pulse / mag)[:, None] * np.c_[1 + g, 1 + g, np.ones_like(t)]
    measured += rng.normal(scale=3.0, size=measured.shape)
    h = (measured[:, 0] ** 2 + measured[:, 1] ** 2) / np.linalg.norm(measured, axis=1)
    shape = g * h - np.mean(g * h)                 # the drift's own shape in |B| (nT)

    def kept(**kw):
        fixed, info = fit_gain_drift(t, measured, mag, **kw)
        rec = np.linalg.norm(fixed, axis=1) - mag
        return float(rec @ pulse / (pulse @ pulse)), info

    plain, _ = kept()
    robust, info = kept(robust_c=3.0, shape=shape)
    # measured: 0.27 of the pulse's amplitude kept by the plain cubic, 0.83 robust
    assert plain < 0.4
    assert robust > 0.75
    assert 0.2 < info["weighted_out_fraction"] < 0.5     # about the pulse's FWHM / pass
    # and without a pulse the robust fit still takes the whole drift
    clean = truth * np.c_[1 + g, 1 + g, np.ones_like(t)]
    fixed, info = fit_gain_drift(t, clean, mag, robust_c=3.0, shape=shape)
    assert rms(np.linalg.norm(fixed, axis=1) - mag) < 1.0


def test_single_direction_gain_drift_gives_matching_2x_and_isotropic_shapes():
    """A gain change along one spin-plane direction: 2x and isotropic halves agree."""
    rng = np.random.default_rng(6)
    t, T, truth = _pass()
    theta = 2e-3 * (T ** 2 - 1 / 3) + 1e-3 * T                      # the common driver
    n = np.array([np.cos(0.4), np.sin(0.4)])                        # drifting direction
    along = truth[:, :2] @ n
    measured = truth.copy()
    measured[:, :2] += (theta * along)[:, None] * n
    measured += rng.normal(scale=0.3, size=measured.shape)
    out = drift_shape_agreement(t, measured, np.linalg.norm(truth, axis=1))
    # |B| changes by theta (n.B)^2/|B| = theta |B_perp|^2/(2|B|) (1 + cos 2(psi - a)):
    # the isotropic and the 2x halves are equal (ratio 1) with one time shape
    assert abs(out["correlation"]) > 0.99
    assert abs(out["ratio"] - 1.0) < 0.05
    assert out["drift2_line_fraction"] > 0.99


def test_slow_reference_error_makes_no_2x_drift():
    """A smooth error of the reference magnitude is slow part only, never a 2x drift."""
    rng = np.random.default_rng(7)
    t, T, truth = _pass()
    measured = truth + rng.normal(scale=0.3, size=truth.shape)
    ref_error = 120.0 * T ** 2 - 40.0 * T                           # nT, like the slow part
    out = drift_shape_agreement(t, measured, np.linalg.norm(truth, axis=1) - ref_error)
    assert out["slow_rms_nT"] > 40.0
    assert out["drift2_rms_nT"] < 0.5


def test_screen_recovers_an_injected_reference_error_for_the_day():
    rng = np.random.default_rng(8)
    zones = []
    for k in range(5):
        t = np.arange(0.0, 360.0, 1.0)
        T = 2 * t / t[-1] - 1
        ref = 45000 + rng.normal(0, 2000) * T + 300 * T ** 2
        cand = rng.normal(0, 10) * T + rng.normal(0, 10) * T ** 2 + rng.normal(0, 5) * T ** 3
        other = rng.normal(0, 10) * T ** 2
        # slow part = 3.0 x the candidate + what the calibration absorbs (1, |B|)
        slow = 3.0 * cand + rng.normal(0, 20) + 1e-3 * (ref - ref.mean())
        zones.append({"zone": k, "t": t, "slow": slow, "ref": ref, "cand": cand,
                      "other": other})
    tab = screen_slow_part(zones, names=("cand", "other")).set_index("candidate")
    np.testing.assert_allclose(tab.loc["cand", "day_coefficient"], 3.0, rtol=1e-9)
    np.testing.assert_allclose(tab.loc["cand", "zone_coefficients"], 3.0, rtol=1e-9)
    assert tab.loc["cand", "zone_sign_changes"] == 0
    assert tab.loc["cand", "slow_left_median_nT"] < 1e-6
    assert tab.loc["other", "slow_left_median_nT"] > 1.0


@pytest.fixture(scope="module")
def real_zones():
    from tests.conftest import real_data_path

    folder = real_data_path("elfin")
    from magcal.missions.elfin.linear import calibrate_elfin
    from magcal.missions.elfin.files import read_elfin_fgs, read_elfin_state

    fgs = read_elfin_fgs(folder / "ela_l1_fgs_20220112_v01.cdf")
    state = read_elfin_state(folder / "ela_l1_state_defn_20220112_v01.cdf")
    return calibrate_elfin(fgs, state, zones=[2, 7])     # one dusk, one dawn pass


def test_a_quintic_gain_drift_needs_gain_drift_degree_5():
    """A drift with structure beyond a cubic (a few nT, as the real day's 2x-spin
    harmonic shows) is left by the default cubic and recovered by ``degree=5``, the
    value ``ElfinSettings.gain_drift_degree`` passes."""
    rng = np.random.default_rng(11)
    t, T, truth = _pass()
    coef = [4e-4, 1.5e-3, -2.5e-3, 6e-4, 3e-4, -2e-4]
    g = sum(c * T ** d for d, c in enumerate(coef))
    measured = truth * np.c_[1 + g, 1 + g, np.ones_like(t)]
    measured += rng.normal(scale=0.3, size=measured.shape)
    ref = np.linalg.norm(truth, axis=1)
    _, cubic = fit_gain_drift(t, measured, ref)
    fixed, quintic = fit_gain_drift(t, measured, ref, degree=5)
    assert_allclose(quintic["gain_coefficients"], coef, atol=2e-5)
    # the cubic leaves the T^4, T^5 terms' part beyond it: about 2 nT RMS at 45000 nT
    assert cubic["scalar_slow_after_nT"] > 1.0
    assert quintic["scalar_slow_after_nT"] < 0.2
    assert rms(fixed - truth) < 0.5


@pytest.mark.realdata
def test_real_gain_drift_removes_the_slow_part(real_zones):
    from magcal.missions.elfin.harmonic import correct_elfin_calibration
    from magcal.missions.elfin.drift import correct_gain_drift, drift_agreement_table
    from magcal.missions.elfin.joint import score_field

    harmonic, _ = correct_elfin_calibration(real_zones)
    drifted, table = correct_gain_drift(harmonic)
    before, after = score_field(harmonic.field), score_field(drifted.field)
    # the slow part (about 60-80 nT in these zones) is at least 80 % gone; the scalar
    # target of issue 15 (30 nT) is met in both zones and the fast part does not grow
    assert np.all(before["scalar_slow_nT"] > 50.0)
    assert np.all(after["scalar_slow_nT"] < 0.2 * before["scalar_slow_nT"])
    assert np.all(after["scalar_rms_nT"] < 30.0)
    assert np.all(after["scalar_fast_nT"] < before["scalar_fast_nT"] + 0.5)
    # the drift is a gain change of a few tenths of a percent, and the vector improves
    assert np.all((table["gain_drift_pp"] > 1e-3) & (table["gain_drift_pp"] < 1e-2))
    assert np.all(after["vector_rms_nT"] < before["vector_rms_nT"])
    # the reference-free 2x drift has the slow part's time shape in both zones
    agree = drift_agreement_table(real_zones)
    assert np.all(agree["correlation"].abs() > 0.9)


@pytest.mark.realdata
def test_real_structure_beyond_a_cubic_follows_the_2x_drift(real_zones):
    """The reference-free case for ``gain_drift_degree``: in these two passes the
    ``|B|`` residual beyond a cubic follows the 2x-spin harmonic's drift beyond a cubic
    (a gain change makes both, a natural field only the first), and a quintic drift
    (``degree=5``, six gain coefficients per pass) takes more of the slow part."""
    from magcal.missions.elfin.drift import (_zone_body, correct_gain_drift, fit_samples,
                                             harmonic_shape)
    from magcal.missions.elfin.harmonic import correct_elfin_calibration
    from magcal.missions.elfin.joint import score_field

    f = real_zones.field
    for k in dict.fromkeys(f["zone"]):
        z = f[f["zone"] == k]
        t, b, ref, *_ = _zone_body(z)
        use = fit_samples(z, scalar=True)
        a = harmonic_shape(t, b, ref, fit_mask=use, drift_degree=7, poly_degree=7)[use]
        t = t[use]
        r = np.linalg.norm(b[use], axis=1) - ref[use]
        slow = r - fast_part(t, r, 7)
        T = 2 * (t - t[0]) / (t[-1] - t[0]) - 1

        def beyond(v, d):
            return v - np.vander(T, d + 1) @ np.linalg.lstsq(np.vander(T, d + 1), v,
                                                             rcond=None)[0]

        # measured: correlation 0.85 and 0.69
        assert abs(np.corrcoef(beyond(a, 3), beyond(slow, 3))[0, 1]) > 0.6
    harmonic, _ = correct_elfin_calibration(real_zones)
    cubic = score_field(correct_gain_drift(harmonic)[0].field)
    quintic_cal, table = correct_gain_drift(harmonic, degree=5)
    assert [len(c) for c in table["gain_coefficients"]] == [6, 6]      # two passes
    assert quintic_cal.parameters["gain_drift"]["shape"] == "polynomial of degree 5"
    assert np.all(score_field(quintic_cal.field)["scalar_slow_nT"]
                  < cubic["scalar_slow_nT"])


@pytest.mark.realdata
def test_real_slow_part_is_in_the_spin_plane_magnitude(real_zones):
    """The spin-axis component adds < 5 nT to the slow part: not an attitude error."""
    from magcal.missions.elfin.harmonic import correct_elfin_calibration

    harmonic, _ = correct_elfin_calibration(real_zones)
    f = harmonic.field
    for k in sorted(f["zone"].unique()):
        z = f[(f["zone"] == k) & (f["used"] == 1)]
        t = (z.index.asi8 - z.index.asi8[0]) / 1e9
        b = z[["bx_despun", "by_despun", "bz_despun"]].to_numpy()
        r = z[["igrf_x_despun", "igrf_y_despun", "igrf_z_despun"]].to_numpy()
        mag = np.linalg.norm(r, axis=1)
        perp = np.hypot(b[:, 0], b[:, 1]) - np.hypot(r[:, 0], r[:, 1])
        axial = (b[:, 2] ** 2 - r[:, 2] ** 2) / (2 * mag)
        slow = [rms(v - fast_part(t, v)) for v in (perp, axial)]
        assert slow[0] > 50.0 and slow[1] < 5.0


def test_vector_step_removes_body_fixed_terms_and_keeps_natural_fields():
    """Body-fixed spin harmonics and a tilt go; an inertial (natural) field stays."""
    from magcal.missions.elfin.vector import correct_vector_zone

    rng = np.random.default_rng(9)
    t, T, _ = _pass()
    phase = 2 * np.pi * t / SPIN_S
    ang = np.radians(-30 - 40 * (T + 1) / 2)
    ref = np.column_stack([45000 * np.cos(ang), 45000 * np.sin(ang), 2000 - 700 * T])
    # a natural field IGRF lacks: a 60 nT transverse bump over ~30 s (despun frame)
    natural = np.zeros_like(ref)
    natural[:, 0] = 60 * np.exp(-0.5 * ((t - 150) / 15) ** 2) * np.sin(ang)
    natural[:, 1] = -60 * np.exp(-0.5 * ((t - 150) / 15) ** 2) * np.cos(ang)
    truth = ref + natural
    body = spin(truth, phase)
    beta = body[:, 0] + 1j * body[:, 1]
    psi = np.angle(beta)
    wobble = 1j * beta * 1e-3 * np.cos(2 * psi - 0.7)            # 2x angle wobble, 0.06 deg
    bad = body.copy()
    bad[:, 0] += wobble.real
    bad[:, 1] += wobble.imag
    bad[:, 2] += (40 + 20 * T) * np.cos(psi - 0.3)                # drifting spin-axis tilt
    bad += rng.normal(scale=0.3, size=bad.shape)
    fixed, info = correct_vector_zone(t, despin(bad, phase), phase, ref, bound_deg=0.0)
    # the body-fixed terms are removed (to < 1 nT RMS), the natural field is kept whole
    assert rms(np.linalg.norm(fixed - truth, axis=1)) < 1.0
    assert rms(np.linalg.norm(fixed - ref, axis=1)) > 0.9 * rms(np.linalg.norm(natural, axis=1))
    assert info["vector_rms_before_nT"] > 20.0


def test_vector_step_with_spin_sectors_missing_leaves_the_slow_phase_error_alone():
    """Clipped counts take out the same spin-phase sectors every spin; the harmonics
    fitted on the rest must not take a slow (despun-frame) residual with them."""
    from magcal.missions.elfin.vector import correct_vector_zone

    rng = np.random.default_rng(10)
    t, T, _ = _pass()
    phase = 2 * np.pi * t / SPIN_S
    ang = np.radians(-30 - 40 * (T + 1) / 2)
    ref = np.column_stack([45000 * np.cos(ang), 45000 * np.sin(ang), 2000 - 700 * T])
    err = np.radians(0.1) * T ** 3                                # slow phase error, 0.2 deg p-p
    slow = ref.copy()
    slow[:, 0] = np.cos(err) * ref[:, 0] - np.sin(err) * ref[:, 1]
    slow[:, 1] = np.sin(err) * ref[:, 0] + np.cos(err) * ref[:, 1]
    body = spin(slow, phase)
    psi = np.angle(body[:, 0] + 1j * body[:, 1])
    bad = body.copy()
    bad[:, 2] += 40 * np.cos(psi - 0.3)                           # body-fixed, to remove
    bad += rng.normal(scale=0.3, size=bad.shape)
    # the samples where body x reads within 5 % of its peak, both signs: 20 % of each spin
    kept = np.abs(np.cos(psi)) < 0.95
    fixed, _ = correct_vector_zone(t, despin(bad, phase), phase, ref, bound_deg=0.0,
                                   fit_mask=kept)
    # what is left is the slow phase error (78.5 nT x rms(T^3) = 29.7 nT), to within 1 nT
    assert rms(np.linalg.norm(slow - ref, axis=1)[kept]) > 25.0
    assert rms(np.linalg.norm(fixed - slow, axis=1)[kept]) < 1.0


def test_tilt_is_recovered_inside_the_bound_and_clipped_outside():
    from magcal.missions.elfin.vector import refine_tilt

    t, T, _ = _pass()
    ang = np.radians(-30 - 40 * (T + 1) / 2)
    ref = np.column_stack([45000 * np.cos(ang), 45000 * np.sin(ang), 2000 - 700 * T])
    w = np.radians([0.12, -0.05, 0.0])
    _, got, at_bound = refine_tilt(ref + np.cross(w, ref), ref)
    np.testing.assert_allclose(got, [0.12, -0.05], atol=2e-3)
    assert not at_bound
    # beyond the attitude file's 0.2 deg the angle stops on the bound and says so (the
    # other angle then takes up what it can: over a 40 deg sweep the two are correlated)
    _, got, at_bound = refine_tilt(ref + np.cross(np.radians([0.35, -0.05, 0.0]), ref), ref)
    np.testing.assert_allclose(got[0], 0.2, atol=1e-3)
    assert at_bound


@pytest.mark.realdata
def test_real_vector_step_lowers_the_vector_residual(real_zones):
    from magcal.missions.elfin.harmonic import correct_elfin_calibration
    from magcal.missions.elfin.drift import correct_gain_drift
    from magcal.missions.elfin.joint import score_field
    from magcal.missions.elfin.vector import correct_vector

    drifted, _ = correct_gain_drift(correct_elfin_calibration(real_zones)[0])
    final, table = correct_vector(drifted)
    before, after = score_field(drifted.field), score_field(final.field)
    # the body-fixed spin harmonics are 15-50 nT: the vector RMS falls by a fifth at
    # least; the scalar stays under issue 15's 30 nT and its fast part grows < 1 nT
    # (zone 7's fast part is 17 nT before and after: the sunlit dawn passes keep it)
    assert np.all(after["vector_rms_nT"] < 0.8 * before["vector_rms_nT"])
    assert np.all(after["scalar_rms_nT"] < 30.0)
    assert np.all(after["scalar_fast_nT"] < before["scalar_fast_nT"] + 1.0)
    assert np.all(np.abs(np.vstack(table["tilt_deg"])) <= 0.2 + 1e-9)


def test_drift_pair_tells_one_direction_from_isotropic_gain_drift():
    from magcal.missions.elfin.drift import drift_pair

    rng = np.random.default_rng(10)
    t, T, truth = _pass()
    theta = 2e-3 * (T ** 2 - 1 / 3) + 1e-3 * T
    n = np.array([np.cos(0.4), np.sin(0.4)])
    one = truth.copy()
    one[:, :2] += (theta * (truth[:, :2] @ n))[:, None] * n
    iso = truth * np.c_[1 + theta, 1 + theta, np.ones_like(t)]
    half = theta * np.hypot(truth[:, 0], truth[:, 1]) / 2             # theta |beta| / 2
    expected = rms(half - half.mean())
    for measured, k1, km1 in ((one, expected, expected), (iso, 2 * expected, 0.0)):
        out = drift_pair(t, measured + rng.normal(scale=0.3, size=truth.shape), truth)
        np.testing.assert_allclose([out["drift_k1_nT"], out["drift_km1_nT"]], [k1, km1],
                                   rtol=0.03, atol=0.2)


def test_instrument_candidates_closed_form():
    import pandas as pd

    from magcal.missions.elfin.diagnostics.reference import instrument_candidates

    idx = pd.date_range("2022-01-12", periods=4000, freq="1s", tz="UTC").as_unit("ns")
    sun = np.r_[np.zeros(2000), np.ones(2000)]                     # eclipse, then sunlight
    state = pd.DataFrame({"sun": sun}, index=idx)
    t = np.arange(0.0, 600.0, 0.1)
    ref = np.full(t.size, 45000.0)
    start = idx.asi8[2000]                                          # zone starts at sunrise
    out = instrument_candidates(t, start, ref, state, sun_tau_s=300.0, warm_tau_s=60.0)
    # first-order low-pass of a step sampled at 1 s: 1 - exp(-(k + 1)/300) at the k-th
    # record after sunrise, linear between records, scaled by |B| 1e-3
    k = np.arange(1000.0)
    np.testing.assert_allclose(out["sun_lowpass"],
                               45.0 * np.interp(t, k, 1 - np.exp(-(k + 1) / 300)), rtol=1e-9)
    np.testing.assert_allclose(out["warm_up"], 45.0 * (1 - np.exp(-t / 60)), rtol=1e-12)


def test_tilt_with_a_level_step_keeps_the_natural_step():
    """A spin-axis tilt of 0.1 deg plus a 300 nT natural step along the spin axis after
    an interval left out of the fit. Truth: the injected tilt and step. Without a level
    step the tilt takes part of the step (and hits its 0.2 deg bound); with it the tilt
    comes back and the step stays in the field."""
    from magcal.missions.elfin.levels import step_columns
    from magcal.missions.elfin.vector import refine_tilt

    t = np.arange(0.0, 360.0, 0.1)
    ang = np.linspace(0.0, 0.8, t.size)
    ref = np.column_stack([45000 * np.cos(ang), 45000 * np.sin(ang), np.full(t.size, 2000.0)])
    th = np.radians(0.1)
    natural = np.zeros_like(ref)
    natural[:, 2] = np.where(t > 200.0, 300.0, 0.0)
    b = ref + np.cross([th, 0.0, 0.0], ref) + natural
    fit = (t < 170.0) | (t > 200.0)
    fixed, angles, _ = refine_tilt(b, ref, fit_mask=fit, steps=step_columns(~fit))
    assert_allclose(angles, [0.1, 0.0], atol=0.005)
    assert_allclose((fixed - ref)[t > 200.0, 2], 300.0, atol=4.0)
    _, plain, _ = refine_tilt(b, ref, fit_mask=fit)
    assert np.max(np.abs(plain - [0.1, 0.0])) > 0.05
