"""Spin-ripple cross-check of the ELFIN IGRF calibration
(magcal.missions.elfin.diagnostics.ripple)."""

from __future__ import annotations

import numpy as np
import pytest

from magcal.missions.elfin.diagnostics.ripple import ripple_zone
from magcal.spin.despin import spin


@pytest.mark.parametrize("sense", [1.0, -1.0])
def test_ripple_recovers_the_true_calibration_of_simulated_counts(sense):
    rng = np.random.default_rng(21)
    t = np.arange(0.0, 300.0, 0.1)
    phase = sense * 2 * np.pi * t / 2.85
    b_desp = np.column_stack([30000 + 20 * t, -20000 + 30 * t, 2000 + 500 * np.sin(t / 90)])
    c_true = np.array([[0.0090, 0.0004, 0.0002], [-0.0003, 0.0100, 0.0005],
                       [0.0010, -0.0020, 0.0089]])
    o_true = np.array([2.0e4, -1.5e4, 8.0e3])                  # counts
    counts = np.linalg.solve(c_true, spin(b_desp, phase).T).T + o_true
    counts += rng.normal(scale=5.0, size=counts.shape)
    res = ripple_zone(t, counts, phase, c_true, o_true)
    np.testing.assert_allclose(res["anisotropy_ripple"], res["anisotropy_igrf"], atol=2e-5)
    np.testing.assert_allclose(res["offset_ripple_nT"], res["offset_igrf_nT"], atol=1.0)


def test_real_elfin_ripple_agrees_with_igrf_on_an_eclipse_pass():
    from tests.conftest import real_data_path

    folder = real_data_path("elfin")
    from magcal.missions.elfin.linear import calibrate_elfin
    from magcal.missions.elfin.files import read_elfin_fgs, read_elfin_state
    from magcal.missions.elfin.diagnostics.ripple import ripple_crosscheck

    fgs = read_elfin_fgs(folder / "ela_l1_fgs_20220112_v01.cdf")
    cal = calibrate_elfin(fgs, read_elfin_state(folder / "ela_l1_state_defn_20220112_v01.cdf"),
                          zones=[6])
    row = ripple_crosscheck(cal, fgs).iloc[0]
    # gain ratio and non-orthogonality from two independent methods: 0.1 % agreement
    assert abs(row.aniso_a_ripple - row.aniso_a_igrf) < 1e-3
    assert abs(row.aniso_b_ripple - row.aniso_b_igrf) < 1e-3
    # effective spin-plane offset: within 5 % of its size (drifts within the pass)
    assert row.offset_diff_nT < 0.05 * row.offset_igrf_nT
