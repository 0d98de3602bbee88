"""magcal: calibrated magnetic field products from raw multi-sensor spacecraft magnetometer data.

Importing magcal has no side effects: no files are written, nothing is downloaded and
no heavy dependency (spacepy, astropy, matplotlib) is imported until a stage needs it.
Call :func:`magcal.offline.configure_offline` (the CLI does) before a stage that uses
spacepy or astropy when running without network access.
"""

from magcal._version import __version__
from magcal.errors import InputError, MagcalError

__all__ = ["__version__", "InputError", "MagcalError"]
