"""Sample quality control (issue 20): every check against injected truth, and the
false-flag rate on clean simulated data (target: below 1e-4 of the samples)."""

from __future__ import annotations

import numpy as np
import pytest

from magcal.errors import InputError
from magcal.qc import EXCLUDE, FLAG_NAMES, QCSettings, flag_samples, plausibility_flags
from magcal.qc.checks import spike_mask, stuck_mask, time_mask
from magcal.simulate.archive import ArchiveConfig, simulate_archive


@pytest.fixture(scope="module")
def clean():
    """Ten clean days of the archive simulator at 10 s (86,400 samples, two sensors:
    a heater's steps, a 120 s tone, storms, ULF waves)."""
    res = simulate_archive(ArchiveConfig(n_days=10, cadence_s=10.0),
                           rng=np.random.default_rng(20))
    t = res.times.astype("datetime64[ns]").astype(np.int64)
    return t, {"fgmo": res.outboard, "fgmi": res.inboard}


def _per_day(t, vectors, settings=None):
    """Flags of each UTC day on its own, as the chain's partitions run them."""
    day = (t // (86_400 * 10**9)).astype(np.int64)
    out = np.zeros(t.size, dtype=np.uint16)
    for d in np.unique(day):
        k = day == d
        out[k] = flag_samples(t[k], {s: v[k] for s, v in vectors.items()}, 10.0,
                              settings).flags
    return out


def test_false_flag_rate_on_clean_data_is_below_1e4(clean):
    t, vectors = clean
    flags = _per_day(t, vectors)
    rate = np.count_nonzero(flags & EXCLUDE) / t.size
    assert rate < 1e-4, f"false-flag rate {rate:.2e}"


@pytest.mark.parametrize("kind", ["spikes", "burst", "saturation", "stuck", "fill", "time"])
def test_injected_bad_samples_are_flagged_with_their_bit(clean, kind):
    """At least 95 % of the spoiled samples carry the right bit, and the good samples of
    the spoiled day stay (almost all) unflagged."""
    t, vectors = clean
    rng = np.random.default_rng(5)
    day = slice(86_400 // 10 * 3, 86_400 // 10 * 4)
    tt, b = t[day].copy(), {s: v[day].copy() for s, v in vectors.items()}
    n = tt.size
    bit = {"spikes": 1, "burst": 1, "saturation": 2, "stuck": 2, "fill": 4, "time": 8}[kind]
    if kind == "spikes":  # the case: one component at 1e6 nT every 97th sample
        bad = np.arange(48, n, 97)
        b["fgmo"][bad, 0] = 1e6
    elif kind == "burst":  # bursts of 1-4 samples, a few nT to 50 nT, random signs
        starts = rng.choice(np.arange(20, n - 20, 40), 60, replace=False)
        bad = np.unique(np.concatenate([s + np.arange(rng.integers(1, 5)) for s in starts]))
        b["fgmi"][bad, 1] += rng.choice([-1, 1], bad.size) * rng.uniform(5, 50, bad.size)
    elif kind == "saturation":  # all three components at 65535 for 400 samples
        bad = np.arange(3000, 3400)
        b["fgmo"][bad] = 65535.0
    elif kind == "stuck":  # one reading held for 200 samples
        bad = np.arange(5000, 5200)
        b["fgmi"][bad] = b["fgmi"][4999]
    elif kind == "fill":
        bad = np.arange(6000, 6120)
        b["fgmo"][bad[:60]] = np.nan
        b["fgmi"][bad[60:], 2] = np.inf
    else:  # 20 stamps 0.4 cadence off the grid
        bad = np.arange(7000, 7020)
        tt[bad] += 4 * 10**9
    flags = flag_samples(tt, b, 10.0).flags
    recall = np.count_nonzero(flags[bad] & bit) / bad.size
    assert recall >= 0.95, f"{kind}: {recall:.3f} of the bad samples flagged"
    good = np.setdiff1d(np.arange(n), bad)
    assert np.count_nonzero(flags[good] & EXCLUDE) <= 3


def test_quantised_quiet_record_is_not_spiky():
    """A 10 Hz record quantised to 1/64 nT with 0.01 nT noise (most first differences 0
    or one step, like GOES-R's quiet minutes): a one-step change is not a spike."""
    rng = np.random.default_rng(2)
    n = 36_000
    b = np.round((100 + rng.normal(0, 0.01, (n, 3))
                  + 0.5 * np.sin(np.arange(n)[:, None] / 3000.0)) * 64) / 64
    t = np.arange(n, dtype=np.int64) * 100_000_000
    assert not flag_samples(t, {"ob": b}, 0.1).flags.any()


def test_stuck_needs_a_minute_at_high_cadence_and_a_declared_range_saturates():
    b = np.cumsum(np.random.default_rng(1).normal(0, 1, (3000, 3)), axis=0)
    b[100:130] = b[100]  # 30 repeats: 3 s at 10 Hz, not stuck; 15 min at 30 s, stuck
    t10 = np.arange(3000, dtype=np.int64) * 100_000_000
    t30 = np.arange(3000, dtype=np.int64) * 30 * 10**9
    assert not (flag_samples(t10, {"s": b}, 0.1).flags & 2).any()
    assert (flag_samples(t30, {"s": b}, 30.0).flags[100:130] & 2).all()
    b2 = b.copy()
    b2[500, 0] = 1000.0  # one sample at the declared range
    flags = flag_samples(t30, {"s": b2}, 30.0, QCSettings(range_nT=1000.0)).flags
    assert flags[500] & 2


def test_time_grid_follows_a_clock_slightly_off_the_nominal_cadence():
    """GOES-R stamps: 0.100054 s nominal, 1 ms jitter; nothing flagged over a minute."""
    rng = np.random.default_rng(3)
    t = (np.arange(600) * 100_000_000 + rng.normal(0, 1e6, 600)).astype(np.int64)
    assert not time_mask(t, 0.100054).any()


def test_implausible_magnitude_against_the_model():
    model = np.tile([100.0, 20.0, -50.0], (5, 1))
    b = model.copy()
    b[2] = [900.0, 0.0, 0.0]    # 900 nT vs 114 nT: within the 1000 nT allowance
    b[3] = [2000.0, 0.0, 0.0]
    assert plausibility_flags(b, model).tolist() == [0, 0, 0, 32, 0]


def test_settings_are_checked_and_bits_are_the_contracts():
    assert [FLAG_NAMES[b] for b in (1, 2, 4, 8, 16)] == [
        "spike", "saturated_or_stuck", "fill_or_nonfinite", "time_anomaly",
        "offset_held_or_extrapolated"]
    with pytest.raises(InputError, match="spike_window"):
        QCSettings(spike_window=4)
    with pytest.raises(InputError, match="unknown key 'spike'"):
        QCSettings.from_mapping({"spike": 3})
    assert not QCSettings.from_mapping({"enabled": False}).enabled


def test_spike_and_stuck_masks_leave_a_clean_random_walk_alone():
    x = np.cumsum(np.random.default_rng(9).normal(0, 0.1, (50_000, 3)), axis=0)
    assert not spike_mask(x).any()
    assert not stuck_mask(x).any()
