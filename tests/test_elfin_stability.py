"""Which ELFIN parameters are stable across zones (magcal.missions.elfin.diagnostics.stability).

Injected truth: a simulated multi-zone spinner whose sensor (gains, coupling) is shared
and whose offsets differ from zone to zone, with autocorrelated noise; and a real-data
smoke test (skipped with a reason when the ELFIN files are absent).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose

from magcal.missions.elfin.diagnostics.stability import LINEAR_NAMES, linear_zone_parameters, spread
from magcal.spin.despin import spin

DATA = Path(__file__).resolve().parents[2] / "shared" / "real-data" / "elfin"
SPIN_S = 2.85
#: Shared sensor: body field = A @ counts + offset (nT per count), right-handed,
#: non-orthogonal by about a degree; gains = column norms.
A_TRUE = np.array([[0.0075, 0.0060, 0.0001], [-0.0060, 0.0075, 0.0002],
                   [0.0002, 0.0001, 0.0096]])


def _zone(rng, offsets, bz_mean, duration_s=372.0, noise_nT=2.0, tau_s=3.0):
    """One pass: IGRF-like despun field whose spin-axis part changes by a few uT and
    not as a quadratic in time (otherwise the spin-plane rows' share of the spin-axis
    counts is the offset drift: the degeneracy of the real zones), counts from ``A_TRUE`` and
    ``offsets``, AR(1) noise with correlation time ``tau_s`` (the residuals of real zones
    are autocorrelated)."""
    t = np.arange(0.0, duration_s, 0.1)
    T = 2 * t / t[-1] - 1
    ang = np.radians(20 + 50 * (T + 1) / 2)
    perp = 43000 + 2500 * T
    ref = np.column_stack([perp * np.cos(ang), perp * np.sin(ang),
                           bz_mean + 3000 * np.sin(2.6 * np.pi * T)])
    phase = 2 * np.pi * t / SPIN_S + rng.uniform(0, 2 * np.pi)
    rho = np.exp(-0.1 / tau_s)
    e = rng.normal(scale=noise_nT * np.sqrt(1 - rho ** 2), size=(t.size, 3))
    for i in range(1, t.size):
        e[i] += rho * e[i - 1]
    body = spin(ref, phase) + e
    counts = np.linalg.solve(A_TRUE, (body - offsets).T).T + 3.0e6
    return t, counts, ref, phase, t >= 2.0


def _fit(rng, offsets, bz_mean, block_s=30.0):
    return linear_zone_parameters(*_zone(rng, offsets, bz_mean), block_s=block_s)


def test_gains_are_stable_and_offsets_are_not():
    rng = np.random.default_rng(11)
    offsets = [np.array([300.0, -200.0, 150.0]), np.array([-100.0, 250.0, 900.0]),
               np.array([50.0, 80.0, -600.0]), np.array([-400.0, 10.0, 300.0]),
               np.array([200.0, 500.0, 0.0])]
    # blocks of 10 s, several noise correlation times: 37 blocks for 20 weights (with
    # 30 s blocks, 12 blocks, the errors come out up to 1.3x small; see the next test)
    fits = [_fit(rng, o, bz, block_s=10.0)
            for o, bz in zip(offsets, (3000.0, -2500.0, 1200.0, 0.0, 2000.0))]
    idx = {n: i for i, n in enumerate(LINEAR_NAMES)}
    gains_true = np.linalg.norm(A_TRUE, axis=0)
    for j in range(3):
        name = f"gain{j + 1}_nT_per_count"
        vals = np.array([f["values"][idx[name]] for f in fits])
        std = np.array([f["std"][idx[name]] for f in fits])
        # recovered within 5 sigma of the injected gain, and judged stable
        assert np.all(np.abs(vals - gains_true[j]) < 5 * std), name
        assert spread(vals, std)["verdict"] == "stable", name
    for j, c in enumerate("xyz"):
        name = f"offset_{c}_nT"
        vals = np.array([f["values"][idx[name]] for f in fits])
        std = np.array([f["std"][idx[name]] for f in fits])
        # B = A counts + offset: the counts' 3e6 baseline is part of the offset
        truth = np.array([(o - A_TRUE @ np.full(3, 3.0e6))[j] for o in offsets])
        assert np.all(np.abs(vals - truth) < 5 * std + 1.0), name
        sp = spread(vals, std)
        assert sp["verdict"] == "per zone", name
        # the scatter beyond the errors is the injected spread of the offsets
        assert abs(sp["excess_scatter"] - np.std(truth, ddof=1)) < 0.1 * np.std(truth, ddof=1)


def test_standard_errors_match_the_scatter_over_seeds():
    """Block-sandwich errors within a factor 2 of the scatter of the estimates over
    16 noise draws (the naive errors, which ignore the autocorrelation, are too small)."""
    offsets, reports, ests, naive = np.array([300.0, -200.0, 150.0]), [], [], []
    keys = [LINEAR_NAMES.index(n) for n in ("gain1_nT_per_count", "gain3_nT_per_count",
                                            "nonorth12_deg", "offset_x_nT")]
    for seed in range(16):
        f = _fit(np.random.default_rng(100 + seed), offsets, 1500.0)
        ests.append(f["values"][keys])
        reports.append(f["std"][keys])
        naive.append(f["std_naive"][keys])
    scatter = np.std(ests, axis=0, ddof=1)
    ratio = np.median(reports, axis=0) / scatter
    assert np.all((ratio > 0.5) & (ratio < 2.0)), ratio
    assert np.all(np.median(naive, axis=0) < np.median(reports, axis=0))


def test_a_smooth_spin_axis_field_moves_the_gains_but_not_the_plane_responses():
    """Noise-free pass whose spin-axis field is a quadratic in time: the spin-plane
    rows' share of the spin-axis counts is then the offset drift (the degeneracy of the
    real zones). The gains come out wrong by 3e-4 without any noise; the spin-plane
    responses (spin-plane columns of C^-1) are exact."""
    t = np.arange(0.0, 372.0, 0.1)
    T = 2 * t / t[-1] - 1
    ang = np.radians(20 + 25 * (T + 1))
    perp = 43000 + 2500 * T
    ref = np.column_stack([perp * np.cos(ang), perp * np.sin(ang), 1500 + 3000 * T ** 2])
    phase = 2 * np.pi * t / SPIN_S
    counts = np.linalg.solve(A_TRUE, (spin(ref, phase) - [300.0, -200.0, 150.0]).T).T + 3e6
    fit = linear_zone_parameters(t, counts, ref, phase, t >= 2.0)
    idx = [LINEAR_NAMES.index(f"gain{j}_nT_per_count") for j in (1, 2, 3)]
    gains = np.linalg.norm(A_TRUE, axis=0)
    assert np.max(np.abs(fit["values"][idx] / gains - 1)) > 1e-4
    idx = [LINEAR_NAMES.index(f"plane_response{j}_counts_per_nT") for j in (1, 2, 3)]
    plane = np.linalg.norm(np.linalg.inv(A_TRUE)[:, :2], axis=1)
    assert_allclose(fit["values"][idx], plane, rtol=1e-9)


def test_spread_threshold_is_the_chi2_quantile():
    from scipy.stats import chi2

    sp = spread(np.zeros(12), np.ones(12))
    assert sp["chi2_dof"] == 0.0
    assert sp["threshold"] == pytest.approx(chi2.ppf(0.99, 11) / 11)


@pytest.mark.skipif(not (DATA / "ela_l1_fgs_20220112_v01.cdf").is_file(),
                    reason=f"ELFIN data not found under {DATA}")
def test_real_zone_reproduces_the_delivered_linear_fit():
    from magcal.missions.elfin.linear import calibrate_elfin
    from magcal.missions.elfin.files import read_elfin_fgs, read_elfin_state
    from magcal.missions.elfin.diagnostics.stability import parameter_stability

    fgs = read_elfin_fgs(DATA / "ela_l1_fgs_20220112_v01.cdf")
    state = read_elfin_state(DATA / "ela_l1_state_defn_20220112_v01.cdf")
    cal = calibrate_elfin(fgs, state, zones=[6, 9])
    doc = parameter_stability(cal)
    for z, row in zip(cal.zones, doc["zones"]):
        # the refit on the delivered phase is the delivered fit
        assert np.allclose([row[f"gain{j}_nT_per_count"] for j in (1, 2, 3)],
                           z.gains_nT_per_count, rtol=1e-6)
        assert np.allclose([row[f"offset_{c}_nT"] for c in "xyz"], z.offsets_nT, atol=1e-3)
        assert row["gain3_nT_per_count_std"] > 0
    assert set(doc["stable"]) | set(doc["per_zone"]) == set(LINEAR_NAMES)
