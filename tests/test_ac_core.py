"""PiCoG core, chain and upload matrices against closed-form truth."""

import numpy as np
import pytest
from numpy.testing import assert_allclose

from magcal.ac.chain import Order, Plan, Stage, apply_weights, run_chain
from magcal.ac.core import (correction_matrix, fit_first_order, first_order_from_moments,
                            variance_system)
from magcal.ac.scan import scan_first_order, scan_loop_reference, summarize_scan
from magcal.errors import InputError


def _unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def test_collinear_alpha_is_a_over_a_minus_1(rng):
    # Eq. 19: disturbance a times stronger at i than at j, same direction
    n, a = 4000, 3.7
    s = rng.normal(size=(n, 1))
    u = _unit([0.2, -0.5, 0.8])
    amb = np.array([120.0, -30.0, 60.0]) + 0.05 * rng.normal(size=(n, 3))
    b_i, b_j = amb + a * s * u, amb + s * u
    fit = fit_first_order(b_i, b_j)
    assert_allclose(fit.alpha, a / (a - 1), rtol=1e-3)
    assert_allclose(abs(fit.direction_i @ u), 1.0, atol=1e-6)
    assert_allclose(abs(fit.direction_ij @ u), 1.0, atol=1e-9)
    # Eq. 20: alpha_ij + alpha_ji = 1 when both directions share a sense
    fit_ji = fit_first_order(b_j, b_i)
    a_ji = fit_ji.alpha * np.sign(fit_ji.direction_i @ u) * np.sign(fit_ji.direction_ij @ u)
    a_ij = fit.alpha * np.sign(fit.direction_i @ u) * np.sign(fit.direction_ij @ u)
    assert_allclose(a_ij + a_ji, 1.0, atol=2e-3)


def test_noncollinear_first_order_exact():
    # different directions at the two sensors; ambient constant -> exact removal
    n = 3000
    t = np.arange(n, dtype=float)
    s = np.sign(np.sin(2 * np.pi * t / 300)) + 0.3 * np.sin(2 * np.pi * t / 37)
    u_i, u_j = _unit([0, 0.6, 0.8]), _unit([0.5, 0.5, 0.7])
    amb = np.array([10.0, 20.0, 30.0])
    b_i = amb + 2.0 * s[:, None] * u_i
    b_j = amb + 50.0 * s[:, None] * u_j
    fit = fit_first_order(b_i, b_j)
    d = 2.0 * u_i - 50.0 * u_j
    # alpha = |a_i| / |a_i u_i - a_j u_j| up to the sign convention
    assert_allclose(abs(fit.alpha), 2.0 / np.linalg.norm(d), rtol=1e-12)
    assert_allclose(abs(fit.alpha_variance), 2.0 / np.linalg.norm(d), rtol=1e-12)
    cleaned = b_i + (b_i - b_j) @ fit.A.T
    assert_allclose(cleaned, np.broadcast_to(amb, cleaned.shape), atol=1e-10)


def test_variance_alpha_biased_by_ambient_decorrelation_not(rng):
    # ambient variance along the disturbance direction inflates Eq. 14, not the refinement
    n = 20000
    s = rng.normal(size=(n, 1))
    u = _unit([1, 0, 0])
    amb = rng.normal(size=(n, 3)) * np.array([0.5, 0.1, 0.1])
    b_i, b_j = amb + 2 * s * u, amb + 6 * s * u
    fit = fit_first_order(b_i, b_j)
    truth = 2 / (2 - 6)
    assert_allclose(fit.alpha * np.sign(fit.direction_i[0] * fit.direction_ij[0]), truth, rtol=5e-3)
    assert abs(abs(fit.alpha_variance) - abs(truth)) > 0.01  # Eq. 14 alone is biased here


def test_variance_system_right_handed():
    t = np.arange(200.0)
    b = np.c_[3 * np.sin(t), np.cos(t), 0.1 * np.sin(0.3 * t)]
    lam, r = variance_system(b)
    assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
    assert_allclose(np.linalg.det(r), 1.0, atol=1e-12)
    assert lam[0] > lam[1] > lam[2]


