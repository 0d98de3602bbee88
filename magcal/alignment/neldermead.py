"""Nelder-Mead simplex search for a handful of parameters, in plain Python floats.

The two-scale noise fit (:mod:`magcal.alignment.twoscale`) runs a four-parameter
simplex search a few hundred evaluations long, thousands of times in an alignment with
its window checks. ``scipy.optimize.minimize(method="Nelder-Mead")`` spends about
35 us of NumPy calls on small arrays per evaluation there, as much as the objective
itself. This is the same algorithm (scipy's non-adaptive coefficients, its step order,
its initial simplex and its stopping rules) on lists of floats: the same points are
evaluated in the same order, so the result is the same to the last bit, without that
overhead.
"""

from __future__ import annotations

import math
from typing import Callable, NamedTuple, Sequence

import numpy as np

#: scipy's coefficients: reflection, expansion, contraction, shrink.
_RHO, _CHI, _PSI, _SIGMA = 1, 2, 0.5, 0.5


class SimplexResult(NamedTuple):
    """End of a search: the best point, its value and the number of evaluations."""

    x: np.ndarray
    fun: float
    nfev: int


def initial_simplex(x0: Sequence[float]) -> list[list[float]]:
    """scipy's default simplex: ``x0`` and, per coordinate, ``x0`` with that coordinate
    5 % larger (0.00025 where it is zero)."""
    x0 = [float(v) for v in x0]
    sim = [list(x0)]
    for k in range(len(x0)):
        y = list(x0)
        y[k] = (1 + 0.05) * y[k] if y[k] != 0 else 0.00025
        sim.append(y)
    return sim


def nelder_mead(func: Callable[[list], float], x0: Sequence[float], *, simplex=None,
                xatol: float = 1e-4, fatol: float = 1e-4, maxiter: int | None = None,
                maxfev: float | None = None) -> SimplexResult:
    """Minimise ``func`` over a few parameters from ``x0`` by the Nelder-Mead simplex.

    Parameters
    ----------
    func : callable
        Takes a list of floats, returns a float.
    x0 : sequence of float
        Starting point (the first vertex).
    simplex : array_like (n + 1, n), optional
        The starting simplex (default: :func:`initial_simplex` of ``x0``).
    xatol, fatol : float
        Stop when every vertex is within ``xatol`` of the best in every coordinate and
        within ``fatol`` of it in value (both, as scipy's).
    maxiter, maxfev : int, optional
        Iteration and evaluation limits, with scipy's defaults (200 per parameter when
        neither is given). The evaluation limit ends the search at the call that would
        pass it, as scipy's does.

    Examples
    --------
    >>> res = nelder_mead(lambda p: (p[0] - 1.0) ** 2 + 4.0 * (p[1] + 2.0) ** 2,
    ...                   [0.0, 0.0], xatol=1e-8, fatol=1e-12)
    >>> np.round(res.x, 6).tolist()
    [1.0, -2.0]
    """
    sim = initial_simplex(x0) if simplex is None else [list(map(float, v)) for v in simplex]
    n = len(sim[0])
    if len(sim) != n + 1:
        raise ValueError(f"the simplex needs {n + 1} vertices of {n} coordinates")
    if maxiter is None and maxfev is None:
        maxiter = maxfev = n * 200
    elif maxiter is None:
        maxiter = n * 200 if maxfev == math.inf else math.inf
    elif maxfev is None:
        maxfev = n * 200 if maxiter == math.inf else math.inf
    calls = 0

    class _Limit(Exception):
        pass

    def f(x):
        nonlocal calls
        if calls >= maxfev:
            raise _Limit
        calls += 1
        return float(func(list(x)))

    def order():
        # numpy's argsort, as scipy's: the same order of equal values (and NaN last)
        idx = np.argsort(fsim).tolist()
        return [sim[i] for i in idx], [fsim[i] for i in idx]

    fsim = [math.inf] * (n + 1)
    try:
        for k in range(n + 1):
            fsim[k] = f(sim[k])
    except _Limit:
        pass
    sim, fsim = order()
    iterations = 1
    while calls < maxfev and iterations < maxiter:
        try:
            best = sim[0]
            if (max(abs(v[j] - best[j]) for v in sim[1:] for j in range(n)) <= xatol
                    and max(abs(fsim[0] - fv) for fv in fsim[1:]) <= fatol):
                break
            xbar = list(sim[0])
            for v in sim[1:-1]:
                xbar = [a + b for a, b in zip(xbar, v)]
            xbar = [a / n for a in xbar]
            worst = sim[-1]
            xr = [(1 + _RHO) * a - _RHO * w for a, w in zip(xbar, worst)]
            fxr = f(xr)
            if fxr < fsim[0]:
                xe = [(1 + _RHO * _CHI) * a - _RHO * _CHI * w for a, w in zip(xbar, worst)]
                fxe = f(xe)
                sim[-1], fsim[-1] = (xe, fxe) if fxe < fxr else (xr, fxr)
            elif fxr < fsim[-2]:
                sim[-1], fsim[-1] = xr, fxr
            else:
                shrink = False
                if fxr < fsim[-1]:
                    xc = [(1 + _PSI * _RHO) * a - _PSI * _RHO * w for a, w in zip(xbar, worst)]
                    fxc = f(xc)
                    if fxc <= fxr:
                        sim[-1], fsim[-1] = xc, fxc
                    else:
                        shrink = True
                else:
                    xcc = [(1 - _PSI) * a + _PSI * w for a, w in zip(xbar, worst)]
                    fxcc = f(xcc)
                    if fxcc < fsim[-1]:
                        sim[-1], fsim[-1] = xcc, fxcc
                    else:
                        shrink = True
                if shrink:
                    for j in range(1, n + 1):
                        sim[j] = [b + _SIGMA * (v - b) for b, v in zip(sim[0], sim[j])]
                        fsim[j] = f(sim[j])
            iterations += 1
        except _Limit:
            pass
        sim, fsim = order()
    return SimplexResult(x=np.array(sim[0]), fun=min(fsim), nfev=calls)
