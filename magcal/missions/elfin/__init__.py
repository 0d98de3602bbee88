"""ELFIN-A fluxgate counts calibrated against IGRF, one science zone at a time.

The calibration path, in the order the pipeline runs it:

* :mod:`~magcal.missions.elfin.files` - the level-1 FGS and state CDF readers;
* :mod:`~magcal.missions.elfin.phase` - spin phase from the counts, zones, time-stamp
  repairs; :mod:`~magcal.missions.elfin.timing` - time stamps checked against the spin;
* :mod:`~magcal.missions.elfin.linear` - the 12-parameter per-zone fit against IGRF;
* :mod:`~magcal.missions.elfin.harmonic` - the spin-harmonic (cubic) correction and the
  fast 1x/2x drift;
* :mod:`~magcal.missions.elfin.drift` - the spin-plane gain drift within a pass;
* :mod:`~magcal.missions.elfin.vector` - the vector step and the phase refit;
* :mod:`~magcal.missions.elfin.joint` - one fit across zones (opt-in);
* :mod:`~magcal.missions.elfin.scalar` - the residual measures (scalar, fast and slow
  parts, spin harmonics) that every step scores itself with;
* :mod:`~magcal.missions.elfin.pipeline` - :func:`calibrate_elfin_day` and
  :class:`ElfinSettings`, called by the chain and the workflows;
* :mod:`~magcal.missions.elfin.injection` - synthetic natural signals injected into the
  raw counts, to measure what each step keeps;
* :mod:`~magcal.missions.elfin.detect` - disturbed intervals located from the counts
  alone (opt-in ``detect_disturbed``; finds localized fields across B only).

:mod:`magcal.missions.elfin.diagnostics` holds what measures the product without
changing it: the vector evidence, the Sun-locked test, parameter stability, the
mechanism tables, the reference screens and the spin-ripple cross-check.
"""
