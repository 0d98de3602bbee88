"""Timing helper shared by the benchmark scripts (run as ``python benchmarks/bench_*.py``,
which puts this folder on the import path)."""

from __future__ import annotations

import time


def best(func, repeat=3):
    """(fastest seconds of ``repeat`` calls of ``func``, its last value)."""
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = func()
        times.append(time.perf_counter() - t0)
    return min(times), out
