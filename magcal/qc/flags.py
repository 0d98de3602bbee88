"""The per-sample quality flag: bits, names and their meanings (CONTRACTS §7.1).

A ``quality`` value is the bitwise OR of the reasons a sample is not to be trusted;
0 means good. Bits 1-16 are fixed by the contract; higher bits are magcal's own checks,
listed here and in the README. The names are the CF ``flag_meanings`` of the netCDF
products, so they are single words.

Examples
--------
>>> int(SPIKE | STUCK)
3
>>> describe(SPIKE | OFFSET_HELD)
['spike', 'offset_held_or_extrapolated']
"""

from __future__ import annotations

import numpy as np

#: An isolated value far from its neighbours (Hampel test on the running median).
SPIKE = np.uint16(1)
#: Saturated (at the declared or detected instrument range) or stuck (one reading repeated).
STUCK = np.uint16(2)
#: Fill value or not finite in the input.
FILL = np.uint16(4)
#: Time stamp off the file's cadence grid.
TIME = np.uint16(8)
#: The offset applied was held beyond the first/last window centre or is missing.
OFFSET_HELD = np.uint16(16)
#: Field magnitude implausible against the model field.
IMPLAUSIBLE = np.uint16(32)
#: The offset applied was interpolated across a window without a valid offset
#: (``offset_flag`` 4): a line over twice the window step or more.
OFFSET_BRIDGED = np.uint16(64)
#: The offset applied was interpolated across a detected level change of the offset (a
#: sudden step, :mod:`magcal.offsets.levels`), or from a window straddling one: the line
#: spreads the change over a week or more, so the offset is off by up to the change.
OFFSET_ACROSS_LEVEL_CHANGE = np.uint16(128)
#: The sample lies inside the 95 % time interval of a level change of the offset at which
#: the windows were split (``split_at_level_changes``, :mod:`magcal.offsets.apply`):
#: which side's offset applies is uncertain here, so the offset may be off by the change.
OFFSET_NEAR_LEVEL_CHANGE = np.uint16(256)

#: Bit -> name, in bit order (the CF flag_masks / flag_meanings of every product).
FLAG_NAMES = {
    int(SPIKE): "spike",
    int(STUCK): "saturated_or_stuck",
    int(FILL): "fill_or_nonfinite",
    int(TIME): "time_anomaly",
    int(OFFSET_HELD): "offset_held_or_extrapolated",
    int(IMPLAUSIBLE): "implausible_vs_model",
    int(OFFSET_BRIDGED): "offset_bridged_over_missing_window",
    int(OFFSET_ACROSS_LEVEL_CHANGE): "offset_interpolated_across_level_change",
    int(OFFSET_NEAR_LEVEL_CHANGE): "offset_near_level_change",
}

#: Bits that keep a sample out of every fit, average and statistic (all but the offset
#: bits, which describe the correction applied, not the measurement).
EXCLUDE = np.uint16(int(SPIKE) | int(STUCK) | int(FILL) | int(TIME) | int(IMPLAUSIBLE))


def describe(value: int) -> list[str]:
    """Names of the bits set in one quality value."""
    return [name for bit, name in FLAG_NAMES.items() if int(value) & bit]


def counts(flags: np.ndarray) -> dict:
    """Samples carrying each bit: ``{name: count}`` (only bits that occur)."""
    flags = np.asarray(flags, dtype=np.uint16)
    out = {}
    for bit, name in FLAG_NAMES.items():
        n = int(np.count_nonzero(flags & bit))
        if n:
            out[name] = n
    return out
