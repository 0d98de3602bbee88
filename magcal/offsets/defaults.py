"""Default thresholds of the offset product, in a module that imports nothing heavy
(the ``magcal offsets`` command shows them in its help without loading SciPy)."""

#: Fewest of a window's days (fraction) that must hold used samples (7 of 28 days).
MIN_DAY_COVERAGE = 0.25
#: Fewest of the 24 local-time hours (fraction) that must hold used samples (12 of 24).
MIN_LT_COVERAGE = 0.5
#: Shortest piece (days) of a window split at a level change
#: (``OffsetEstimator(split_at_level_changes=True)``) that keeps its offset; shorter
#: pieces are NaN with the reason (:class:`magcal.offsets.OffsetEstimator` has the
#: measurements behind it).
MIN_PIECE_DAYS = 7.0
