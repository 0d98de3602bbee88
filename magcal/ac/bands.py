"""Band-selective PiCoG: apply the correction only in the bands where it helps.

The on-board correction (constant matrices, Eq. 28) changes the target by
``delta = sum_k M_k B_k + G - B_target``, a linear combination of sensor differences:
the disturbers' fields minus the other sensors' noise scaled by the matrices (Eq. 22).
Where no disturber is present the correction only adds that noise (Venus Express: the
inboard sensor's floor at 40-64 Hz). The "ground" product splits ``delta`` into the
eighth-octave bands (:data:`WEIGHT_BAND_RATIO`; the check's bands are half-octave, see
:func:`magcal.ac.bandcheck.record_bands_hz`) with FFT brick-wall filters (their sum is
``delta`` again) and weights each band and component:

- ``w = 1`` where the full correction does not raise the band's power by more than
  :data:`RISE_TOLERANCE` (the ambient field cancels in ``delta``, so power can only
  fall by removing a disturbance or rise by adding noise; the tolerance keeps the
  ambient field's random cross term from switching bands off);
- otherwise ``w = clip(-Re<R, D> / <D, D>, 0, 1)`` with ``R`` and ``D`` the band's
  Fourier coefficients of the raw target and of ``delta``: the weight that minimises the
  band's power, ``|d|^2 / (|d|^2 + |noise|^2)`` for a disturber ``d`` under added noise.

Below the check's lowest band (four Welch bins) the record's own Fourier coefficients
still resolve octave bands (:func:`low_bands_hz`). The ambient field dominates them,
so there the full correction is kept only where it lowers a band's power beyond the
scatter of its cross term with the ambient field (slow disturbers, heater cycles and
steps live there); a band the record cannot judge takes the weight of the band above
it. The lowest checked band passes its weight down only where the correction lowers
raw's power over the checked bands as a whole by more than the same :data:`LOW_Z`
standard deviations of its cross term; otherwise the unjudged bands get weight 0. A
full weight kept because the correction raises a band's power by less than
:data:`RISE_TOLERANCE` says only that it is neutral there: passed down on a record
where the correction removes nothing, it put the partner's red noise into every band
below the check, where the ambient field hides it from raw's power but not from the
error against the ambient truth. A correction that removes something (a step or a
drift, a tone, the pair's own noise averaged out) shows over the checked bands and is
passed down as before. These bands are left out when the lowest checked band fails,
since their leakage reaches it.

**Never worse than raw** (:func:`deliver`): the product is checked against the raw
target with :func:`magcal.ac.bandcheck.band_check`; a band/component still above
``WORSE_FACTOR`` times the raw power gets ``w = 0`` (the band-limited correction), and
when that cannot meet the rule either the raw target is delivered. The kind delivered
and the reason travel with the product.

On records of a geostationary day or more, the correction's smooth slow part that is
not a step (:func:`magcal.ac.slow.slow_part`: a boom sensor's temperature drift, the
ambient field through the sensors' misalignments) is taken out of the correction
before the bands are weighted: the target keeps its own offsets instead of receiving
the partner's.

When every weight is 1 and no slow part is removed, the ground product equals the
on-board one (it "collapses" to the constant matrices); otherwise it is a filter and
cannot be uploaded as matrices.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from magcal.ac.bandcheck import WORSE_FACTOR, BandCheck, band_check, record_bands_hz
from magcal.ac.slow import SlowPart, slow_part
from magcal.errors import InputError

#: a band's weight is lowered only where the full correction raises its power by more
#: than this factor (in-sample, over the record's Fourier coefficients)
RISE_TOLERANCE = 1.02
#: weights are chosen on bands finer than the check's (eighth-octave, at least this many
#: Welch bins of the check): a disturber's band then holds little of the noise around
#: it, and the step in noise density at its edges leaks less into the next checked band
WEIGHT_BAND_RATIO = 2 ** 0.125
WEIGHT_MIN_BINS = 4
#: delivered kinds, best first
KINDS = ("on_board", "ground", "band_limited", "raw")


def _centered(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``x`` minus its mean with NaN set to 0, and the valid-row mask."""
    x = np.asarray(x, dtype=float)
    ok = np.all(np.isfinite(x), axis=1)
    out = np.zeros_like(x)
    if ok.any():
        out[ok] = x[ok] - x[ok].mean(axis=0)
    return out, ok


