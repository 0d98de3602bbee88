"""``magcal.lstsq.lstsq``: the normal-equation solver equals numpy's SVD solver.

Truth here is closed form (a polynomial's coefficients, read back from noise-free
values) and :func:`numpy.linalg.lstsq` itself: on the design with its columns scaled to
unit norm (where the SVD solver is accurate to rounding; on columns of very different
sizes it is not, 4e-12 relative below where this solver reaches 4e-15), and unchanged
(the same array) where the fast path hands the design over.
"""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from magcal.lstsq import MAX_COND, lstsq


def _numpy(a, b):
    return np.linalg.lstsq(a, b, rcond=None)[0]


def _accurate(a, b):
    """numpy's answer on the design with unit-norm columns, scaled back."""
    s = np.linalg.norm(a, axis=0)
    x = _numpy(a / s, b)
    return x / (s[:, None] if x.ndim == 2 else s)


@pytest.mark.parametrize("complex_", [False, True])
@pytest.mark.parametrize("k", [None, 1, 3])
def test_equals_numpy_on_random_designs_with_uneven_columns(complex_, k):
    rng = np.random.default_rng(7)
    a = rng.normal(size=(3700, 20))
    if complex_:
        a = a + 1j * rng.normal(size=a.shape)
    a *= np.logspace(-3, 3, 20)                       # columns 1e6 apart in size
    b = rng.normal(size=(3700,) if k is None else (3700, k))
    x, want = lstsq(a, b), _accurate(a, b)
    assert x.shape == want.shape and x.dtype == _numpy(a, b).dtype
    # each coefficient to 1e-12 of its own size (the columns' scales differ by 1e6)
    assert_allclose(x, want, rtol=1e-12, atol=0)


def test_polynomial_coefficients_come_back_exactly():
    t = np.linspace(-1.0, 1.0, 4000)
    truth = np.array([2.0, -3.0, 0.5, 0.25, -1.0, 0.125])
    a = np.column_stack([t ** d for d in range(truth.size)])
    assert_allclose(lstsq(a, a @ truth), truth, rtol=0, atol=1e-13)


def test_an_ill_conditioned_design_keeps_numpy_accuracy_by_the_refinement():
    # monomials to degree 5 on [0, 1]: cond(A)^2 ~ 6e6 after column scaling, inside the
    # limit; the plain normal equations lose ~eps * cond^2 there (1.8e-10 measured),
    # the refined solution must stay within 1e-12 of the accurate one
    rng = np.random.default_rng(3)
    t = np.linspace(0.0, 1.0, 3000)
    a = np.column_stack([t ** d for d in range(6)])
    b = np.sin(7 * t) + rng.normal(0, 0.1, t.size)
    scaled = a / np.linalg.norm(a, axis=0)
    assert 1e6 < np.linalg.cond(scaled) ** 2 < MAX_COND / 10   # the fast path is taken
    want = _accurate(a, b)
    assert_allclose(lstsq(a, b), want, rtol=0, atol=1e-12 * np.abs(want).max())


def test_columns_of_zeros_get_zero_and_the_rest_numpys_answer():
    # a term switched off (ELFIN's attitude columns without fit_attitude)
    rng = np.random.default_rng(2)
    a = rng.normal(size=(800, 6))
    a[:, [1, 4]] = 0.0
    b = rng.normal(size=(800, 2))
    x = lstsq(a, b)
    assert np.all(x[[1, 4]] == 0.0)
    assert_allclose(x, _numpy(a, b), rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("case", ["all zeros", "equal columns", "too ill-conditioned",
                                  "fewer rows", "nan in b"])
def test_hands_every_other_design_to_numpy_unchanged(case):
    rng = np.random.default_rng(11)
    t = np.linspace(0.0, 1.0, 500)
    a = np.column_stack([np.ones_like(t), t, np.cos(3 * t)])
    b = rng.normal(size=t.size)
    if case == "all zeros":
        a = 0 * a
    elif case == "equal columns":
        a = np.column_stack([a, t])
    elif case == "too ill-conditioned":
        a = np.column_stack([t ** d for d in range(14)])
    elif case == "fewer rows":
        a, b = a[:2], b[:2]
    else:
        b[3] = np.nan
    assert_array_equal(lstsq(a, b), _numpy(a, b))


def test_real_design_with_complex_right_hand_side():
    rng = np.random.default_rng(5)
    a = rng.normal(size=(300, 4))
    b = rng.normal(size=300) + 1j * rng.normal(size=300)
    assert_allclose(lstsq(a, b), _numpy(a, b), rtol=1e-12)


def test_zero_weight_rows_drop_out():
    # the robust fits weight outliers to zero: the answer is the fit without those rows
    rng = np.random.default_rng(9)
    a = rng.normal(size=(1000, 5))
    b = a @ np.arange(1.0, 6.0) + rng.normal(0, 0.1, 1000)
    w = np.ones(1000)
    w[::3] = 0.0
    b_bad = b.copy()
    b_bad[::3] += 1e6
    assert_allclose(lstsq(a * w[:, None], b_bad * w), _numpy(a[w > 0], b[w > 0]),
                    rtol=1e-12)
