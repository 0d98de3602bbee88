"""Localized fields along B in an ELFIN pass, kept out of the gain drift.

The spin-plane gain drift (:mod:`magcal.missions.elfin.drift`, a polynomial in time
per zone against ``|B| - |IGRF|``, of degree ``ElfinSettings.gain_drift_degree``: 4,
a cubic until 2026-11-30, which the numbers below were measured with) and a natural
field along B are the same vector (along
the spin-plane field), so the drift takes such a field whenever its time shape allows:
71 % of the energy of a 90 s pulse in a 6 min pass is a cubic, and the product keeps
8 % of it (2022-01-12). Leaving the pulse out of the fits does not save it either: the
cubic bridged over the two minutes the pulse covers errs by tens of nT (76 % kept,
distortion 19 % with the interval given to the injected run only).

What separates the two is their time scale: a thermal gain drift is as slow as the
pass, while a compressional pulse is localized. So the product's ``|B|`` residual is
searched, zone by zone, for Gaussian pulses on top of the drift's polynomial
(:func:`find_pulses`:
greedy, centre and width refined); a pulse is kept when it divides the residual's sum
of squares by :data:`PULSE_MIN_GAIN` or more, is at least :data:`PULSE_MIN_NT` high,
narrower than :data:`PULSE_MAX_FWHM_S` and rises and falls inside the zone (a wider
best fit, or one cut by a zone end, is a drift the cubic lacks, not a pulse: the real
day's delivered product has two such, zones 9 and 10, 172 and 179 s wide, +111 and
+104 nT, both cut by the zone end, fitted with the drift and removed). Every shape
found is stated with the reason it is removed (``why``, :func:`drift_reason`; the
JSON's ``pulses_b.search`` and the CLI), so a wide ``|B|`` structure is not lost
silently. A pulse beside such a structure is searched with it as a pair
(:func:`_best_pair`): the greedy search alone finds one shape between the two, wider
and higher than the pulse, and not the structure. The
day is then calibrated again with each kept pulse's shape fitted alongside the drift
and left in the product (``pulse_b_<j>`` field columns; ``fit_gain_drift(natural=)``).

The decision is taken once, on the product without pulses, as for the level steps
(:mod:`magcal.missions.elfin.levels`).

Measured on 2022-01-12 (``ElfinSettings.pulses_b``; ``workflows/elfin_preservation.py
--zones all --signals pulse_b --no-held --centres 0.35,0.5,0.65 --settings
pulses_b=true``): a 100 nT pulse along B of 90 s FWHM keeps 93 % of its energy (median
of 36 placements, 2-8 % without) with 9 % distortion (37 %), but its size is poorly
determined: 56 % of the cases keep 90 % or more, 72 % within 0.5-2 times the energy
(0.33-2.98). The clean day itself holds -30 to +20 nT on a 90 s pulse's shape beyond
the cubic (the amplitude of the true shape fitted to the clean day), and the cubic and
a pulse wider than a minute are close to collinear, so the width the search picks
amplifies that. Hence :func:`pulse_trials`: the height's error from the same pulse
found again in other zones' counts. No natural pulse on the clean day, on 160 draws of
correlated plus white noise, nor where the scan finds only drifts (when measured, zones
3, 4, 9, 10 of the clean day: 170-300 s wide, fitted as drift; scalar residual 6.8 ->
6.3 nT, zone median).

A natural pulse whose gain is near :data:`PULSE_MIN_GAIN` is a close call that a
small change of the residual turns over (2022-01-12 zone 10: its own dip, -38 to
-49 nT over 120-138 s, gain 10.6-21.0, is kept as natural only when an east-west or
along-track pulse, whose small part along B changes the ``|B|`` residual by about
10 nT, is put in nearby; the clean run removes a 179 s drift at the zone's end
instead; the 100 nT pulses along B put into the counts were found with gains
13-312). That turn-over is what costs those east-west and along-track pulses their
distortion target (15-24 %, 4-5 % with ``pulses_b`` off); the gain is listed so
that a user can see it.

Data: ELFIN SOC (PI V. Angelopoulos, UCLA), "Open Data for Scientific Use".
"""

from __future__ import annotations

import numpy as np
import pandas as pd

