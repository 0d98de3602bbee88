"""One ELFIN calibration across science zones: shared sensor, per-zone offsets and attitude.

The per-zone linear fit (:mod:`magcal.missions.elfin.linear`) gives every zone its own 12
parameters; on ELFIN-A it trades the poorly sampled spin-axis direction against gains
and offsets (spin-axis "turns" of 1-5 deg within a pass, two zones with the mirrored
sensor triad). Here the sensor is one instrument for the whole day:

* shared by all zones: the gains and non-orthogonality (an upper-triangular matrix
  ``U`` times a fixed start ``M0``), the tilt ``theta`` of the sensor triad from the
  spin axis (two angles; the rotation about the spin axis is the spin phase's), and the
  complex cubic non-linearity ``e`` of the spin-plane field found in the scalar residual
  (:mod:`magcal.missions.elfin.scalar`): ``beta -> beta - e conj(beta)^3 / B0^2`` with
  ``beta = Bx + i By`` in the spinning frame and ``B0 = 45000 nT``;
* per zone: offsets in the spinning frame (spin plane: polynomial of degree
  ``offset_degree`` in the zone time ``T`` in [-1, 1]; spin axis: constant), a drifting
  spin-plane anisotropy ``[[a, b], [b, -a]]`` (polynomials in ``T`` without constant
  term: the 2x harmonic that drifts within a pass), and the attitude: a rotation
  ``(ax, ay, 0)`` of the reference in the despun frame, bounded by ``tilt_bound_deg``
  (the state file's stated 0.2 deg);
* per zone, by alternation: the spin phase (a cubic spline correction, as in the
  per-zone fit).

The model::

    body = R(theta) M0 (I + U) (b - C0) + o_k(T);   beta += A_k(T) beta;
    beta -= e conj(beta)^3 / B0^2;   despin(body, phase_k) ~ R(alpha_k) B_IGRF,despun

is fitted to the three vector components and, with weight ``scalar_weight``, to
``|body| - |B_IGRF|`` of every used sample of every zone at once (sparse trust-region
least squares), from a start by alternating linear least squares
(:func:`_linear_start`). Uncertainties: the Jacobian sandwich with residuals summed over blocks
of ``block_s`` seconds (the residuals are strongly autocorrelated, so the plain
``sigma^2 (J^T J)^-1`` understates them), conditional on the fitted phases.

What ELFIN-A 2022-01-12 says (``python workflows/elfin_calibration.py --no-scan``):

* one linear matrix for all 12 zones (gains shared) leaves 240-390 nT per component
  (zone medians; 700-1800 nT in zones 7 and 8) against 66 nT for the per-zone fit,
  and per-zone isotropic gains do not help (zones 7, 8 want +2.3 %, +3.0 %): the gains
  are not stable across zones, hence ``zone_gains`` (three relative gains per zone);
* the shared cubic is well determined and agrees with the scalar-only estimate
  (4x amplitude 36.6-36.8 nT at |B_perp| = 45000 nT, phase 82 deg, formal error 0.4 nT);
* the attitude angles end on the 0.2 deg bound in nearly every zone; a 5 deg bound
  takes the vector RMS median from 217 to 89 nT with tilts of 1-5 deg and spin-axis
  sensor gains changing by +-40 % between zones: the spin-axis direction is traded
  against the sensor matrix (the field stays within a few degrees of the spin plane),
  so the joint fit is not delivered (:func:`choose_product`) and the per-zone linear
  fit with the spin-harmonic correction stays the product.

Data: ELFIN SOC (PI V. Angelopoulos, UCLA), "Open Data for Scientific Use".
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import pandas as pd

from magcal.errors import InputError
from magcal.missions.elfin.phase import despun_basis, unwrap_predictive, wrap
from magcal.spin.despin import despin, spin

B0_NT = 45000.0
_TRIU = np.triu_indices(3)


@dataclass(frozen=True)
class JointZone:
    """Input of one zone: times (s), raw counts, IGRF in the despun frame, start phase."""

    t: np.ndarray
    counts: np.ndarray
    ref: np.ndarray
    used: np.ndarray


def _rot(ax, ay) -> np.ndarray:
    """Rotation matrix of the rotation vector ``(ax, ay, 0)`` (Rodrigues)."""
    v = np.array([ax, ay, 0.0])
    ang = float(np.linalg.norm(v))
    if ang == 0.0:
        return np.eye(3)
    k = v / ang
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(ang) * kx + (1 - np.cos(ang)) * kx @ kx


def _powers(T, first: int, last: int) -> np.ndarray:
    return np.column_stack([T ** d for d in range(first, last + 1)]) if last >= first \
        else np.empty((T.size, 0))


class _Model:
    """Parameter layout and forward model of the joint fit."""

    def __init__(self, zones, m0, c0, offset_degree, aniso_degree, scalar_weight,
                 zone_gains=True):
        self.zones, self.m0, self.c0 = zones, m0, c0
        self.od, self.ad, self.ws, self.zg = offset_degree, aniso_degree, scalar_weight, zone_gains
        # with per-zone gains the diagonal of U is theirs: U keeps the coupling only
        self.u_idx = [(i, j) for i, j in zip(*_TRIU) if not (zone_gains and i == j)]
        self.n_shared = len(self.u_idx) + 4
        self.n_zone = 3 * zone_gains + 2 * (offset_degree + 1) + 1 + 2 * aniso_degree + 2
        self.n_par = self.n_shared + len(zones) * self.n_zone
        self.T = []
        for z in zones:
            tu = z.t[z.used]
            self.T.append(2.0 * (z.t - tu[0]) / (tu[-1] - tu[0]) - 1.0)

    def names(self) -> list[str]:
        """Parameter names in the order of the parameter vector."""
        shared = [f"U{i + 1}{j + 1}" for i, j in self.u_idx] + [
            "sensor_tilt_x_rad", "sensor_tilt_y_rad", "cubic_re", "cubic_im"]
        zone = ([f"gain{j}_rel" for j in (1, 2, 3)] if self.zg else []) + (
                [f"ox_T{d}_nT" for d in range(self.od + 1)]
                + [f"oy_T{d}_nT" for d in range(self.od + 1)] + ["oz_nT"]
                + [f"aniso_a_T{d}" for d in range(1, self.ad + 1)]
                + [f"aniso_b_T{d}" for d in range(1, self.ad + 1)]
                + ["attitude_x_rad", "attitude_y_rad"])
        return shared + [f"z{k}_{n}" for k in range(len(self.zones)) for n in zone]

    def zone_slice(self, k: int) -> slice:
        a = self.n_shared + k * self.n_zone
        return slice(a, a + self.n_zone)

    def offset_index(self, k: int) -> tuple[int, int, int]:
        """Positions of the constant x, y, z offsets of zone ``k`` in the vector."""
        a = self.zone_slice(k).start + 3 * self.zg
        n1 = self.od + 1
        return a, a + n1, a + 2 * n1

    def matrix(self, p) -> np.ndarray:
        """Shared counts -> spinning-frame matrix ``R(theta) M0 (I + U)`` (nT/count)."""
        u = np.zeros((3, 3))
        for v, ij in zip(p, self.u_idx):
            u[ij] = v
        ns = len(self.u_idx)
        return _rot(p[ns], p[ns + 1]) @ self.m0 @ (np.eye(3) + u)

    def cubic(self, p) -> complex:
        ns = len(self.u_idx)
        return complex(p[ns + 2], p[ns + 3])

    def body(self, p, k, mat=None) -> np.ndarray:
        """Calibrated field of zone ``k`` in the spinning frame (all samples)."""
        z, T = self.zones[k], self.T[k]
        mat = self.matrix(p) if mat is None else mat
        q = p[self.zone_slice(k)]
        x = z.counts - self.c0
        if self.zg:
            x = x * (1.0 + q[:3])
            q = q[3:]
        n1 = self.od + 1
        po = _powers(T, 0, self.od)
        b = x @ mat.T
        b[:, 0] += po @ q[:n1]
        b[:, 1] += po @ q[n1:2 * n1]
        b[:, 2] += q[2 * n1]
        pa = _powers(T, 1, self.ad)
        i = 2 * n1 + 1
        a, bb = pa @ q[i:i + self.ad], pa @ q[i + self.ad:i + 2 * self.ad]
        bx, by = b[:, 0].copy(), b[:, 1].copy()
        b[:, 0] += a * bx + bb * by
        b[:, 1] += bb * bx - a * by
        beta = b[:, 0] + 1j * b[:, 1]
        beta = beta - self.cubic(p) * np.conj(beta) ** 3 / B0_NT ** 2
        b[:, 0], b[:, 1] = beta.real, beta.imag
        return b

    def reference(self, p, k) -> np.ndarray:
        """IGRF of zone ``k`` in the attitude-corrected despun frame."""
        q = p[self.zone_slice(k)]
        return self.zones[k].ref @ _rot(q[-2], q[-1]).T

    def residual_zone(self, p, k, phase, mat=None) -> np.ndarray:
        z = self.zones[k]
        b = self.body(p, k, mat)[z.used]
        ref = self.reference(p, k)[z.used]
        d = despin(b, phase[z.used]) - ref
        s = np.linalg.norm(b, axis=1) - np.linalg.norm(z.ref[z.used], axis=1)
        return np.column_stack([d, self.ws * s]).ravel()

    def residual(self, p, phases) -> np.ndarray:
        mat = self.matrix(p)
        return np.concatenate([self.residual_zone(p, k, phases[k], mat)
                               for k in range(len(self.zones))])

    def sparsity(self):
        from scipy.sparse import lil_matrix

        rows = [4 * int(z.used.sum()) for z in self.zones]
        s = lil_matrix((sum(rows), self.n_par), dtype=int)
        r0 = 0
        for k, n in enumerate(rows):
            s[r0:r0 + n, :self.n_shared] = 1
            s[r0:r0 + n, self.zone_slice(k)] = 1
            r0 += n
        return s


def _phase_update(model, p, k, phase, knot_s) -> np.ndarray:
    """Add the spline fit of the angle between the model and the reference spin-plane field."""
    from scipy.interpolate import make_lsq_spline

    z = model.zones[k]
    b = model.body(p, k)
    tgt = spin(model.reference(p, k), phase)
    dphi = wrap(np.arctan2(tgt[:, 1], tgt[:, 0]) - np.arctan2(b[:, 1], b[:, 0]))
    tu = z.t[z.used]
    inner = np.arange(z.t[0], z.t[-1], knot_s)
    inner = inner[(inner > tu[0]) & (inner < tu[-1])]
    knots = np.r_[[tu[0]] * 4, inner, [tu[-1]] * 4]
    spl = make_lsq_spline(tu, dphi[z.used], knots, k=3)
    return phase + spl(np.clip(z.t, tu[0], tu[-1]))


def _start_phase(model, p, k) -> np.ndarray:
    """Phase that turns the start calibration's spin-plane field onto the reference."""
    z = model.zones[k]
    b = model.body(p, k)
    ang, _ = unwrap_predictive(z.t, np.arctan2(z.ref[:, 1], z.ref[:, 0])
                               - np.arctan2(b[:, 1], b[:, 0]))
    tu = z.t[z.used]
    coef = np.polyfit(tu - tu[0], ang[z.used], 2)
    return np.polyval(coef, z.t - tu[0])


