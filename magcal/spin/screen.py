"""Quality screen of a spinning-spacecraft record before the ripple fit or the flipper.

The spin-ripple fit and the flipper average spin-harmonic coefficients by least squares;
one saturated interval, 0.5 % of spikes or a few fill values decide them (measured on
the Galileo-like sample: a 10-minute flat ``b1`` gave O1 = -164 nT against 0.8, spikes
made the 2x tone six times larger after calibration than before, 99999 in ``b2`` gave
O2 = 1322 nT). :func:`screen_spin` applies the chain's own quality tests
(:mod:`magcal.qc.checks`) in the form that suits spinning data:

* fill values: non-finite readings and the all-nines fills (:data:`FILL_VALUES`);
* saturated or stuck: a component repeating its record's extreme value
  (:func:`~magcal.qc.checks.saturation_mask`), all three repeating one reading for a
  minute (:func:`~magcal.qc.checks.stuck_mask`);
* spikes: :func:`~magcal.qc.checks.spike_mask` on the field magnitude. The components
  of a spinning triad oscillate by the spin amplitude, which hides a spike from a test
  on them; the magnitude is constant but for the offsets' and gains' ripple, so a
  spike stands out in it whatever its direction (a spike of ``d`` nT on a field of
  ``B`` moves the magnitude by at least ``d**2 / (2 B)``, by ``d`` along the field).

The rows left out are treated as missing (the spin blocks they fall in are dropped when
the gap is too wide in phase) and counted in the products' ``screened`` record.
"""

from __future__ import annotations

import numpy as np

from magcal.qc import checks

#: All-nines fill values of instrument and index files (the reader already turns the
#: -1e31 family and -9999 into missing values).
FILL_VALUES = (99999.0, 999999.0, 9999.99, 99999.9)
#: A stuck run: all three readings identical for this long (the chain's ``[qc]``
#: ``stuck_seconds``) and at least :data:`STUCK_SAMPLES` samples.
STUCK_SECONDS = 60.0
STUCK_SAMPLES = 10
#: A component at its record's extreme this many samples in a row is saturated.
SATURATION_SAMPLES = 3

TESTS = {
    "fill": "non-finite or an all-nines fill value (" + ", ".join(
        f"{v:g}" for v in FILL_VALUES) + ", either sign)",
    "saturated_or_stuck": f"a component repeating its record's extreme value "
                          f"{SATURATION_SAMPLES}+ times, or all three repeating one reading "
                          f"for {STUCK_SECONDS:g} s",
    "spike": "the field magnitude beyond 8 robust sigma of an 11-sample running median, "
             "with a jump in and a jump out (at most 5 samples; magcal.qc spike_mask)",
}


def fill_mask(b) -> np.ndarray:
    """Rows with a non-finite reading or an all-nines fill value in any component.

    Examples
    --------
    >>> fill_mask([[1.0, 2.0, 3.0], [99999.0, 0.0, 0.0], [0.0, np.nan, 1.0]]).tolist()
    [False, True, True]
    """
    x = np.asarray(b, dtype=float)
    x = x[:, None] if x.ndim == 1 else x
    with np.errstate(invalid="ignore"):
        fill = np.isin(np.abs(x), FILL_VALUES)
    return fill.any(axis=1) | ~np.isfinite(x).all(axis=1)


def screen_spin(t_s, b) -> tuple[np.ndarray, dict]:
    """Rows of a spinning record to leave out, and what was left out.

    Parameters
    ----------
    t_s : array_like, shape (n,)
        Sample times (s), increasing.
    b : array_like, shape (n, 3)
        Readings in nT (missing values NaN).

    Returns
    -------
    bad : ndarray of bool, shape (n,)
        Rows to leave out (missing rows included).
    record : dict
        ``{"samples": rows left out that had all three readings, "fill": ...,
        "saturated_or_stuck": ..., "spike": ..., "tests": {...}}``; a row counts under
        the first test that caught it.

    Examples
    --------
    >>> from magcal.spin.despin import spin
    >>> p = np.arange(4000) * 2 * np.pi / 80
    >>> rng = np.random.default_rng(0)
    >>> b = spin(np.tile([30.0, 0.0, 10.0], (p.size, 1)), p) + rng.normal(0, 0.05, (4000, 3))
    >>> bad, rec = screen_spin(p, b)
    >>> rec["samples"]
    0
    >>> b[100, 0] += 40.0; b[2000, 1] = 99999.0; b[3000:3400, 0] = b[:, 0].max() + 50
    >>> bad, rec = screen_spin(p, b)
    >>> rec["spike"], rec["fill"], rec["saturated_or_stuck"]
    (1, 1, 400)
    """
    t = np.asarray(t_s, dtype=float)
    x = np.asarray(b, dtype=float)
    missing = ~np.isfinite(x).all(axis=1)
    fill = fill_mask(x) & ~missing
    x = np.where(fill[:, None], np.nan, x)
    dt = float(np.median(np.diff(t))) if t.size > 1 else STUCK_SECONDS
    run = max(STUCK_SAMPLES, int(np.ceil(STUCK_SECONDS / max(dt, 1e-9))))
    stuck = (checks.stuck_mask(x, min_run=run)
             | checks.saturation_mask(x, min_run=SATURATION_SAMPLES)) & ~missing & ~fill
    # spikes among the rest: rows already bad are bridged, not jumps
    magnitude = np.linalg.norm(np.where(stuck[:, None], np.nan, x), axis=1)
    spike = checks.spike_mask(magnitude) & ~missing & ~fill & ~stuck
    bad = missing | fill | stuck | spike
    record = {"samples": int((fill | stuck | spike).sum()), "fill": int(fill.sum()),
              "saturated_or_stuck": int(stuck.sum()), "spike": int(spike.sum()),
              "tests": dict(TESTS)}
    return bad, record


def describe_screened(screened: dict | None) -> str:
    """What the screen left out, in words ("" when nothing).

    Examples
    --------
    >>> describe_screened({"samples": 401, "fill": 1, "saturated_or_stuck": 400, "spike": 0})
    '401 samples left out (1 fill, 400 saturated or stuck)'
    >>> describe_screened({"samples": 0})
    ''
    """
    if not screened or not screened.get("samples"):
        return ""
    parts = ", ".join(f"{screened[k]} {k.replace('_', ' ')}" for k in
                      ("fill", "saturated_or_stuck", "spike") if screened.get(k))
    return f"{screened['samples']} samples left out ({parts})"