#: Smallest gain of a pulse: the sum of squares of the ``|B|`` residual about the cubic
#: (and the pulses already kept) over that with the pulse too.
PULSE_MIN_GAIN = 10.0
#: Smallest pulse height (nT): the detector's own smallest disturbance.
PULSE_MIN_NT = 30.0
#: Widest pulse (FWHM, s) kept; auroral structures last 20-120 s at ELFIN's altitude.
PULSE_MAX_FWHM_S = 150.0
#: Narrowest pulse searched (FWHM, s): shorter ones are the detector's (they leave the
#: cubic alone).
PULSE_MIN_FWHM_S = 20.0
#: Smallest gain that lets the greedy search go on (the pulses are then judged
#: against each other with :data:`PULSE_MIN_GAIN`: two pulses in a zone each leave the
#: other's sum of squares, so neither alone divides it tenfold).
SEARCH_GAIN = 1.5
#: Pulses searched per zone.
PULSE_MAX_COUNT = 3
#: FWHMs (s) of the search grid.
SEARCH_FWHM_S = (20.0, 30.0, 45.0, 60.0, 90.0, 120.0, 180.0, 240.0)
#: Largest correlation (about the trend) of the two shapes of a pair searched together:
#: closer ones are one shape twice, with large opposite heights.
PAIR_MAX_CORRELATION = 0.9
#: Trend under the pulses by default, and the degree above which a search on the product
#: with a cubic drift states what the drift took (:func:`taken_by_the_drift`).
PULSE_TREND_DEGREE = 3
#: RMS floor of the residual (nT) in the gain: finer structure than this is not
#: resolved against the model (the day's fast part is about 5 nT).
PULSE_FLOOR_NT = 1.0
#: Resampling step of the spin-averaged residual for the search (s).
PULSE_STEP_S = 1.0
#: Field columns of the shapes fitted with the gain drift: kept in the product
#: (natural pulses along B) and removed with the drift.
NATURAL_COLUMNS, DRIFT_COLUMNS = "pulse_b_", "drift_b_"
#: What ``pulses_b.search`` of ``ELFIN_CAL.json`` holds (:func:`zone_pulses`).
SEARCH_NOTE = (
    "every shape the search found in the |B| residual of the product without pulses "
    "(height_nT as found there, nT; gain: that residual's sum of squares about the drift's "
    "polynomial "
    f"without the shape over that with it, kept from {PULSE_MIN_GAIN:g}): natural ones "
    "are kept in the product, the others removed with the gain drift for the reason "
    f"given (why). A natural pulse whose gain is near {PULSE_MIN_GAIN:g} is a close call: "
    "on 2022-01-12 a zone's own dip (-38 to -49 nT, gain 10.6-21.0) was kept only when "
    "an east-west or along-track pulse was put in nearby, against 13-312 for 100 nT "
    "pulses along B put into the counts")
_SIGMA_PER_FWHM = 1.0 / (2.0 * np.sqrt(2.0 * np.log(2.0)))


def gaussian(t_s, centre_s: float, fwhm_s: float) -> np.ndarray:
    """Unit-height Gaussian pulse of full width at half maximum ``fwhm_s``.

    Examples
    --------
    >>> round(float(gaussian(np.array([45.0]), 0.0, 90.0)[0]), 6)
    0.5
    """
    x = (np.asarray(t_s, dtype=float) - centre_s) / (fwhm_s * _SIGMA_PER_FWHM)
    return np.exp(-0.5 * x ** 2)


def _orth(columns: np.ndarray) -> np.ndarray:
    q, _ = np.linalg.qr(columns)
    return q


def _rss(y, q) -> float:
    r = y - q @ (q.T @ y)
    return float(r @ r)


def _design(t, trend, pulses):
    cols = [trend] + [gaussian(t, c, w)[:, None] for c, w in pulses]
    return np.column_stack(cols)


def _refine(t, y, trend, fixed, new, lo, hi):
    """Centre and width of the pulse ``new`` refined with the ``fixed`` ones held
    (amplitudes linear): refined together, two pulses trade shapes (a true one becomes a
    wide pulse plus a narrow one of the other sign)."""
    from scipy.optimize import minimize

    def cost(x):
        if not (PULSE_MIN_FWHM_S <= x[1] <= 2 * PULSE_MAX_FWHM_S and lo <= x[0] <= hi):
            return np.inf
        return _rss(y, _orth(_design(t, trend, fixed + [tuple(x)])))

    x0 = np.asarray(new, dtype=float)
    res = minimize(cost, x0, method="Nelder-Mead",
                   options={"xatol": 0.5, "fatol": 1e-6 * max(cost(x0), 1e-12),
                            "maxiter": 800})
    return fixed + [tuple(res.x) if np.isfinite(res.fun) else tuple(new)]


