"""Offsets split at the level changes found (``split_at_level_changes``, opt-in): no
window mixes both levels, ``offsets apply`` interpolates within a segment only, and the
samples inside a change's 95 % time interval get quality bit 256."""

import numpy as np
import pandas as pd
import pytest

from magcal.offsets import OffsetEstimator
from magcal.offsets.table import read_offsets_csv, write_offsets_csv
from test_offsets_levels import STEP, STEP_TIME, TRUTH, _record

DAY = np.timedelta64(1, "D")


@pytest.fixture(scope="module")
def stepped():
    """The 120-day record of test_offsets_levels (seed 7: a 3 / -1.8 / 1.2 nT step at
    day 61.4, found on 2020-03-03, 95 %: 03-01 .. 03-04) fitted both ways."""
    t, diff, kp = _record(7, step=STEP)
    zeros = np.zeros_like(diff)
    plain = OffsetEstimator(min_used=100).fit(t, diff, zeros, kp)
    split = OffsetEstimator(min_used=100, split_at_level_changes=True).fit(t, diff, zeros, kp)
    return t, diff, kp, plain, split


def test_split_offsets_hold_each_side_level_within_their_errors(stepped):
    """Each valid row of the split product against the true level of its side: all
    within 1.5 half-widths of their 95 % intervals and at least 85 % within one (measured
    on this record: largest 0.97, 89.5 % within; the rows overlap, so they are not 40
    independent trials). No row straddles the change, no row's reason cautions that it
    mixes levels, and the short pieces by the change are NaN with the reason."""
    tab = stepped[4].table_
    assert len(tab.level_changes) == 1
    change = tab.level_changes[0].time
    assert abs(change - STEP_TIME) <= DAY
    np.testing.assert_array_equal(tab.segment, (tab.start >= change).astype(int))
    assert not np.any((tab.start < change) & (change < tab.end))
    true = np.where(tab.segment[:, None] == 0, TRUTH, TRUTH + STEP)
    ratio = np.abs(tab.offset_nT - true)[tab.valid] / tab.interval95()[tab.valid]
    assert np.all(ratio <= 1.5), ratio.max(axis=0)
    assert np.mean(ratio <= 1.0) >= 0.85
    length = (tab.end - tab.start) / DAY
    short = length < 7
    assert short.any() and not np.any(tab.valid[short])
    assert all(r.startswith("piece of ") and "shorter than 7" in r
               for r in np.asarray(tab.reason)[short])
    assert not any("inside the window" in r and r.startswith("caution: level change")
                   for r in tab.reason)
    assert tab.parameters["split_at_level_changes"] is True
    assert stepped[3].table_.parameters["split_at_level_changes"] is False


def test_apply_does_not_blend_across_the_change(stepped):
    """3 and 5 days either side of the true step the split product applies that side's
    level within 0.5 nT (measured: 0.38 at most), where the default product blends the
    levels (Hp off by about 1 nT there); samples on either side take their own segment's
    offsets only, with no quality bit 128."""
    from magcal.offsets import across_level_change

    t, diff, _, plain, split = stepped
    truth = TRUTH + STEP * (t >= STEP_TIME)[:, None]
    at = np.searchsorted(t, [STEP_TIME + d * DAY for d in (-5, -3, 3, 5)])
    err_split = split.apply(t, diff)[1][at] - truth[at]
    err_plain = plain.apply(t, diff)[1][at] - truth[at]
    assert np.all(np.abs(err_split) < 0.5), err_split
    assert np.all(np.abs(err_plain[:, 0]) > 0.8), err_plain
    assert not across_level_change(t, split.table_).any()
    # the flag: held at the segment's ends, out to the change
    change = split.table_.level_changes[0].time
    flag = split.apply(t, diff)[2]
    seg0 = split.table_.center[split.table_.valid & (split.table_.segment == 0)]
    seg1 = split.table_.center[split.table_.valid & (split.table_.segment == 1)]
    held = ((t > seg0[-1]) & (t < change)) | ((t >= change) & (t < seg1[0]))
    np.testing.assert_array_equal(np.isin(flag, (1, 2))[~((t < seg0[0]) | (t > seg1[-1]))],
                                  held[~((t < seg0[0]) | (t > seg1[-1]))])


