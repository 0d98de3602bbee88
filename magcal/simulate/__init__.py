"""Seeded simulators with known truth, used by every test and by ``data_samples/``.

* :mod:`magcal.simulate.geostationary` - GK-2A-like multi-sensor spacecraft at 1 s:
  ambient field, disturbers, sensors, offsets; returns measurements and truth.
* :mod:`magcal.simulate.month` - a month (or more) of 1-min Hpen data with its Kp
  series, drifting offsets and the local-time field the model lacks.
* :mod:`magcal.simulate.spinning` - Galileo-like and ELFIN-like spinning spacecraft.

Every generator takes an explicit :class:`numpy.random.Generator`.
Names are imported lazily so ``import magcal.simulate`` stays cheap.
"""

from __future__ import annotations

import importlib

_LAZY = {
    "simulate_geostationary": "magcal.simulate.geostationary",
    "GeostationaryConfig": "magcal.simulate.geostationary",
    "simulate_month": "magcal.simulate.month",
    "MonthConfig": "magcal.simulate.month",
    "simulate_spinning": "magcal.simulate.spinning",
    "SpinningConfig": "magcal.simulate.spinning",
}

__all__ = sorted(_LAZY)


def __getattr__(name):
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'magcal.simulate' has no attribute {name!r}")