def _polish(t, y, trend, pulses, lo, hi):
    """All centres and widths refined together, each within a quarter of its width of
    where the one-at-a-time search put it and its width within a factor 4/3: the
    pulses settle against each other without trading shapes."""
    from scipy.optimize import minimize

    x0 = np.ravel(pulses)
    start = x0.reshape(-1, 2)
    q = _orth(trend)

    def cost(x):
        p = x.reshape(-1, 2)
        if np.any(np.abs(p[:, 0] - start[:, 0]) > start[:, 1] / 4) \
                or np.any(p[:, 1] < 0.75 * start[:, 1]) or np.any(p[:, 1] > start[:, 1] / 0.75) \
                or np.any(p[:, 0] < lo) or np.any(p[:, 0] > hi):
            return np.inf
        return _rss(y, _orth(_design(t, trend, p))) if _separable(t, q, p) else np.inf

    res = minimize(cost, x0, method="Nelder-Mead",
                   options={"xatol": 0.2, "fatol": 1e-8 * max(cost(x0), 1e-12),
                            "maxiter": 600 * x0.size})
    return [tuple(p) for p in res.x.reshape(-1, 2)] if np.isfinite(res.fun) else pulses


def _separable(t, q, pulses) -> bool:
    """Whether no two of ``pulses`` correlate (about the trend, orthonormal basis ``q``)
    more than :data:`PAIR_MAX_CORRELATION`: refined together, two shapes can otherwise
    merge into one with huge opposite heights."""
    if len(pulses) < 2:
        return True
    g = np.column_stack([gaussian(t, c, w) for c, w in pulses])
    g -= q @ (q.T @ g)
    g /= np.maximum(np.linalg.norm(g, axis=0), 1e-12)
    c = np.abs(g.T @ g)
    np.fill_diagonal(c, 0.0)
    return bool(c.max() <= PAIR_MAX_CORRELATION)


def _cut(t, centre, fwhm, edge_s):
    """Whether a shape's half maximum comes within ``edge_s`` of the fitted span's ends
    (scalars or arrays): as much the cubic's end as a pulse."""
    return (centre - fwhm / 2 < t[0] + edge_s) | (centre + fwhm / 2 > t[-1] - edge_s)


def _drift_shape(t, centre, fwhm, edge_s, max_fwhm_s) -> bool:
    """Whether a shape is one the search removes with the drift: ``max_fwhm_s`` wide or
    more, or cut by a zone end (:func:`_cut`)."""
    return bool(fwhm >= max_fwhm_s or _cut(t, centre, fwhm, edge_s))


def _best_pair(t, y, trend, centres, lo, hi, edge_s, max_fwhm_s):
    """A shape beside a drift: the pair of grid shapes, one of them a drift shape
    (:func:`_drift_shape`), that together leave the least sum of squares about the trend
    (every pair, in closed form), then refined together (:func:`_polish`); [] when no
    pair is separable or the refined drift shape no longer is one.

    The greedy search takes the best single shape first; a pulse beside a wide
    structure at a zone's end (a drift the cubic lacks) then comes out as one shape
    between the two, wider and higher than either (2022-01-12 zone 9: a 100 nT pulse
    found at 152 nT), and the structure is not found again. Two localized shapes are
    not searched as a pair: together they trade one pulse into a wide shape and a
    narrow one of the other sign."""
    q = _orth(trend)
    y0 = y - q @ (q.T @ y)
    shapes = [(c, w) for w in SEARCH_FWHM_S for c in centres]
    drift = np.array([_drift_shape(t, c, w, edge_s, max_fwhm_s) for c, w in shapes])
    if not drift.any():
        return []
    g = np.concatenate([gaussian(t[:, None], centres[None, :], w) for w in SEARCH_FWHM_S],
                       axis=1)
    g -= q @ (q.T @ g)
    m = g.T @ g[:, drift]
    b, bd = g.T @ y0, g[:, drift].T @ y0
    d = np.maximum(np.einsum("ij,ij->j", g, g), 1e-12)
    dd = d[drift]
    det = d[:, None] * dd[None, :] - m ** 2
    separable = m ** 2 < PAIR_MAX_CORRELATION ** 2 * d[:, None] * dd[None, :]
    red = np.where(separable, (dd[None, :] * b[:, None] ** 2 - 2 * m * b[:, None] * bd[None, :]
                               + d[:, None] * bd[None, :] ** 2) / np.where(separable, det, 1.0),
                   0.0)
    if not red.any():
        return []
    i, j = np.unravel_index(int(np.argmax(red)), red.shape)
    pair = _polish(t, y, trend, [shapes[i], shapes[np.flatnonzero(drift)[j]]], lo, hi)
    return pair if _drift_shape(t, *pair[1], edge_s, max_fwhm_s) else []


