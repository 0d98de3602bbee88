"""Is there a daily (local-time) field in an alignment residual? A spectral F test.

The Wald test of fitted local-time harmonics (:func:`magcal.alignment.localtime.
describe_harmonics`) judges the harmonics' coefficients against the covariance that the
fitted noise model gives them. When that model misses part of the low-frequency noise
(a fitted time constant a little short, power-law noise read as OU plus white) the test
is liberal: on pure OU records it rejected "no field" three times as often as its level
(issue 21), and each needless set of harmonics costs the angles' precision.

This test needs no noise model. The residual's power at the daily harmonics ``k / day``
is compared with its power at neighbouring Fourier frequencies of the record (the
harmonic F test of spectral analysis): for noise whose spectrum is smooth across a few
bins (white, OU, two time scales, power laws, heavy tails) the ratio follows an F
distribution whatever the spectrum's level and shape, while a field fixed in local time
puts power at the harmonics only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from magcal.frames.localtime import DAY_S

#: Neighbouring Fourier frequencies per side of each harmonic (at most).
NEIGHBOURS = 4


@dataclass(frozen=True)
class HarmonicFTest:
    """Result of :func:`harmonic_f_test`, per component.

    Attributes
    ----------
    f_stat : ndarray, shape (m,)
        Mean power at the harmonics over mean power at the neighbours.
    dof : tuple of int
        ``(2 K, 2 n_neighbours)``.
    p_value : ndarray, shape (m,)
        Chance of a ratio at least as large without a daily field.
    harmonic_power, neighbour_power : ndarray, shape (m,)
        Mean squared amplitude (nT^2) at the harmonics and at the neighbours.
    """

    f_stat: np.ndarray
    dof: tuple
    p_value: np.ndarray
    harmonic_power: np.ndarray
    neighbour_power: np.ndarray

    def to_dict(self, components=("Hp", "He", "Hn")) -> dict:
        """JSON-ready, keyed by component."""
        def comp(a):
            return {c: float(v) for c, v in zip(components, a)}

        return {"test": "harmonic F test against neighbouring frequencies",
                "f_stat": comp(self.f_stat), "dof": list(self.dof),
                "p_value": comp(self.p_value),
                "harmonic_power_nT2": comp(self.harmonic_power),
                "neighbour_power_nT2": comp(self.neighbour_power)}


def comparison_frequencies(span_s: float, n_harmonics: int, cadence_s: float,
                           neighbours: int = NEIGHBOURS, period_s: float = DAY_S):
    """The harmonic frequencies ``k / period`` and their neighbours (Hz).

    Neighbours are the record's Fourier frequencies ``f_k +- j / T``, ``j = 2 ..
    neighbours + 1`` (the adjacent bin can hold a harmonic's leakage when the record is
    not a whole number of periods), kept when they are more than 1.5 bins from every
    harmonic and from zero and below the Nyquist frequency, and as many below each
    harmonic as above it, so that a sloped (red) spectrum averages out; when a harmonic
    has none on one side (records shorter than about 4 periods) there are none.

    Returns
    -------
    harmonics, neighbours : ndarray
    """
    df = 1.0 / span_s
    harm = np.arange(1, n_harmonics + 1) / period_s
    kept = []
    for h in harm:
        sides = []
        for side in (-1, 1):  # nearest first
            cand = h + side * np.arange(2, neighbours + 2) * df
            far = np.all(np.abs(cand[:, None] - harm[None, :]) > 1.5 * df, axis=1)
            sides.append(cand[far & (cand > 1.5 * df) & (cand < 0.5 / cadence_s)])
        m = min(len(sides[0]), len(sides[1]))  # as many below as above
        if m == 0:
            return harm, np.zeros(0)
        kept += [sides[0][:m], sides[1][:m]]
    return harm, np.unique(np.round(np.concatenate(kept), 15))


def amplitude_power(times_s, values, freqs) -> np.ndarray:
    """Squared amplitude (nT^2) of the least-squares sinusoid at each frequency, fitted
    with a mean, per column: shape ``(len(freqs), m)``. Works on uneven sampling."""
    t = np.asarray(times_s, dtype=float)
    v = np.asarray(values, dtype=float)
    v = v.reshape(v.shape[0], -1)
    v = v - v.mean(axis=0)
    out = np.empty((len(freqs), v.shape[1]))
    for i, f in enumerate(freqs):
        phase = 2.0 * np.pi * f * t
        x = np.stack([np.cos(phase), np.sin(phase)], axis=1)
        x = x - x.mean(axis=0)
        coef, *_ = np.linalg.lstsq(x, v, rcond=None)
        out[i] = np.sum(coef ** 2, axis=0)
    return out


def harmonic_f_test(times_s, residual, n_harmonics: int, neighbours: int = NEIGHBOURS,
                    period_s: float = DAY_S) -> HarmonicFTest | None:
    """F test of ``n_harmonics`` daily harmonics in each column of ``residual``.

    Parameters
    ----------
    times_s : array_like, shape (n,)
        Sample times (s), increasing; gaps allowed.
    residual : array_like, shape (n, m)
        Data minus the fit without local-time terms (nT).
    n_harmonics : int
        Harmonics ``k = 1 .. K`` of ``1 / period_s``.

    Returns
    -------
    HarmonicFTest or None
        None when the record has no neighbouring frequency to compare with (shorter
        than about three periods).

    Examples
    --------
    >>> rng = np.random.default_rng(1)
    >>> t = np.arange(0.0, 10 * 86400.0, 600.0)
    >>> noise = rng.normal(0.0, 2.0, (t.size, 2))
    >>> daily = np.stack([2.0 * np.cos(2 * np.pi * t / 86400.0), 0.0 * t], axis=1)
    >>> res = harmonic_f_test(t, noise + daily, 3)  # 3 x 8 neighbours, 1.5 and 2.5 / day shared
    >>> bool(res.p_value[0] < 1e-3), bool(res.p_value[1] > 0.01), res.dof
    (True, True, (6, 44))
    """
    from scipy.stats import f as f_dist

    t = np.asarray(times_s, dtype=float)
    r = np.asarray(residual, dtype=float)
    r = r.reshape(r.shape[0], -1)
    ok = np.isfinite(r).all(axis=1) & np.isfinite(t)
    t, r = t[ok], r[ok]
    if t.size < 4 * n_harmonics + 4:
        return None
    cadence = float(np.median(np.diff(t)))
    span = float(t[-1] - t[0]) + cadence
    harm, nb = comparison_frequencies(span, n_harmonics, cadence, neighbours, period_s)
    if nb.size == 0:
        return None
    p_h = amplitude_power(t, r, harm).mean(axis=0)
    p_n = amplitude_power(t, r, nb).mean(axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        stat = np.where(p_n > 0, p_h / p_n, np.inf)
    dof = (2 * harm.size, 2 * nb.size)
    return HarmonicFTest(stat, dof, f_dist.sf(stat, *dof), p_h, p_n)


def residual_without_harmonics(result, times, data, ref):
    """``(t_s, data - scale R(w) ref - offset, keep)`` of a fit without local-time
    terms, on the rows :func:`magcal.alignment.gls.prepare` keeps (``keep``)."""
    from scipy.spatial.transform import Rotation

    from magcal.alignment.gls import prepare

    t_s, d, r, keep = prepare(times, data, ref)
    rot = Rotation.from_rotvec(np.deg2rad(np.asarray(result.angles_deg, dtype=float)))
    offset = np.zeros(3) if result.offset_nT is None else np.asarray(result.offset_nT)
    scale = 1.0 if result.scale is None else float(result.scale)
    return t_s, d - (scale * rot.apply(r) + offset), keep


def lt_field_test(result, times, data, ref, n_harmonics: int,
                  lon_deg=None) -> HarmonicFTest | None:
    """:func:`harmonic_f_test` of the residual of ``result`` (a fit without local-time
    harmonics) for ``n_harmonics`` daily harmonics.

    At a fixed longitude local-time harmonics are UT harmonics with other phases, and the
    test's power does not depend on phase; a moving spacecraft's ``lon_deg`` (per
    sample) shifts each sample's time by ``lon / 15`` h so the harmonics are in local
    time.
    """
    t_s, resid, keep = residual_without_harmonics(result, times, data, ref)
    if lon_deg is not None and np.ndim(lon_deg) and np.ptp(np.asarray(lon_deg, float)) > 0:
        t_s = t_s + np.asarray(lon_deg, dtype=float)[keep] / 15.0 * 3600.0
        order = np.argsort(t_s, kind="stable")
        t_s, resid = t_s[order], resid[order]
    return harmonic_f_test(t_s, resid, n_harmonics)
