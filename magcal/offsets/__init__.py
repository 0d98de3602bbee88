"""DC offsets of AC-cleaned data against a field model on quiet days.

* :mod:`magcal.offsets.averaging` - :func:`average_to_cadence` (1-min means, never
  across gaps);
* :mod:`magcal.offsets.windows` - :func:`window_grid`, :func:`window_statistics` (the
  28-day / 7-day sliding-window medians);
* :mod:`magcal.offsets.estimator` - :class:`OffsetEstimator`, :func:`fit_offsets` and
  :func:`fit_offsets_frame` (data minus model, Kp <= kp_max selection, coverage checks);
* :mod:`magcal.offsets.apply` - :func:`interpolate_offsets`, :func:`apply_offsets`,
  :func:`outside_valid_windows` (samples no valid window saw), :func:`across_level_change`
  (samples whose interpolation spans a level change);
* :mod:`magcal.offsets.levels` - :func:`detect_level_changes` (sudden level changes of
  the offset in the record's day values);
* :mod:`magcal.offsets.table` - :class:`OffsetTable` and the ``OFFSETS.csv`` reader and
  writer;
* :mod:`magcal.offsets.diagnostics` - residual versus local time per month (Fig. 19);
* :mod:`magcal.offsets.plots` - the Fig. 19 and Fig. 20 style plots.
"""

from __future__ import annotations

from magcal._lazy import lazy_exports

#: Public name -> the submodule that defines it, imported on first use (PEP 562): the
#: estimator needs SciPy's statistics (about 1 s to import), which ``magcal offsets
#: --help`` and the light submodules do not.
_WHERE = {"FLAG_MEANING": "apply", "apply_offsets": "apply", "interpolate_offsets": "apply",
          "offset_uncertainty": "apply", "batch_standard_error": "windows",
          "outside_valid_windows": "apply", "average_to_cadence": "averaging",
          "local_time_hours": "diagnostics", "residual_by_local_time": "diagnostics",
          "OffsetEstimator": "estimator", "fit_offsets": "estimator",
          "fit_offsets_frame": "estimator", "quiet_mask": "estimator",
          "OffsetTable": "table", "read_offsets_csv": "table", "write_offsets_csv": "table",
          "window_coverage": "windows", "window_grid": "windows",
          "window_statistics": "windows", "across_level_change": "apply",
          "detect_level_changes": "levels", "LevelChange": "levels"}

__getattr__, __dir__, __all__ = lazy_exports(__name__, _WHERE, globals())