def _gains(t, y, trend, pulses, floor) -> list[float]:
    """Sum of squares without each pulse over that with all (each plus ``floor``)."""
    full = _rss(y, _orth(_design(t, trend, pulses))) + floor
    return [(_rss(y, _orth(_design(t, trend, pulses[:j] + pulses[j + 1:]))) + floor) / full
            for j in range(len(pulses))]


def find_pulses(t_s, residual, fit, *, edge_s: float = 20.0,
                max_count: int = PULSE_MAX_COUNT, min_gain: float = PULSE_MIN_GAIN,
                min_nT: float = PULSE_MIN_NT, max_fwhm_s: float = PULSE_MAX_FWHM_S,
                degree: int = PULSE_TREND_DEGREE, pair_search: bool = True
                ) -> pd.DataFrame:
    """Gaussian pulses on top of a polynomial trend in one zone's ``|B|`` residual.

    Greedy: the pulse (centre on a 2 s grid at least ``edge_s`` inside the fitted
    span, FWHM 20-240 s) that most reduces the sum of squares about the trend and the
    pulses already found is added, then all centres and widths are refined together;
    the search stops at the first pulse whose gain (sum of squares without it over
    with it) is under ``min_gain``, or at ``max_count``. For the second shape, the best
    pair of any shape and a drift shape (one wider than ``max_fwhm_s`` or cut by a zone
    end; every pair of the grid, :func:`_best_pair`) replaces the first shape and its
    greedy successor where it leaves the smaller sum of squares and each of its shapes
    has ``min_gain`` (``pair_search``): a pulse beside a wide structure at a zone's end
    is otherwise found as one shape between the two. The pulses kept are those with
    that gain, a height of ``min_nT`` or more and a FWHM under ``max_fwhm_s``.

    Parameters
    ----------
    t_s : array_like (n,)
        Times, s.
    residual : array_like (n,)
        ``|B| - |IGRF|`` of the product, spin-averaged (nT).
    fit : array_like of bool (n,)
        Samples the gain drift fits (the search uses only these).
    pair_search : bool
        Also search a shape and a drift shape as a pair (see above). Off: the greedy
        search alone (2022-01-12: a 100 nT pulse at 0.35 of zone 9 found at +152 and
        -116 nT for either polarity, 90 and -110 nT with the pair).

    Returns
    -------
    DataFrame
        One row per shape found: ``centre_s``, ``fwhm_s``, ``height_nT``, ``gain``,
        ``natural`` (kept in the product) and ``why`` (:func:`drift_reason`: why it is
        removed with the drift instead; "" if natural).

    Examples
    --------
    >>> t = np.arange(0.0, 370.0, 0.5)
    >>> rng = np.random.default_rng(1)
    >>> r = 40 * (t / 370) ** 3 + 100 * gaussian(t, 130.0, 90.0) + rng.normal(0, 3, t.size)
    >>> p = find_pulses(t, r, np.ones(t.size, bool))
    >>> len(p), round(float(p["centre_s"][0])), round(float(p["fwhm_s"][0]) / 10)
    (1, 130, 9)
    """
    t = np.asarray(t_s, dtype=float)
    fit = np.asarray(fit, bool)
    cols = ["centre_s", "fwhm_s", "height_nT", "gain", "natural", "why"]
    if fit.sum() < 4 * (degree + 2):
        return pd.DataFrame(columns=cols)
    grid = np.arange(t[fit][0], t[fit][-1], PULSE_STEP_S)
    src = np.flatnonzero(fit)
    y = np.interp(grid, t[src], np.asarray(residual, dtype=float)[src])
    near = np.abs(t[src][np.clip(np.searchsorted(t[src], grid), 0, src.size - 1)] - grid)
    y, tg = y[near <= 2 * PULSE_STEP_S], grid[near <= 2 * PULSE_STEP_S]
    x = (tg - tg[0]) / max(tg[-1] - tg[0], 1e-9) * 2.0 - 1.0
    trend = np.vander(x, degree + 1)
    lo, hi = tg[0] + edge_s, tg[-1] - edge_s
    centres = np.arange(lo, hi, 2.0)
    if centres.size == 0:
        return pd.DataFrame(columns=cols)
    floor = y.size * PULSE_FLOOR_NT ** 2
    pulses = []
    for _ in range(max_count):
        q = _orth(_design(tg, trend, pulses))
        y0 = y - q @ (q.T @ y)
        rss0 = float(y0 @ y0) + floor
        best = None
        for w in SEARCH_FWHM_S:
            g = gaussian(tg[:, None], centres[None, :], w)
            g -= q @ (q.T @ g)
            red = (g.T @ y0) ** 2 / np.maximum(np.einsum("ij,ij->j", g, g), 1e-12)
            j = int(np.argmax(red))
            if best is None or red[j] > best[0]:
                best = (float(red[j]), (float(centres[j]), w))
        trial = _refine(tg, y, trend, pulses, best[1], lo, hi)
        rss = _rss(y, _orth(_design(tg, trend, trial)))
        if len(pulses) == 1 and pair_search:
            pair = _best_pair(tg, y, trend, centres, lo, hi, edge_s, max_fwhm_s)
            # the pair replaces the greedy step only where it explains more and each
            # of its shapes is demanded (a pair of which one goes would leave its other
            # shape refined against the first, not the greedy's best)
            rss_pair = _rss(y, _orth(_design(tg, trend, pair))) if pair else np.inf
            if rss_pair < rss and min(_gains(tg, y, trend, pair, floor)) >= min_gain:
                trial, rss = pair, rss_pair
        if rss0 / (rss + floor) < SEARCH_GAIN:
            break
        pulses = trial
    # each pulse judged against the others: the weakest under min_gain goes, then again
    while pulses:
        gains = _gains(tg, y, trend, pulses, floor)
        j = int(np.argmin(gains))
        if gains[j] >= min_gain:
            break
        pulses = pulses[:j] + pulses[j + 1:]
    if not pulses:
        return pd.DataFrame(columns=cols)
    if len(pulses) > 1:
        pulses = _polish(tg, y, trend, pulses, lo, hi)
    design = _design(tg, trend, pulses)
    amp = np.linalg.lstsq(design, y, rcond=None)[0][trend.shape[1]:]
    out = pd.DataFrame({"centre_s": [c for c, _ in pulses], "fwhm_s": [w for _, w in pulses],
                        "height_nT": amp, "gain": _gains(tg, y, trend, pulses, floor)})
    # a natural pulse rises and falls inside the zone (half maximum ``edge_s`` inside
    # the fitted span): one cut by a zone end is as much the cubic's end as a pulse
    cut = _cut(tg, out["centre_s"], out["fwhm_s"], edge_s)
    low, wide = np.abs(out["height_nT"]) < min_nT, out["fwhm_s"] >= max_fwhm_s
    out["natural"] = ~low & ~wide & ~cut
    out["why"] = [drift_reason(*x, min_nT=min_nT, max_fwhm_s=max_fwhm_s)
                  for x in zip(low, wide, cut)]
    return out


