"""PiCoG with a varying ambient field: coherent directions, high-pass, the partner step
of Eq. 21, ill-defined scan windows, and the Table-2 remnant metrics in closed form."""

import numpy as np
import pytest
from numpy.testing import assert_allclose

from magcal.ac.chain import Order, Plan, Stage, apply_weights, rank_one_parts, run_chain
from magcal.ac.core import correction_matrix, fit_first_order
from magcal.ac.filters import highpass, running_mean
from magcal.ac.metrics import hf_peak_to_peak, ramp_sizes, spike_heights
from magcal.ac.plan import plan_from_dict
from magcal.ac.scan import scan_first_order, summarize_scan
from magcal.errors import InputError


def _unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def _ambient_case(rng, n=20000):
    """A step disturber (non-collinear at the two sensors) under a large, slowly varying
    ambient field that dominates the outboard variance in a direction of its own."""
    t = np.arange(n, dtype=float)
    amb = np.c_[20 * np.sin(2 * np.pi * t / 30000), 30 * np.cos(2 * np.pi * t / 25000),
                5 * np.sin(2 * np.pi * t / 9000)] + np.array([100.0, -20.0, 50.0])
    s = np.where((t % 4000) < 2000, 1.0, 0.0)
    u_i, u_j = _unit([0.2, 0.3, 0.93]), _unit([0.5, 0.1, 0.86])
    b_i = amb + 2.0 * s[:, None] * u_i + 0.01 * rng.normal(size=(n, 3))
    b_j = amb + 9.0 * s[:, None] * u_j + 0.01 * rng.normal(size=(n, 3))
    return t, b_i, b_j, amb, 2.0 * u_i, 9.0 * u_j


def test_coherent_direction_ignores_the_ambient_field(rng):
    t, b_i, b_j, amb, p_i, p_j = _ambient_case(rng)
    paper = fit_first_order(b_i, b_j)
    # the paper's e_i follows the ambient field (it has most of the outboard variance)
    assert np.degrees(np.arccos(abs(paper.direction_i @ _unit(p_i)))) > 30
    coh = fit_first_order(highpass(b_i, 1000), highpass(b_j, 1000), direction="coherent")
    assert np.degrees(np.arccos(abs(coh.direction_i @ _unit(p_i)))) < 0.5
    A_true = -np.outer(p_i, p_i - p_j) / np.sum((p_i - p_j) ** 2)
    # exact for one disturber: A (p_i - p_j) = -p_i
    assert_allclose(coh.A @ (p_i - p_j), -p_i, atol=0.02)
    assert_allclose(A_true @ (p_i - p_j), -p_i, atol=1e-12)


def test_highpass_is_linear_and_nan_aware():
    t = np.arange(3000.0)
    x = np.c_[np.sin(t / 500), t / 1000, np.ones_like(t)]
    x[100] = np.nan
    y = highpass(2 * x + 3, 201)
    assert np.isnan(y[100]).all()
    assert_allclose(y[~np.isnan(y[:, 0])], 2 * highpass(x, 201)[~np.isnan(y[:, 0])], atol=1e-9)
    assert_allclose(running_mean(np.ones(10), 3), np.ones(10))
    with pytest.raises(InputError):
        running_mean(np.ones(10), 0)


def test_partner_step_removes_one_difference_direction_per_order(rng):
    # Eqs. 20-21: with coherent orders the corrected pair agrees along e_ij, so the
    # difference loses one dimension per order and three orders exhaust it
    n = 6000
    s = rng.normal(size=(3, n, 1))
    u = [_unit([1, 0, 0]), _unit([1, 1, 0]), _unit([1, 0.3, 1])]
    b_o = sum(g * s[q] * u[q] for q, g in enumerate((1.0, 0.8, 0.5)))
    b_i = sum(g * s[q] * u[q] for q, g in enumerate((4.0, 1.3, 2.0)))
    data = {"o": b_o, "i": b_i}
    for k in (1, 2, 3):
        res = run_chain(data, np.arange(n, dtype=float), Plan("o", (Stage(
            "pair", ("o", "i"), orders=(Order(direction="coherent"),) * k),)))
        d = res.corrected - apply_weights(data, res.weights["i"])
        sv = np.linalg.svd(d - d.mean(0), compute_uv=False)
        assert np.sum(sv > 1e-9 * np.linalg.norm(b_i)) == 3 - k
        assert res.identity_error < 1e-12
        partner = [st for st in res.steps if st.kind == "partner"]
        assert len(partner) == k
        for st in partner:
            assert_allclose(correction_matrix(st.alpha, st.direction_i, st.direction_ij), st.A,
                            atol=1e-12)
    # three disturbers, three orders, full-rank difference: removed exactly (Sect. 5)
    assert_allclose(res.corrected, 0.0, atol=1e-9)