def weights_per_frequency(f: np.ndarray, bands_hz, weights) -> np.ndarray:
    """``(len(f), 3)`` weights: band ``b``'s weight on ``lo_b <= f < hi_b``, 1 below the
    first band, the last band's weight above it.

    Examples
    --------
    >>> w = weights_per_frequency(np.array([0.0, 1.0, 2.5, 9.0]), [(1, 2), (2, 4)],
    ...                           [[0.5, 0.5, 0.5], [0.0, 1.0, 0.0]])
    >>> w[:, 0].tolist()
    [1.0, 0.5, 0.0, 0.0]
    """
    f = np.asarray(f, dtype=float)
    weights = np.asarray(weights, dtype=float).reshape(-1, 3)
    out = np.ones((f.size, 3))
    if not len(bands_hz):
        return out
    lows = np.array([lo for lo, _ in bands_hz], dtype=float)
    idx = np.searchsorted(lows, f, side="right") - 1
    inside = idx >= 0
    out[inside] = weights[idx[inside]]
    return out


#: below the check's lowest band the record's own Fourier coefficients still resolve
#: octave bands of at least this many coefficients (:func:`low_bands_hz`)
LOW_MIN_BINS = 4
#: there the full correction is kept where it lowers the band's power by more than this
#: many standard deviations of its cross term with what of the raw target it does not
#: explain (2 h records: a 2 nT step then leaves 0.51 of raw's error, as the full
#: correction did (0.50); 3 left 0.60)
LOW_Z = 2.0


def low_bands_hz(low_hz: float, n: int, dt_s: float) -> list[tuple[float, float]]:
    """Octave bands below ``low_hz`` of at least :data:`LOW_MIN_BINS` Fourier
    coefficients of an ``n``-sample record, lowest first (:func:`select_weights` adds
    ``[0, lo)`` below the first).

    Examples
    --------
    Two hours at 1 s below the check's 4.4 mHz: 0.56-1.1, 1.1-2.2 and 2.2-4.4 mHz.

    >>> [(round(lo * 1e3, 2), round(hi * 1e3, 2)) for lo, hi in low_bands_hz(1 / 225, 7200, 1.0)]
    [(0.56, 1.11), (1.11, 2.22), (2.22, 4.44)]
    """
    df = 1.0 / (n * dt_s)
    edges = [float(low_hz)]
    while edges[-1] / 2.0 >= LOW_MIN_BINS * df * (1.0 - 1e-9):
        edges.append(edges[-1] / 2.0)
    edges = edges[::-1]
    return list(zip(edges[:-1], edges[1:]))


def band_filter(x: np.ndarray, dt_s: float, bands_hz, weights) -> np.ndarray:
    """``x`` (NaN rows as 0, mean removed) weighted per band in the Fourier domain."""
    xc, _ = _centered(x)
    f = np.fft.rfftfreq(xc.shape[0], dt_s)
    spec = np.fft.rfft(xc, axis=0) * weights_per_frequency(f, bands_hz, weights)
    return np.fft.irfft(spec, n=xc.shape[0], axis=0)


