"""Localized fields along B kept out of the ELFIN gain drift (magcal.missions.elfin.pulses).

Closed-form cases with known truth (a Gaussian pulse on a cubic is found where it was
put; fitted with the drift it stays in the field, without it the drift takes it), rates
over seeded correlated plus white noise (no false pulse; injected pulses found), and on
the real day: no natural pulse on the clean day, and a 100 nT pulse along B injected
into the counts comes back in its shape instead of being taken by the drift.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from conftest import real_data_path
from magcal.alignment.noise import simulate_ou
from magcal.missions.elfin.drift import fit_gain_drift
from magcal.missions.elfin.pulses import find_pulses, gaussian, pulse_templates

FGS = "ela_l1_fgs_20220112_v01.cdf"
STATE = "ela_l1_state_defn_20220112_v01.cdf"

T = np.arange(0.0, 370.0, 0.2)          # one ELFIN zone at 5 Hz
FIT = np.ones(T.size, bool)


def test_gaussian_has_its_fwhm():
    g = gaussian(T, 185.0, 90.0)
    above = T[g >= 0.5]
    assert above[-1] - above[0] == pytest.approx(90.0, abs=0.4)
    assert g.max() == pytest.approx(1.0, abs=1e-3)


def test_a_pulse_on_a_cubic_is_found_where_it_was_put():
    r = 60.0 * ((T - 185) / 185) ** 3 - 20.0 * ((T - 185) / 185) + 100.0 * gaussian(T, 240.0, 60.0)
    p = find_pulses(T, r, FIT)
    assert len(p) == 1 and bool(p["natural"][0])
    assert p["centre_s"][0] == pytest.approx(240.0, abs=1.0)
    assert p["fwhm_s"][0] == pytest.approx(60.0, abs=1.0)
    assert p["height_nT"][0] == pytest.approx(100.0, abs=2.0)


def test_a_wide_bump_is_drift_not_a_natural_pulse():
    """A 200 s wide bump (the real day's zone-end drifts are 170-180 s) is fitted but
    not kept as a natural field; a 20 nT pulse is under the height floor."""
    p = find_pulses(T, 100.0 * gaussian(T, 250.0, 200.0), FIT)
    assert len(p) == 1 and not bool(p["natural"][0])
    assert "FWHM 150 s or more" in p["why"][0]
    p = find_pulses(T, 20.0 * gaussian(T, 150.0, 60.0), FIT)
    assert len(p) == 1 and not bool(p["natural"][0])
    assert p["why"][0] == "under 30 nT"


def test_a_pulse_cut_by_the_zone_end_is_drift_and_says_so():
    """Half maximum within 20 s of the fitted span's end: as much the cubic's end as a
    pulse, so removed with the drift, and the reason is the cut alone."""
    p = find_pulses(T, 100.0 * gaussian(T, 330.0, 60.0), FIT)
    assert len(p) == 1 and not bool(p["natural"][0])
    assert p["centre_s"][0] == pytest.approx(330.0, abs=2.0)
    assert p["why"][0] == "cut by a zone end"
    assert find_pulses(T, 100.0 * gaussian(T, 185.0, 60.0), FIT)["why"][0] == ""


def test_two_pulses_in_a_zone_are_both_found():
    r = 100.0 * gaussian(T, 110.0, 40.0) - 80.0 * gaussian(T, 260.0, 70.0)
    p = find_pulses(T, r, FIT).sort_values("centre_s")
    assert len(p) == 2 and p["natural"].all()
    assert p["centre_s"].tolist() == pytest.approx([110.0, 260.0], abs=1.5)
    assert p["height_nT"].tolist() == pytest.approx([100.0, -80.0], abs=3.0)


@pytest.mark.parametrize("centre", [130.0, 240.0])
@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_a_pulse_beside_a_wide_structure_at_the_zone_end_keeps_its_own_height(centre, sign):
    """A 100 nT, 90 s pulse beside a 112 nT, 173 s structure cut by the zone's end (the
    real day's zone 9): the pulse is found with its own height and the structure is
    drift. The greedy search alone (``pair_search=False``) finds one shape between the
    two, 111-148 nT high and 100-112 s wide, and not the structure."""
    r = sign * 100.0 * gaussian(T, centre, 90.0) + 112.0 * gaussian(T, 304.0, 173.0) \
        + 30.0 * ((T - 185) / 185) ** 3
    p = find_pulses(T, r, FIT)
    kept = p[p["natural"].astype(bool)]
    assert len(kept) == 1
    assert kept["centre_s"].iloc[0] == pytest.approx(centre, abs=2.0)
    assert kept["fwhm_s"].iloc[0] == pytest.approx(90.0, abs=3.0)
    assert kept["height_nT"].iloc[0] == pytest.approx(sign * 100.0, abs=3.0)
    drift = p[~p["natural"].astype(bool)]
    assert len(drift) == 1 and drift["centre_s"].iloc[0] == pytest.approx(304.0, abs=3.0)


def test_pair_search_over_seeded_noise_keeps_the_height():
    """The same pair over 2 nT OU (30 s) and 1 nT white noise (the real day's ``|B|``
    residual about the fitted shapes is 1.0-1.6 nT RMS), 20 draws: the pulse is found
    in every draw, the median height within 10 nT of 100 and the median error at most
    20 nT (measured 99 and 14 nT; the greedy search alone: 128 and 28 nT)."""
    rng = np.random.default_rng(20261128)
    heights = []
    for _ in range(20):
        r = simulate_ou(rng, T, 2.0, 30.0) + rng.normal(0.0, 1.0, T.size) \
            + 100.0 * gaussian(T, 130.0, 90.0) + 112.0 * gaussian(T, 304.0, 173.0)
        p = find_pulses(T, r, FIT)
        p = p[p["natural"].astype(bool)]
        assert len(p) == 1
        heights.append(p["height_nT"].iloc[0])
    assert np.median(heights) == pytest.approx(100.0, abs=10.0)
    assert np.median(np.abs(np.asarray(heights) - 100.0)) <= 20.0


def test_no_pulse_over_seeded_correlated_noise():
    """40 draws each of a 5 and a 10 nT OU wander (30 and 60 s) plus 3 nT white noise on
    a cubic: no pulse at all (truth: none)."""
    rng = np.random.default_rng(20261127)
    for std, tau in ((5.0, 30.0), (10.0, 60.0)):
        for _ in range(40):
            r = simulate_ou(rng, T, std, tau) + rng.normal(0.0, 3.0, T.size) \
                + 40.0 * (T / 370.0) ** 3
            assert len(find_pulses(T, r, FIT)) == 0


def test_pulses_over_seeded_noise_are_found_with_their_height():
    """A 100 nT pulse of 90 s FWHM over 5 nT OU (30 s) and 3 nT white noise: found in
    all 20 draws, its height within 20 nT (measured spread -12..+14 nT)."""
    rng = np.random.default_rng(11)
    for _ in range(20):
        r = simulate_ou(rng, T, 5.0, 30.0) + rng.normal(0.0, 3.0, T.size) \
            + 100.0 * gaussian(T, 150.0, 90.0)
        p = find_pulses(T, r, FIT)
        p = p[p["natural"].astype(bool)]
        assert len(p) == 1
        assert p["centre_s"].iloc[0] == pytest.approx(150.0, abs=10.0)
        assert p["height_nT"].iloc[0] == pytest.approx(100.0, abs=20.0)


def _spinning(pulse_nT):
    """Body-frame field of a zone: 45000 nT spinning, 2000 nT along the spin axis, plus
    a field along B of ``pulse_nT``; measured with a cubic spin-plane gain drift."""
    psi = 2 * np.pi * T / 2.85
    true = np.column_stack([45000 * np.cos(psi), 45000 * np.sin(psi), 2000 + 0 * T])
    mag = np.linalg.norm(true, axis=1)
    natural = true * (1.0 + pulse_nT / mag)[:, None]
    x = 2 * T / T[-1] - 1
    g = 1e-3 * (0.3 + 0.5 * x - 0.8 * x ** 2 + 0.6 * x ** 3)
    measured = natural * np.c_[1 + g, 1 + g, np.ones_like(T)]
    return measured, natural, mag


def test_a_pulse_fitted_with_the_drift_stays_in_the_field():
    """Truth: the field with the pulse along B. With its shape given, the drift is
    removed and the pulse kept to 1 nT; without, the drift takes most of it (closed
    form: 71 % of a 90 s pulse's energy in a 6 min zone is a cubic)."""
    pulse = 100.0 * gaussian(T, 185.0, 90.0)
    measured, natural, mag = _spinning(pulse)
    kept, info = fit_gain_drift(T, measured, mag, natural=gaussian(T, 185.0, 90.0)[:, None])
    assert np.abs(kept - natural).max() < 1.0
    assert info["natural_amplitudes"][0] == pytest.approx(100.0, abs=1.0)
    lost, _ = fit_gain_drift(T, measured, mag)
    back = np.linalg.norm(lost, axis=1) - mag
    share = float(back @ pulse / (pulse @ pulse))
    assert share < 0.35


def test_pulse_templates_put_each_zone_s_shapes_on_its_rows():
    idx = pd.date_range("2022-01-12", periods=2 * T.size, freq="200ms", tz="UTC")
    field = pd.DataFrame({"zone": np.repeat([3, 5], T.size)}, index=idx)
    pulses = pd.DataFrame({"zone": [5, 5], "centre_s": [100.0, 250.0],
                           "fwhm_s": [60.0, 40.0]})
    tpl = pulse_templates(field, pulses)
    assert tpl.shape == (2 * T.size, 2)
    assert not tpl[:T.size].any()
    assert T[np.argmax(tpl[T.size:, 0])] == pytest.approx(100.0)
    assert T[np.argmax(tpl[T.size:, 1])] == pytest.approx(250.0)
    assert pulse_templates(field, pulses.iloc[:0]).shape == (2 * T.size, 0)


@pytest.fixture(scope="module")
def zones_1_4():
    from magcal.missions.elfin.files import read_elfin_fgs, read_elfin_state
    from magcal.missions.elfin.injection import select_zones

    fgs = read_elfin_fgs(real_data_path("elfin", FGS))
    state = read_elfin_state(real_data_path("elfin", STATE))
    return select_zones(fgs, [1, 4]), state


def test_a_pulse_along_b_injected_on_the_real_day_comes_back(zones_1_4):
    """2022-01-12 zone 1, a 100 nT pulse along B (90 s FWHM) injected at mid-zone
    through the clean calibration, with the delivered settings (``pulses_b`` on by
    default; without it the drift takes the pulse: 8 % of its energy kept, asserted in
    test_elfin_injection): one natural pulse is listed within
    10 s and 25 nT of the truth (the clean day holds -10 nT on that shape beyond the cubic) and the
    product keeps at least 60 % of the energy with under 15 % distortion, while the
    clean zones get no natural pulse. The stated height error (the pulse put into
    zone 4's counts at the same place and found again) covers the truth within twice
    it."""
    from magcal.missions.elfin.injection import inject_counts, preservation, signal_gei
    from magcal.missions.elfin.pipeline import ElfinSettings, calibrate_elfin_day

    fgs, state = zones_1_4
    on = ElfinSettings(bridge_trials=0, pulse_trials=1)
    assert on.pulses_b
    clean = calibrate_elfin_day(fgs, state, on, diagnostics=False)
    assert clean.pulses_along_b() == []
    lf = clean.linear.field
    sig = signal_gei("pulse_b", lf[lf["zone"] == 0], state)
    injected = inject_counts(fgs, clean.linear, {0: sig})
    day = calibrate_elfin_day(injected, state, on, diagnostics=False)
    pulses = day.pulses_along_b()
    assert len(pulses) == 1 and pulses[0]["zone"] == 0
    truth_t = lf[lf["zone"] == 0].index[int(np.argmax(np.linalg.norm(sig, axis=1)))]
    got_t = pd.Timestamp(pulses[0]["centre"], tz="UTC")
    assert abs((got_t - truth_t).total_seconds()) <= 10.0
    # the search states it: natural, where it was put, above the gain it needed
    found = [x for x in day.to_json()["pulses_b"]["search"] if x["natural"]]
    assert len(found) == 1 and found[0]["why"] == "" and found[0]["gain"] >= 10.0
    found_t = pd.Timestamp(found[0]["centre"], tz="UTC")
    assert abs((found_t - truth_t).total_seconds()) <= 10.0
    assert pulses[0]["height_nT"] == pytest.approx(100.0, abs=25.0)
    listed = day.to_json()["pulses_b"]["pulses"]
    assert len(listed) == 1 and len(listed[0]["trial_heights_nT"]) == 1
    error = listed[0]["height_error_nT"]
    assert 0.0 < error and abs(listed[0]["height_nT"] - 100.0) <= 2.0 * error
    tab = preservation(clean, day, {0: sig}, "pulse_b")
    last = tab[(tab["product"] == tab["product"].iloc[-1]) & (tab["zone"] == 0)].iloc[0]
    assert last["energy_kept"] >= 0.6 and last["distortion"] <= 0.15


def test_a_wide_structure_along_b_is_removed_with_the_drift_and_stated(zones_1_4):
    """2022-01-12 zone 1, a 100 nT structure along B of 200 s FWHM injected at 0.8 of
    the zone (wider than the 150 s a natural pulse may have): the product removes it
    with the gain drift, and the JSON's search listing and the CLI line state it with
    its reason, within 20 s and 25 nT of the truth, so that nothing is lost silently.
    (At mid-zone the cubic takes most of such a structure and the search finds only
    what is left, elsewhere: measured, not asserted.)"""
    from magcal.chain.spin_elfin import pulse_lines
    from magcal.missions.elfin.injection import directions, inject_counts
    from magcal.missions.elfin.pipeline import ElfinSettings, calibrate_elfin_day

    fgs, state = zones_1_4
    on = ElfinSettings(bridge_trials=0, pulse_trials=0, level_trials=0)
    clean = calibrate_elfin_day(fgs, state, on, diagnostics=False)
    assert clean.pulse_search_listing() == []
    zf = clean.linear.field[clean.linear.field["zone"] == 0]
    t = (zf.index.asi8 - zf.index.asi8[0]) / 1e9
    t0 = t[0] + 0.8 * (t[-1] - t[0])
    along_b = directions(zf.index, state,
                         zf[["igrf_x_gei", "igrf_y_gei", "igrf_z_gei"]].to_numpy())["b"]
    sig = 100.0 * gaussian(t, t0, 200.0)[:, None] * along_b
    injected = inject_counts(fgs, clean.linear, {0: sig})
    day = calibrate_elfin_day(injected, state, on, diagnostics=False)
    assert day.pulses_along_b() == []
    listed = day.to_json()["pulses_b"]["search"]
    assert len(listed) == 1 and not listed[0]["natural"]
    assert "FWHM 150 s or more" in listed[0]["why"]
    got_t = pd.Timestamp(listed[0]["centre"], tz="UTC")
    assert abs((got_t - (zf.index[0] + pd.to_timedelta(t0, unit="s"))).total_seconds()) <= 20
    assert listed[0]["height_nT"] == pytest.approx(100.0, abs=25.0)
    removed = [x for x in pulse_lines(day) if x.startswith("|B| structures")]
    assert len(removed) == 1 and "zone 0" in removed[0] and "FWHM 150 s or more" in removed[0]



def test_what_a_drift_above_a_cubic_takes_unseen_is_stated_and_not_fitted():
    """:func:`taken_by_the_drift`: a shape of the cubic search that none of the drift's
    own search matches (centres within half the wider FWHM) is added, not natural and
    not fitted, with the reason; a matched one is not repeated; at degree 3 nothing is
    added and every found shape is fitted."""
    from magcal.missions.elfin.pulses import taken_by_the_drift

    start = pd.Timestamp("2022-01-12T06:30", tz="UTC")
    cols = dict(start=start, gain=20.0, why="")
    found = pd.DataFrame([dict(zone=1, centre_s=100.0, fwhm_s=60.0, height_nT=80.0,
                               natural=True, **cols)])
    cubic = pd.DataFrame([dict(zone=1, centre_s=120.0, fwhm_s=60.0, height_nT=70.0,
                               natural=True, **cols),        # 20 s from the found one
                          dict(zone=1, centre_s=300.0, fwhm_s=200.0, height_nT=100.0,
                               natural=False, **{**cols, "why": "FWHM 150 s or more"}),
                          dict(zone=2, centre_s=100.0, fwhm_s=60.0, height_nT=50.0,
                               natural=True, **cols)])
    out = taken_by_the_drift(found, cubic, 4)
    assert len(out) == 3
    assert out["fitted"].tolist() == [True, False, False]
    assert out["natural"].tolist() == [True, False, False]
    assert out["zone"].tolist() == [1, 1, 2]
    assert out["why"].iloc[1] == ("FWHM 150 s or more; taken by the degree-4 drift "
                                  "(found with a cubic drift)")
    assert out["why"].iloc[2] == "taken by the degree-4 drift (found with a cubic drift)"
    assert out["height_nT"].tolist() == [80.0, 100.0, 50.0]
    same = taken_by_the_drift(found, cubic, 3)
    assert len(same) == 1 and same["fitted"].all()


def test_the_quartic_drift_keeps_a_pulse_along_b_of_either_polarity_to_the_target():
    """2022-01-12 zone 7 alone, a 100 nT pulse along B (90 s FWHM) at mid-zone, both
    polarities, delivered settings (quartic gain drift): the target of issue 24 (at
    least 90 % of the energy, at most 10 % distortion) is met for each (measured 1.11 /
    0.92 of the energy, distortion 5 / 4 %). With the cubic the + polarity kept 0.79:
    the zone's own ``|B|`` beyond a cubic on the pulse's shape, which the cubic clean
    run leaves and a found pulse takes with it (``ElfinSettings.gain_drift_degree``)."""
    from magcal.missions.elfin.files import read_elfin_fgs, read_elfin_state
    from magcal.missions.elfin.injection import run_injections, select_zones
    from magcal.missions.elfin.pipeline import ElfinSettings

    fgs = select_zones(read_elfin_fgs(real_data_path("elfin", FGS)), [7])
    state = read_elfin_state(real_data_path("elfin", STATE))
    settings = ElfinSettings(bridge_trials=0, pulse_trials=0, level_trials=0,
                             perp_trials=0)
    assert settings.gain_drift_degree == 4
    tab = run_injections(fgs, state, settings, kinds=("pulse_b",), both_signs=True)[0]
    last = tab[tab["product"] == tab["product"].iloc[-1]]
    assert set(last["sign"]) == {1.0, -1.0}
    for _, r in last.iterrows():
        assert r["energy_kept"] >= 0.90, r["sign"]
        assert r["energy_kept"] <= 1.25, r["sign"]
        assert r["distortion"] <= 0.10, r["sign"]
