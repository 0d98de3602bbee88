"""Geomagnetic indices and Tsyganenko model drivers.

Readers detect the file format from the content and return pandas objects with a
tz-aware UTC index named ``time``:

- :func:`read_kp` -> Series of Kp in exact thirds (index = start of each 3-hour
  interval); :func:`kp_at` looks values up at arbitrary times; :func:`kp_to_irbem`
  gives the one-decimal values IRBEM expects; :func:`kp_thirds_label` the ``1+``
  notation.
- :func:`read_drivers` -> DataFrame with the 16 IRBEM input columns
  (:data:`DRIVER_COLUMNS`); :func:`drivers_at` interpolates them into the ``omnivals``
  dict for ``irbempy.get_Bfield``.
"""

from magcal.indices.drivers import DRIVER_COLUMNS, drivers_at, read_drivers
from magcal.indices.kp import (kp_at, kp_thirds_label, kp_to_irbem, read_kp,
                               snap_to_thirds, write_kp_csv)

__all__ = ["DRIVER_COLUMNS", "drivers_at", "kp_at", "kp_thirds_label", "kp_to_irbem",
           "read_drivers", "read_kp", "snap_to_thirds", "write_kp_csv"]
