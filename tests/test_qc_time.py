"""Time anomalies (bit 8) against injected truth: a regular pattern of unequal steps
(a clock period that is not a whole number of the stamps' resolution) is no anomaly;
late stamps, shifted blocks, duplicates and jumps backwards are, at exactly their rows."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from magcal.qc import flag_samples
from magcal.qc.checks import clock_period, time_mask

ROOT = Path(__file__).resolve().parents[1]


def _galileo_stamps(n: int) -> np.ndarray:
    """A 4.5 Hz clock (2/9 s) stamped in 1/30 s ticks: steps 0.2333, 0.2333, 0.2 s."""
    ticks = np.ceil(np.arange(n) * 2 / 9 * 30 - 1e-9)
    return np.round(ticks / 30 * 1e9).astype(np.int64)


def _median_cadence(t) -> float:
    return float(np.median(np.diff(t))) / 1e9


def test_a_regular_pattern_of_steps_is_no_anomaly():
    t = _galileo_stamps(9000)
    assert _median_cadence(t) == pytest.approx(7 / 30, abs=1e-8)  # the median step
    assert clock_period(t, _median_cadence(t)) == pytest.approx(2 / 9 * 1e9, rel=1e-4)
    assert np.count_nonzero(time_mask(t, _median_cadence(t))) == 0  # was 3816 of 9000


def test_anomalies_on_a_patterned_clock_are_flagged_at_their_rows():
    t = _galileo_stamps(9000)
    t[3000] += 100_000_000                      # one stamp 0.1 s late (0.45 period)
    t[6000:6010] -= 90_000_000                  # a block 0.09 s early (0.4 period)
    flagged = np.flatnonzero(time_mask(t, _median_cadence(t)))
    assert flagged.tolist() == [3000] + list(range(6000, 6010))


def test_one_late_stamp_on_a_regular_1hz_record_is_flagged():
    t = np.arange(3600, dtype=np.int64) * 10**9  # stamped to the millisecond or better
    t[1000] += 100_000_000                       # 0.1 s late: under the 0.25 tolerance
    t[2000] += 30_000_000                        # 30 ms late
    assert np.flatnonzero(time_mask(t, 1.0)).tolist() == [1000, 2000]


def test_duplicates_and_jumps_backwards_are_flagged_at_the_later_row():
    t = np.arange(3600, dtype=np.int64) * 10**9
    t[1200] = t[1199]                            # a duplicate stamp
    t[2500:] -= 3600 * 10**9                     # the clock jumps back an hour
    assert np.flatnonzero(time_mask(t, 1.0)).tolist() == [1200, 2500]


def test_gaps_of_whole_periods_and_clock_jitter_are_not_anomalies():
    rng = np.random.default_rng(7)
    t = np.delete(np.arange(3600, dtype=np.int64), np.arange(1000, 1100)) * 10**9
    t = t + np.r_[0, np.full(t.size - 1, 7200 * 10**9)] * (np.arange(t.size) > 2000)
    assert not time_mask(t, 1.0).any()           # a 100 s hole and a 2 h gap
    jitter = (np.arange(6000) * 100_000_000 + rng.normal(0, 1e6, 6000)).astype(np.int64)
    assert not time_mask(jitter, 0.1).any()      # GOES-R-like 1 ms jitter at 10 Hz


def test_flag_samples_sets_bit_8_only_at_the_injected_rows():
    t = _galileo_stamps(4000)
    b = 100 + np.cumsum(np.random.default_rng(3).normal(0, 0.05, (4000, 3)), axis=0)
    t[2222] += 100_000_000
    res = flag_samples(t, {"": b}, _median_cadence(t))
    assert np.flatnonzero(res.flags & 8).tolist() == [2222]


@pytest.mark.slow
def test_the_shipped_spinning_sample_has_no_time_anomaly():
    from magcal.qc.files import check_files

    path = ROOT / "data_samples" / "spinning_galileo_5h.csv.gz"
    if not path.exists():
        pytest.skip("data_samples/ not present")
    res = check_files([path])
    assert res.result.counts().get("time_anomaly", 0) == 0  # was 34714 of 81000
    assert res.result.flags.size == 81000


def test_gaps_are_listed_not_flagged():
    from magcal.qc.checks import time_gaps

    t = np.delete(np.arange(3600, dtype=np.int64), np.arange(1000, 1100)) * 10**9
    t[2500:] += 7200 * 10**9
    assert time_gaps(t, 1.0) == [(1000, 101.0), (2500, 7201.0)]
    assert not time_mask(t, 1.0).any()
