"""The rotating spacecraft frame and the despun frame of a spinner (CONTRACTS §4).

``BX = Bx cos p - By sin p``, ``BY = Bx sin p + By cos p``, ``BZ = Bz`` with the spin
phase ``p``: a rotation about the spin axis, used by the spin calibration, the ELFIN
adapter and the spinning-spacecraft simulator alike.
"""

from __future__ import annotations

import numpy as np

TWO_PI = 2.0 * np.pi


def despin(b_sc, phase_rad) -> np.ndarray:
    """Rotate spacecraft-frame vectors into the despun (inertial) frame.

    Parameters
    ----------
    b_sc : array_like, shape (n, 3)
        Field in the rotating spacecraft frame (x, y in the spin plane, z spin axis).
    phase_rad : array_like, shape (n,)
        Spin phase ``p`` of each sample.

    Returns
    -------
    ndarray, shape (n, 3)
        ``(BX, BY, BZ)``.

    Examples
    --------
    >>> import numpy as np
    >>> despin([[1.0, 0.0, 5.0]], [np.pi / 2]).round(12)
    array([[0., 1., 5.]])
    """
    b = np.asarray(b_sc, dtype=float)
    p = np.asarray(phase_rad, dtype=float)
    c, s = np.cos(p), np.sin(p)
    out = np.empty_like(b)
    out[:, 0] = b[:, 0] * c - b[:, 1] * s
    out[:, 1] = b[:, 0] * s + b[:, 1] * c
    out[:, 2] = b[:, 2]
    return out


def spin(b_despun, phase_rad) -> np.ndarray:
    """Inverse of :func:`despin`: despun vectors into the rotating spacecraft frame.

    Examples
    --------
    >>> import numpy as np
    >>> spin(despin([[1.0, 2.0, 3.0]], [0.7]), [0.7]).round(12)
    array([[1., 2., 3.]])
    """
    return despin(b_despun, -np.asarray(phase_rad, dtype=float))