def test_rank_one_parts_round_trip():
    A = correction_matrix(-0.37, _unit([0.2, -0.5, 0.8]), _unit([0.6, 0.6, 0.1]))
    a, e_i, e_ij = rank_one_parts(A)
    assert_allclose(correction_matrix(a, e_i, e_ij), A, atol=1e-14)


def test_ill_defined_windows_are_counted(rng):
    # isotropic difference in the first half: no preferred direction there
    n = 4000
    s = rng.normal(size=(n, 1))
    u = _unit([0, 0, 1])
    iso = np.where(np.arange(n)[:, None] < 2000, rng.normal(size=(n, 3)), 0.0)
    b_i = 3 * s * u + 0.01 * rng.normal(size=(n, 3))
    b_j = b_i - (2 * s * u * (np.arange(n)[:, None] >= 2000) + iso)
    scan = scan_first_order(b_i, b_j, 100)
    ill = scan.ill_defined(1.5)
    assert ill[:1800].mean() > 0.5 and ill[2000:].sum() == 0
    summ = summarize_scan(scan)
    assert summ.n_ill_defined == int(ill.sum())
    excl = summarize_scan(scan, exclude_ill_defined=True)
    assert not np.any(excl.selected & ill)


def test_plan_keys_direction_and_highpass():
    plan, _ = plan_from_dict({"target": "a", "direction": "coherent", "highpass_s": 1800,
                              "stage": [{"pair": ["a", "b"], "orders": [
                                  {"window_s": 100}, {"window_s": 700, "highpass_s": 0},
                                  {"direction": "variance"}]}]})
    o = plan.stages[0].orders
    assert [x.direction for x in o] == ["coherent", "coherent", "variance"]
    assert [x.highpass_s for x in o] == [1800.0, None, 1800.0]
    with pytest.raises(InputError, match="direction"):
        plan_from_dict({"target": "a", "direction": "pca", "stage": [{"pair": ["a", "b"]}]})
    with pytest.raises(InputError, match="highpass_s"):
        plan_from_dict({"target": "a", "highpass_s": -5, "stage": [{"pair": ["a", "b"]}]})


# --- Table-2 remnant metrics on closed-form series -------------------------------------

def test_ramp_sizes_closed_form():
    t = np.arange(5000.0)
    slope = np.array([0.001, -0.002, 0.0])
    b = t[:, None] * slope + np.where(t[:, None] >= 2500, [1.5, -2.0, 0.25], 0.0)
    r = ramp_sizes(b, t, [2500.0, 10.0])          # the second is too close to the start
    # step + slope x (span + 2 gap) = step + slope x 120 s
    assert_allclose(r, [[1.5 + 0.12, -2.0 - 0.24, 0.25]], atol=1e-12)


def test_spike_heights_closed_form():
    t = np.arange(1000.0)
    centres = np.array([200.0, 500.0, 800.0])
    heights = np.array([2.0, -3.0, 5.0])
    x = sum(h * np.exp(-0.5 * ((t - c) / 2.0) ** 2) for c, h in zip(centres, heights))
    b = np.c_[x, 0.5 * x, 7.0 + 0 * t]
    # peak sample on the centre; the 20 s medians 5 s away see exp(-0.5 (>=6/2)^2) ~ 0
    assert_allclose(spike_heights(b, t, centres + 0.4), np.c_[heights, heights / 2, 0 * heights],
                    atol=1e-3)


def test_hf_peak_to_peak_closed_form():
    t = np.arange(2400.0)
    tone = np.where(t >= 1200, 0.8, 0.0) * np.cos(np.pi * t)      # +-0.8 alternating
    b = np.c_[tone, 0.01 * t, np.zeros_like(t)]
    out = hf_peak_to_peak(b, t, (0, 1200), (1200, 2400), block_s=61.0)
    # odd block: the alternating sequence is orthogonal to the centred trend, p2p 1.6
    assert_allclose(out, [1.6, 0.0, 0.0], atol=1e-9)