def _linear_start(model, p, phases, n_iter: int) -> np.ndarray:
    """Start values by alternating linear least squares, the phases updated in between.

    With the phases fixed, ``spin(B_IGRF, phase) = M (b - C0) + o_k`` is linear in the
    shared ``M`` and the constant offsets ``o_k`` (one solve per component over all
    zones) and, with ``M`` fixed, linear in each zone's relative gains and offsets.
    ``model.m0`` is replaced by the resulting ``M``; returns the parameter vector.
    """
    zones = model.zones
    rows = [int(z.used.sum()) for z in zones]
    for _ in range(n_iter):
        phases[:] = [_phase_update(model, p, k, phases[k], model.knot_s)
                     for k in range(len(zones))]
        gains = [1.0 + (p[model.zone_slice(k)][:3] if model.zg else np.zeros(3))
                 for k in range(len(zones))]
        design = np.zeros((sum(rows), 3 + len(zones)))
        target = np.zeros((sum(rows), 3))
        r0 = 0
        for k, (z, n) in enumerate(zip(zones, rows)):
            design[r0:r0 + n, :3] = (z.counts[z.used] - model.c0) * gains[k] / 1e6
            design[r0:r0 + n, 3 + k] = 1.0
            target[r0:r0 + n] = spin(model.reference(p, k), phases[k])[z.used]
            r0 += n
        w = np.linalg.lstsq(design, target, rcond=None)[0]
        model.m0 = w[:3].T / 1e6
        for k in range(len(zones)):
            p[list(model.offset_index(k))] = w[3 + k]
        if not model.zg:
            continue
        for k, z in enumerate(zones):
            x = z.counts[z.used] - model.c0
            a = np.zeros((3 * x.shape[0], 6))
            for i in range(3):
                a[i::3, :3] = x * model.m0[i]
                a[i::3, 3 + i] = 1.0
            tgt = spin(model.reference(p, k), phases[k])[z.used].ravel()
            sol = np.linalg.lstsq(a, tgt, rcond=None)[0]
            sl = model.zone_slice(k)
            p[sl.start:sl.start + 3] = sol[:3] - 1.0
            p[list(model.offset_index(k))] = sol[3:]
        # the mean gain goes into M, so the relative gains scatter about zero
        mean = np.mean([1.0 + p[model.zone_slice(k)][:3] for k in range(len(zones))], axis=0)
        model.m0 = model.m0 * mean
        for k in range(len(zones)):
            sl = model.zone_slice(k)
            p[sl.start:sl.start + 3] = (1.0 + p[sl.start:sl.start + 3]) / mean - 1.0
    return p


