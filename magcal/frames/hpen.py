"""The Hpen frame from a geographic position, and GK-2A's nominal OSRF -> Hpen mapping.

Hpen unit vectors at geographic longitude ``lon`` and latitude ``lat`` (geocentric,
expressed in GEO cartesian coordinates):

* ``p`` (Hp) = local north, perpendicular to the radius in the meridian plane;
* ``e`` (He) = earthward, ``-r_hat``;
* ``n`` (Hn) = east, ``phi_hat``.

At the geographic equator ``p`` is the GEO z axis, so Hp is the field component along
Earth's rotation axis, as in the GOES EPN frame. The triad is left-handed
(``p x e = -n``), so converting to Hpen is an orthogonal map with determinant -1, not a
rotation: it is written here as a projection on the three unit vectors.
"""

from __future__ import annotations

import numpy as np


def hpen_basis(lon_deg, lat_deg) -> np.ndarray:
    """Hpen unit vectors in GEO cartesian coordinates.

    Parameters
    ----------
    lon_deg, lat_deg : float or array_like, shape (n,)
        Geographic (geocentric) longitude and latitude in degrees.

    Returns
    -------
    ndarray, shape (n, 3, 3)
        ``basis[k]`` has rows ``p, e, n`` so that ``b_hpen = basis @ b_geo``.

    Examples
    --------
    >>> hpen_basis(0.0, 0.0)[0].round(12) + 0.0
    array([[ 0.,  0.,  1.],
           [-1.,  0.,  0.],
           [ 0.,  1.,  0.]])
    """
    lon = np.deg2rad(np.atleast_1d(np.asarray(lon_deg, dtype=float)))
    lat = np.deg2rad(np.atleast_1d(np.asarray(lat_deg, dtype=float)))
    lon, lat = np.broadcast_arrays(lon, lat)
    clon, slon, clat, slat = np.cos(lon), np.sin(lon), np.cos(lat), np.sin(lat)
    r_hat = np.stack([clat * clon, clat * slon, slat], axis=-1)
    north = np.stack([-slat * clon, -slat * slon, clat], axis=-1)
    east = np.stack([-slon, clon, np.zeros_like(lon)], axis=-1)
    return np.stack([north, -r_hat, east], axis=-2)


def geo_to_hpen(b_geo, lon_deg, lat_deg) -> np.ndarray:
    """Project GEO cartesian vectors on the Hpen axes at the given positions.

    Parameters
    ----------
    b_geo : array_like, shape (n, 3) or (3,)
        Field in GEO cartesian components (nT).
    lon_deg, lat_deg : float or array_like, shape (n,)
        Position (degrees); scalars apply to all samples.

    Returns
    -------
    ndarray, shape (n, 3)
        ``(Hp, He, Hn)`` in nT.

    Examples
    --------
    A field along GEO +z at the equator is all Hp:

    >>> geo_to_hpen([0.0, 0.0, 100.0], 135.0, 0.0).round(9)
    array([[100.,   0.,   0.]])
    """
    b = np.atleast_2d(np.asarray(b_geo, dtype=float))
    basis = hpen_basis(lon_deg, lat_deg)
    if basis.shape[0] == 1:  # one position: a plain matrix product (BLAS, ~10x einsum)
        return b @ basis[0].T
    return np.einsum("nij,nj->ni", basis, b) if basis.shape[0] == b.shape[0] else (
        _shape_error(b, basis))


def hpen_to_geo(b_hpen, lon_deg, lat_deg) -> np.ndarray:
    """Inverse of :func:`geo_to_hpen` (the basis is orthonormal: transpose)."""
    b = np.atleast_2d(np.asarray(b_hpen, dtype=float))
    basis = hpen_basis(lon_deg, lat_deg)
    if basis.shape[0] == 1:
        return b @ basis[0]
    return np.einsum("nji,nj->ni", basis, b) if basis.shape[0] == b.shape[0] else (
        _shape_error(b, basis))


def osrf_to_hpen(b_osrf) -> np.ndarray:
    """GK-2A nominal attitude (SOSMAG paper §5.1): Hp = By, He = Bx, Hn = Bz of the OSRF.

    Examples
    --------
    >>> osrf_to_hpen([1.0, 2.0, 3.0])
    array([[2., 1., 3.]])
    """
    b = np.atleast_2d(np.asarray(b_osrf, dtype=float))
    return b[:, [1, 0, 2]].copy()


def _shape_error(b, basis):
    raise ValueError(f"{b.shape[0]} vectors but {basis.shape[0]} positions")
