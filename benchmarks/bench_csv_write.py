"""CSV writing speed: :func:`magcal.io.csv.write_csv_frame` against pandas' ``to_csv``
with the same format (the baseline, timed in the same run) on a corrected day at 1 s
(86 400 rows: time, Hp, He, Hn at 0.1 pT, offset_flag, quality).

Target: at least 3x faster than the baseline, byte-identical files.

Run: ``python benchmarks/bench_csv_write.py``
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

from magcal.io.csv import format_times, write_csv_frame
from timing import best


def main() -> None:
    rng = np.random.default_rng(2019)
    n = 86_400
    index = pd.date_range("2019-11-01", periods=n, freq="1s", tz="UTC")
    frame = pd.DataFrame({"Hp": rng.normal(80, 20, n), "He": rng.normal(-5, 3, n),
                          "Hn": rng.normal(100, 10, n),
                          "offset_flag": rng.integers(0, 4, n).astype(np.int8),
                          "quality": rng.integers(0, 64, n).astype(np.int16)}, index=index)
    frame.iloc[::500, :3] = np.nan
    with tempfile.TemporaryDirectory() as tmp:
        mine, theirs = Path(tmp) / "magcal.csv", Path(tmp) / "pandas.csv"

        def baseline():
            out = frame.copy()
            out.index = pd.Index(format_times(index), name="time")
            out.to_csv(theirs, float_format="%.4f", na_rep="NaN", index_label="time")

        base_s = best(baseline)[0]
        fast_s = best(lambda: write_csv_frame(mine, frame))[0]
        same = mine.read_bytes() == theirs.read_bytes()
    print(f"a day at 1 s ({n} rows): pandas to_csv {base_s:.2f} s, write_csv_frame "
          f"{fast_s:.2f} s = {base_s / fast_s:.1f}x (target >= 3x); byte-identical: {same}")


if __name__ == "__main__":
    main()