def _sandwich(jac, resid, blocks) -> np.ndarray:
    """Covariance ``H^-1 (sum_b g_b g_b^T) H^-1`` with ``g_b = J_b^T r_b`` over blocks."""
    h = (jac.T @ jac)
    h = h.toarray() if hasattr(h, "toarray") else np.asarray(h)
    g = []
    for sl in blocks:
        jb = jac[sl]
        g.append(np.asarray(jb.T @ resid[sl]).ravel())
    meat = np.einsum("bi,bj->ij", np.array(g), np.array(g))
    hinv = np.linalg.pinv(h)
    return hinv @ meat @ hinv


@dataclass(frozen=True)
class JointFit:
    """Result of :func:`fit_joint`.

    Attributes
    ----------
    names : list of str
        Parameter names (shared first, then ``z<k>_...`` per zone).
    values, std, std_naive : ndarray
        Parameters, their block-sandwich standard errors and the plain
        ``sigma (J^T J)^-1/2`` ones (which ignore the residual autocorrelation).
    matrix : ndarray (3, 3)
        Shared counts -> spinning-frame matrix (nT/count), rows X, Y, Z = spin axis.
    at_bound : list of str
        Attitude angles that end on the ``tilt_bound_deg`` bound (their std is not
        meaningful).
    body, phase, reference : list of ndarray
        Per zone: calibrated spinning-frame field, spin phase, IGRF in the
        attitude-corrected despun frame (all samples).
    rotations : list of ndarray (3, 3)
        Per zone attitude rotation (file despun frame -> corrected frame).
    cost_history : list of float
        RMS of the stacked residual after the linear start and after each alternation.
    """

    names: list
    values: np.ndarray
    std: np.ndarray
    std_naive: np.ndarray
    matrix: np.ndarray
    at_bound: list
    body: list
    phase: list
    reference: list
    rotations: list
    cost_history: list

    def shared(self) -> dict:
        """Shared parameters with their standard errors, in physical units."""
        m = self.matrix
        gains = np.linalg.norm(m, axis=0)
        axis_sensor = np.linalg.inv(m)[:, 2]
        axis_sensor = axis_sensor / np.linalg.norm(axis_sensor)
        v, s = dict(zip(self.names, self.values)), dict(zip(self.names, self.std))
        eps = complex(v["cubic_re"], v["cubic_im"])
        return {
            "matrix_nT_per_count": m, "gains_nT_per_count": gains,
            "angle_between_sensors_deg": [
                float(np.degrees(np.arccos(m[:, i] @ m[:, j] / gains[i] / gains[j])))
                for i, j in ((0, 1), (0, 2), (1, 2))],
            "spin_axis_in_counts_frame": axis_sensor,
            "U": {n: [v[n], s[n]] for n in self.names if n.startswith("U")},
            "sensor_tilt_deg": [[float(np.degrees(v[n])), float(np.degrees(s[n]))]
                                for n in ("sensor_tilt_x_rad", "sensor_tilt_y_rad")],
            "cubic_eps": [abs(eps), float(np.hypot(s["cubic_re"], s["cubic_im"]) / np.sqrt(2))],
            "cubic_phase_deg": float(np.degrees(np.angle(eps))),
            "cubic_4x_at_45000nT_nT": abs(eps) * B0_NT,
        }

    def per_zone(self) -> pd.DataFrame:
        """Per-zone parameters (one row per zone) with standard errors (``_std``)."""
        rows = []
        keys = [n.split("_", 1)[1] for n in self.names if n.startswith("z0_")]
        by = dict(zip(self.names, zip(self.values, self.std)))
        k = 0
        while f"z{k}_oz_nT" in by:
            row = {"zone": k}
            for key in keys:
                val, err = by[f"z{k}_{key}"]
                if key.startswith("attitude"):
                    val, err = np.degrees(val), np.degrees(err)
                    key = key.replace("_rad", "_deg")
                row[key], row[key + "_std"] = float(val), float(err)
            rows.append(row)
            k += 1
        return pd.DataFrame(rows)

    def spread(self) -> dict:
        """Mean, standard deviation over zones and median standard error per zone parameter."""
        tab = self.per_zone()
        out = {}
        for c in tab.columns:
            if c == "zone" or c.endswith("_std"):
                continue
            out[c] = {"mean": float(tab[c].mean()), "spread": float(tab[c].std(ddof=1)),
                      "median_std": float(tab[c + "_std"].median())}
        return out


