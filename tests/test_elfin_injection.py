"""Synthetic natural signals injected into the ELFIN counts (magcal.missions.elfin.injection).

Closed-form checks of the signal shapes and the measures, then the real day (one zone,
skipped with a reason when ../shared/real-data is absent): the inverse of the clean
calibration is exact, the phase-held linear fit keeps an injected pulse but for its zone
mean (which any per-zone calibration against a model takes), and the measured
absorbers are what the settings name. The full table: workflows/elfin_preservation.py.
"""

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from conftest import real_data_path
from magcal.errors import InputError
from magcal.missions.elfin.injection import (
    SIGNALS,
    WAVE_HZ,
    fwhm,
    inject_counts,
    kept,
    signal_gei,
    signal_shape,
    zone_mean_share,
)

FGS = "ela_l1_fgs_20220112_v01.cdf"
STATE = "ela_l1_state_defn_20220112_v01.cdf"
ZONE = 1


def test_signal_shapes_match_their_definitions():
    t = np.arange(0.0, 400.0, 0.1)
    for kind, (amp, _, shape, width) in SIGNALS.items():
        y = signal_shape(kind, t, 200.0)
        if shape == "gauss":
            assert y.max() == pytest.approx(amp, rel=1e-6)
            assert fwhm(t, y) == pytest.approx(width, abs=0.2)
        elif shape == "tanh":   # 10-90 % rise time, then the full amplitude to the end
            lo, hi = t[np.argmax(y >= 0.1 * amp)], t[np.argmax(y >= 0.9 * amp)]
            assert hi - lo == pytest.approx(width, abs=0.2)
            assert y[-1] == pytest.approx(amp, rel=1e-6)
        else:                   # a packet of `width` s at WAVE_HZ
            inside = np.abs(y) > 0
            assert t[inside][-1] - t[inside][0] == pytest.approx(width, abs=0.2)
            spec = np.abs(np.fft.rfft(y))
            assert np.fft.rfftfreq(t.size, 0.1)[np.argmax(spec)] == pytest.approx(WAVE_HZ,
                                                                                   abs=0.05)
            assert np.abs(y).max() == pytest.approx(amp, rel=0.01)
    with pytest.raises(InputError, match="unknown signal"):
        signal_shape("nope", t, 0.0)


def test_kept_measures_in_closed_form():
    rng = np.random.default_rng(24)
    s = rng.normal(size=(500, 3))
    other = np.cross(s, [0.0, 0.0, 1.0])            # orthogonal to s sample by sample
    k = kept(0.8 * s + 0.3 * other, s)
    assert k.gain == pytest.approx(0.8, abs=1e-12)
    assert k.energy == pytest.approx(0.64, abs=1e-12)
    expected = 0.3 * np.sqrt(np.sum(other ** 2) / np.sum(s ** 2))
    assert k.distortion == pytest.approx(expected, rel=1e-12)
    box = np.zeros((100, 3))
    box[:25, 0] = 2.0                               # mean 0.5, energy 100 -> 25/100
    assert zone_mean_share(box) == pytest.approx(0.25)


@pytest.fixture(scope="module")
def day():
    from magcal.missions.elfin.files import read_elfin_fgs, read_elfin_state
    from magcal.missions.elfin.phase import split_zones

    fgs = read_elfin_fgs(real_data_path("elfin", FGS))
    state = read_elfin_state(real_data_path("elfin", STATE))
    t = (fgs.index.asi8 - fgs.index.asi8[0]) / 1e9
    return fgs.iloc[slice(*split_zones(t, 60.0)[ZONE])], state


