"""Benchmark: a year of 1-min T89 at geostationary orbit (issue 4 performance targets).

Measures, in one run:

* raw: IRBEM ``get_field_multi_`` through ctypes in this process, chunked, no overhead;
* first: :func:`magcal.models.field.model_field_hpen` on all cores, cache empty;
* rerun: the same call again, served from the on-disk cache.

Targets: first <= 1.2 x raw / n_cores; rerun at least 50 x faster than first.
Run: ``python benchmarks/bench_models.py [--days 365]``.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time

import numpy as np

from magcal.offline import configure_offline


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--days", type=float, default=365.0)
    parser.add_argument("--n-jobs", type=int, default=None)
    args = parser.parse_args()
    configure_offline()
    from magcal.models import irbem
    from magcal.models.field import default_n_jobs, model_field_hpen

    n = int(args.days * 1440)
    t = np.datetime64("2019-01-01T00:00", "ns") + np.arange(n) * np.timedelta64(60, "s")
    gen = np.random.default_rng(1)
    kp3h = np.round(gen.gamma(2.0, 0.8, n // 180 + 1) * 3) / 3
    kp = np.minimum(kp3h[np.arange(n) // 180], 9.0)
    xyz = irbem.geo_position_re(128.2, 0.0, 6.6)[0]
    n_jobs = args.n_jobs or default_n_jobs()

    year, doy, sec = irbem.time_parts(t)
    mag, _, _ = irbem.build_maginput({"Kp": kp}, n, "T89")
    pos = np.broadcast_to(xyz, (n, 3))
    tic = time.perf_counter()
    for a in range(0, n, irbem.NTIME_MAX):
        z = a + irbem.NTIME_MAX
        irbem._call_multi(4, irbem.DEFAULT_OPTIONS, year[a:z], doy[a:z], sec[a:z], pos[a:z],
                          mag[a:z])
    raw = time.perf_counter() - tic

    with tempfile.TemporaryDirectory() as cache:
        tic = time.perf_counter()
        first = model_field_hpen(t, 128.2, 0.0, 6.6, "T89", kp=kp, n_jobs=n_jobs,
                                 cache_dir=cache)
        t_first = time.perf_counter() - tic
        tic = time.perf_counter()
        again = model_field_hpen(t, 128.2, 0.0, 6.6, "T89", kp=kp, n_jobs=n_jobs,
                                 cache_dir=cache)
        t_again = time.perf_counter() - tic
    assert again.cache_hits == 1 and np.array_equal(first.b_hpen_nT, again.b_hpen_nT,
                                                    equal_nan=True)
    ideal = raw / n_jobs
    print(f"points: {n} (1-min T89, {args.days:g} days), cores used: {n_jobs}")
    print(f"raw IRBEM call (1 process):  {raw:8.3f} s  ({raw / n * 1e6:.2f} us/point)")
    print(f"model_field_hpen first run:  {t_first:8.3f} s  ratio to raw/cores = "
          f"{t_first / ideal:.2f}  (target <= 1.2)")
    print(f"model_field_hpen cached:     {t_again * 1e3:8.1f} ms speed-up = "
          f"{t_first / t_again:.0f}x  (target >= 50x)")
    print(f"load average now: {os.getloadavg()[0]:.2f} (other work on the machine skews "
          "the parallel ratio)")


if __name__ == "__main__":
    main()
