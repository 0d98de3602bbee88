"""Messy ELFIN input: clipped counts (saturation), fill, short and unattitude zones.

Synthetic truth for the clipping detector; then the real day (ELFIN-A 2022-01-12,
ELFIN SOC, PI V. Angelopoulos, UCLA) made messy on purpose, with the untouched day as
the reference: a bad zone must be reported and left out, never stop the day or spoil
the zones around it.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import real_data_path
from numpy.testing import assert_allclose

from magcal.errors import InputError
from magcal.missions.elfin.clipping import clipped_samples

FGS, STATE = "ela_l1_fgs_20220112_v01.cdf", "ela_l1_state_defn_20220112_v01.cdf"
COLS = ["bx_gei", "by_gei", "bz_gei"]


def _spinner(rng, n=3000, period_s=2.85, amp=4e6, noise=500.0):
    t = np.arange(n) * 0.1
    w = 2 * np.pi / period_s
    c = np.column_stack([amp * np.cos(w * t), 0.8 * amp * np.sin(w * t), 2e5 + 0 * t])
    return c + rng.normal(scale=noise, size=c.shape)


def test_clipped_samples_are_exactly_the_cut_tops():
    rng = np.random.default_rng(240)
    c = _spinner(rng)
    assert not clipped_samples(c).any()                       # noise never repeats a peak
    cut = 0.95 * np.abs(c[:, 1]).max()
    truth = np.abs(c[:, 1]) >= cut
    c[:, 1] = np.clip(c[:, 1], -cut, cut)
    flagged = clipped_samples(c)
    assert np.array_equal(flagged, truth)
    # closed form: a sine above 0.95 of its peak (noise aside) for 2 acos(0.95)/pi of
    # the time, about 10 %; the peak here is the noisy maximum, so a little less
    assert 0.06 < flagged.mean() < 2 * np.arccos(0.95) / np.pi + 0.01


def test_clipped_samples_known_limit_and_fill():
    c = np.array([[1.0, 5.0], [np.nan, 2.0], [3.0, 9.0], [2.0, -9.5]])
    assert clipped_samples(c, limit=9.0).tolist() == [False, False, True, True]
    assert not clipped_samples(c).any()                       # each extreme read once
    flat = np.ones((10, 1))                                   # a stuck axis: all flagged
    assert clipped_samples(flat).all()


@pytest.fixture(scope="module")
def elfin():
    from magcal.missions.elfin.files import read_elfin_fgs, read_elfin_state
    from magcal.missions.elfin.phase import split_zones

    fgs = read_elfin_fgs(real_data_path("elfin", FGS))
    state = read_elfin_state(real_data_path("elfin", STATE))
    ranges = split_zones((fgs.index.asi8 - fgs.index.asi8[0]) / 1e9)
    return fgs, state, ranges


def _plain():
    from magcal.missions.elfin.pipeline import ElfinSettings

    return ElfinSettings(detect_disturbed=False)


def test_saturated_axis_is_left_out_and_counted(elfin):
    from magcal.missions.elfin.linear import calibrate_elfin
    from magcal.missions.elfin.pipeline import calibrate_elfin_day

    fgs, state, ranges = elfin
    a, b = ranges[4]
    zone = fgs.iloc[a:b].copy()
    cut = 0.95 * np.abs(zone["b3"]).max()
    truth = (np.abs(zone["b3"]) >= cut).to_numpy()           # 631 samples, 17 %
    zone["b3"] = zone["b3"].clip(-cut, cut)
    lin = calibrate_elfin(zone, state)
    z = lin.zones[0]
    assert z.n_clipped == truth.sum() and z.n_timing_flagged == 0
    used = lin.field["used"].to_numpy() == 1
    assert not (used & truth).any()
    assert lin.to_json()["summary"]["n_clipped"] == truth.sum()
    # left in, the flat tops spoil the linear fit (measured 477 against 95 nT |B|)
    blind = calibrate_elfin(zone, state, check_clipping=False).zones[0]
    assert blind.rms_scalar_nT > 3 * z.rms_scalar_nT
    # the delivered |B| is no worse than the untouched zone's (6.2 nT; 6.1 measured)
    clean = calibrate_elfin_day(fgs.iloc[a:b], state, _plain(), diagnostics=False)
    day = calibrate_elfin_day(zone, state, _plain(), diagnostics=False)
    last = list(day.medians())[-1]
    assert day.medians()[last]["scalar_rms_nT"] <= clean.medians()[last]["scalar_rms_nT"] + 0.3
    assert any("clipped extreme" in line and "631" in line for line in day.data_warnings())


def test_short_stub_zone_is_skipped_and_its_rows_delivered(elfin):
    from magcal.missions.elfin.pipeline import calibrate_elfin_day

    fgs, state, ranges = elfin
    sub = fgs.iloc[ranges[4][0]:ranges[5][1]]
    n4 = ranges[4][1] - ranges[4][0]
    # a 70 s gap leaves a 10 s stub of zone 4 on its own (100 samples, fewer than 200)
    messy = sub.drop(sub.index[n4 - 800:n4 - 100])
    day = calibrate_elfin_day(messy, state, diagnostics=False)       # delivered settings
    skipped = day.calibration.skipped
    assert [(z.zone, z.n_samples) for z in skipped] == [(1, 100)]
    assert "fewer than 200" in skipped[0].reason
    assert day.to_json()["summary"]["n_zones_skipped"] == 1
    table = day.calibrated_table()
    assert len(table) == len(messy)                   # times: as repaired by the calibration
    stub = table["zone"].to_numpy() == 1
    assert table.index[stub].equals(messy.index[n4 - 800:n4 - 700])
    assert (table["used"].to_numpy()[stub] == 0).all()
    assert np.isnan(table[COLS].to_numpy()[stub]).all()
    assert any("not calibrated" in line for line in day.data_warnings())
    # the other zones come out exactly as when the stub's rows were never there; zone
    # 2 keeps its number
    keep = ~messy.index.isin(messy.index[n4 - 800:n4 - 700])
    alone = calibrate_elfin_day(messy[keep], state, diagnostics=False).calibrated_table()
    kept = table[~stub]
    assert sorted(kept["zone"].unique()) == [0, 2]
    assert_allclose(kept[COLS].to_numpy(), alone[COLS].to_numpy(), atol=1e-6)


def test_fill_zone_and_zone_without_attitude_are_skipped(elfin):
    from magcal.missions.elfin.pipeline import calibrate_elfin_day

    fgs, state, ranges = elfin
    a, b = ranges[4][0], ranges[6][1]
    sub = fgs.iloc[a:b].copy()
    n4 = ranges[4][1] - ranges[4][0]
    sub.iloc[:n4] = np.nan                                    # zone 4 all fill
    t5 = fgs.index[ranges[5][0]], fgs.index[ranges[5][1] - 1]
    state_gap = state.copy()
    inside = (state.index >= t5[0] - np.timedelta64(10, "s")) & \
        (state.index <= t5[1] + np.timedelta64(10, "s"))
    state_gap.loc[inside, ["spin_axis_gei_x", "spin_axis_gei_y", "spin_axis_gei_z"]] = np.nan
    day = calibrate_elfin_day(sub, state_gap, _plain(), diagnostics=False)
    reasons = {z.zone: z.reason for z in day.calibration.skipped}
    assert sorted(reasons) == [0, 1]
    assert "0 samples" in reasons[0] and "attitude" in reasons[1]
    only = calibrate_elfin_day(fgs.iloc[ranges[6][0]:ranges[6][1]], state, _plain(),
                               diagnostics=False).calibrated_table()
    table = day.calibrated_table()
    assert len(table) == len(sub)
    assert_allclose(table[table["zone"] == 2][COLS].to_numpy(), only[COLS].to_numpy(),
                    atol=1e-6)
    with pytest.raises(InputError, match="no science zone could be calibrated"):
        calibrate_elfin_day(sub.iloc[:n4], state, _plain(), diagnostics=False)


@pytest.mark.realdata
@pytest.mark.slow
def test_messy_copy_through_the_cli(tmp_path, capsys):
    """workflows/elfin_messy.py, then ``magcal run`` on its copy: every fault reported,
    every row delivered, the untouched zones as on the clean day."""
    import glob
    import importlib.util

    import pandas as pd
    from conftest import REPO_ROOT

    from magcal.cli import main

    real_data_path("elfin", FGS)
    spec = importlib.util.spec_from_file_location(
        "wf_elfin_messy", REPO_ROOT / "workflows" / "elfin_messy.py")
    wf = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(wf)
    assert wf.main([str(tmp_path)]) == 0
    assert main(["run", str(tmp_path / "ELFIN_messy.toml"), "-o", str(tmp_path / "run")]) == 0
    err = capsys.readouterr().err
    assert "zone 7 (" in err and "zone 10 (" in err and "not calibrated" in err
    assert "631 of 3726 samples (17%) read a clipped extreme" in err
    table = pd.read_csv(glob.glob(str(tmp_path / "run" / "**" / "elfin_calibrated.csv"),
                                  recursive=True)[0], index_col=0)
    assert len(table) == 43594 - 700                        # every row read is delivered
    fill = table["zone"].to_numpy() == 7
    assert fill.sum() == 3713 and (table["used"].to_numpy()[fill] == 0).all()
    # spikes: 40 injected in zone 1, none used (the zone's other flags are the clean
    # day's 20 turn-on samples)
    assert (table["used"].to_numpy()[table["zone"].to_numpy() == 1] == 0).sum() >= 40 + 20