def test_inverse_of_the_clean_calibration_is_exact(day):
    from magcal.missions.elfin.linear import calibrate_elfin
    from magcal.missions.elfin.phase import despun_basis
    from magcal.spin.despin import despin

    fgs, state = day
    clean = calibrate_elfin(fgs, state)
    f = clean.field
    sig = signal_gei("gauss_along", f, state)
    dc = (inject_counts(fgs, clean, {0: sig})[["b1", "b2", "b3"]].to_numpy()
          - fgs[["b1", "b2", "b3"]].to_numpy())
    basis = despun_basis(f[[f"spin_axis_gei_{c}" for c in "xyz"]].to_numpy())
    back = np.einsum("nji,nj->ni", basis,
                     despin((clean.zones[0].coupling @ dc.T).T, f["phase"].to_numpy()))
    assert np.abs(back - sig).max() < 1e-6 * np.abs(sig).max()
    with pytest.raises(InputError, match="rows"):
        inject_counts(fgs.iloc[:-1], clean, {0: sig})


@pytest.fixture(scope="module")
def runs(day, tmp_path_factory):
    from magcal.missions.elfin.injection import run_injections
    from magcal.missions.elfin.pipeline import ElfinSettings

    # each step's own absorption, without the detection that leaves the signal out
    fgs, state = day
    kinds = ("gauss_ew", "gauss_along", "pulse_b")
    # (pulses along B kept out of the drift, pulses_b, are tested in test_elfin_pulses)
    steps = ElfinSettings(detect_disturbed=False, pulses_b=False)
    pictures = tmp_path_factory.mktemp("parts")
    both = run_injections(fgs, state, steps, kinds=kinds, hold=True, both_signs=True,
                          plot_dir=pictures)[0].assign(pictures=str(pictures))
    held = both[both["sign"] == 1.0]
    delivered = run_injections(fgs, state, steps, kinds=kinds)[0]
    free = run_injections(fgs, state, ElfinSettings(gain_drift_2x=True, detect_disturbed=False,
                                                    pulses_b=False), kinds=kinds)[0]
    splines = run_injections(fgs, state, ElfinSettings(linear_phase_knot_s=30.0,
                                                       phase_refit=True,
                                                       detect_disturbed=False),
                             kinds=("gauss_along",))[0]
    return held, delivered, free, splines, both


def _row(tab, kind, product):
    r = tab[(tab["signal"] == kind) & (tab["product"] == product)]
    assert len(r) == 1
    return r.iloc[0]


def test_phase_held_linear_fit_keeps_all_but_the_zone_mean(runs):
    """The machinery check: with the phase held, the linear fit can only take what a
    constant calibration can make, the zone mean; the rest comes back whole."""
    held = runs[0]
    for kind in ("gauss_ew", "gauss_along", "pulse_b"):
        r = _row(held, kind, "linear")
        assert r["energy_kept_ac"] >= 0.90, kind
        assert r["distortion_ac"] <= 0.20, kind
        # whole-signal gain = 1 - share of the zone mean (closed form), within 0.05
        assert r["gain"] == pytest.approx(1.0 - r["zone_mean_share"], abs=0.05), kind


def test_with_the_phase_held_the_signal_is_the_odd_part_and_nothing_is_even(runs):
    """``polarity_parts`` on the machinery check: with the phase held the linear fit is
    a least-squares fit linear in the counts, so what comes back is odd in the signal
    (even part at most 0.1 of the signal's RMS; measured 0.001-0.08 on zone 1) and the
    odd part's gain is 1 minus the share of the zone mean (closed form, within 0.05)."""
    both = runs[4]
    assert sorted(both["sign"].unique()) == [-1.0, 1.0]
    for kind in ("gauss_ew", "gauss_along", "pulse_b"):
        rows = both[(both["signal"] == kind) & (both["product"] == "linear")]
        assert len(rows) == 2, kind
        r = rows.iloc[0]
        assert r["even_rms"] <= 0.1, kind
        assert r["gain_odd"] == pytest.approx(1.0 - r["zone_mean_share"], abs=0.05), kind
        # the gain of the odd part is the mean of the two polarities' gains
        assert r["gain_odd"] == pytest.approx(rows["gain"].mean(), abs=1e-9), kind
        png = (Path(r["pictures"]) / f"parts_{kind}.png").read_bytes()   # the picture
        assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000, kind


