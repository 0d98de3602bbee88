"""DC offsets of AC-cleaned data against a field model on quiet days.

* :mod:`magcal.offsets.averaging` - :func:`average_to_cadence` (1-min means, never
  across gaps);
* :mod:`magcal.offsets.windows` - :func:`window_grid`, :func:`window_statistics` (the
  28-day / 7-day sliding-window medians);
* :mod:`magcal.offsets.estimator` - :class:`OffsetEstimator`, :func:`fit_offsets` and
  :func:`fit_offsets_frame` (data minus model, Kp <= kp_max selection, coverage checks);
* :mod:`magcal.offsets.apply` - :func:`interpolate_offsets`, :func:`apply_offsets`,
  :func:`outside_valid_windows` (samples no valid window saw);
* :mod:`magcal.offsets.table` - :class:`OffsetTable` and the ``OFFSETS.csv`` reader and
  writer;
* :mod:`magcal.offsets.diagnostics` - residual versus local time per month (Fig. 19);
* :mod:`magcal.offsets.plots` - the Fig. 19 and Fig. 20 style plots.
"""

from magcal.offsets.apply import (FLAG_MEANING, apply_offsets, interpolate_offsets,
                                  outside_valid_windows)
from magcal.offsets.averaging import average_to_cadence
from magcal.offsets.diagnostics import local_time_hours, residual_by_local_time
from magcal.offsets.estimator import (OffsetEstimator, fit_offsets, fit_offsets_frame,
                                      quiet_mask)
from magcal.offsets.table import OffsetTable, read_offsets_csv, write_offsets_csv
from magcal.offsets.windows import window_coverage, window_grid, window_statistics

__all__ = ["FLAG_MEANING", "OffsetEstimator", "OffsetTable", "apply_offsets",
           "average_to_cadence", "fit_offsets", "fit_offsets_frame", "interpolate_offsets",
           "local_time_hours", "outside_valid_windows", "quiet_mask", "read_offsets_csv",
           "residual_by_local_time", "window_coverage", "window_grid", "window_statistics",
           "write_offsets_csv"]
