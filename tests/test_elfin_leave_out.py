"""The product's change when a signal's rows are left out, no signal added
(magcal.missions.elfin.leave_out), against what an injection with those rows left out
returns on top of the injected signal (the truth). Real day, skipped with a reason when
../shared/real-data is absent."""

import pytest
from conftest import real_data_path

from magcal.errors import InputError

FGS = "ela_l1_fgs_20220112_v01.cdf"
STATE = "ela_l1_state_defn_20220112_v01.cdf"
# one process computes the module's fixtures once
pytestmark = pytest.mark.xdist_group("elfin_leave_out")


@pytest.fixture(scope="module")
def elfin_day():
    from magcal.missions.elfin.files import read_elfin_fgs, read_elfin_state

    return (read_elfin_fgs(real_data_path("elfin", FGS)),
            read_elfin_state(real_data_path("elfin", STATE)))


@pytest.fixture(scope="module")
def zone4_effect(elfin_day):
    """Zone 4, no detection: the leave-out effect of an east-west 40 s pulse at
    mid-zone, and the settings it was measured with."""
    from magcal.missions.elfin.leave_out import leave_out_effect
    from magcal.missions.elfin.pipeline import ElfinSettings

    fgs, state = elfin_day
    s = ElfinSettings(detect_disturbed=False)
    return s, leave_out_effect(fgs, state, s, kinds=("gauss_ew",), zones=[4]).iloc[0]


def test_the_leave_out_effect_is_what_a_detector_flagging_exactly_the_signal_leaves(
        elfin_day, zone4_effect):
    """Zone 4 of 2022-01-12, no detection: an east-west 200 nT, 40 s pulse injected with
    its rows above 5 % of its peak left out of the injected run's fits comes back with
    gain g and distortion d against the injected pulse. Leaving the same rows out of
    the clean counts' fits, with nothing injected, must give the same g and d within
    0.02 (the pulse's tails under 5 % are fitted in the injection and can be taken
    there; nothing else differs; measured d 0.196 and 0.192, g 1.040 and 1.034). The
    premise: that change is not small (d > 0.1)."""
    from magcal.missions.elfin.injection import run_injections

    fgs, state = elfin_day
    s, effect = zone4_effect
    tab = run_injections(fgs, state, s, kinds=("gauss_ew",), zones=[4], mask_signal=0.05,
                         mask_clean=False)[0]
    injected = tab[tab["product"] == effect["product"]].iloc[0]
    assert effect["zone"] == injected["zone"] == 4
    assert effect["distortion"] > 0.10
    assert abs(effect["distortion"] - injected["distortion"]) < 0.02
    assert abs(effect["gain"] - injected["gain"]) < 0.02
    assert 60.0 < effect["left_out_s"] < 100.0          # 5 % of a 40 s FWHM Gaussian: 83 s
    assert effect["amplitude_for_target_nT"] == pytest.approx(
        200.0 * effect["distortion"] / 0.1)


def test_the_leave_out_effect_falls_as_one_over_the_amplitude(elfin_day, zone4_effect):
    """The rows left out do not depend on the pulse's amplitude, so the change they
    make is the same and its share of a 2.5 times larger pulse (500 nT) is the share
    of the 200 nT one over 2.5 (closed form). An injected 500 nT pulse with those rows
    left out (the truth) comes back with that distortion within 0.01 (zone 4, no
    detection: 0.196 / 2.5 = 0.078)."""
    from magcal.missions.elfin.injection import run_injections
    from magcal.missions.elfin.leave_out import leave_out_effect

    fgs, state = elfin_day
    s, one = zone4_effect
    tab, clean = run_injections(fgs, state, s, kinds=("gauss_ew",), zones=[4],
                                mask_signal=0.05, mask_clean=False, scale=2.5)
    # the injection's clean day reused: the closed form below holds only if it is the
    # clean day leave_out_effect calibrates itself
    big = leave_out_effect(fgs, state, s, kinds=("gauss_ew",), zones=[4], scale=2.5,
                           clean=clean).iloc[0]
    assert big["distortion"] == pytest.approx(one["distortion"] / 2.5, rel=1e-9)
    assert big["gain"] - 1.0 == pytest.approx((one["gain"] - 1.0) / 2.5, rel=1e-9)
    assert big["left_out_s"] == one["left_out_s"]
    assert big["amplitude_for_target_nT"] == pytest.approx(one["amplitude_for_target_nT"])
    injected = tab[tab["product"] == big["product"]].iloc[0]
    assert abs(injected["distortion"] - big["distortion"]) < 0.01
    with pytest.raises(InputError, match="scale"):
        run_injections(fgs, state, s, kinds=("gauss_ew",), zones=[4], scale=-1.0)
    with pytest.raises(InputError, match="rows"):
        leave_out_effect(fgs, state, s, zones=[3], clean=clean)


def test_nothing_left_out_changes_nothing(elfin_day):
    """A share above the peak leaves no row out: the product is the clean one exactly
    (gain 1, distortion 0, no shift)."""
    from magcal.missions.elfin.leave_out import leave_out_effect
    from magcal.missions.elfin.pipeline import ElfinSettings

    fgs, state = elfin_day
    row = leave_out_effect(fgs, state, ElfinSettings(detect_disturbed=False),
                           kinds=("gauss_ew",), zones=[4], fraction=1.5).iloc[0]
    assert row["gain"] == pytest.approx(1.0, abs=1e-9)
    assert row["distortion"] == pytest.approx(0.0, abs=1e-9)
    assert row["zone_shift_nT"] == pytest.approx(0.0, abs=1e-9)
    assert row["left_out_s"] == 0.0