def fit_joint(zones, m0, *, offset_degree: int = 3, aniso_degree: int = 3,
              tilt_bound_deg: float = 0.2, scalar_weight: float = 1.0,
              phase_knot_s: float = 30.0, n_alternations: int = 2, block_s: float = 30.0,
              max_nfev: int = 20, zone_gains: bool = True, n_linear: int = 8,
              stride: int = 2) -> JointFit:
    """Fit the shared sensor and per-zone offsets/attitude/phase to IGRF in all zones.

    Parameters
    ----------
    zones : list of JointZone
        Zone data; ``ref`` is IGRF in the despun frame of the attitude file.
    m0 : array_like (3, 3)
        Start counts -> spinning-frame matrix (nT/count), e.g. one zone's linear
        coupling with a right-handed triad; the fit refines it by ``(I + U)`` and the
        sensor tilt.
    offset_degree : int
        Degree of the spin-plane offset polynomials per zone (0: constant).
    aniso_degree : int
        Degree of the drifting spin-plane anisotropy per zone (0: none).
    tilt_bound_deg : float
        Bound on each attitude angle per zone (the state file's uncertainty).
    scalar_weight : float
        Weight of ``|B| - |IGRF|`` rows relative to the vector rows.
    phase_knot_s : float
        Knot spacing of the spline spin-phase correction.
    n_alternations : int
        Least-squares / phase-update cycles.
    block_s : float
        Block length for the autocorrelation-aware standard errors.
    max_nfev : int
        Cap on function evaluations of each least-squares step.
    zone_gains : bool
        Give every zone its own three relative gains (the shared matrix keeps the
        coupling, tilt and cubic). On ELFIN-A 2022-01-12 one shared linear matrix leaves
        240-390 nT median per component (zones 7 and 8: 700-1800 nT), so the gains are
        not stable across zones; see the module notes.
    n_linear : int
        Alternations of the linear start (:func:`_linear_start`).
    stride : int
        Fit every ``stride``-th used sample (10 Hz at a 2.85 s spin: 2 keeps 14
        samples a spin, enough for the 4x harmonic); the output covers all samples.

    Returns
    -------
    JointFit
    """
    from scipy.optimize import least_squares

    zones = list(zones)
    if not zones:
        raise InputError("fit_joint needs at least one zone")
    thin = [replace(z, used=z.used & (np.arange(z.t.size) % max(1, stride) == 0))
            for z in zones]
    c0 = np.mean(np.vstack([z.counts[z.used] for z in zones]), axis=0)
    model = _Model(thin, np.asarray(m0, float), c0, offset_degree, aniso_degree,
                   scalar_weight, zone_gains)
    model.knot_s = phase_knot_s
    p = np.zeros(model.n_par)
    bound = np.radians(tilt_bound_deg)
    lo, hi = np.full(model.n_par, -np.inf), np.full(model.n_par, np.inf)
    for k in range(len(zones)):
        sl = model.zone_slice(k)
        lo[sl.stop - 2:sl.stop], hi[sl.stop - 2:sl.stop] = -bound, bound
    phases = [_start_phase(model, p, k) for k in range(len(zones))]
    p = _linear_start(model, p, phases, n_linear)
    history = [float(np.sqrt(np.mean(model.residual(p, phases) ** 2)))]
    sparsity = model.sparsity()
    res = None
    for it in range(max(1, n_alternations)):
        phases = [_phase_update(model, p, k, phases[k], phase_knot_s)
                  for k in range(len(zones))]
        res = least_squares(model.residual, p, args=(phases,), jac_sparsity=sparsity,
                            bounds=(lo, hi), method="trf", x_scale="jac",
                            max_nfev=max_nfev)
        p = res.x
        history.append(float(np.sqrt(np.mean(res.fun ** 2))))
    resid = res.fun
    jac = res.jac
    blocks, r0 = [], 0
    for z in thin:
        tu = z.t[z.used]
        edges = np.searchsorted(tu, np.arange(tu[0], tu[-1] + block_s, block_s))
        edges = np.unique(np.r_[edges, tu.size])
        blocks += [slice(r0 + 4 * a, r0 + 4 * b) for a, b in zip(edges[:-1], edges[1:])
                   if b > a]
        r0 += 4 * tu.size
    cov = _sandwich(jac, resid, blocks)
    h = jac.T @ jac
    h = h.toarray() if hasattr(h, "toarray") else np.asarray(h)
    sigma2 = float(resid @ resid) / max(resid.size - model.n_par, 1)
    std_naive = np.sqrt(np.clip(np.diag(np.linalg.pinv(h)) * sigma2, 0, None))
    names = model.names()
    at_bound = [n for n, v in zip(names, p) if n.endswith("attitude_x_rad")
                or n.endswith("attitude_y_rad") if abs(abs(v) - bound) < 1e-3 * bound]
    mat = model.matrix(p)
    return JointFit(
        names=names, values=p, std=np.sqrt(np.clip(np.diag(cov), 0, None)),
        std_naive=std_naive, matrix=mat, at_bound=at_bound,
        body=[model.body(p, k, mat) for k in range(len(zones))], phase=phases,
        reference=[model.reference(p, k) for k in range(len(zones))],
        rotations=[_rot(*p[model.zone_slice(k)][-2:]) for k in range(len(zones))],
        cost_history=history)