def test_near_change_bit_exactly_inside_the_interval(stepped):
    """Quality bit 256 (``offset_near_level_change``) on the samples in [time_lo,
    time_hi) of the change, none elsewhere; none for the unsplit product."""
    from magcal.offsets.apply import near_level_change, quality_bits
    from magcal.qc.flags import FLAG_NAMES

    t, _, _, plain, split = stepped
    ch = split.table_.level_changes[0]
    edges = np.array([ch.time_lo - np.timedelta64(1, "ns"), ch.time_lo, ch.time,
                      ch.time_hi - np.timedelta64(1, "ns"), ch.time_hi]).astype("datetime64[ns]")
    np.testing.assert_array_equal(near_level_change(edges, split.table_),
                                  [False, True, True, True, False])
    near = near_level_change(t, split.table_)
    np.testing.assert_array_equal(near, (t >= ch.time_lo) & (t < ch.time_hi))
    bits = quality_bits(split.apply(t, np.zeros((t.size, 3)))[2], near_change=near)
    np.testing.assert_array_equal((bits & 256) > 0, near)
    assert FLAG_NAMES[256] == "offset_near_level_change"
    assert not near_level_change(t, plain.table_).any()


def test_segment_round_trips_and_a_file_without_it_reads_as_before(stepped, tmp_path):
    """OFFSETS.csv of the split product ends with ``segment``; read back (with or
    without its JSON sidecar) it applies the same offsets and names the change. The
    default product has no ``segment`` column and reads with ``segment`` None."""
    t, diff, _, plain, split = stepped
    path = write_offsets_csv(tmp_path / "OFFSETS.csv", split.table_)
    assert pd.read_csv(path).columns[-1] == "segment"
    back = read_offsets_csv(path)
    np.testing.assert_array_equal(back.segment, split.table_.segment)
    np.testing.assert_allclose(_applied(t, diff, back), split.apply(t, diff)[1], atol=1e-3)
    (tmp_path / "OFFSETS.csv.provenance.json").unlink()
    bare = read_offsets_csv(path)
    assert [c.time for c in bare.level_changes] == [split.table_.level_changes[0].time]
    np.testing.assert_allclose(_applied(t, diff, bare), split.apply(t, diff)[1], atol=1e-3)
    default = write_offsets_csv(tmp_path / "DEFAULT.csv", plain.table_)
    assert "segment" not in pd.read_csv(default).columns
    assert read_offsets_csv(default).segment is None


def _applied(t, diff, table):
    from magcal.offsets import apply_offsets

    return apply_offsets(t, diff, table)[1]


def test_without_a_change_the_split_product_is_the_default_one(tmp_path):
    """A record without a step (none found): the option changes no number; the file is
    the default one with a ``segment`` column of zeros appended."""
    t, diff, kp = _record(41, days=100, tau_s=6 * 3600.0)
    zeros = np.zeros_like(diff)
    plain = OffsetEstimator(min_used=100).fit(t, diff, zeros, kp)
    split = OffsetEstimator(min_used=100, split_at_level_changes=True).fit(t, diff, zeros, kp)
    assert plain.level_test_["tested"] and not split.level_changes_
    a = write_offsets_csv(tmp_path / "A.csv", plain.table_).read_text().splitlines()
    b = write_offsets_csv(tmp_path / "B.csv", split.table_).read_text().splitlines()
    assert [f"{line},segment" if k == 0 else f"{line},0" for k, line in enumerate(a)] == b
    np.testing.assert_array_equal(plain.apply(t, diff)[1], split.apply(t, diff)[1])


def test_split_windows_keep_centres_strictly_increasing():
    """Two changes inside one window: its middle piece equals other windows' middle
    pieces; one is kept, and the centres stay strictly increasing."""
    from magcal.offsets.windows import DAY_NS, split_windows, window_grid

    s, e = window_grid(0, 80 * DAY_NS, 28, 7)
    s2, e2, seg, _ = split_windows(s, e, [30 * DAY_NS, 40 * DAY_NS])
    c = s2 + (e2 - s2) // 2
    assert np.all(np.diff(c) > 0)
    assert np.all(np.diff(seg) >= 0)
    assert sum((a, b) == (30 * DAY_NS, 40 * DAY_NS) for a, b in zip(s2, e2)) == 1
    for a, b, g in zip(s2, e2, seg):
        assert not (a < 30 * DAY_NS < b or a < 40 * DAY_NS < b)
        assert g == int(a >= 30 * DAY_NS) + int(a >= 40 * DAY_NS)


