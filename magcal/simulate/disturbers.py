"""Spacecraft disturbers: a multipole at a fixed place with a time profile.

A disturber's field at a sensor is its fixed spatial pattern times its time profile
(PiCoG §2.1, ``M(t) = m(t) M0`` and ``Q(t) = q(t) Q0``), so it is linearly polarised at
every sensor: the direction is fixed and only the amplitude changes. The exception is
``kind="rotating"``: the moment turns in the plane perpendicular to ``rotation_axis``
(a reaction wheel), which gives an elliptically polarised field that PiCoG cannot
remove with one linear correction, by design.

Positions and moments are given in the spacecraft body frame (metres, A m^2); the
simulator rotates the fields into the common measurement frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from magcal.errors import InputError
from magcal.simulate.multipoles import dipole_field, quadrupole_field
from magcal.simulate.profiles import Profile

KINDS = ("dipole", "quadrupole", "rotating")


@dataclass(frozen=True)
class Disturber:
    """One spacecraft disturbance source.

    Parameters
    ----------
    name : str
        Identifier used in the truth dictionaries.
    position_m : tuple of 3 floats
        Position in the body frame (metres).
    moment_Am2 : tuple of 3 floats
        Dipole moment at profile value 1 (for a quadrupole: the moment of the positive
        dipole of the pair; for a rotating disturber: the moment at phase 0).
    profile : Profile
        Time profile (see :mod:`magcal.simulate.profiles`); two components for
        ``kind="rotating"``, one otherwise.
    kind : {"dipole", "quadrupole", "rotating"}
        Field type. ``"rotating"`` is a dipole whose moment turns about
        ``rotation_axis``.
    separation_m : tuple of 3 floats, optional
        Quadrupole only: vector from the negative to the positive dipole.
    rotation_axis : tuple of 3 floats, optional
        Rotating only: axis of the rotation (the part of the moment along it is
        dropped, so the moment has constant magnitude).

    Examples
    --------
    >>> from magcal.simulate.profiles import ToneProfile
    >>> d = Disturber("coil", (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), ToneProfile())
    >>> disturber_patterns(d, [[0.0, 0.0, 1.0]]).round(6)
    array([[[  0.,   0., 200.]]])
    """

    name: str
    position_m: tuple
    moment_Am2: tuple
    profile: Profile
    kind: str = "dipole"
    separation_m: tuple | None = None
    rotation_axis: tuple | None = None

    def __post_init__(self):
        if self.kind not in KINDS:
            raise InputError(f"disturber {self.name!r}: kind must be one of {KINDS}")
        for label, vec in (("position_m", self.position_m), ("moment_Am2", self.moment_Am2)):
            if np.shape(vec) != (3,):
                raise InputError(f"disturber {self.name!r}: {label} must have 3 elements")
        want = 2 if self.kind == "rotating" else 1
        if self.profile.n_components != want:
            raise InputError(f"disturber {self.name!r}: a {self.kind} disturber needs a "
                             f"profile with {want} component(s)")
        if self.kind == "quadrupole" and (self.separation_m is None
                                          or np.shape(self.separation_m) != (3,)
                                          or not np.any(self.separation_m)):
            raise InputError(f"disturber {self.name!r}: a quadrupole needs a non-zero "
                             "3-element separation_m")
        if self.kind == "rotating":
            if self.rotation_axis is None or np.shape(self.rotation_axis) != (3,):
                raise InputError(f"disturber {self.name!r}: a rotating disturber needs a "
                                 "3-element rotation_axis")
            if np.linalg.norm(_perpendicular(self.moment_Am2, self.rotation_axis)) == 0:
                raise InputError(f"disturber {self.name!r}: moment is along rotation_axis")

    def basis_moments(self) -> np.ndarray:
        """Moments multiplied by the profile's components, shape (k, 3)."""
        m = np.asarray(self.moment_Am2, dtype=float)
        if self.kind != "rotating":
            return m[None, :]
        axis = np.asarray(self.rotation_axis, dtype=float)
        axis = axis / np.linalg.norm(axis)
        u = _perpendicular(m, axis)
        return np.stack([u, np.cross(axis, u)])


def _perpendicular(m, axis) -> np.ndarray:
    m = np.asarray(m, dtype=float)
    a = np.asarray(axis, dtype=float)
    a = a / np.linalg.norm(a)
    return m - (m @ a) * a


def disturber_patterns(disturber: Disturber, points_m) -> np.ndarray:
    """Field patterns of a disturber at the given points (body frame).

    Parameters
    ----------
    disturber : Disturber
    points_m : array_like, shape (p, 3)
        Sensor positions in the body frame (metres).

    Returns
    -------
    ndarray, shape (k, p, 3)
        Field in nT per unit profile component; ``k`` is the profile's number of
        components. The field at sensor ``j`` is ``sum_i coeff_i(t) * pattern[i, j]``.
    """
    moments = disturber.basis_moments()
    if disturber.kind == "quadrupole":
        return quadrupole_field(moments, disturber.position_m, disturber.separation_m,
                                points_m)
    return dipole_field(moments, disturber.position_m, points_m)


def disturber_fields(patterns: np.ndarray, coefficients: np.ndarray) -> np.ndarray:
    """Time series of a disturber's field at each point.

    Parameters
    ----------
    patterns : ndarray, shape (k, p, 3)
        From :func:`disturber_patterns` (possibly rotated into another frame).
    coefficients : ndarray, shape (n, k)
        Profile values.

    Returns
    -------
    ndarray, shape (p, n, 3)
        Field in nT.

    Examples
    --------
    >>> pat = np.array([[[0.0, 0.0, 2.0]]])
    >>> disturber_fields(pat, np.array([[0.0], [1.0], [-0.5]]))[0]
    array([[ 0.,  0.,  0.],
           [ 0.,  0.,  2.],
           [ 0.,  0., -1.]])
    """
    return np.einsum("nk,kpc->pnc", np.asarray(coefficients, dtype=float), patterns)


def moment_for_amplitude(kind: str, position_m, direction, point_m, amplitude_nT,
                         separation_m=None) -> np.ndarray:
    """Moment along ``direction`` that gives a field of ``amplitude_nT`` at ``point_m``.

    Used to build layouts from the field sizes reported in the papers.

    Examples
    --------
    >>> moment_for_amplitude("dipole", [0, 0, 0], [0, 0, 1], [0, 0, 1.0], 50.0)
    array([0.  , 0.  , 0.25])
    """
    u = np.asarray(direction, dtype=float)
    u = u / np.linalg.norm(u)
    if kind == "quadrupole":
        b = quadrupole_field(u, position_m, separation_m, point_m)
    else:
        b = dipole_field(u, position_m, point_m)
    return u * (amplitude_nT / np.linalg.norm(b))
