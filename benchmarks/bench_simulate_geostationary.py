"""Geostationary simulator speed and memory: one GK-2A-like day at 1 s.

Targets (issue 2): a day at 1 s with 4 sensors and 7 disturbers generated in a few
seconds (< 5 s here) with a peak Python allocation well under 1 GB (< 400 MB), and the
vectorised disturber fields at least 100x faster than evaluating the multipole field
sample by sample (the naive baseline, timed on one hour and scaled to the day).

Run: ``python benchmarks/bench_simulate_geostationary.py``
"""

from __future__ import annotations

import time
import tracemalloc

import numpy as np

from magcal.simulate.disturbers import disturber_fields, disturber_patterns
from magcal.simulate.geostationary import GeostationaryConfig, simulate_geostationary
from magcal.simulate.multipoles import dipole_field, quadrupole_field
from magcal.simulate.profiles import ProfileContext


def _naive_fields(cfg, t_s, context):
    """Baseline: the field of each disturber at each sensor, one sample at a time."""
    pos = np.array([s.position_m for s in cfg.sensors])
    out = []
    for d in cfg.disturbers:
        coeff = d.profile.evaluate(t_s, rng=np.random.default_rng(0), context=context).values
        moments = d.basis_moments()
        b = np.empty((len(pos), len(t_s), 3))
        for k in range(len(t_s)):
            m = coeff[k] @ moments
            if d.kind == "quadrupole":
                b[:, k] = quadrupole_field(m, d.position_m, d.separation_m, pos)
            else:
                b[:, k] = dipole_field(m, d.position_m, pos)
        out.append(b)
    return out


def _fast_fields(cfg, t_s, context):
    pos = np.array([s.position_m for s in cfg.sensors])
    out = []
    for d in cfg.disturbers:
        coeff = d.profile.evaluate(t_s, rng=np.random.default_rng(0), context=context).values
        out.append(disturber_fields(disturber_patterns(d, pos), coeff))
    return out


def main() -> None:
    cfg = GeostationaryConfig()
    times = []
    for seed in range(3):
        start = time.perf_counter()
        res = simulate_geostationary(cfg, rng=np.random.default_rng(seed))
        times.append(time.perf_counter() - start)
    n = len(res.times)
    tracemalloc.start()
    simulate_geostationary(cfg, rng=np.random.default_rng(99))
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    print(f"day at 1 s: {n} samples, {len(cfg.sensors)} sensors, {len(cfg.disturbers)} "
          f"disturbers, ambient {res.truth.ambient_model}")
    print(f"  time (best of 3)   {min(times):7.2f} s    target < 5 s")
    print(f"  peak allocation    {peak / 1e6:7.0f} MB   target < 400 MB")

    context = ProfileContext(res.times[0], cfg.longitude_deg, cfg.cadence_s)
    t_hour = np.arange(3600.0)
    start = time.perf_counter()
    slow = _naive_fields(cfg, t_hour, context)
    t_naive = (time.perf_counter() - start) * 24
    start = time.perf_counter()
    fast = _fast_fields(cfg, np.arange(86400.0), context)
    t_fast = time.perf_counter() - start
    check = _fast_fields(cfg, t_hour, context)  # same samples and draws as the baseline
    worst = max(np.abs(s - f).max() for s, f in zip(slow, check))
    del fast
    print(f"disturber fields for the day: naive loop {t_naive:7.2f} s (1 h x 24), "
          f"vectorised {t_fast:6.3f} s, ratio {t_naive / t_fast:6.0f}x   target >= 100x "
          f"(max difference {worst:.1e} nT)")


if __name__ == "__main__":
    main()