def zones_from_calibration(cal) -> list[JointZone]:
    """Joint-fit input from a per-zone :class:`~magcal.missions.elfin.ElfinCalibration`."""
    out = []
    for k in sorted(cal.field["zone"].unique()):
        z = cal.field[cal.field["zone"] == k]
        out.append(JointZone(
            t=(z.index.asi8 - z.index.asi8[0]) / 1e9,
            counts=z[["b1", "b2", "b3"]].to_numpy(float),
            ref=z[["igrf_x_despun", "igrf_y_despun", "igrf_z_despun"]].to_numpy(float),
            used=z["used"].to_numpy() == 1))
    return out


def start_matrix(cal) -> np.ndarray:
    """Start matrix: the coupling of the zone with the smallest vector RMS among the
    zones whose linear fit found a right-handed triad (the per-zone fit mirrors some)."""
    good = [z for z in cal.zones if z.det_coupling_sign > 0]
    if not good:
        raise InputError("no zone with a right-handed linear calibration to start from")
    return min(good, key=lambda z: float(np.sqrt(np.mean(z.rms_vector_nT ** 2)))).coupling


def calibrate_joint(cal, **kw):
    """Joint fit of all zones of a per-zone calibration; the same product with its field.

    Parameters
    ----------
    cal : magcal.missions.elfin.ElfinCalibration
        Per-zone fit (its ``field`` holds counts, IGRF, attitude axis, used flags).
    **kw
        Passed to :func:`fit_joint`.

    Returns
    -------
    joint : ElfinCalibration
        ``field`` with ``bx_gei ..``, ``bx_despun ..`` (file despun frame) and ``phase``
        from the joint fit (the per-zone summaries stay those of the linear fit).
    fit : JointFit
    """
    zones = zones_from_calibration(cal)
    fit = fit_joint(zones, start_matrix(cal), **kw)
    f = cal.field.copy()
    for k, zone_id in enumerate(sorted(f["zone"].unique())):
        sel = (f["zone"] == zone_id).to_numpy()
        desp = despin(fit.body[k], fit.phase[k]) @ fit.rotations[k]   # R^T: file frame
        basis = despun_basis(f.loc[sel, ["spin_axis_gei_x", "spin_axis_gei_y",
                                         "spin_axis_gei_z"]].to_numpy())
        f.loc[sel, ["bx_despun", "by_despun", "bz_despun"]] = desp
        f.loc[sel, ["bx_gei", "by_gei", "bz_gei"]] = np.einsum("nji,nj->ni", basis, desp)
        f.loc[sel, "phase"] = fit.phase[k]
    params = {**cal.parameters, "joint_fit": {k: str(v) for k, v in kw.items()}}
    return replace(cal, field=f, parameters=params), fit


