"""The plain-float simplex search (:mod:`magcal.alignment.neldermead`) against
``scipy.optimize.minimize(method="Nelder-Mead")``, the algorithm it restates: the same
points in the same order, so the same result to the last bit."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import minimize, rosen

from magcal.alignment.neldermead import nelder_mead


@pytest.mark.parametrize("seed", range(3))
def test_same_result_as_scipy_to_the_last_bit(seed):
    """Rosenbrock in four dimensions, smooth and rounded down to steps of 0.25 (equal
    values, whose order decides the step, and shrinks), from random starts, with
    scipy's default simplex and a given one, tolerances over seven decades, and
    evaluation limits that stop the search part way: best point, value and evaluation
    count equal scipy's exactly."""

    def stepped(p):
        return float(np.floor(rosen(np.asarray(p)) * 4.0) / 4.0)

    rng = np.random.default_rng(seed)
    for k in range(20):
        x0 = rng.normal(size=4) * 2.0
        tol = {"xatol": 10 ** rng.uniform(-6, -1), "fatol": 10 ** rng.uniform(-8, -1)}
        limits = {}
        if k % 3 == 0:
            limits["maxiter"] = int(rng.integers(50, 800))
        if k % 4 == 0:
            limits["maxfev"] = int(rng.integers(5, 400))
        simplex = np.vstack([x0, x0 + 0.1 * np.eye(4)]) if k % 2 else None
        options = dict(tol, **limits)
        if simplex is not None:
            options["initial_simplex"] = simplex
        func = stepped if k % 5 in (1, 2) else rosen
        want = minimize(func, x0, method="Nelder-Mead", options=options)
        got = nelder_mead(lambda p: func(np.asarray(p)), x0, simplex=simplex, **tol,
                          **limits)
        assert got.nfev == want.nfev, (k, got.nfev, want.nfev)
        assert np.array_equal(got.x, want.x) and got.fun == want.fun, k


def test_finds_a_known_minimum_and_refuses_a_wrong_simplex():
    res = nelder_mead(lambda p: (p[0] - 3.0) ** 2 + 10.0 * (p[1] + 1.0) ** 2 + p[2] ** 2,
                      [0.0, 0.0, 1.0], xatol=1e-9, fatol=1e-14, maxiter=5000)
    np.testing.assert_allclose(res.x, [3.0, -1.0, 0.0], atol=1e-7)
    with pytest.raises(ValueError, match="3 vertices"):
        nelder_mead(lambda p: 0.0, [0.0, 0.0], simplex=np.zeros((2, 2)))
