"""Static magnetic fields of point dipoles and dipole-pair quadrupoles (PiCoG §2.1).

All positions in metres, moments in A m^2, fields in nT. The dipole field is

    b(r) = mu0 / (4 pi) * (3 (m . r_hat) r_hat - m) / r^3,

with mu0 / (4 pi) = 1e-7 T m / A = 100 nT m^3 / (A m^2). A quadrupole is modelled as
two opposite dipoles ``+m`` at ``p + s/2`` and ``-m`` at ``p - s/2`` (separation vector
``s``); far from the pair its field falls as 1/r^4.
"""

from __future__ import annotations

import numpy as np

#: mu0 / (4 pi) in nT m^3 / (A m^2).
MU0_OVER_4PI_NT = 100.0


def dipole_field(moment_Am2, source_m, points_m) -> np.ndarray:
    """Field of a point dipole at the given points.

    Parameters
    ----------
    moment_Am2 : array_like, shape (3,) or (k, 3)
        Dipole moment(s). With ``k`` moments the result has a leading axis of length
        ``k`` (one field pattern per moment).
    source_m : array_like, shape (3,)
        Position of the dipole.
    points_m : array_like, shape (p, 3) or (3,)
        Where to evaluate the field.

    Returns
    -------
    ndarray, shape (p, 3) or (k, p, 3)
        Field in nT.

    Raises
    ------
    ValueError
        If a point coincides with the source.

    Examples
    --------
    A 1 A m^2 dipole along z, seen 1 m away on its axis and on its equator:

    >>> dipole_field([0, 0, 1.0], [0, 0, 0], [[0, 0, 1.0], [1.0, 0, 0]])
    array([[   0.,    0.,  200.],
           [   0.,    0., -100.]])
    """
    m = np.asarray(moment_Am2, dtype=float)
    single = m.ndim == 1
    m = np.atleast_2d(m)
    pts = np.atleast_2d(np.asarray(points_m, dtype=float))
    r = pts - np.asarray(source_m, dtype=float)[None, :]
    dist = np.linalg.norm(r, axis=1)
    if np.any(dist <= 0.0):
        raise ValueError("field requested at the position of the dipole")
    r_hat = r / dist[:, None]
    m_dot_r = m @ r_hat.T  # (k, p)
    field = (3.0 * m_dot_r[:, :, None] * r_hat[None, :, :] - m[:, None, :])
    field *= (MU0_OVER_4PI_NT / dist**3)[None, :, None]
    return field[0] if single else field


def quadrupole_field(moment_Am2, source_m, separation_m, points_m) -> np.ndarray:
    """Field of a dipole pair ``+m`` at ``p + s/2`` and ``-m`` at ``p - s/2``.

    Parameters
    ----------
    moment_Am2 : array_like, shape (3,) or (k, 3)
        Moment ``m`` of the positive dipole.
    source_m : array_like, shape (3,)
        Centre ``p`` of the pair.
    separation_m : array_like, shape (3,)
        Separation vector ``s`` from the negative to the positive dipole.
    points_m : array_like, shape (p, 3) or (3,)
        Where to evaluate the field.

    Returns
    -------
    ndarray, shape (p, 3) or (k, p, 3)
        Field in nT; it falls as 1/r^4 at distances much larger than ``|s|``.

    Examples
    --------
    Doubling the distance along the axis divides the field by about 16:

    >>> near = quadrupole_field([0, 0, 1.0], [0, 0, 0], [0, 0, 0.01], [0, 0, 1.0])
    >>> far = quadrupole_field([0, 0, 1.0], [0, 0, 0], [0, 0, 0.01], [0, 0, 2.0])
    >>> round(float(near[0, 2] / far[0, 2]), 2)
    16.0
    """
    p = np.asarray(source_m, dtype=float)
    s = np.asarray(separation_m, dtype=float)
    return (dipole_field(moment_Am2, p + 0.5 * s, points_m)
            - dipole_field(moment_Am2, p - 0.5 * s, points_m))
