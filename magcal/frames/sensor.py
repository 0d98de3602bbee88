"""Single-sensor frames -> one common frame (e.g. the outboard sensor reference frame).

Each sensor ``k`` has a 3x3 matrix ``M_k`` with ``b_common = M_k @ b_k`` (SOSMAG paper
§5.1: every sensor is transformed into the outboard fluxgate frame, OSRF, before AC
cleaning). A mounting rotation is orthonormal with determinant +1 and is checked as such;
a general calibration matrix (scales, non-orthogonality) is accepted only when asked for
with ``orthonormal=False``.

Examples
--------
>>> frames = SensorFrames.from_euler({"fgmi": [90.0, 0.0, 0.0], "fgmo": [0.0, 0.0, 0.0]},
...                                  common="fgmo")
>>> frames.to_common("fgmi", [1.0, 0.0, 0.0]).round(12) + 0.0
array([[0., 1., 0.]])
"""

from __future__ import annotations

from dataclasses import dataclass
from types import MappingProxyType
from typing import Mapping

import numpy as np

from magcal.errors import InputError

#: Default tolerance on ``max|M M^T - I|`` for a matrix claimed to be a rotation.
ROTATION_ATOL = 1e-6


def rotation_from_euler(angles_deg, seq: str = "ZYX") -> np.ndarray:
    """Rotation matrix from Euler angles (degrees), via :mod:`scipy.spatial.transform`.

    Parameters
    ----------
    angles_deg : array_like, shape (3,) or (k,)
        Angles in degrees, one per axis letter of ``seq``.
    seq : str
        Axis sequence as in :meth:`scipy.spatial.transform.Rotation.from_euler`:
        upper case = intrinsic, lower case = extrinsic rotations.

    Returns
    -------
    ndarray, shape (3, 3)
        Active rotation: ``R @ v`` rotates the vector ``v``.

    Examples
    --------
    >>> rotation_from_euler([90.0, 0.0, 0.0]).round(12) + 0.0
    array([[ 0., -1.,  0.],
           [ 1.,  0.,  0.],
           [ 0.,  0.,  1.]])
    """
    from scipy.spatial.transform import Rotation

    angles = np.atleast_1d(np.asarray(angles_deg, dtype=float))
    if angles.shape != (len(seq),):
        raise InputError(f"need {len(seq)} angles for sequence {seq!r}, got {angles.shape}")
    return Rotation.from_euler(seq, angles, degrees=True).as_matrix()


def check_rotation(matrix, *, atol: float = ROTATION_ATOL, name: str | None = None) -> np.ndarray:
    """Return ``matrix`` as a float (3, 3) array if it is a proper rotation, else raise.

    Parameters
    ----------
    matrix : array_like, shape (3, 3)
    atol : float
        Largest accepted ``|M M^T - I|`` element.
    name : str, optional
        Sensor name for the error message.

    Raises
    ------
    InputError
        Not 3x3, not finite, not orthonormal within ``atol``, or a reflection
        (determinant -1).

    Examples
    --------
    >>> check_rotation(np.diag([1.0, 1.0, 1.01]))  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    magcal.errors.InputError: column M: matrix is not orthonormal: max |M M^T - I| = 0.0201 ...
    """
    m = _matrix(matrix, name)
    dev = float(np.abs(m @ m.T - np.eye(3)).max())
    where = "M" if name is None else f"M[{name}]"
    if dev > atol:
        raise InputError(f"matrix is not orthonormal: max |M M^T - I| = {dev:.3g} > {atol:g}; "
                         "pass orthonormal=False for a general calibration matrix", column=where)
    if np.linalg.det(m) < 0:
        raise InputError("matrix is a reflection (determinant -1), not a rotation; pass "
                         "orthonormal=False if the sensor frame really is left-handed",
                         column=where)
    return m


def _matrix(matrix, name: str | None = None) -> np.ndarray:
    m = np.array(matrix, dtype=float)
    where = "M" if name is None else f"M[{name}]"
    if m.shape != (3, 3):
        raise InputError(f"matrix must be 3x3, got shape {m.shape}", column=where)
    if not np.all(np.isfinite(m)):
        raise InputError("matrix has non-finite entries", column=where)
    if abs(np.linalg.det(m)) < 1e-12 * max(1.0, float(np.abs(m).max()) ** 3):
        raise InputError("matrix is singular", column=where)
    return m


