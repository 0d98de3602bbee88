"""ELFIN-A diagnostics: measurements of the calibrated product that do not change it.

* :mod:`~magcal.missions.elfin.diagnostics.evidence` - vector/scalar evidence by time
  scale and direction;
* :mod:`~magcal.missions.elfin.diagnostics.sun` - the Sun-locked test with a control
  angle;
* :mod:`~magcal.missions.elfin.diagnostics.stability` - per-zone parameter errors and
  the spread over zones;
* :mod:`~magcal.missions.elfin.diagnostics.mechanisms` - the scalar-floor mechanism
  tables;
* :mod:`~magcal.missions.elfin.diagnostics.reference` - the reference screens of the
  slow part;
* :mod:`~magcal.missions.elfin.diagnostics.ripple` - the spin-ripple cross-check.
"""
