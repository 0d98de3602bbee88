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

from __future__ import annotations

from magcal._lazy import lazy_exports

#: Public name -> the submodule that defines it, imported on first use (PEP 562): the
#: band check needs scipy.signal (which imports scipy.stats: about 0.8 s), which a
#: chain with ``plan = "none"`` and ``magcal picog --help`` do not.
_WHERE = {"BandCheck": "bandcheck", "band_check": "bandcheck",
          "ChainResult": "chain", "Order": "chain", "Plan": "chain", "Stage": "chain",
          "apply_weights": "chain", "run_chain": "chain",
          "FirstOrderFit": "core", "correction_matrix": "core", "fit_first_order": "core",
          "variance_system": "core",
          "PiCoG": "estimator", "TimeGrid": "estimator", "apply_params": "estimator",
          "apply_upload": "estimator", "fit_time_grid": "estimator",
          "params_from_json": "estimator",
          "read_plan": "plan",
          "ScanResult": "scan", "ScanSummary": "scan", "scan_first_order": "scan",
          "summarize_scan": "scan"}

__getattr__, __dir__, __all__ = lazy_exports(__name__, _WHERE, globals())
