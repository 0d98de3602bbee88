"""Time-stamp irregularities found in the counts (magcal.missions.elfin.timing).

Injected truth on a simulated spinner; then the unpaired jump of ELFIN-A 2022-01-12
(zone 4, 14:16:50.85; ELFIN SOC, PI V. Angelopoulos, UCLA).
"""

from __future__ import annotations

import numpy as np
from numpy.testing import assert_allclose

from magcal.missions.elfin.linear import fit_zone
from magcal.missions.elfin.phase import repair_timestamps
from magcal.missions.elfin.timing import check_timing
from magcal.spin.despin import spin

PERIOD_S = 2.85
A_TRUE = np.array([[0.0090, 0.0004, 0.0002], [-0.0003, 0.0100, 0.0005],
                   [0.0010, -0.0020, 0.0089]])            # nT per count, as on ELFIN-A


def _field(t):
    """Despun field (nT) changing along a LEO pass."""
    return np.column_stack([30000 + 40 * t, -20000 + 60 * t, 2000 + 3000 * np.sin(t / 200)])


def _counts(true_t, rng):
    b_body = spin(_field(true_t), 2 * np.pi * true_t / PERIOD_S)
    counts = np.linalg.solve(A_TRUE, b_body.T).T
    return counts + rng.normal(scale=300.0, size=counts.shape)   # 3 nT of noise


def test_unpaired_jump_repaired_straddling_sample_and_spike_flagged_paired_kept():
    rng = np.random.default_rng(5)
    n, dt, jump = 3000, 0.1, 0.0125
    nominal = np.arange(n) * dt
    true_t = nominal.copy()
    # paired: samples 400-424 stamped 8.77 ms late (jump out and back in the stamps)
    stamps = nominal.copy()
    stamps[400:425] += 0.00877
    # unpaired: the sampler slips by 12.5 ms at sample 1200 (sample 1199 straddles the
    # slip: 3/4 of it), the stamps catch up only at 1207, as on ELFIN-A
    true_t[1200:] += jump
    true_t[1199] += 0.75 * jump
    stamps[1207:] += jump
    counts = _counts(true_t, rng)
    counts[2500] += 2000.0 / 0.009                      # a 2000 nT spike
    t1, anomalies = repair_timestamps(stamps)
    assert [a["kind"] for a in anomalies] == ["paired", "unpaired"]
    out = check_timing(t1, counts, anomalies)
    # the seven early samples are moved by the jump: their times are the true ones
    assert out.n_repaired == 7
    assert_allclose(out.t_s[1200:1207], true_t[1200:1207], atol=1e-9)
    assert_allclose(out.t_s[:1199], true_t[:1199], atol=1e-9)   # the paired block too
    assert_allclose(out.t_s[1207:], true_t[1207:], atol=1e-9)
    # what no shift by the jump explains is flagged, nothing else
    assert np.flatnonzero(out.bad).tolist() == [1199, 2500]
    flagged = [e for e in out.events if e["kind"] == "flagged"]
    assert_allclose(flagged[0]["implied_shift_s"], 0.75 * jump, atol=1e-3)


def test_clean_spinner_flags_nothing():
    rng = np.random.default_rng(6)
    t = np.arange(0.0, 300.0, 0.1)
    t = np.delete(t, np.s_[1000:1026])                    # a 2.6 s packet gap
    out = check_timing(t, _counts(t, rng))
    assert out.n_flagged == 0 and out.events == [] and np.array_equal(out.t_s, t)


def test_flagged_samples_are_left_out_of_the_fit_and_counted():
    rng = np.random.default_rng(7)
    t = np.arange(0.0, 300.0, 0.1)
    counts = _counts(t, rng)
    counts[1500:1503] += 5.0e5                            # 4500 nT: a corrupt run
    out = check_timing(t, counts)
    assert np.flatnonzero(out.bad).tolist() == [1500, 1501, 1502]
    fit = fit_zone(t, counts, _field(t), skip_s=0.0, offset_degree=0, axis_degree=0,
                   exclude=out.bad)
    assert not fit.used[1500:1503].any() and fit.used.sum() == t.size - 3
    assert fit.summary.n_timing_flagged == 3
    # the noise (300 counts, 2.7-3.0 nT per component), not the run (it would add 140 nT)
    assert fit.summary.rms_vector_nT.max() < 1.1 * 300 * 0.0100


def test_elfin_zone4_unpaired_jump_repaired_from_the_counts():
    from conftest import real_data_path
    from magcal.missions.elfin.files import read_elfin_fgs
    from magcal.missions.elfin.phase import split_zones

    fgs = read_elfin_fgs(real_data_path("elfin") / "ela_l1_fgs_20220112_v01.cdf")
    t_all = (fgs.index.asi8 - fgs.index.asi8[0]) / 1e9
    a, b = split_zones(t_all)[4]
    t, anomalies = repair_timestamps(t_all[a:b])
    counts = fgs[["b1", "b2", "b3"]].to_numpy()[a:b]
    out = check_timing(t, counts, anomalies, mask=t >= t[0] + 2.0)
    # measured: samples 1950-1955 (14:16:50.25-50.75) imply +12.5 ms, the jump's size;
    # 1949 implies 9.4 ms (it straddles the slip) and is 160x the median residual
    repaired = [e for e in out.events if e["kind"] == "unpaired_repaired"]
    assert [(e["index"], e["end_index"]) for e in repaired] == [(1950, 1956)]
    assert_allclose(repaired[0]["jump_s"], 0.0125, atol=1e-4)
    assert np.flatnonzero(out.bad).tolist() == [1949]
    # after the repair the block fits the spin like its neighbours (< 30x median; it
    # was 300x: 1240 nT)
    from magcal.missions.elfin.timing import spin_model_residuals

    res, _ = spin_model_residuals(out.t_s, counts, mask=(t >= t[0] + 2.0) & ~out.bad)
    size = np.linalg.norm(res, axis=1)
    assert np.nanmax(size[1950:1956]) < 10 * np.nanmedian(size)


def test_spin_windows_solved_together_equal_one_numpy_fit_each():
    """The spin model's windows are fitted at once (zero rows pad the shorter ones, a
    zero row changes no least-squares answer); each must equal numpy's fit of the
    window alone, a singular window (too few distinct samples) included, which goes to
    numpy's minimum-norm solver."""
    from magcal.lstsq import lstsq_stack
    from magcal.missions.elfin.timing import _design

    rng = np.random.default_rng(31)
    w = 2 * np.pi / PERIOD_S
    lengths = [86, 80, 60, 86]
    a = np.zeros((4, 86, 19))
    b = np.zeros((4, 86, 3))
    want = []
    for j, m in enumerate(lengths):
        tau = np.sort(rng.uniform(-4.3, 4.3, m))
        if j == 3:
            tau = np.repeat(tau[:6], m // 6 + 1)[:m]   # six distinct times: rank < 19
        aj = _design(tau, w, 4)[0]
        bj = rng.normal(size=(m, 3)) * 1e6
        a[j, :m], b[j, :m] = aj, bj
        want.append(np.linalg.lstsq(aj, bj, rcond=None)[0])
    got = lstsq_stack(a, b)
    for j in range(3):
        assert_allclose(got[j], want[j], rtol=1e-9, atol=1e-9 * np.abs(want[j]).max())
    # the singular window: numpy's own answer (padded rows included), exactly
    assert np.array_equal(got[3], np.linalg.lstsq(a[3], b[3], rcond=None)[0])