def test_cli_fit_split_and_apply(tmp_path, capsys):
    """``offsets fit --split-at-level-changes`` on a 120-day 5-min record (T89 plus the
    offset with a step twice the other tests', a 1-hour model miss): OFFSETS.csv has
    ``segment`` and the provenance records the option; ``offsets apply`` counts the
    samples near the change and none interpolated across it; the corrected data 3 days
    either side of the step are within 0.5 nT of the truth (the model field is removed
    exactly)."""
    from magcal.cli import main
    from magcal.indices import write_kp_csv
    from magcal.io.csv import write_csv_frame
    from magcal.models.field import model_field_hpen

    t, diff, _ = _record(7, step=2 * STEP)
    kp_times = pd.date_range(str(t[0])[:10], periods=int(120 * 8) + 8, freq="3h")
    rng = np.random.default_rng(1)
    kp = pd.Series(np.where(rng.random(kp_times.size) < 0.7, 0.0, 3.0), index=kp_times)
    kp_at = kp.to_numpy()[((t - t[0]) // np.timedelta64(3, "h")).astype(int)]
    model = model_field_hpen(t, 128.2, 0.0, 6.6, model="T89", kp=kp_at, cadence_s=None,
                             n_jobs=1).b_hpen_nT
    frame = pd.DataFrame(model + diff, columns=["Hp", "He", "Hn"],
                         index=pd.DatetimeIndex(t, name="time").tz_localize("UTC"))
    write_csv_frame(tmp_path / "DATA.csv", frame)
    write_kp_csv(tmp_path / "KP.csv", kp.tz_localize("UTC"), thirds=True)
    args = ["offsets", "fit", str(tmp_path / "DATA.csv"), "--kp", str(tmp_path / "KP.csv"),
            "--longitude", "128.2", "--jobs", "1", "--min-used", "100"]
    capsys.readouterr()
    assert main(args + ["--split-at-level-changes", "-o", str(tmp_path / "OFF.csv")]) == 0
    err = capsys.readouterr().err
    assert "1 level change of the offset, windows split at it" in err
    off = pd.read_csv(tmp_path / "OFF.csv")
    assert off.columns[-1] == "segment" and set(off["segment"]) == {0, 1}
    side = (tmp_path / "OFF.csv.provenance.json").read_text()
    assert '"split_at_level_changes": true' in side
    assert main(["offsets", "apply", str(tmp_path / "DATA.csv"), "--offsets",
                 str(tmp_path / "OFF.csv"), "-o", str(tmp_path / "CORR.csv")]) == 0
    err = capsys.readouterr().err
    assert "samples lie inside a change's 95 % time interval" in err
    assert "across a level change" not in err
    corr = pd.read_csv(tmp_path / "CORR.csv")
    offset = (model + diff) - corr[["Hp", "He", "Hn"]].to_numpy()  # the offset applied
    truth = TRUTH + 2 * STEP * (t >= STEP_TIME)[:, None]
    at = np.searchsorted(t, [STEP_TIME + d * DAY for d in (-3, 3)])
    assert np.all(np.abs(offset[at] - truth[at]) < 0.5), offset[at] - truth[at]


def test_chain_offsets_stage_reads_the_option(stepped):
    """``[offsets] split_at_level_changes = true`` reaches the chain's offsets stage (the
    table is split, its parameters and the stage's provenance say so); a non-boolean
    value is a configuration error naming the key."""
    from magcal.chain import parse_chain_config
    from magcal.chain.calibrate import run_offsets
    from magcal.chain.prepare import MinuteData
    from magcal.errors import InputError

    t, diff, kp, _, split = stepped
    base = ('[input]\nfiles = ["raw/*.csv"]\ntarget = "fgmo"\n[position]\n'
            'longitude_deg = 128.2\n[offsets]\nmin_used = 100\n')
    cfg = parse_chain_config(base + "split_at_level_changes = true\n", "CHAIN.toml")
    n = t.size
    minute = MinuteData(times=t, hpen=diff, model=np.zeros_like(diff), kp=kp,
                        lon_deg=np.full(n, 128.2), lat_deg=np.zeros(n), r_re=np.full(n, 6.6))
    table, product = run_offsets(minute, cfg)
    np.testing.assert_array_equal(table.segment, split.table_.segment)
    np.testing.assert_allclose(table.offset_nT, split.table_.offset_nT, equal_nan=True)
    assert table.parameters["split_at_level_changes"] is True
    assert product.provenance["parameters"]["offsets"]["split_at_level_changes"] is True
    with pytest.raises(InputError, match="split_at_level_changes"):
        parse_chain_config(base + 'split_at_level_changes = "yes"\n', "CHAIN.toml")