def drift_reason(low: bool, wide: bool, cut: bool, *, min_nT: float = PULSE_MIN_NT,
                 max_fwhm_s: float = PULSE_MAX_FWHM_S) -> str:
    """Why a shape :func:`find_pulses` found is removed with the drift ("" if it is kept
    as a natural pulse): what the product's JSON and the CLI state for each.

    Examples
    --------
    >>> drift_reason(False, True, True)
    'FWHM 150 s or more; cut by a zone end'
    >>> drift_reason(False, False, False)
    ''
    """
    return "; ".join(text for flag, text in (
        (low, f"under {min_nT:g} nT"), (wide, f"FWHM {max_fwhm_s:g} s or more"),
        (cut, "cut by a zone end")) if flag)


def zone_pulses(field: pd.DataFrame, **kw) -> pd.DataFrame:
    """:func:`find_pulses` on each zone of a calibrated field.

    Returns
    -------
    DataFrame
        ``zone``, ``start`` (UTC of the zone's first row), ``centre_s`` (from it),
        ``fwhm_s``, ``height_nT``, ``gain``, ``natural``, ``why`` (see :func:`find_pulses`).
    """
    from magcal.missions.elfin.detect import zone_residuals
    from magcal.missions.elfin.drift import fit_samples

    zone = field["zone"].to_numpy()
    tabs = []
    for k in dict.fromkeys(zone):
        z = field.iloc[np.flatnonzero(zone == k)]
        ns = z.index.as_unit("ns").asi8
        t = (ns - ns[0]) / 1e9
        p = find_pulses(t, zone_residuals(z)[:, 3], fit_samples(z, scalar=True), **kw)
        tabs.append(p.assign(zone=int(k), start=z.index[0]))
    cols = ["zone", "start", "centre_s", "fwhm_s", "height_nT", "gain", "natural", "why"]
    out = pd.concat([t for t in tabs if len(t)], ignore_index=True) if any(
        len(t) for t in tabs) else pd.DataFrame(columns=cols)
    return out[cols]


