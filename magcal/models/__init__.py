"""Model magnetic field at the spacecraft: IGRF and Tsyganenko models through IRBEM.

* :mod:`magcal.models.irbem` - the array core: :func:`field_geo` / :func:`evaluate_geo`
  (GEO cartesian nT at GEO positions, ctypes fast path on spacepy's IRBEM library).
* :mod:`magcal.models.field` - :func:`model_field_hpen`: Hpen field along an orbit at a
  chosen cadence, in parallel processes, with an on-disk cache.

Names are imported lazily so ``import magcal.models`` stays cheap.
"""

from __future__ import annotations

import importlib

_LAZY = {
    "field_geo": "magcal.models.irbem",
    "evaluate_geo": "magcal.models.irbem",
    "GeoFieldResult": "magcal.models.irbem",
    "ModelRangeWarning": "magcal.models.irbem",
    "kp_to_irbem": "magcal.models.irbem",
    "geo_position_re": "magcal.models.irbem",
    "model_field_hpen": "magcal.models.field",
    "ModelFieldResult": "magcal.models.field",
}

__all__ = sorted(_LAZY)


def __getattr__(name):
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'magcal.models' has no attribute {name!r}")
