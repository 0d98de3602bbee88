"""Pulses across B fitted as natural-field templates (magcal.missions.elfin.perp).

Closed-form cases with known truth (a noisy Gaussian on a linear baseline gives back
its centre, width and amplitude; the acceptance tests keep a pulse across B and turn
down a pulse along B, a wide bump and a pulse cut by the zone's end), and on the real
day: the option off leaves the delivered product as it is, and a 200 nT 40 s east-west
pulse injected into the counts comes back whole with less distortion than leaving its
rows out can give.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pandas as pd
import pytest

from conftest import real_data_path
from magcal.missions.elfin.perp import fit_gaussian, find_perp_pulses, without_templates
from magcal.missions.elfin.pulses import gaussian

FGS = "ela_l1_fgs_20220112_v01.cdf"
STATE = "ela_l1_state_defn_20220112_v01.cdf"
# the real-data tests share one module fixture: one process
pytestmark = pytest.mark.xdist_group("elfin_perp")

T = np.arange(0.0, 370.0, 0.2)          # one ELFIN zone at 5 Hz
AMP = np.array([120.0, -150.0, 40.0])   # nT, |AMP| 196 nT


def test_a_noisy_gaussian_gives_back_its_shape():
    """200 nT, 40 s FWHM on a linear baseline with 5 nT white noise per component
    (the clean day's residual over a minute is of that size): the Cramer-Rao spread
    of the centre and width is about 0.05 s and of the amplitude about 0.5 nT, so the
    tolerances (0.5 s, 1 s, 3 nT) are several of those wide and still far inside what
    matters (a 1 s width error is a 2.5 % shape error)."""
    rng = np.random.default_rng(24)
    window = (T > 120.0) & (T < 260.0)
    t = T[window]
    r = (np.outer(gaussian(t, 187.0, 40.0), AMP) + np.outer(t - 190.0, [0.2, -0.1, 0.05])
         + 30.0 + rng.normal(0.0, 5.0, (t.size, 3)))
    p = fit_gaussian(t, r, 195.0, 60.0)
    assert p["centre_s"] == pytest.approx(187.0, abs=0.5)
    assert p["fwhm_s"] == pytest.approx(40.0, abs=1.0)
    assert np.abs(p["amplitude"] - AMP).max() < 3.0
    assert p["share"] > 0.95


def _field(pulse_nT, along=None) -> pd.DataFrame:
    """One calibrated zone: IGRF along x (45000 nT), the product IGRF plus ``pulse_nT``
    (n, 3) plus 3 nT of seeded noise, nothing left out but what the runs say."""
    rng = np.random.default_rng(5)
    idx = pd.date_range("2022-01-12T05:00:00", periods=T.size, freq="200ms", tz="UTC",
                        name="time")
    ref = np.zeros((T.size, 3))
    ref[:, 0] = 45000.0
    b = ref + pulse_nT + rng.normal(0.0, 3.0, (T.size, 3))
    data = {"zone": 4, "used": 1, "level_step": 0}
    data.update({f"b{c}_gei": b[:, j] for j, c in enumerate("xyz")})
    data.update({f"igrf_{c}_gei": ref[:, j] for j, c in enumerate("xyz")})
    if along is not None:
        data["pulse_b_1"] = along
    return pd.DataFrame(data, index=idx)


def _runs(start, end) -> pd.DataFrame:
    return pd.DataFrame({"zone": [4], "start_s": [start], "end_s": [end], "kept": [True]})


def test_a_pulse_across_b_is_accepted_and_others_are_not():
    across = np.outer(gaussian(T, 185.0, 40.0), [0.0, 160.0, -120.0])
    p = find_perp_pulses(_field(across), _runs(145.0, 226.0))
    assert bool(p["accepted"][0]) and p["why"][0] == ""
    assert p["centre_s"][0] == pytest.approx(185.0, abs=0.5)
    assert p["height_nT"][0] == pytest.approx(200.0, abs=3.0)
    # along B (x): left to pulses_b
    along = np.outer(gaussian(T, 185.0, 40.0), [200.0, 0.0, 0.0])
    p = find_perp_pulses(_field(along), _runs(145.0, 226.0))
    assert not bool(p["accepted"][0]) and "along B" in p["why"][0]
    # a bump of 200 s FWHM: a slow change, not a pulse
    wide = np.outer(gaussian(T, 185.0, 200.0), [0.0, 160.0, -120.0])
    p = find_perp_pulses(_field(wide), _runs(100.0, 270.0))
    assert not bool(p["accepted"][0]) and "FWHM" in p["why"][0]
    # cut by the zone's end
    cut = np.outer(gaussian(T, 360.0, 40.0), [0.0, 160.0, -120.0])
    p = find_perp_pulses(_field(cut), _runs(320.0, 369.0))
    assert not bool(p["accepted"][0]) and "inside the zone" in p["why"][0]
    # a run that overlaps a kept pulse along B is not fitted again
    p = find_perp_pulses(_field(across, along=gaussian(T, 185.0, 40.0)), _runs(145.0, 226.0))
    assert not bool(p["accepted"][0]) and p["why"][0] == "a pulse along B"


def test_the_delivered_reference_is_igrf_alone():
    """The template added to the reference during the fits is taken off again in GEI
    and in the despun frame."""
    f = _field(np.zeros((T.size, 3)))
    f = f.assign(spin_axis_gei_x=0.0, spin_axis_gei_y=1.0, spin_axis_gei_z=0.0,
                 igrf_x_despun=0.0, igrf_y_despun=0.0, igrf_z_despun=0.0)
    pulses = pd.DataFrame({"zone": [4], "start": [f.index[0]], "centre_s": [185.0],
                           "fwhm_s": [40.0], "amp_x_nT": [0.0], "amp_y_nT": [100.0],
                           "amp_z_nT": [0.0]})
    g = without_templates(f, pulses)
    k = int(np.argmin(np.abs(T - 185.0)))
    assert g["igrf_y_gei"].iloc[k] == pytest.approx(-100.0, abs=1e-6)
    assert g["igrf_z_despun"].iloc[k] == pytest.approx(-100.0, abs=1e-6)   # Z: spin axis
    assert g["igrf_x_gei"].iloc[k] == pytest.approx(45000.0)


@pytest.fixture(scope="module")
def zone4():
    from magcal.missions.elfin.files import ns_index, read_elfin_fgs, read_elfin_state
    from magcal.missions.elfin.injection import select_zones

    fgs = read_elfin_fgs(real_data_path("elfin", FGS))
    state = read_elfin_state(real_data_path("elfin", STATE))
    return select_zones(ns_index(fgs, "FGS"), [4]), ns_index(state, "state")


@pytest.mark.slow
@pytest.mark.realdata
def test_option_off_is_the_delivered_product(zone4):
    """``pulses_perp`` is on by default; on a zone where nothing is detected it changes
    nothing (no pulse fitted, the product of the option off)."""
    from magcal.missions.elfin.pipeline import ElfinSettings, calibrate_elfin_day

    fgs, state = zone4
    s = ElfinSettings(bridge_trials=0, pulse_trials=0, level_trials=0)
    assert s.pulses_perp
    off = calibrate_elfin_day(fgs, state, replace(s, pulses_perp=False), diagnostics=False)
    on = calibrate_elfin_day(fgs, state, s, diagnostics=False)
    pd.testing.assert_frame_equal(off.calibration.field, on.calibration.field)
    assert "pulses_perp" not in off.to_json() and on.to_json()["pulses_perp"]["pulses"] == []


@pytest.mark.slow
@pytest.mark.realdata
def test_an_east_west_pulse_beats_the_leave_out_floor(zone4):
    """A 200 nT 40 s east-west pulse at the middle of zone 4: with the option it comes
    back with 0.9-1.1 of its energy and a whole-signal distortion under half of what
    leaving exactly its rows out does to the same zone's calibration (the floor of any
    detect-and-leave-out product, :mod:`magcal.missions.elfin.leave_out`) and within
    the issue's 10 %. On 2022-01-12 the floor there is 0.31, the delivered product
    0.16 and the template 0.05: half the floor and the target leave room for a
    changed detector or fit, and still fail a template no better than leaving out."""
    from magcal.missions.elfin.injection import run_injections
    from magcal.missions.elfin.leave_out import leave_out_effect
    from magcal.missions.elfin.pipeline import ElfinSettings

    fgs, state = zone4
    s = ElfinSettings(bridge_trials=0, pulse_trials=0, level_trials=0, pulses_perp=True)
    tab, clean = run_injections(fgs, state, s, kinds=("gauss_ew",), centre=0.5)
    got = tab[tab["product"] == tab["product"].iloc[-1]].iloc[0]
    floor = leave_out_effect(fgs, state, replace(s, pulses_perp=False),
                             kinds=("gauss_ew",), centres=(0.5,))
    floor = floor[floor["product"] == floor["product"].iloc[-1]]["distortion"].iloc[0]
    assert 0.9 <= got["energy_kept"] <= 1.1
    assert got["distortion"] < 0.5 * floor
    assert got["distortion"] <= 0.1


@pytest.mark.slow
@pytest.mark.realdata
def test_a_backfit_that_does_not_settle_keeps_the_delivered_product(zone4, monkeypatch):
    """With a tolerance no correction meets, the zone's pulse is fitted, its backfit
    runs out of iterations and the interval stays left out: the delivered product, with
    the reason in the table."""
    from magcal.missions.elfin import perp
    from magcal.missions.elfin.injection import inject_counts, signal_gei
    from magcal.missions.elfin.pipeline import ElfinSettings, calibrate_elfin_day

    fgs, state = zone4
    s = ElfinSettings(bridge_trials=0, pulse_trials=0, level_trials=0, pulses_perp=False)
    clean = calibrate_elfin_day(fgs, state, s, diagnostics=False)
    f = clean.linear.field
    injected = inject_counts(fgs, clean.linear, {0: signal_gei("gauss_ew", f, state)})
    monkeypatch.setattr(perp, "TOL_NT", 1e-12)
    monkeypatch.setattr(perp, "TOL_SHARE", 0.0)
    monkeypatch.setattr(perp, "MAX_ITER", 2)
    on = calibrate_elfin_day(injected, state, replace(s, pulses_perp=True),
                             diagnostics=False)
    off = calibrate_elfin_day(injected, state, s, diagnostics=False)
    pd.testing.assert_frame_equal(off.calibration.field, on.calibration.field)
    table = on.steps["pulses_perp"]
    fitted = table[table["accepted"].astype(bool)]
    assert len(fitted) == 1 and not fitted["kept"].iloc[0]
    assert fitted["iterations"].iloc[0] == 2 and "did not settle" in fitted["why"].iloc[0]


@pytest.mark.slow
@pytest.mark.realdata
def test_a_kept_pulse_states_an_error_of_its_size():
    """Zones 3-5 with a 200 nT 40 s east-west pulse in zone 4: the pulse is kept as a
    template, and its stated error (``perp_trials``: a pulse like it put into zones 3
    and 5 at the same place) is finite, on exactly the pulse's rows of the calibrated
    table (``pulse_error_nT``), covers the actual error of the kept pulse against the
    injected truth (one draw: within twice the stated RMS, the 95 % range of a normal
    error) and says something (under a fifth of the pulse's own RMS over those rows,
    about 20 nT: an error of the pulse's size would state nothing). On 2022-01-12 the
    stated error is 15 nT and the actual 4 nT."""
    from magcal.missions.elfin.files import ns_index, read_elfin_fgs, read_elfin_state
    from magcal.missions.elfin.injection import inject_counts, select_zones, signal_gei
    from magcal.missions.elfin.perp import REACH_FWHM
    from magcal.missions.elfin.pipeline import ElfinSettings, calibrate_elfin_day

    fgs = select_zones(ns_index(read_elfin_fgs(real_data_path("elfin", FGS)), "FGS"),
                       [3, 4, 5])
    state = ns_index(read_elfin_state(real_data_path("elfin", STATE)), "state")
    s = ElfinSettings(bridge_trials=0, pulse_trials=0, level_trials=0, perp_trials=2)
    clean = calibrate_elfin_day(fgs, state, replace(s, perp_trials=0), diagnostics=False)
    f = clean.linear.field
    zone = f["zone"].to_numpy()
    truth = signal_gei("gauss_ew", f[zone == 1], state)
    day = calibrate_elfin_day(inject_counts(fgs, clean.linear, {1: truth}), state, s,
                              diagnostics=False)
    trials = day.steps["perp_trials"]
    assert len(trials) == 1 and trials["zone"].iloc[0] == 1
    stated = float(trials["error_rms_nT"].iloc[0])
    assert len(trials["trial_errors_nT"].iloc[0]) == 2 and np.isfinite(stated)
    table = day.calibrated_table()
    mine = np.flatnonzero(zone == 1)
    centre = pd.Timestamp(trials["centre"].iloc[0], tz="UTC").value
    near = np.abs(f.index.as_unit("ns").asi8[mine] - centre) / 1e9 \
        <= REACH_FWHM * trials["fwhm_s"].iloc[0]
    marked = np.isfinite(table["pulse_error_nT"].to_numpy())
    assert np.array_equal(np.flatnonzero(marked), mine[near])
    cols = ["bx_gei", "by_gei", "bz_gei"]
    rec = (table[cols].to_numpy()[mine] - clean.calibrated_table()[cols].to_numpy()[mine])
    actual = float(np.sqrt(np.mean(np.sum((rec - truth)[near] ** 2, axis=1))))
    own = float(np.sqrt(np.mean(np.sum(truth[near] ** 2, axis=1))))
    assert actual <= 2.0 * stated, (stated, actual)
    assert stated <= 0.2 * own, (stated, own)
