"""Sample quality control: spikes, saturated and stuck values, fills, time anomalies
and magnitudes implausible against the model, as a per-sample bit flag.

Every input of ``magcal run`` goes through :func:`flag_samples` before any fit; the
flags travel with the samples into the corrected products (their ``quality`` column)
and keep flagged samples out of PiCoG, the offsets, the alignment and discovery.
Bits and names: :mod:`magcal.qc.flags`; checks: :mod:`magcal.qc.checks`.
"""

from magcal.qc.flags import EXCLUDE, FLAG_NAMES, describe
from magcal.qc.quality import QCResult, QCSettings, flag_samples, masked, plausibility_flags

__all__ = ["EXCLUDE", "FLAG_NAMES", "QCResult", "QCSettings", "describe", "flag_samples",
           "masked", "plausibility_flags"]
