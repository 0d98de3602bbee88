"""Validation against a reference spacecraft in conjunction (SOSMAG paper §5.3, MMS 4).

When a well-calibrated spacecraft B passes close to spacecraft A, both measure nearly
the same field. Comparing both *minus the model* (``(A - model_A) - (B - model_B)``)
removes the field gradient between them as far as the model has it, and any field the
model lacks that is common to both (ring current, magnetopause, substorm disturbance)
cancels. What remains is A's offset (and, optionally, rotation) relative to B, with an
uncertainty from the same correlated-noise treatment as the model alignment.

Each spacecraft's vectors are in its own Hpen frame, which differs by the angle between
their positions (about 4 degrees at 2,900 km apart at geostationary distance), so B's
residual is carried into A's Hpen frame through GEO.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from magcal.alignment.gls import fit_alignment
from magcal.alignment.result import AlignmentResult
from magcal.errors import InputError
from magcal.frames.hpen import hpen_basis
from magcal.io.jsonio import product_dict


@dataclasses.dataclass(frozen=True)
class ConjunctionInterval:
    """One interval with the two spacecraft closer than the threshold."""

    start: np.datetime64
    end: np.datetime64
    closest_time: np.datetime64
    min_distance_km: float
    n_samples: int

    def to_dict(self) -> dict:
        return {"start": str(self.start), "end": str(self.end),
                "closest_time": str(self.closest_time),
                "min_distance_km": float(self.min_distance_km), "n_samples": self.n_samples}


def find_conjunctions(times, pos_a_km, pos_b_km, max_distance_km: float,
                      min_samples: int = 2) -> list[ConjunctionInterval]:
    """Intervals where two spacecraft are within ``max_distance_km`` of each other.

    Parameters
    ----------
    times : array_like of datetime64, shape (n,)
    pos_a_km, pos_b_km : array_like, shape (n, 3)
        Positions at the same times, in one Cartesian frame (e.g. GEO), km.
    max_distance_km : float
    min_samples : int
        Shorter runs are ignored.

    Returns
    -------
    list of ConjunctionInterval

    Examples
    --------
    >>> t = np.datetime64("2019-03-01T22:00", "ns") + np.arange(5) * np.timedelta64(60, "s")
    >>> a = np.zeros((5, 3)); b = np.array([[9e3, 0, 0], [4e3, 0, 0], [2e3, 0, 0],
    ...                                      [3e3, 0, 0], [8e3, 0, 0]])
    >>> [(str(c.closest_time), c.min_distance_km, c.n_samples)
    ...  for c in find_conjunctions(t, a, b, 5000.0)]
    [('2019-03-01T22:02:00.000000000', 2000.0, 3)]
    """
    t = np.asarray(times).astype("datetime64[ns]")
    dist = np.linalg.norm(np.asarray(pos_a_km, float) - np.asarray(pos_b_km, float), axis=1)
    close = np.isfinite(dist) & (dist <= max_distance_km)
    edges = np.diff(np.concatenate([[0], close.astype(int), [0]]))
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    out = []
    for s, e in zip(starts, stops):
        if e - s < min_samples:
            continue
        k = s + int(np.argmin(dist[s:e]))
        out.append(ConjunctionInterval(t[s], t[e - 1], t[k], float(dist[k]), int(e - s)))
    return out


def _lon_lat(pos):
    x, y, z = np.asarray(pos, dtype=float).T
    return np.rad2deg(np.arctan2(y, x)), np.rad2deg(np.arctan2(z, np.hypot(x, y)))


@dataclasses.dataclass(frozen=True)
class ConjunctionComparison:
    """Offset (and rotation) of spacecraft A relative to reference spacecraft B.

    ``fit`` holds ``data_A ~= R(w) @ (model_A + (B - model_B)) + offset`` in A's Hpen
    frame: ``fit.offset_nT`` is A's offset relative to B, ``fit.angles_deg`` its rotation
    (zeros when not fitted).
    """

    intervals: list
    fit: AlignmentResult
    naive_offset_nT: np.ndarray

    def to_json(self) -> dict:
        """JSON-ready product dictionary."""
        body = {k: v for k, v in self.fit.to_json().items()
                if k not in ("schema_version", "magcal_version")}
        return product_dict({
            "intervals": [c.to_dict() for c in self.intervals],
            "offset_difference_nT": body["offset_nT"],
            "offset_difference_std_nT": body["offset_std_nT"],
            "naive_offset_vs_model_nT": dict(zip(("Hp", "He", "Hn"),
                                                 map(float, self.naive_offset_nT))),
            "fit": body,
        })


def compare_in_conjunction(times, data_a, model_a, pos_a_km, data_b, model_b, pos_b_km,
                           max_distance_km: float, fit_rotation: bool = False,
                           min_samples: int = 10) -> ConjunctionComparison:
    """Offset (and optionally rotation) of A against reference B during conjunctions.

    Parameters
    ----------
    times : array_like of datetime64, shape (n,)
        Common sample times of both spacecraft.
    data_a, model_a : array_like, shape (n, 3)
        Spacecraft A measurement and model field in A's Hpen frame (nT).
    pos_a_km : array_like, shape (n, 3)
        A's position in GEO Cartesian coordinates (km).
    data_b, model_b, pos_b_km : array_like
        The same for the reference spacecraft B (its Hpen frame, its position).
    max_distance_km : float
        Conjunction threshold (the paper's MMS 4 comparison: below one Earth radius).
    fit_rotation : bool
        Fit A's rotation relative to B as well. It needs enough change of the field's
        direction inside the conjunctions: when the data cannot determine it
        (:mod:`magcal.alignment.determinability`) the angles are NaN, the offset is that
        of the identity fit and ``fit.determinability`` says why.
    min_samples : int

    Returns
    -------
    ConjunctionComparison
    """
    pa = np.asarray(pos_a_km, dtype=float)
    pb = np.asarray(pos_b_km, dtype=float)
    intervals = find_conjunctions(times, pa, pb, max_distance_km, min_samples=min_samples)
    if not intervals:
        raise InputError(f"no conjunction closer than {max_distance_km:g} km")
    t = np.asarray(times).astype("datetime64[ns]")
    sel = np.zeros(t.size, dtype=bool)
    for c in intervals:
        sel |= (t >= c.start) & (t <= c.end)
    lon_a, lat_a = _lon_lat(pa[sel])
    lon_b, lat_b = _lon_lat(pb[sel])
    basis_a = hpen_basis(lon_a, lat_a)
    basis_b = hpen_basis(lon_b, lat_b)
    resid_b_geo = np.einsum("nji,nj->ni", basis_b,
                            np.asarray(data_b, float)[sel] - np.asarray(model_b, float)[sel])
    resid_b_in_a = np.einsum("nij,nj->ni", basis_a, resid_b_geo)
    ref = np.asarray(model_a, float)[sel] + resid_b_in_a
    da = np.asarray(data_a, float)[sel]
    if fit_rotation:
        fit = _rotation_if_determinable(t[sel], da, ref)
    else:
        fit = fit_alignment(t[sel], da, ref, fit_rotation=False, fit_offset=True)
    naive = np.nanmean(da - np.asarray(model_a, float)[sel], axis=0)
    return ConjunctionComparison(intervals=intervals, fit=fit, naive_offset_nT=naive)


def _rotation_if_determinable(times, data, ref) -> AlignmentResult:
    """Rotation and offset fit, or the offset-only fit with NaN angles and the reason
    when the rotation is not determinable."""
    from magcal.alignment.determinability import (check_after, check_before, identity_fit,
                                                  not_determinable)

    identity = identity_fit(times, data, ref)
    verdict = check_before(times, data, ref, identity)
    if verdict.determinable:
        fit = fit_alignment(times, data, ref, fit_rotation=True, fit_offset=True)
        verdict = check_after(fit, verdict)
        if verdict.determinable:
            return dataclasses.replace(fit, determinability=verdict)
    return not_determinable(identity, verdict)