def test_degenerate_difference_raises():
    b = np.random.default_rng(1).normal(size=(100, 3))
    with pytest.raises(InputError, match="no variance"):
        fit_first_order(b, b.copy())


def test_nan_rows_are_skipped(rng):
    n = 2000
    s = rng.normal(size=(n, 1))
    u = _unit([0, 1, 1])
    b_i, b_j = 3 * s * u, 1 * s * u
    b_i[::7] = np.nan
    fit = fit_first_order(b_i, b_j)
    assert np.isfinite(fit.alpha)
    assert fit.n_used == n - len(range(0, n, 7))
    assert_allclose(abs(fit.alpha), 1.5, rtol=1e-12)


def test_moments_batched_matches_single(rng):
    c = rng.normal(size=(5, 6, 6))
    c = c @ c.transpose(0, 2, 1)
    m = first_order_from_moments(c[:, :3, :3], c[:, 3:, 3:], c[:, :3, 3:])
    for k in range(5):
        mk = first_order_from_moments(c[k, :3, :3], c[k, 3:, 3:], c[k, :3, 3:])
        assert_allclose(m.alpha[k], mk.alpha, rtol=1e-12)


def _three_disturber_case(rng, n=20000, noise=0.0):
    """Two boom sensors (s outboard, t inboard) and a body sensor a near disturber 1."""
    t = np.arange(n, dtype=float)
    amb = np.c_[0.5 * np.sin(2 * np.pi * t / 20000), 0.3 * np.cos(2 * np.pi * t / 15000),
                0.2 * np.sin(2 * np.pi * t / 9000)] + np.array([80.0, -10.0, 40.0])
    s1 = np.where((t > 5000) & (t < 9000), 30.0, 0.0)           # big step, seen by amr
    s2 = rng.normal(size=n)                                      # broadband
    s3 = np.where((t % 600) < 5, 5.0, 0.0)                       # spikes
    u1s, u1t, u1a = _unit([1, 1, 0]), _unit([1, 0.8, 0.1]), _unit([0.7, 1, 0.2])
    u2 = _unit([0, 0, 1])
    u3 = _unit([1, -1, 0])
    b_s = amb + 1.0 * s1[:, None] * u1s + 1.0 * s2[:, None] * u2 + 0.5 * s3[:, None] * u3
    b_t = amb + 1.7 * s1[:, None] * u1t + 2.5 * s2[:, None] * u2 + 1.2 * s3[:, None] * u3
    b_a = amb + 40.0 * s1[:, None] * u1a
    if noise:
        b_s += noise * rng.normal(size=(n, 3))
        b_t += noise * rng.normal(size=(n, 3))
        b_a += 20 * noise * rng.normal(size=(n, 3))
    return t, {"s": b_s, "t": b_t, "a": b_a}, amb


def test_chain_upload_matrices_reproduce_iteration(rng):
    t, data, amb = _three_disturber_case(rng)
    plan = Plan("s", (
        Stage("reference", ("s", "t"), reference="a",
              orders=(Order(interval=(4000.0, 10000.0)),)),
        Stage("pair", ("s", "t"), orders=(Order(window_s=100.0), Order(window_s=700.0),
                                          Order())),
    ))
    res = run_chain(data, t, plan)
    assert set(res.M) == {"s", "t", "a"}
    assert res.identity_error < 1e-12                       # Eq. 33
    one_step = apply_weights(data, res.M)
    assert np.max(np.abs(one_step - res.corrected)) < 1e-9  # Eq. 28 == iteration
    # Eqs. 29-30 written out for this chain
    A = {(st.stage, st.order, st.i): st.A for st in res.steps}
    I = np.eye(3)  # noqa: E741 (the identity of Eqs. 29-30)
    A0sa, A0ta = A[(1, 1, "s")], A[(1, 1, "t")]
    a0st, a0ts = A[(2, 1, "s")], A[(2, 1, "t")]
    a1st, a1ts = A[(2, 2, "s")], A[(2, 2, "t")]
    a2st = A[(2, 3, "s")]
    p0 = a0st + a0ts
    p1 = a1st + a1ts
    C = a0st + a1st @ (I + p0) + a2st @ (I + p1) @ (I + p0)    # Eq. 30 (product form)
    assert_allclose(res.M["s"], (I + C) @ (I + A0sa), atol=1e-12)        # Eq. 29a
    assert_allclose(res.M["t"], -C @ (I + A0ta), atol=1e-12)             # Eq. 29b
    assert_allclose(res.M["a"], C @ A0ta - (I + C) @ A0sa, atol=1e-12)   # Eq. 29c
    # Eq. 31: G is the mean removed by the correction and independent of the ambient
    assert_allclose(res.G, data["s"].mean(0) - one_step.mean(0), atol=1e-9)
    shifted = {k: v + np.array([7.0, -3.0, 11.0]) for k, v in data.items()}
    res2 = run_chain(shifted, t, plan)
    assert_allclose(res2.G, res.G, atol=1e-8)


