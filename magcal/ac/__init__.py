"""AC cleaning of multi-sensor magnetometer data with PiCoG.

The principal-component gradiometer of Constantinescu et al. (2020): variance analysis
and first-order correction (:mod:`magcal.ac.core`), chained higher orders and upload
matrices (:mod:`magcal.ac.chain`), the sliding-window scan (:mod:`magcal.ac.scan`),
automatic plans (:mod:`magcal.ac.auto`), the non-orthogonal regression gradiometer
(:mod:`magcal.ac.nonorthogonal`), quality metrics (:mod:`magcal.ac.metrics`), plots
(:mod:`magcal.ac.plots`), PLAN.toml (:mod:`magcal.ac.plan`) and the estimator
(:class:`PiCoG`).
"""

from magcal.ac.chain import ChainResult, Order, Plan, Stage, apply_weights, run_chain
from magcal.ac.core import FirstOrderFit, correction_matrix, fit_first_order, variance_system
from magcal.ac.estimator import PiCoG, apply_upload
from magcal.ac.plan import read_plan
from magcal.ac.scan import ScanResult, ScanSummary, scan_first_order, summarize_scan

__all__ = ["PiCoG", "Plan", "Stage", "Order", "ChainResult", "run_chain", "apply_weights",
           "apply_upload", "fit_first_order", "FirstOrderFit", "correction_matrix",
           "variance_system", "scan_first_order", "summarize_scan", "ScanResult",
           "ScanSummary", "read_plan"]
