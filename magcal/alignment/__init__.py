"""Alignment of calibrated data against a reference, with honest uncertainty.

Convention (CONTRACTS §3): ``data ~= R(w) @ ref`` with ``w`` the rotation vector about
(Hp, He, Hn). Closed form (:func:`fit_alignment`: Wahba start, generalised least squares
under a fitted correlated-noise model), full posterior (:func:`sample_posterior`, emcee),
angles by time window (:func:`angles_by_window`), validation against a reference
spacecraft in conjunction (:mod:`magcal.alignment.conjunction`), whether the data
determine the rotation at all (:mod:`magcal.alignment.determinability`), and the
ALIGN.json product (:func:`align_product`, :mod:`magcal.alignment.product`).
"""

from magcal.alignment.determinability import Determinability
from magcal.alignment.estimator import Aligner
from magcal.alignment.gls import fit_alignment
from magcal.alignment.noise import OUNoise, fit_noise, fit_ou, simulate_ou
from magcal.alignment.posterior import sample_posterior
from magcal.alignment.result import AlignmentResult
from magcal.alignment.wahba import wahba_rotation
from magcal.alignment.windows import WindowAngles, angles_by_window
from magcal.alignment.plots import plot_angles_by_window, plot_posterior_corner
from magcal.alignment.product import (AlignmentProduct, AlignSettings, align_product,
                                      match_frames)

__all__ = ["AlignSettings", "Aligner", "AlignmentProduct", "AlignmentResult",
           "Determinability", "OUNoise", "WindowAngles", "align_product", "angles_by_window",
           "fit_alignment", "fit_noise", "fit_ou", "match_frames", "plot_angles_by_window",
           "plot_posterior_corner", "sample_posterior", "simulate_ou", "wahba_rotation"]
