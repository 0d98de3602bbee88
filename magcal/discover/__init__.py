"""Model-gap discovery: find, name and add what a model of the field is missing.

The user holds measured data and a model of it. :func:`discover_gap` measures the gap
(residual = measured - model), fits every candidate effect of the vocabulary of
CONTRACTS §5 (``offset``, ``drift``, ``diurnal``, ``temperature``, ``scale``,
``rotation``, ``activity``, ``spin_tone``, ``step``, ``periodic``) jointly with the
effects already added, adds the one with the strongest held-out evidence and repeats
until no candidate earns its parameters.

Modules: :mod:`~magcal.discover.effects` (vocabulary and regressors),
:mod:`~magcal.discover.selection` (blocked cross-validation),
:mod:`~magcal.discover.scan` (step and period scans),
:mod:`~magcal.discover.step_time` (a named step time's interval),
:mod:`~magcal.discover.break_time` (a drift break's), :mod:`~magcal.discover.gap`
(where the residual concentrates), :mod:`~magcal.discover.loop` (the loop and its
result), :mod:`~magcal.discover.account` (text), :mod:`~magcal.discover.plots`.
"""

from magcal.discover.effects import EFFECT_NAMES
from magcal.discover.loop import (DiscoveryResult, DiscoverySettings, FittedEffect, discover,
                                  discover_gap)

__all__ = ["EFFECT_NAMES", "DiscoveryResult", "DiscoverySettings", "FittedEffect", "discover",
           "discover_gap"]