def test_chain_removes_disturbances(rng):
    t, data, amb = _three_disturber_case(rng)
    plan = Plan("s", (
        Stage("reference", ("s", "t"), reference="a",
              orders=(Order(interval=(4000.0, 10000.0)),)),
        Stage("pair", ("s", "t"), orders=(Order(window_s=100.0), Order(window_s=700.0))),
    ))
    res = run_chain(data, t, plan)
    before = data["s"] - amb
    after = res.corrected + res.G - amb
    before -= before.mean(0)
    after -= after.mean(0)
    ratio = np.sum(before ** 2) / np.sum(after ** 2)
    assert ratio > 5e3, ratio


def test_chain_bad_input(rng):
    t, data, amb = _three_disturber_case(rng, n=2000)
    with pytest.raises(InputError, match="missing"):
        run_chain({"s": data["s"], "t": data["t"]}, t,
                  Plan("s", (Stage("reference", ("s",), reference="a"),)))
    with pytest.raises(InputError, match="longer than the data"):
        run_chain(data, t, Plan("s", (Stage("pair", ("s", "t"),
                                             orders=(Order(window_s=5000.0),)),)))


def test_scan_matches_loop(rng):
    n = 1500
    s = rng.normal(size=(n, 1))
    amb = rng.normal(size=(n, 3)) * 0.2 + np.array([100.0, 50.0, -20.0])
    u = _unit([0.3, 0.4, 0.8])
    b_i = amb + 3 * s * u + 0.1 * rng.normal(size=(n, 3))
    b_j = amb + 1 * s * _unit([0.35, 0.4, 0.8])
    res = scan_first_order(b_i, b_j, 100)
    a_loop, ei_loop, eij_loop = scan_loop_reference(b_i, b_j, 100)
    # loop signs: largest component positive; bring the scan to the same convention
    sgn = np.sign(np.sum(res.direction_i * ei_loop, axis=1))
    sgn2 = np.sign(np.sum(res.direction_ij * eij_loop, axis=1))
    assert_allclose(res.direction_i * sgn[:, None], ei_loop, atol=1e-8)
    assert_allclose(res.direction_ij * sgn2[:, None], eij_loop, atol=1e-8)
    assert_allclose(res.alpha * sgn * sgn2, a_loop, rtol=1e-8)
    summ = summarize_scan(res)
    e = summ.direction_i
    assert np.degrees(np.arccos(abs(e @ u))) < 2.5
    assert summ.n_selected > 0.5 * summ.n_windows


def test_scan_windows_with_gaps_are_invalid(rng):
    n = 1000
    s = rng.normal(size=(n, 1))
    u = _unit([0, 0, 1])
    b_i, b_j = 2 * s * u + 0.01 * rng.normal(size=(n, 3)), s * u
    b_i[400:450] = np.nan
    res = scan_first_order(b_i, b_j, 100)
    assert not res.valid[res.start == 380]      # 50 % missing
    assert res.valid[res.start == 0]
    assert_allclose(res.alpha[res.valid], 2.0, rtol=2e-2)


def test_correction_matrix_rank_one():
    A = correction_matrix(0.5, [1, 0, 0], _unit([0, 1, 1]))
    assert np.linalg.matrix_rank(A) == 1