def score_field(field: pd.DataFrame, *, poly_degree: int = 5) -> pd.DataFrame:
    """Per zone: ``|B| - |IGRF|`` RMS and fast part, vector RMS per GEI component.

    Parameters
    ----------
    field : DataFrame
        ``zone, used, bx_gei .. bz_gei, igrf_x_gei .. igrf_z_gei`` (nT).
    poly_degree : int
        The fast part is the scalar residual minus its polynomial of this degree in time.

    Returns
    -------
    DataFrame
        ``zone, scalar_rms_nT, scalar_fast_nT, scalar_slow_nT, vector_rms_x_nT ..z,
        vector_rms_nT`` (RMS over the three components).
    """
    from magcal.missions.elfin.scalar import fast_part, rms

    rows = []
    for k in sorted(field["zone"].unique()):
        z = field[(field["zone"] == k) & (field["used"] == 1)]
        t = (z.index.asi8 - z.index.asi8[0]) / 1e9
        b = z[["bx_gei", "by_gei", "bz_gei"]].to_numpy(float)
        r = z[["igrf_x_gei", "igrf_y_gei", "igrf_z_gei"]].to_numpy(float)
        s = np.linalg.norm(b, axis=1) - np.linalg.norm(r, axis=1)
        fast = fast_part(t, s, poly_degree)
        rows.append({"zone": int(k), "scalar_rms_nT": rms(s), "scalar_fast_nT": rms(fast),
                     "scalar_slow_nT": rms(s - fast),
                     **{f"vector_rms_{c}_nT": rms((b - r)[:, j]) for j, c in enumerate("xyz")},
                     "vector_rms_nT": rms(b - r)})
    return pd.DataFrame(rows)


