"""AC cleaning of multi-sensor magnetometer data with PiCoG.

The principal-component gradiometer of Constantinescu et al. (2020): variance analysis
and first-order correction (:mod:`magcal.ac.core`), chained higher orders and upload
matrices (:mod:`magcal.ac.chain`), the sliding-window scan (:mod:`magcal.ac.scan`),
automatic plans (:mod:`magcal.ac.auto`), the non-orthogonal regression gradiometer
(:mod:`magcal.ac.nonorthogonal`), the joint pair fit (:mod:`magcal.ac.joint`), quality
metrics (:mod:`magcal.ac.metrics`), the per-band check of a product against the raw
sensor (:mod:`magcal.ac.bandcheck`), steps, spikes and remnants
(:mod:`magcal.ac.events`), daily-refit stability (:mod:`magcal.ac.stability`), plots
(:mod:`magcal.ac.plots`), PLAN.toml (:mod:`magcal.ac.plan`) and the estimator
(:class:`PiCoG`, with the fitted sample grid :func:`fit_time_grid`).
"""

from magcal.ac.bandcheck import BandCheck, band_check
from magcal.ac.chain import ChainResult, Order, Plan, Stage, apply_weights, run_chain
from magcal.ac.core import FirstOrderFit, correction_matrix, fit_first_order, variance_system
from magcal.ac.estimator import (PiCoG, TimeGrid, apply_params, apply_upload, fit_time_grid,
                                 params_from_json)
from magcal.ac.plan import read_plan
from magcal.ac.scan import ScanResult, ScanSummary, scan_first_order, summarize_scan

__all__ = ["PiCoG", "Plan", "Stage", "Order", "ChainResult", "run_chain", "apply_weights",
           "apply_upload", "apply_params", "params_from_json", "fit_time_grid", "TimeGrid",
           "band_check", "BandCheck", "fit_first_order", "FirstOrderFit",
           "correction_matrix", "variance_system", "scan_first_order", "summarize_scan",
           "ScanResult", "ScanSummary", "read_plan"]
