"""ELFIN-A fluxgate counts calibrated against IGRF, one science zone at a time.

The calibration path, in the order the pipeline runs it:

* :mod:`~magcal.missions.elfin.files` - the level-1 FGS and state CDF readers;
* :mod:`~magcal.missions.elfin.phase` - spin phase from the counts, zones, time-stamp
  repairs; :mod:`~magcal.missions.elfin.timing` - time stamps checked against the spin;
* :mod:`~magcal.missions.elfin.clipping` - saturated samples flagged;
* :mod:`~magcal.missions.elfin.linear` - the 12-parameter per-zone fit against IGRF;
* :mod:`~magcal.missions.elfin.harmonic` - the spin-harmonic (cubic) correction and the
  fast 1x/2x drift;
* :mod:`~magcal.missions.elfin.drift` - the spin-plane gain drift within a pass;
* :mod:`~magcal.missions.elfin.vector` - the vector step and the phase refit;
* :mod:`~magcal.missions.elfin.joint` - one fit across zones (opt-in);
* :mod:`~magcal.missions.elfin.scalar` - the residual measures (scalar, fast and slow
  parts, spin harmonics) that every step scores itself with;
* :mod:`~magcal.missions.elfin.settings` - :class:`ElfinSettings`, which steps run
  and what each trades in natural signal;
* :mod:`~magcal.missions.elfin.pipeline` - :func:`calibrate_elfin_day` (and
  :class:`ElfinSettings` again), called by the chain and the workflows;
* :mod:`~magcal.missions.elfin.detect` and :mod:`~magcal.missions.elfin.disturbed` -
  disturbed intervals located from the counts alone and left out of the fits
  (``detect_disturbed``; finds localized fields across B only);
* :mod:`~magcal.missions.elfin.perp` - a detected interval holding a Gaussian pulse
  across B fitted as a natural field in the reference instead of left out
  (``pulses_perp``), with its stated error (``perp_trials``);
* :mod:`~magcal.missions.elfin.levels` - where a left-out interval changes the
  spin-axis level (a current sheet), kept as a step (``level_steps``);
* :mod:`~magcal.missions.elfin.bridge` - the error of the product over the left-out
  intervals, measured on quiet trial gaps (``bridge_trials``);
* :mod:`~magcal.missions.elfin.injection` (and ``injection_plot``) - synthetic natural
  signals injected into the raw counts, to measure what each step keeps;
  :mod:`~magcal.missions.elfin.noise` - the same on counts with added instrument noise;
  :mod:`~magcal.missions.elfin.leave_out` - how much leaving a pulse's rows out of the
  fits moves the product with no signal injected (the whole-signal reading's floor).

:mod:`magcal.missions.elfin.diagnostics` holds what measures the product without
changing it: the vector evidence, the Sun-locked test, parameter stability, the
mechanism tables, the reference screens and the spin-ripple cross-check.
"""
