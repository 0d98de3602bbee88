"""Benchmark: rotating 10 Hz field vectors GSE -> GEO (magcal.frames.geo).

Measures, in one run, on the same synthetic 10 Hz series:

* default: spacepy ``Coords.convert`` with its default backend, per sample (only on a
  short slice: about 16 ms per distinct time);
* per-sample IRBEM: ``Coords.convert(use_irbem=True)`` on every field vector;
* magcal: :func:`magcal.frames.convert_vectors` (three unit vectors per distinct whole
  second through the same IRBEM call, then a matrix product per sample).

Target: magcal at least 3 x faster than per-sample IRBEM at 10 Hz (ideal 10/3), equal
to it within 7.3e-5 x |B| (spacepy drops the fraction of a second, magcal rounds to
the nearest second: the two are up to 1 s of Earth rotation apart).
Run: ``python benchmarks/bench_frames.py [--minutes 10]``.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import pandas as pd

from magcal.offline import configure_offline


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=10.0)
    args = parser.parse_args()
    configure_offline()
    import spacepy.coordinates as spc
    from spacepy.time import Ticktock

    from magcal.frames import convert_vectors

    n = int(args.minutes * 600)
    times = pd.date_range("2017-04-14T19:24:00", periods=n, freq="100ms")
    gen = np.random.default_rng(1)
    b = gen.normal(0.0, 60.0, (n, 3)) + [0.0, 0.0, 100.0]

    def spacepy_convert(k: int, use_irbem: bool) -> np.ndarray:
        coords = spc.Coords(b[:k], "GSE", "car", units=["Re"] * 3, use_irbem=use_irbem)
        coords.ticks = Ticktock(times[:k].to_pydatetime(), "UTC")
        return np.asarray(coords.convert("GEO", "car").data)

    k_default = min(n, 50)
    t0 = time.perf_counter()
    spacepy_convert(k_default, use_irbem=False)
    default_s = (time.perf_counter() - t0) / k_default * n
    t0 = time.perf_counter()
    per_sample = spacepy_convert(n, use_irbem=True)
    irbem_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    ours = convert_vectors(b, times, "GSE", "GEO")
    ours_s = time.perf_counter() - t0
    diff = float((np.linalg.norm(ours - per_sample, axis=1) / np.linalg.norm(b, axis=1)).max())
    print(f"{n} samples at 10 Hz, GSE -> GEO")
    print(f"  spacepy default backend (extrapolated from {k_default}): {default_s:8.2f} s")
    print(f"  spacepy per-sample IRBEM:                     {irbem_s:8.3f} s")
    print(f"  magcal.frames.convert_vectors:                {ours_s:8.3f} s")
    print(f"  speed-up vs per-sample IRBEM: {irbem_s / ours_s:5.1f} x (target >= 3)")
    print(f"  speed-up vs default backend:  {default_s / ours_s:5.0f} x")
    print(f"  max |difference|/|B| vs per-sample IRBEM: {diff:.2e} (target <= 7.3e-05)")


if __name__ == "__main__":
    main()