def test_measured_absorbers_are_the_named_switches(runs):
    """The phase splines (linear_phase_knot_s, phase_refit) remove an along-track pulse,
    the delivered quadratic phase keeps part of it; the cubic gain drift removes a pulse
    along B, the reference-free drift (gain_drift_2x) keeps what the linear fit left."""
    held, delivered, free, splines, _ = runs
    last = delivered["product"].iloc[-1]
    assert last == "+ phase refit"
    # measured on zone 1: 0.002 with the splines; delivered 0.42 after the linear step
    # (its quadratic phase takes the pulse's projection on 1, t, t^2), 0.25 after the
    # cubic refit
    assert _row(splines, "gauss_along", "linear")["energy_kept"] < 0.1
    assert _row(splines, "gauss_along", "+ phase refit")["energy_kept"] < 0.1
    assert _row(delivered, "gauss_along", "linear")["energy_kept"] > 0.3
    assert _row(delivered, "gauss_along", last)["energy_kept"] > 0.15
    lin_b = _row(delivered, "pulse_b", "harmonic")["energy_kept"]
    assert _row(delivered, "pulse_b", "harmonic + gain drift")["energy_kept"] < 0.5 * lin_b
    assert _row(free, "pulse_b", "harmonic + gain drift")["energy_kept"] == pytest.approx(
        _row(free, "pulse_b", "harmonic")["energy_kept"], abs=0.05)
    # an east-west pulse is kept by every later step as the linear fit left it
    assert _row(delivered, "gauss_ew", last)["energy_kept_ac"] >= 0.9
    assert _row(delivered, "gauss_ew", last)["energy_kept"] == pytest.approx(
        _row(held, "gauss_ew", "linear")["energy_kept"], abs=0.05)


@pytest.mark.parametrize("degree, kinds", [(4, ("gauss_along",)),
                                            (3, ("gauss_along", "pulse_b"))])
def test_a_disturbed_interval_left_out_of_the_fits_comes_back_whole(day, degree, kinds):
    """Given where the signal is (``fit_exclude``: the samples above 5 % of its peak),
    no step can absorb it: the target of issue 24 (>= 90 % of the energy, <= 10 %
    distortion) is met for an along-track pulse (delivered quartic gain drift) and,
    with a cubic drift, for a pulse along B, the two that the delivered product loses
    most of without it. The quartic's bridge over a pulse along B's left-out rows takes
    more of it (its tails under 5 % stay in the fit, and a quartic is 90 % of the
    pulse's shape): 0.79 kept on zone 1, 0.84 zone median over the whole day against
    the cubic's 0.84 (the trade of ``ElfinSettings.gain_drift_degree``)."""
    from magcal.missions.elfin.injection import run_injections
    from magcal.missions.elfin.pipeline import ElfinSettings

    fgs, state = day
    tab = run_injections(fgs, state,
                         ElfinSettings(detect_disturbed=False, gain_drift_degree=degree),
                         kinds=kinds, mask_signal=0.05)[0]
    last = tab["product"].iloc[-1]
    for kind in kinds:
        r = _row(tab, kind, last)
        # measured on zone 1: 0.97 and 0.91 of the energy, distortion 0.02 and 0.03
        assert r["energy_kept"] >= 0.90, kind
        assert r["distortion"] <= 0.10, kind


