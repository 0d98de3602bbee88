"""Geocentric frames (GEO, GEI, GSE, GSM, SM) and the Hpen frame, for vectors.

The rotations come from IRBEM through :class:`spacepy.coordinates.Coords`
(``use_irbem=True``, about 14 us per point; spacepy's default backend needs about 16 ms
per distinct time). Nothing here writes a rotation by hand: at each distinct time the
three GEO unit vectors (or those of the source frame) are sent through the library, and
the images are the columns of the rotation matrix. All these frames share the Earth's
centre as origin, so field vectors and position vectors transform the same way (no
translation is ever involved).

Time resolution: spacepy passes IRBEM whole UTC seconds (it drops the fraction), so the
matrices are evaluated at each sample time rounded to the nearest whole second, once per
distinct second. The largest rotation rate among these frames is the Earth's
(7.3e-5 rad/s), so the rounding error is at most 3.6e-5 of |B| (0.004 nT at 100 nT).

IRBEM's GSE axes are built from rounded constants: they are orthonormal only to about
3e-5 (a GSE vector can be off by 0.003 nT in 100 nT from an exact rotation), while
the GEO, GEI, GSM and SM matrices are orthonormal to 1e-15. Each inverse transform is
the exact inverse (round trips close to 1e-15). The GOES-R files' own GSE and ECI
fields are related by the same matrices (to 5e-5 nT), so this is kept as the library
gives it rather than re-orthonormalised.

Frame names follow spacepy/IRBEM: ``GEO`` geographic (Earth-fixed), ``GEI`` IRBEM's
geocentric equatorial inertial of date (the GOES-R ``b_eci`` agrees with it to 5e-5 nT),
``GSE``, ``GSM`` and ``SM`` (dipole axis of IGRF at the date).

Examples
--------
>>> import numpy as np
>>> b = np.array([[0.0, 0.0, 100.0]])
>>> b_gsm = convert_vectors(b, ["2017-03-05T02:09:00"], "GEO", "GSM")
>>> round(float(np.linalg.norm(b_gsm)), 9)
100.0
>>> convert_vectors(b_gsm, ["2017-03-05T02:09:00"], "GSM", "GEO").round(9) + 0.0
array([[  0.,   0., 100.]])
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from magcal.errors import InputError
from magcal.frames.hpen import geo_to_hpen, hpen_to_geo
from magcal.offline import ensure_spacepy_dir
from magcal.timeconv import utc_index

#: Frames understood by :func:`convert_vectors` (spacepy/IRBEM names).
FRAMES = ("GEO", "GEI", "GSE", "GSM", "SM")
#: Geostationary orbit radius in Earth radii, as used by the CLI (CONTRACTS §2).
GEOSTATIONARY_R_RE = 6.6
#: Earth radius used to express positions in RE (IRBEM's value), km.
EARTH_RADIUS_KM = 6371.2

_CHUNK = 30_000  # unique seconds per spacepy call (3 points each)


def _frame(name: str) -> str:
    key = str(name).strip().upper()
    if key not in FRAMES:
        raise InputError(f"unknown frame {name!r}; expected one of {', '.join(FRAMES)}")
    return key


def _vectors(b, n_times: int, what: str = "b") -> np.ndarray:
    arr = np.asarray(b, dtype=float)
    if arr.ndim == 1:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise InputError(f"{what} must have shape (n, 3), got {np.shape(b)}")
    if arr.shape[0] != n_times:
        raise InputError(f"{what} has {arr.shape[0]} vectors but {n_times} times were given")
    return arr


def _irbem_matrices(seconds_ns: np.ndarray, from_frame: str, to_frame: str) -> np.ndarray:
    """Rotation matrices at whole-second UTC times (int64 ns since 1970), via spacepy/IRBEM."""
    ensure_spacepy_dir()
    import spacepy.coordinates as spc
    from spacepy.time import Ticktock

    out = np.empty((seconds_ns.size, 3, 3))
    for start in range(0, seconds_ns.size, _CHUNK):
        part = seconds_ns[start:start + _CHUNK]
        dts = pd.DatetimeIndex(part.astype("datetime64[ns]")).to_pydatetime()
        coords = spc.Coords(np.tile(np.eye(3), (part.size, 1)), from_frame, "car",
                            units=["Re", "Re", "Re"], use_irbem=True)
        coords.ticks = Ticktock(np.repeat(dts, 3), "UTC")
        images = np.asarray(coords.convert(to_frame, "car").data).reshape(part.size, 3, 3)
        out[start:start + part.size] = images.transpose(0, 2, 1)  # images are the columns
    return out


def rotation_matrices(times, from_frame: str, to_frame: str) -> np.ndarray:
    """Matrices ``M`` with ``b_to = M @ b_from`` at each time.

    Parameters
    ----------
    times : array_like of datetime-like, shape (n,)
        UTC times (naive values are taken as UTC). Rounded to whole seconds.
    from_frame, to_frame : str
        One of :data:`FRAMES`.

    Returns
    -------
    ndarray, shape (n, 3, 3)
        One matrix per time: rotations (orthonormal to 1e-15, determinant +1), except
        that IRBEM's GSE axes are orthonormal only to about 3e-5 (module docstring).

    Examples
    --------
    >>> m = rotation_matrices(["2017-04-14T19:24:00"], "GEO", "GSM")[0]
    >>> bool(np.allclose(m @ m.T, np.eye(3), atol=1e-12)), round(float(np.linalg.det(m)), 12)
    (True, 1.0)
    """
    f, t = _frame(from_frame), _frame(to_frame)
    idx = utc_index(times, allow_nat=False)
    if f == t:
        return np.broadcast_to(np.eye(3), (len(idx), 3, 3)).copy()
    seconds = idx.tz_convert("UTC").tz_localize(None).round("s").as_unit("ns").asi8
    unique, inverse = np.unique(seconds, return_inverse=True)
    return _irbem_matrices(unique, f, t)[inverse]


def convert_vectors(b, times, from_frame: str, to_frame: str) -> np.ndarray:
    """Rotate vectors (field or geocentric position) between geocentric frames.

    Parameters
    ----------
    b : array_like, shape (n, 3) or (3,)
        Vectors in ``from_frame`` (any unit; NaN rows stay NaN).
    times : array_like of datetime-like, shape (n,)
        UTC time of each vector.
    from_frame, to_frame : str
        One of :data:`FRAMES`.

    Returns
    -------
    ndarray, shape (n, 3)

    Examples
    --------
    The GEO z axis (Earth's rotation axis) is also the GEI z axis:

    >>> convert_vectors([0.0, 0.0, 10.0], ["2017-03-05T02:09:00"], "GEO", "GEI").round(9) + 0.0
    array([[ 0.,  0., 10.]])
    """
    idx = utc_index(times, allow_nat=False)
    vec = _vectors(b, len(idx))
    return np.einsum("nij,nj->ni", rotation_matrices(idx, from_frame, to_frame), vec)


def to_hpen(b, times, lon_deg, lat_deg, frame: str = "GEO") -> np.ndarray:
    """Field in a geocentric frame -> ``(Hp, He, Hn)`` at the given geographic position.

    Parameters
    ----------
    b : array_like, shape (n, 3) or (3,)
        Field in ``frame`` (nT).
    times : array_like of datetime-like, shape (n,)
        UTC times.
    lon_deg, lat_deg : float or array_like, shape (n,)
        Geographic (geocentric) longitude and latitude of the spacecraft, degrees.
    frame : str
        One of :data:`FRAMES`.

    Returns
    -------
    ndarray, shape (n, 3)
        ``Hp`` (north), ``He`` (earthward), ``Hn`` (east), nT.

    Examples
    --------
    >>> to_hpen([0.0, 0.0, 100.0], ["2017-03-05T02:09:00"], -89.5, 0.0, "GEO").round(9) + 0.0
    array([[100.,   0.,   0.]])
    """
    b_geo = convert_vectors(b, times, frame, "GEO")
    return geo_to_hpen(b_geo, lon_deg, lat_deg)


def hpen_to(b_hpen, times, lon_deg, lat_deg, frame: str = "GEO") -> np.ndarray:
    """Inverse of :func:`to_hpen`: ``(Hp, He, Hn)`` -> field in ``frame``.

    Examples
    --------
    >>> hpen_to([100.0, 0.0, 0.0], ["2017-03-05T02:09:00"], -89.5, 0.0, "GEO").round(9) + 0.0
    array([[  0.,   0., 100.]])
    """
    idx = utc_index(times, allow_nat=False)
    vec = _vectors(b_hpen, len(idx), "b_hpen")
    b_geo = hpen_to_geo(vec, lon_deg, lat_deg)
    return convert_vectors(b_geo, idx, "GEO", frame)


def position_geo(lon_deg, lat_deg=0.0, r_re=GEOSTATIONARY_R_RE) -> np.ndarray:
    """GEO cartesian position (RE) from geographic longitude, latitude (deg) and radius (RE).

    Examples
    --------
    >>> position_geo(90.0).round(12) + 0.0
    array([[0. , 6.6, 0. ]])
    """
    lon, lat, r = np.broadcast_arrays(np.atleast_1d(np.asarray(lon_deg, dtype=float)),
                                      np.atleast_1d(np.asarray(lat_deg, dtype=float)),
                                      np.atleast_1d(np.asarray(r_re, dtype=float)))
    lon, lat = np.deg2rad(lon), np.deg2rad(lat)
    return np.stack([r * np.cos(lat) * np.cos(lon), r * np.cos(lat) * np.sin(lon),
                     r * np.sin(lat)], axis=-1)


def llr_from_geo(xyz) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Inverse of :func:`position_geo`: ``(lon_deg, lat_deg, r)`` in the unit of ``xyz``.

    Examples
    --------
    >>> [float(v[0]) for v in llr_from_geo([[0.0, -6.6, 0.0]])]
    [-90.0, 0.0, 6.6]
    """
    p = np.atleast_2d(np.asarray(xyz, dtype=float))
    r = np.linalg.norm(p, axis=1)
    lon = np.rad2deg(np.arctan2(p[:, 1], p[:, 0]))
    lat = np.rad2deg(np.arcsin(np.clip(p[:, 2] / np.where(r > 0, r, 1.0), -1.0, 1.0)))
    return lon, lat, r