def choose_product(scores: dict, candidate: str = "joint", incumbent: str = "harmonic",
                   measures=("vector_rms_nT", "scalar_rms_nT", "scalar_fast_nT")) -> tuple:
    """Deliver ``candidate`` only if its zone median is no worse on every measure.

    Parameters
    ----------
    scores : dict of str -> DataFrame
        :func:`score_field` tables by product name.
    candidate, incumbent : str
        Keys of ``scores``.
    measures : sequence of str
        Columns compared (zone medians).

    Returns
    -------
    chosen : str
    reason : str
        The medians that decided, e.g. ``"vector_rms_nT 216.7 > 53.1"``.

    Examples
    --------
    >>> a = pd.DataFrame({"vector_rms_nT": [50.0], "scalar_rms_nT": [60.0],
    ...                   "scalar_fast_nT": [6.0]})
    >>> b = a * 2
    >>> choose_product({"joint": b, "harmonic": a})[0]
    'harmonic'
    """
    worse = []
    for m in measures:
        c, i = float(scores[candidate][m].median()), float(scores[incumbent][m].median())
        if c > i:
            worse.append(f"{m} {c:.1f} > {i:.1f}")
    if worse:
        return incumbent, f"{candidate} worse than {incumbent} (zone medians): " + "; ".join(worse)
    return candidate, f"{candidate} no worse than {incumbent} on " + ", ".join(measures)
