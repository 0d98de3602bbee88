"""Closed-form rotation between two sets of vectors (Wahba's problem).

Convention (CONTRACTS §3): ``data ~= R(w) @ ref`` where ``R`` is the rotation whose
rotation vector is ``w = (wp, we, wn)`` about the Hp, He, Hn axes, applied to the
component vectors as stored (:meth:`scipy.spatial.transform.Rotation.from_rotvec`).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation


def wahba_rotation(data, ref, weights=None, center: bool = False):
    """Least-squares rotation (and, with ``center``, offset) mapping ``ref`` onto ``data``.

    Solves ``min sum_i w_i |data_i - R ref_i - o|^2`` in closed form with
    :meth:`scipy.spatial.transform.Rotation.align_vectors` (Kabsch/SVD). With
    ``center=True`` both sets are centred first, which is the closed form of the
    problem with a free offset ``o`` (Kabsch); otherwise ``o = 0``.

    Parameters
    ----------
    data, ref : array_like, shape (n, 3)
        Vectors in nT.
    weights : array_like, shape (n,), optional
    center : bool
        Fit a constant offset as well.

    Returns
    -------
    rotvec_rad : ndarray, shape (3,)
    offset_nT : ndarray, shape (3,)
        Zero when ``center`` is False.
    sensitivity : ndarray, shape (3, 3)
        scipy's sensitivity matrix (proportional to the covariance of the rotation
        vector for independent isotropic errors); the calibrated covariance comes from
        :func:`magcal.alignment.gls.fit_alignment`.

    Examples
    --------
    >>> ref = np.array([[100.0, 0, 0], [0, 30.0, 0], [0, 0, 20.0], [50.0, 10, -5]])
    >>> true = Rotation.from_rotvec(np.deg2rad([1.0, -2.0, 0.5]))
    >>> w, o, _ = wahba_rotation(true.apply(ref) + [1.0, 2.0, 3.0], ref, center=True)
    >>> np.rad2deg(w).round(6), o.round(6)
    (array([ 1. , -2. ,  0.5]), array([1., 2., 3.]))
    """
    d = np.asarray(data, dtype=float)
    r = np.asarray(ref, dtype=float)
    wts = None if weights is None else np.asarray(weights, dtype=float)
    if center:
        wn = np.ones(len(d)) if wts is None else wts
        d_mean = np.average(d, axis=0, weights=wn)
        r_mean = np.average(r, axis=0, weights=wn)
        rot, _, sens = Rotation.align_vectors(d - d_mean, r - r_mean, weights=wts,
                                              return_sensitivity=True)
        offset = d_mean - rot.apply(r_mean)
    else:
        rot, _, sens = Rotation.align_vectors(d, r, weights=wts, return_sensitivity=True)
        offset = np.zeros(3)
    return rot.as_rotvec(), offset, sens
