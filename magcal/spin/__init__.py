"""Calibration of spinning spacecraft (Kivelson et al. 1992, Galileo magnetometer).

* :mod:`magcal.spin.inputs` - reading a record, units (scale), spin sense, and the
  checks that refuse input breaking the model (counts as nT, spin tone on all axes).
* :mod:`magcal.spin.product` - the ``spincal`` and ``flipper`` products of a checked
  record.
* :mod:`magcal.spin.despin` - despinning and the spin phase (given, from a period, or
  derived from the data).
* :mod:`magcal.spin.harmonics` - spin-harmonic content of signals spin by spin.
* :mod:`magcal.spin.ripple` - spin-ripple calibration: the 8 determinable parameters of
  ``B = C (b - O)`` by minimising the spin tones of the despun field.
* :mod:`magcal.spin.flipper` - spin-axis offset ``O3`` from flipper intervals.
* :mod:`magcal.spin.calcoil` - rotation about the spin axis from the calibration coil.
* :mod:`magcal.spin.onboard_filter` - the on-board recursive filter and its inverse.
* :mod:`magcal.spin.redigitise` - non-equispaced to equispaced by frequency folding.
"""

from magcal.spin.despin import despin, phase_from_data, phase_from_period, spin
from magcal.spin.ripple import (DETERMINABLE, FIXED_BY_RIPPLE, PARAM_NAMES, SpinCalibration,
                                SpinRippleCalibrator, fit_spin_ripple, spin_tone)

__all__ = ["despin", "spin", "phase_from_data", "phase_from_period", "DETERMINABLE",
           "FIXED_BY_RIPPLE", "PARAM_NAMES", "SpinCalibration", "SpinRippleCalibrator",
           "fit_spin_ripple", "spin_tone"]