def to_common(b_sensor, matrix) -> np.ndarray:
    """``b_common = M @ b_sensor`` for each row.

    Examples
    --------
    >>> to_common([[1.0, 2.0, 3.0]], np.diag([2.0, 1.0, 1.0]))
    array([[2., 2., 3.]])
    """
    b = np.atleast_2d(np.asarray(b_sensor, dtype=float))
    if b.shape[-1] != 3:
        raise InputError(f"vectors must have 3 components, got shape {b.shape}")
    return b @ np.asarray(matrix, dtype=float).T


def from_common(b_common, matrix) -> np.ndarray:
    """Inverse of :func:`to_common` (solves ``M x = b``; exact for calibration matrices).

    Examples
    --------
    >>> from_common([[2.0, 2.0, 3.0]], np.diag([2.0, 1.0, 1.0]))
    array([[1., 2., 3.]])
    """
    b = np.atleast_2d(np.asarray(b_common, dtype=float))
    if b.shape[-1] != 3:
        raise InputError(f"vectors must have 3 components, got shape {b.shape}")
    return np.linalg.solve(np.asarray(matrix, dtype=float), b.T).T


@dataclass(frozen=True, eq=False)
class SensorFrames:
    """One matrix per sensor mapping its readings into a common frame.

    Parameters
    ----------
    matrices : mapping of str to array_like (3, 3)
        ``b_common = matrices[name] @ b_name``.
    common : str, optional
        Name of the common frame (e.g. ``"fgmo"`` for the OSRF).
    orthonormal : bool
        If True (default) every matrix must be a proper rotation within ``atol``
        (:func:`check_rotation`); False accepts any non-singular calibration matrix.
    atol : float
        Orthonormality tolerance.

    Examples
    --------
    >>> frames = SensorFrames({"a": np.eye(3), "b": np.diag([1.0, -1.0, -1.0])})
    >>> frames.to_common("b", [1.0, 2.0, 3.0])
    array([[ 1., -2., -3.]])
    >>> SensorFrames({"c": np.diag([1.0, 1.0, 2.0])}, orthonormal=False).from_common("c", [1, 1, 2])
    array([[1., 1., 1.]])
    """

    matrices: Mapping[str, np.ndarray]
    common: str | None = None
    orthonormal: bool = True
    atol: float = ROTATION_ATOL

    def __post_init__(self):
        checked = {}
        for name, m in dict(self.matrices).items():
            arr = check_rotation(m, atol=self.atol, name=name) if self.orthonormal \
                else _matrix(m, name)
            arr.setflags(write=False)
            checked[str(name)] = arr
        if not checked:
            raise InputError("no sensor matrices given")
        object.__setattr__(self, "matrices", MappingProxyType(checked))

    @classmethod
    def from_euler(cls, angles_deg: Mapping[str, object], seq: str = "ZYX",
                   common: str | None = None) -> "SensorFrames":
        """Build from Euler angles (degrees) per sensor; see :func:`rotation_from_euler`."""
        return cls({k: rotation_from_euler(v, seq) for k, v in angles_deg.items()},
                   common=common)

    @property
    def names(self) -> tuple[str, ...]:
        """Sensor names in insertion order."""
        return tuple(self.matrices)

    def _get(self, name: str) -> np.ndarray:
        if name not in self.matrices:
            raise InputError(f"no frame matrix for sensor {name!r}; known: "
                             f"{', '.join(self.names)}", column=name)
        return self.matrices[name]

    def to_common(self, name: str, b) -> np.ndarray:
        """Readings of sensor ``name`` (n, 3) -> common frame (n, 3)."""
        return to_common(b, self._get(name))

    def from_common(self, name: str, b) -> np.ndarray:
        """Common-frame vectors (n, 3) -> the frame of sensor ``name``."""
        return from_common(b, self._get(name))

    def all_to_common(self, readings: Mapping[str, object]) -> dict[str, np.ndarray]:
        """Apply :meth:`to_common` to every sensor in ``readings``."""
        return {name: self.to_common(name, b) for name, b in readings.items()}

    def as_dict(self) -> dict:
        """JSON-ready form: ``{"common": ..., "orthonormal": ..., "M": {name: 3x3 lists}}``."""
        return {"common": self.common, "orthonormal": self.orthonormal,
                "M": {k: v.tolist() for k, v in self.matrices.items()}}
