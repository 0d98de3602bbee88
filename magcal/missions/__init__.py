"""Mission adapters: what is particular to one spacecraft's files and instrument.

* :mod:`magcal.missions.goes` - GOES-R magnetometer L2 netCDF files (hires, 1-min);
* :mod:`magcal.missions.elfin` - ELFIN-A level-1 fluxgate and state CDF files and the
  counts calibrated against IGRF per science zone (the calibration path in the package,
  the diagnostics in :mod:`magcal.missions.elfin.diagnostics`).

The stage packages (``ac``, ``offsets``, ``spin``, ...) stay mission-independent; the
readers are reached through :func:`magcal.io.formats.read_any`.
"""