def select_weights(raw: np.ndarray, onboard: np.ndarray, dt_s: float, bands_hz=None):
    """Per-band, per-component weights of the correction ``onboard - raw`` (see the
    module docstring). Returns ``(bands_hz, weights (n_bands, 3))``.

    Examples
    --------
    A 35 Hz tone removed by the correction, which also adds white noise in y:

    >>> rng = np.random.default_rng(0); t = np.arange(16384) / 128
    >>> tone = np.sin(2 * np.pi * 35 * t)[:, None] * [1.0, 0.0, 0.0]
    >>> raw = rng.normal(0, 0.01, (16384, 3)) + tone
    >>> onboard = raw - tone + rng.normal(0, 0.05, (16384, 3)) * [0, 1, 0]
    >>> bands, w = select_weights(raw, onboard, 1 / 128)
    >>> k = [lo <= 35 < hi for lo, hi in bands].index(True)
    >>> float(w[k, 0]), bool(w[:, 1].max() < 0.1), bands[0][0]   # y left out, to 0 Hz
    (1.0, True, 0.0)
    """
    raw = np.asarray(raw, dtype=float)
    if bands_hz is None:
        bands_hz, _ = record_bands_hz(raw.shape[0], dt_s, min_bins=WEIGHT_MIN_BINS,
                                      ratio=WEIGHT_BAND_RATIO)
    bands_hz = [tuple(map(float, bd)) for bd in bands_hz]
    low = low_bands_hz(bands_hz[0][0], raw.shape[0], dt_s)
    added_low = bands_hz[0][0] > 0
    if added_low:
        bands_hz = [(0.0, low[0][0] if low else bands_hz[0][0])] + low + bands_hz
    r, ok_r = _centered(raw)
    d, ok_d = _centered(np.asarray(onboard, dtype=float) - raw)
    both = ok_r & ok_d
    r[~both], d[~both] = 0.0, 0.0
    f = np.fft.rfftfreq(r.shape[0], dt_s)
    R, D = np.fft.rfft(r, axis=0), np.fft.rfft(d, axis=0)
    weights = np.ones((len(bands_hz), 3))
    for b, (lo, hi) in enumerate(bands_hz):
        sel = (f >= lo) & (f < hi) if b < len(bands_hz) - 1 else f >= lo
        if not sel.any():
            continue
        if added_low and b <= len(low):
            continue                         # below the check: judged below
        cross = np.real(np.sum(np.conj(R[sel]) * D[sel], axis=0))
        dd = np.sum(np.abs(D[sel]) ** 2, axis=0)
        rr = np.sum(np.abs(R[sel]) ** 2, axis=0)
        # |R + D|^2 against |R|^2 over the band: an ambient field that dominates the band
        # makes the cross term noisy, so only a clear rise counts as harm
        helps = 2 * cross + dd <= (RISE_TOLERANCE - 1.0) * rr
        with np.errstate(divide="ignore", invalid="ignore"):
            w_opt = np.clip(np.where(dd > 0, -cross / dd, 0.0), 0.0, 1.0)
        weights[b] = np.where(helps, 1.0, w_opt)
    if added_low:
        # the lowest checked band's weight goes down only where the correction helps
        # beyond chance over the checked bands as a whole (module docstring)
        k0 = len(low) + 1
        checked = f >= bands_hz[k0][0]
        above = np.where(_lowers_power(R[checked], D[checked]), weights[k0], 0.0)
        weights[:k0] = _low_weights(r, d, dt_s, bands_hz[:k0], above)
    return bands_hz, weights


