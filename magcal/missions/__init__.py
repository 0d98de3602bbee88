"""Mission adapters: what is particular to one spacecraft's files and instrument.

* :mod:`magcal.missions.goes` - GOES-R magnetometer L2 netCDF files (hires, 1-min);
* :mod:`magcal.missions.elfin_files` - ELFIN level-1 fluxgate and state CDF files;
* :mod:`magcal.missions.elfin`, :mod:`magcal.missions.elfin_phase` - ELFIN-A counts
  calibrated against IGRF per science zone (spin phase from the counts, time-stamp
  repairs).

The stage packages (``ac``, ``offsets``, ``spin``, ...) stay mission-independent; the
readers are reached through :func:`magcal.io.formats.read_any`.
"""