def test_disturbed_rows_and_the_excluded_count_in_the_product(day):
    from magcal.missions.elfin.pipeline import ElfinSettings, calibrate_elfin_day, disturbed_rows

    fgs, state = day
    t0 = fgs.index[len(fgs) // 2]
    skip = disturbed_rows(fgs.index, [(str(t0.tz_convert(None)),
                                       str((t0 + pd.Timedelta("30s")).tz_convert(None)))])
    n = int(skip.sum())
    assert 250 < n < 350                      # 30 s of 10 Hz samples
    out = calibrate_elfin_day(fgs, state, ElfinSettings(detect_disturbed=False),
                              fit_exclude=skip, diagnostics=False)
    assert out.to_json()["fit_excluded"]["n_samples"] == n
    assert (out.calibration.field["used"].to_numpy()[skip] == 1).all()


def test_detected_intervals_keep_pulses_across_b_and_leave_a_wave_alone(day, tmp_path):
    """The detector (``detect_disturbed``, delivered) against the injected truth on
    zone 1: it flags where an east-west pulse is and the delivered product then keeps
    it, and an along-track one; a 5 nT wave flags nothing new; what it flags of the
    clean zone stays small and costs no residual. (It does not find a pulse along B or a
    lasting sheet: README, preservation table.)"""
    from magcal.missions.elfin.detect import detect_disturbed
    from magcal.missions.elfin.injection import run_injections
    from magcal.missions.elfin.linear import calibrate_elfin
    from magcal.missions.elfin.pipeline import ElfinSettings, calibrate_elfin_day

    fgs, state = day
    clean = calibrate_elfin(fgs, state)
    used = clean.field["used"].to_numpy() == 1
    quiet, _ = detect_disturbed(fgs, state)
    # measured: 0.17 of the clean zone (a 60 s excursion of 50-100 nT near its end)
    assert quiet[used].mean() <= 0.25
    sig = signal_gei("gauss_ew", clean.field, state)
    flags, table = detect_disturbed(inject_counts(fgs, clean, {0: sig}), state)
    energy = np.sum(sig ** 2, axis=1)
    assert energy[flags].sum() >= 0.9 * energy.sum()          # measured: 0.99
    assert table["flagged_share"].iloc[-1] == pytest.approx(flags[used].mean())
    wave = signal_gei("wave_2hz", clean.field, state)
    assert not (detect_disturbed(inject_counts(fgs, clean, {0: wave}), state)[0]
                & ~quiet).any()
    s = ElfinSettings()
    assert s.detect_disturbed
    tab = run_injections(fgs, state, s, kinds=("gauss_ew", "gauss_along"),
                         plot_dir=tmp_path / "plots")[0]
    last = tab["product"].iloc[-1]
    for kind in ("gauss_ew", "gauss_along"):      # the picture of what was kept
        png = (tmp_path / "plots" / f"recovered_{kind}.png").read_bytes()
        assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000
    # measured: 0.95 and 0.98 (0.69 and 0.26 without detection)
    assert _row(tab, "gauss_ew", last)["energy_kept"] >= 0.90
    assert _row(tab, "gauss_along", last)["energy_kept"] >= 0.90
    day_ = calibrate_elfin_day(fgs, state, s, diagnostics=False)
    off = calibrate_elfin_day(fgs, state, ElfinSettings(detect_disturbed=False),
                              diagnostics=False)
    # the clean zone's |B| residual is not worse than without detection (measured 5.59
    # / 5.20 nT against 5.65 / 5.23, scalar / fast part), nor the vector residual where
    # nothing is left out (10.6 against 11.5 nT); the run left out keeps its field
    # (vector 15.1 against 13.2 nT over the zone)
    from magcal.missions.elfin.joint import score_field

    for name in ("scalar_rms_nT", "scalar_fast_nT"):
        assert day_.scores[last][name].iloc[0] <= 1.02 * off.scores[last][name].iloc[0]
    out = day_.calibration.field["fit"].to_numpy() == 0
    quiet_on, quiet_off = day_.calibration.field.copy(), off.calibration.field.copy()
    quiet_on.loc[out, "used"] = 0
    quiet_off.loc[out, "used"] = 0
    assert (score_field(quiet_on)["vector_rms_nT"].iloc[0]
            <= 1.02 * score_field(quiet_off)["vector_rms_nT"].iloc[0])
    doc = day_.to_json()
    assert doc["settings"]["detect_disturbed"] is True
    assert doc["signal_trade"]["switches"]["detect_disturbed"] is True
    det = doc["disturbed_detection"]
    assert det["zones"][0]["flagged_share"] == pytest.approx(quiet[used].mean())
    runs = pd.DataFrame(det["runs"])
    assert (runs["kept"] == (runs["slow_change_nT"] >= runs["tone_change_nT"])).all()
    assert det["zones"][0]["kept_share"] <= det["zones"][0]["flagged_share"] + 1e-12


def test_a_run_the_bridge_check_rejects_goes_back_into_the_fits(day, monkeypatch):
    """The plumbing of the bridge check on zone 1: a run marked as not bridged is put
    back into every fit and the day calibrated again (on 2022-01-12 no run is rejected,
    so the rejection is forced here)."""
    import magcal.missions.elfin.disturbed as disturbed
    from magcal.missions.elfin.pipeline import ElfinSettings, calibrate_elfin_day

    fgs, state = day
    honest = calibrate_elfin_day(fgs, state, ElfinSettings(), diagnostics=False)
    left_out = honest.calibration.field["fit"].to_numpy() == 0
    assert left_out.any()                         # measured: 0.17 of the zone
    real = disturbed.bridge_check

    def reject_all(*args):
        return real(*args).assign(kept=False)

    monkeypatch.setattr(disturbed, "bridge_check", reject_all)
    forced = calibrate_elfin_day(fgs, state, ElfinSettings(), diagnostics=False)
    f = forced.calibration.field
    assert (f.loc[f["used"] == 1, "fit"] == 1).all()
    assert forced.steps["disturbed_detection"]["kept_share"].iloc[0] == 0.0
    assert not forced.steps["disturbed_runs"]["kept"].any()
    # with every run back in, the product is the one without detection
    plain = calibrate_elfin_day(fgs, state, ElfinSettings(detect_disturbed=False),
                                diagnostics=False).calibration.field
    cols = ["bx_gei", "by_gei", "bz_gei"]
    assert np.abs(f[cols].to_numpy() - plain[cols].to_numpy()).max() < 1e-6


def test_a_zone_its_flags_would_leave_unfittable_is_fitted_on_every_sample(day, monkeypatch):
    """Zone 1 with the detector forced to flag all but its first 150 samples (the
    linear fit needs 200): the day used to fail with an InputError. Now the zone's
    flags are dropped and said so, and its product is the one without detection
    (truth: the same rows calibrated with ``detect_disturbed = false``)."""
    from dataclasses import replace

    import magcal.missions.elfin.disturbed as disturbed
    from magcal.missions.elfin.pipeline import ElfinSettings, calibrate_elfin_day

    fgs, state = day
    real = disturbed.locate_disturbed

    def flag_nearly_all(*args, **kw):
        found = real(*args, **kw)
        most = np.arange(len(fgs)) >= 150
        return replace(found, vector=found.vector | most, scalar=found.scalar | most)

    monkeypatch.setattr(disturbed, "locate_disturbed", flag_nearly_all)
    s = ElfinSettings(bridge_trials=0, level_trials=0, pulse_trials=0)
    got = calibrate_elfin_day(fgs, state, s, diagnostics=False)
    f = got.calibration.field
    assert (f.loc[f["used"] == 1, "fit"] == 1).all()
    table = got.steps["disturbed_detection"]
    assert table["dropped"].all()
    assert table["drop_reason"].str.contains("linear fit fails without the flagged rows").all()
    assert got.to_json()["disturbed_detection"]["zones"][0]["drop_reason"].startswith(
        "the linear fit fails")
    assert any("not left out of the fits" in w for w in got.data_warnings())
    plain = calibrate_elfin_day(fgs, state, replace(s, detect_disturbed=False),
                                diagnostics=False).calibration.field
    cols = ["bx_gei", "by_gei", "bz_gei"]
    assert np.abs(f[cols].to_numpy() - plain[cols].to_numpy()).max() < 1e-6


def test_level_steps_keep_a_current_sheet_and_leave_pulses_and_the_clean_zone_alone(day):
    """``level_steps``: the spin-axis level may change across a left-out interval where
    the product without steps says so (:mod:`magcal.missions.elfin.levels`). Zone 1 with
    the detector: the east-west current sheet (300 nT to the zone's end; truth: the
    injected sheet) comes back >= 90 % (2.5 % without the switch), its error over its
    left-out samples within twice the stated bridge error (the trials step at their
    gaps too), the east-west pulse as without it (>= 90 %), and the clean zone gets
    no step."""
    from magcal.missions.elfin.injection import run_injections
    from magcal.missions.elfin.pipeline import ElfinSettings

    fgs, state = day
    s = ElfinSettings(level_steps=True, bridge_trials=3)
    tab, clean = run_injections(fgs, state, s, kinds=("sheet_ew", "gauss_ew"))
    last = tab["product"].iloc[-1]
    sheet = _row(tab, "sheet_ew", last)
    assert sheet["energy_kept"] >= 0.90
    assert sheet["distortion"] <= 0.10
    assert sheet["error_rms_nT"] <= 2.0 * sheet["bridge_rms_nT"]
    assert _row(tab, "gauss_ew", last)["energy_kept"] >= 0.90
    assert [z.n_level_steps for z in clean.linear.zones] == [0]
    assert clean.steps["vector_correction"]["n_level_steps"].tolist() == [0]
    assert clean.calibration.field["level_step"].sum() == 0
    assert clean.to_json()["signal_trade"]["switches"]["level_steps"] is True


def test_a_pulse_beside_the_zone_s_own_disturbance_no_longer_blinds_the_detector():
    """Zone 6 of 2022-01-12 with a -200 nT east-west pulse at 0.35 of the zone: the
    pulse (about 100-160 s) and the zone's real disturbance (about 250-320 s) bent the
    detector's baselines so far that its robust sigma rose from 1.7 to 38 nT and
    neither was flagged; the delivered product kept 43 % of the pulse's energy. With
    the blinding excursions left out of the spline fit (peel_gain) both are flagged and
    the pulse comes back whole (measured: 99.5 % of the energy)."""
    from magcal.missions.elfin.detect import DetectSettings, locate_disturbed
    from magcal.missions.elfin.files import read_elfin_fgs, read_elfin_state
    from magcal.missions.elfin.injection import select_zones
    from magcal.missions.elfin.pipeline import ElfinSettings, calibrate_elfin_day

    fgs = select_zones(read_elfin_fgs(real_data_path("elfin", FGS)), [6])
    state = read_elfin_state(real_data_path("elfin", STATE))
    s = ElfinSettings(bridge_trials=0, pulse_trials=0, level_trials=0)
    clean = calibrate_elfin_day(fgs, state, s, diagnostics=False)
    sig = -signal_gei("gauss_ew", clean.linear.field, state, centre=0.35)
    injected = inject_counts(fgs, clean.linear, {0: sig})
    energy = np.sum(sig ** 2, axis=1)
    f = clean.linear.field
    t = (f.index.asi8 - f.index.asi8[0]) / 1e9
    disturbance = (t > 270) & (t < 300)
    blind = locate_disturbed(injected, state, s, detect=DetectSettings(peel_gain=0.0))
    assert not blind.any.any()
    found = locate_disturbed(injected, state, s)
    assert energy[found.any].sum() >= 0.9 * energy.sum()
    assert found.any[disturbance].all()
    day = calibrate_elfin_day(injected, state, s, diagnostics=False)
    got = kept(day.calibration.field[["bx_gei", "by_gei", "bz_gei"]].to_numpy()
               - clean.calibration.field[["bx_gei", "by_gei", "bz_gei"]].to_numpy(), sig,
               f["used"].to_numpy() == 1)
    assert 0.9 <= got.energy <= 1.1


def test_target_counts_reads_the_whole_signal_per_polarity_and_the_own_part_per_case():
    """Closed form: two zones of one signal, both polarities. Zone 1 meets the targets
    for either sign; zone 2 loses energy for one sign only, while its own part (the odd
    columns, the same on both sign rows) keeps 0.92 with 0.12 distortion."""
    import pandas as pd

    from magcal.missions.elfin.injection import target_counts

    tab = pd.DataFrame({"signal": ["s"] * 4, "zone": [1, 2, 1, 2], "sign": [1, 1, -1, -1],
                        "energy_kept": [0.95, 0.70, 0.91, 1.10],
                        "distortion": [0.05, 0.08, 0.09, 0.11],
                        "energy_kept_odd": [0.93, 0.92, 0.93, 0.92],
                        "distortion_odd": [0.04, 0.12, 0.04, 0.12]})
    got = target_counts(tab).iloc[0].to_dict()
    assert got == {"signal": "s", "cases": 4, "energy": 3, "distortion": 3, "both": 2,
                   "odd_cases": 2, "odd_energy": 2, "odd_distortion": 1, "odd_both": 1}
    strict = target_counts(tab, min_energy=0.95, max_distortion=0.05).iloc[0]
    assert (strict["both"], strict["odd_both"]) == (1, 0)
    joined = tab.assign(energy_kept_odd_joined=[0.95, 0.93, 0.95, 0.93],
                        distortion_odd_joined=[0.03, 0.05, 0.03, 0.05])
    assert target_counts(joined).iloc[0]["joined_both"] == 2


def test_joined_left_out_rows_leave_the_signal_itself_as_the_odd_part():
    """Zone 4 of 2022-01-12 with a 200 nT east-west pulse at 0.65 of the zone: the
    detector ends the left-out interval at about 281 s for one polarity and 317 s for
    the other (the day's own field beside the pulse adds to one excursion and subtracts
    from the other), and the odd part carries what the fits make of those 35 s
    (distortion 0.19). Calibrated again with the union of both runs' left-out rows, the
    odd part is the injected pulse (truth): within 10 % of its energy and distortion
    under 10 % (measured 1.006 and 0.031)."""
    from magcal.missions.elfin.files import read_elfin_fgs, read_elfin_state
    from magcal.missions.elfin.injection import (
        joined_parts,
        left_out_rows,
        polarity_parts,
        select_zones,
    )
    from magcal.missions.elfin.pipeline import ElfinSettings, calibrate_elfin_day

    fgs = select_zones(read_elfin_fgs(real_data_path("elfin", FGS)), [4])
    state = read_elfin_state(real_data_path("elfin", STATE))
    # the interval left out as detected (a pulse across B fitted as a template instead
    # puts its rows back in the fits: nothing for the union to join)
    s = ElfinSettings(bridge_trials=0, pulse_trials=0, level_trials=0, pulses_perp=False)
    clean = calibrate_elfin_day(fgs, state, s, diagnostics=False)
    sig = signal_gei("gauss_ew", clean.linear.field, state, centre=0.65)
    counts = (inject_counts(fgs, clean.linear, {0: sig}),
              inject_counts(fgs, clean.linear, {0: -sig}))
    plus, minus = (calibrate_elfin_day(c, state, s, diagnostics=False) for c in counts)
    t = (fgs.index.asi8 - fgs.index.asi8[0]) / 1e9
    ends = [t[left_out_rows(d.calibration.field)
              & (d.calibration.field["used"].to_numpy() == 1)].max() for d in (plus, minus)]
    assert abs(ends[1] - ends[0]) > 20.0            # the premise: the ends differ (35 s)
    parts = polarity_parts(clean, plus, minus, {0: sig}, "gauss_ew").iloc[-1]
    assert parts["distortion_odd"] > 0.15            # ... and the odd part shows it (0.19)
    joined = joined_parts(counts, state, s, clean, plus, minus, {0: sig},
                          "gauss_ew").iloc[-1]
    assert joined["product"] == parts["product"] == "+ phase refit"
    assert 0.9 <= joined["energy_kept_odd_joined"] <= 1.1
    assert joined["distortion_odd_joined"] <= 0.10
    with pytest.raises(InputError, match="rows"):
        joined_parts((counts[0].iloc[:-1], counts[1]), state, s, clean, plus, minus,
                     {0: sig}, "gauss_ew")