def _lowers_power(R: np.ndarray, D: np.ndarray) -> np.ndarray:
    """Per component: does adding ``D`` lower the power of ``R`` (Fourier coefficients
    of one band or several, rows) by more than :data:`LOW_Z` standard deviations of the
    cross term of ``D`` with what of ``R`` it does not explain (the ambient field, the
    noise)?"""
    cross = np.real(np.sum(np.conj(R) * D, axis=0))
    dd = np.sum(np.abs(D) ** 2, axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        w_ls = np.where(dd > 0, -cross / dd, 0.0)
    scatter = LOW_Z * np.sqrt(2.0 * np.sum(np.abs(R + w_ls * D) ** 2 * np.abs(D) ** 2,
                                           axis=0))
    return 2 * cross + dd < -scatter


def _low_weights(r: np.ndarray, d: np.ndarray, dt_s: float, bands_hz, above) -> np.ndarray:
    """Weights of the bands below the check, lowest first (:func:`select_weights`).

    A band's full correction is kept where it lowers the band's power beyond the
    scatter of the cross term of ``D`` with what of ``R`` it does not explain (the
    ambient field, the noise; :data:`LOW_Z` standard deviations,
    :func:`_lowers_power`); any other band takes the weight of the band above it
    (``above``: what the lowest checked band passes down, see :func:`select_weights`).
    The ambient field dominates these bands, so a rise cannot be told from its random
    cross term: on simulated geostationary days, lowering a weight where the correction
    seemed to raise the power left a slow disturber in (1233x -> 122x). Keeping every
    band whole added the other sensors' red noise to quiet records. ``R`` and ``D`` are
    detrended first, which takes most of a slowly varying ambient field out of the
    statistics.
    """
    t = np.arange(r.shape[0], dtype=float)
    t -= t.mean()
    f = np.fft.rfftfreq(r.shape[0], dt_s)
    R, D = (np.fft.rfft(x - np.outer(t, t @ x / (t @ t)), axis=0) for x in (r, d))
    out = np.full((len(bands_hz), 3), np.nan)
    for b, (lo, hi) in enumerate(bands_hz):
        sel = (f > 0) & (f >= lo) & (f < hi)
        if not sel.any():
            continue
        out[b] = np.where(_lowers_power(R[sel], D[sel]), 1.0, np.nan)
    for b in range(len(bands_hz) - 1, -1, -1):
        above = np.where(np.isfinite(out[b]), out[b], above)
        out[b] = above
    return out


@dataclass(frozen=True)
class Delivery:
    """The product delivered and why (see :func:`deliver`)."""

    product: np.ndarray          #: (n, 3) delivered target, NaN where an input is NaN
    kind: str                    #: one of :data:`KINDS`
    reason: str
    bands_hz: tuple
    weights: np.ndarray          #: (n_bands, 3) weights applied (all 0 for "raw")
    check: BandCheck | None      #: delivered product against raw
    onboard_check: BandCheck | None
    #: the smooth slow part taken out of the correction (:mod:`magcal.ac.slow`)
    slow: SlowPart | None = None
    #: rows of a sensor's own glitch, left out of the band filter's input and the checks
    glitch_rows: int = 0

    @property
    def collapses_to_on_board(self) -> bool:
        """True when the delivered correction is the constant matrices (all weights 1)."""
        return self.kind == "on_board"

    def to_dict(self) -> dict:
        return {"delivered": self.kind, "reason": self.reason,
                "bands_hz": [list(b) for b in self.bands_hz],
                "weights": np.asarray(self.weights).tolist(),
                "collapses_to_on_board": self.collapses_to_on_board,
                "slow_offsets": ({"removed": False} if self.slow is None
                                 else self.slow.to_dict()),
                "glitch_rows_left_out": int(self.glitch_rows),
                "worse_factor": WORSE_FACTOR,
                "rule": "no band/component of the delivered product above worse_factor "
                        "times the raw target's power (log-spaced bands, Welch); below "
                        "the lowest band the correction is kept where the record shows "
                        "it lowering the power beyond chance, else it takes the lowest "
                        "band's weight where the correction lowers the checked bands' "
                        "power beyond chance, else 0"}


def _check(raw, product, dt_s) -> BandCheck | None:
    try:
        return band_check(raw, product, dt_s)
    except InputError:
        return None


def _nan_where(product, raw, onboard):
    bad = ~(np.all(np.isfinite(raw), axis=1) & np.all(np.isfinite(onboard), axis=1))
    product = product.copy()
    product[bad] = np.nan
    return product


def deliver(raw: np.ndarray, onboard: np.ndarray, dt_s: float, *, bands_hz=None,
            weights=None, kind: str | None = None,
            max_rounds: int = 8, slow: bool | None = None, glitches=None) -> Delivery:
    """The best product that is nowhere worse than ``raw`` (module docstring).

    Parameters
    ----------
    raw, onboard : ndarray (n, 3)
        Raw target and on-board product (``sum_k M_k B_k + G``) on one uniform grid,
        NaN for missing samples.
    bands_hz, weights : optional
        Band weights fitted earlier (PARAMS.json ``ground``); chosen here when absent.
    slow : bool, optional
        Take the correction's smooth slow part out (:func:`magcal.ac.slow.slow_part`,
        records of at least :data:`magcal.ac.slow.MIN_RECORD_S` only); None and True
        both try it, False keeps the whole correction (PARAMS.json written before
        ``ground.slow_offsets`` existed).
    glitches : ndarray of bool (n,), optional
        Rows where a sensor has a glitch of its own (:func:`magcal.ac.robust.glitch_rows`):
        missing for the band filter, the band weights and the checks; there the
        product is the constant matrices' (or raw, when raw is delivered). Kept in, a
        glitch of one sensor enters the correction, which the band filter spreads over
        the whole record, and the raw target it is checked against is glitched too, so
        a product worse than raw on every good sample passed the check.

    Examples
    --------
    >>> rng = np.random.default_rng(1); t = np.arange(16384) / 128
    >>> tone = np.sin(2 * np.pi * 35 * t)[:, None] * [1.0, 0.0, 0.0]
    >>> raw = rng.normal(0, 0.01, (16384, 3)) + tone
    >>> onboard = raw - tone + rng.normal(0, 0.05, (16384, 3)) * [0, 1, 0]
    >>> out = deliver(raw, onboard, 1 / 128)
    >>> out.kind, out.check.worse_than_raw   # y's noise left out below 0.27 Hz too
    ('ground', [])
    """
    kw = dict(bands_hz=bands_hz, weights=weights, kind=kind, max_rounds=max_rounds, slow=slow)
    first = _deliver(raw, onboard, dt_s, **kw)
    if glitches is None or not np.any(glitches):
        return first
    # the product with every row kept wins when it is no worse than raw on the rows
    # without a glitch and at least as whole a correction (a flagged row may be a
    # disturber seen by one sensor only, which the whole correction removes)
    glitches = np.asarray(glitches, dtype=bool)
    second = _deliver(raw, onboard, dt_s, glitches=glitches, **kw)
    bad = np.where(glitches[:, None], np.nan, 1.0)
    check = _check(np.asarray(raw, dtype=float) * bad, first.product * bad, dt_s)
    if ((check is None or not check.worse_than_raw)
            and KINDS.index(first.kind) <= KINDS.index(second.kind)):
        return first
    return second


def _deliver(raw: np.ndarray, onboard: np.ndarray, dt_s: float, *, bands_hz=None,
            weights=None, kind: str | None = None,
            max_rounds: int = 8, slow: bool | None = None, glitches=None) -> Delivery:
    """:func:`deliver` with the glitch rows ``glitches`` (or none) left out."""
    raw0 = np.asarray(raw, dtype=float)
    onboard0 = np.asarray(onboard, dtype=float)
    if raw0.shape != onboard0.shape:
        raise InputError(f"raw {raw0.shape} and product {onboard0.shape} differ in shape")
    # raw and onboard: the glitch rows missing (what is filtered and checked);
    # raw0 and onboard0: every row (what is delivered)
    raw, onboard = raw0.copy(), onboard0.copy()
    n_glitch = 0
    if glitches is not None:
        glitches = np.asarray(glitches, dtype=bool)
        raw[glitches] = np.nan
        onboard[glitches] = np.nan
        n_glitch = int(glitches.sum())
    onboard_check = _check(raw, onboard, dt_s)
    if onboard_check is None:
        return Delivery(onboard0.copy(), "on_board", "record too short for a band check: the "
                        "on-board product is delivered unchecked", (), np.ones((0, 3)),
                        None, None, glitch_rows=n_glitch)
    sp = None if slow is False else slow_part(onboard - raw, dt_s)
    if sp is not None and sp.applied:
        onboard = onboard - sp.smooth      # NaN rows stay NaN
        if kind == "on_board":
            kind = None
    else:
        sp = None
    if bands_hz is None or weights is None:
        bands_hz, weights = select_weights(raw, onboard, dt_s)
    weights = np.array(weights, dtype=float).reshape(-1, 3)
    if weights.size and not weights.any():
        return Delivery(raw0.copy(), "raw", "the fit delivered the raw target (no band "
                        "where the correction helps)", tuple(bands_hz), weights,
                        _check(raw, raw, dt_s), onboard_check, sp, n_glitch)
    delta_mean = np.nanmean(onboard - raw, axis=0)
    raw_filled = np.where(np.isfinite(raw0), raw0, np.nanmean(raw, axis=0))
    if kind not in ("ground", "band_limited"):
        kind = "on_board" if np.all(weights == 1.0) and sp is None else "ground"
    reason = {"on_board": "the on-board correction raises no band's power: the constant "
                          "matrices are delivered",
              "ground": ("the correction is weighted down in the bands where it adds the "
                         "other sensors' noise (it no longer collapses to the constant "
                         "matrices)" if sp is None or not np.all(weights == 1.0) else
                         "the correction without its smooth slow part (it no longer "
                         "collapses to the constant matrices)"),
              "band_limited": "the fitted band-limited correction (left out where it was "
                              "worse than raw)"}[kind]
    for _ in range(max_rounds):
        if kind == "on_board":
            product = onboard0.copy()
        else:
            product = _nan_where(raw_filled + band_filter(onboard - raw, dt_s, bands_hz,
                                                          weights) + delta_mean,
                                 raw0, onboard0)
            if n_glitch:  # there the constant matrices' product, not spread by a filter
                product[glitches] = onboard0[glitches]
        check = _check(raw, _nan_where(product, raw, onboard), dt_s)
        worse = [] if check is None else check.worse_than_raw
        if not worse:
            if sp is not None:
                reason += f"; {sp.reason}"
            return Delivery(product, kind, reason, tuple(bands_hz), weights, check,
                            onboard_check, sp, n_glitch)
        listed = ", ".join(f"{w['band_hz'][0]:.3g}-{w['band_hz'][1]:.3g} Hz {w['component']}"
                           for w in worse[:4])
        for w in worse:
            lo, hi = w["band_hz"]
            k = "xyz".index(w["component"])
            for b, (blo, bhi) in enumerate(bands_hz):
                # the band itself, and what lies below the lowest checked band (its
                # leakage reaches the lowest band through the Welch window)
                if blo < hi and (bhi > lo or lo <= check.bands_hz[0][0]):
                    weights[b, k] = 0.0
        kind = "band_limited"
        reason = (f"the correction was still above {WORSE_FACTOR:g}x the raw power in "
                  f"{len(worse)} band/component(s) ({listed}): it is left out there")
    return Delivery(raw0.copy(), "raw", f"no band-limited correction met the rule ({reason}): "
                    "the raw target is delivered", tuple(bands_hz),
                    np.zeros_like(weights), _check(raw, raw, dt_s), onboard_check, sp, n_glitch)