def taken_by_the_drift(found: pd.DataFrame, with_cubic: pd.DataFrame,
                       degree: int) -> pd.DataFrame:
    """``found`` (the search on the trend of the drift's ``degree``, :func:`zone_pulses`)
    with the shapes a cubic search finds on the product with a cubic gain drift
    (``with_cubic``: :func:`zone_pulses` of it) and it does not: what a drift above a
    cubic takes without the search seeing it, stated (``natural`` False, ``why``) so
    that it is not lost silently.

    A drift of degree 4 or more takes a ``|B|`` structure a few minutes wide whole (a
    quartic is 90 % of a 90 s pulse's energy over a 6 min pass), so the search on its
    own trend finds nothing where the cubic's search found a wide shape and stated it.
    A cubic shape matches a found one when their centres are within half the wider
    FWHM. Every row gets ``fitted``: True for the shapes fitted with the drift (those
    of ``found``), False for those only stated here.
    """
    out = found.assign(fitted=True)
    if degree <= PULSE_TREND_DEGREE or not len(with_cubic):
        return out
    rows = []
    for r in with_cubic.itertuples():
        same = found[found["zone"] == r.zone]
        if len(same) and np.any(np.abs(same["centre_s"].to_numpy(float) - r.centre_s)
                                <= np.maximum(same["fwhm_s"].to_numpy(float), r.fwhm_s) / 2):
            continue
        why = f"taken by the degree-{degree} drift (found with a cubic drift)"
        rows.append({**r._asdict(), "natural": False, "fitted": False,
                     "why": why if not r.why else f"{r.why}; {why}"})
    if not rows:
        return out
    extra = pd.DataFrame(rows).drop(columns="Index")
    return pd.concat([out, extra[out.columns]], ignore_index=True).sort_values(
        ["zone", "centre_s"], kind="stable", ignore_index=True)


def shape_columns(frame: pd.DataFrame, prefix: str) -> np.ndarray:
    """The shapes (len(frame), m) in ``frame``'s columns named ``prefix<j>``
    (:data:`NATURAL_COLUMNS` or :data:`DRIFT_COLUMNS`; m = 0 without any)."""
    cols = [c for c in frame.columns if c.startswith(prefix)]
    return frame[cols].to_numpy(float) if cols else np.zeros((len(frame), 0))


def with_shape_columns(frame: pd.DataFrame, prefix: str, shapes) -> pd.DataFrame:
    """``frame`` with the columns ``prefix1 ..`` holding ``shapes`` (len(frame), m)."""
    tpl = np.asarray(shapes, float).reshape(len(frame), -1)
    return frame.assign(**{f"{prefix}{j + 1}": tpl[:, j] for j in range(tpl.shape[1])})


def pulse_templates(field: pd.DataFrame, pulses: pd.DataFrame) -> np.ndarray:
    """Unit-height shapes (len(field), m) of ``pulses`` (:func:`zone_pulses`) on their
    zones' rows (zero elsewhere), ``m`` the most pulses of any zone: the
    ``pulse_templates`` of :func:`~magcal.missions.elfin.pipeline.calibrate_elfin_day`."""
    zone = field["zone"].to_numpy()
    m = int(pulses.groupby("zone").size().max()) if len(pulses) else 0
    out = np.zeros((len(field), m))
    for k, group in pulses.groupby("zone"):
        rows = np.flatnonzero(zone == k)
        ns = field.index.as_unit("ns").asi8[rows]
        t = (ns - ns[0]) / 1e9
        for j, (_, p) in enumerate(group.iterrows()):
            out[rows, j] = gaussian(t, p["centre_s"], p["fwhm_s"])
    return out


def pulse_trials(fgs: pd.DataFrame, state: pd.DataFrame, settings, day,
                 n_trials: int, *, fit_exclude=None) -> pd.DataFrame:
    """How well the day determines each kept pulse's height: the pulse put into the
    counts of other zones at the same place and found again.

    For each natural pulse of ``day`` (:meth:`ElfinDay.pulses_along_b`), a pulse of
    its height and width along IGRF is added to the counts of up to ``n_trials`` other
    zones without a pulse of their own (the nearest in time first), at the same
    fraction of the zone's used span, through the day's linear calibration
    (:func:`~magcal.missions.elfin.injection.inject_counts`). The day is calibrated
    again with ``settings`` and the trial pulses (the trial zones together, as the
    level trials of :func:`magcal.missions.elfin.levels.level_trials` are: a zone
    calibrated alone lacks the day's spin-axis prior and its ``fit_exclude``), and the
    height of the natural pulse found in each trial zone within half a FWHM of the
    place (0 if none) is a trial. The RMS of the trials' errors is the height's stated
    error: it holds the day's own ``|B|`` structure on that shape beyond the cubic and
    how the search's width choice amplifies it. ``fit_exclude`` (rows of ``fgs``) is
    what ``day`` was given.

    Returns
    -------
    DataFrame
        Per kept pulse: ``zone``, ``centre``, ``fwhm_s``, ``height_nT``,
        ``trial_heights_nT`` (list), ``height_error_nT`` (NaN without trials: no zone
        without a pulse, or the day with the trial pulses could not be calibrated).
    """
    from magcal.missions.elfin.injection import trial_day, trial_places

    kept = day.pulses_along_b()
    cols = ["zone", "centre", "fwhm_s", "height_nT", "trial_heights_nT", "height_error_nT"]
    if not kept or n_trials <= 0:
        return pd.DataFrame(kept, columns=cols[:4]).reindex(columns=cols)
    f = day.linear.field
    busy = {p["zone"] for p in kept}
    ns = f.index.as_unit("ns").asi8
    out = []
    for p in kept:
        signals, places = {}, []
        for k, sel, t, c in trial_places(f, p["zone"], [p["centre"]], busy, n_trials):
            b = f.iloc[sel][["igrf_x_gei", "igrf_y_gei", "igrf_z_gei"]].to_numpy(float)
            signals[k] = p["height_nT"] * gaussian(t, c, p["fwhm_s"])[:, None] \
                * b / np.linalg.norm(b, axis=1, keepdims=True)
            places.append((k, ns[sel][0], c))
        heights = []
        if signals:
            trial = trial_day(fgs, state, settings, day, signals, fit_exclude=fit_exclude)
            if trial is not None:
                found = trial.pulses_along_b()
                for k, start_ns, c in places:
                    near = [q["height_nT"] for q in found if q["zone"] == k and abs(
                        (pd.Timestamp(q["centre"], tz="UTC").value - start_ns) / 1e9 - c)
                        <= p["fwhm_s"] / 2]
                    heights.append(near[0] if near else 0.0)
        h = np.asarray(heights)
        out.append({**p, "trial_heights_nT": h.tolist(),
                    "height_error_nT": float(np.sqrt(np.mean((h - p["height_nT"]) ** 2)))
                    if h.size else float("nan")})
    return pd.DataFrame(out, columns=cols)
