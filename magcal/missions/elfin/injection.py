"""Synthetic natural signals injected into ELFIN counts: what each calibration step keeps.

Every step after the linear fit (and the linear fit's own spin-phase spline) is fitted
against IGRF with time-varying freedom, so part of a natural field that IGRF does not
hold (auroral field-aligned currents: 50-500 nT over 20-120 s, mostly east-west) can be
absorbed into the calibration. This module measures it on the real day:

1. the day is calibrated once (the *clean* run);
2. a signal ``dB(t)`` in GEI is turned into counts through the inverse of the clean
   linear calibration and spin phase (:func:`inject_counts`): despun with the attitude
   file's spin axis, spun with the clean phase, divided by the zone's coupling;
3. the injected counts are calibrated again, and ``recovered = calibrated(injected) -
   calibrated(clean)`` in GEI is compared with ``dB`` product by product
   (:func:`preservation`).

The machinery is checked with the phase held at its clean solution
(``hold_phase``): there the linear step cannot rotate a spin-plane field away, and an
injected signal must come back almost whole.

Zones are calibrated independently, so one run carries one signal in each chosen zone
(one signal per zone per run).

Examples
--------
>>> import numpy as np
>>> t = np.arange(0.0, 360.0, 0.1)
>>> s = signal_shape("gauss_ew", t, t0=180.0)
>>> round(float(s.max()), 6), round(float(fwhm(t, s)), 1)
(200.0, 40.0)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from magcal.errors import InputError

#: Signal types: (amplitude nT, direction, shape, width s). Directions: "ew" the orbit
#: normal (east-west for a polar orbit), "along" the along-track direction
#: perpendicular to it, "b" along IGRF.
SIGNALS = {
    "gauss_ew": (200.0, "ew", "gauss", 40.0),       # FWHM 40 s
    "gauss_along": (200.0, "along", "gauss", 40.0),
    "sheet_ew": (300.0, "ew", "tanh", 20.0),        # 10-90 % rise 20 s, to the zone's end
    "pulse_b": (100.0, "b", "gauss", 90.0),         # FWHM 90 s
    "wave_2hz": (5.0, "ew", "wave", 10.0),          # 2 Hz, 10 s Hann packet
}
WAVE_HZ = 2.0
_TANH_10_90 = 2.0 * np.arctanh(0.8)                 # rise 10-90 % of 0.5 (1 + tanh(x / tau))


def signal_shape(kind: str, t_s, t0: float) -> np.ndarray:
    """Signed amplitude (nT) of signal ``kind`` at times ``t_s`` (s), centred on ``t0``."""
    if kind not in SIGNALS:
        raise InputError(f"unknown signal {kind!r} (known: {', '.join(SIGNALS)})")
    amp, _, shape, width = SIGNALS[kind]
    x = np.asarray(t_s, dtype=float) - t0
    if shape == "gauss":
        return amp * np.exp(-4.0 * np.log(2.0) * x ** 2 / width ** 2)
    if shape == "tanh":
        return amp * 0.5 * (1.0 + np.tanh(x * _TANH_10_90 / width))
    env = np.where(np.abs(x) <= width / 2, np.cos(np.pi * x / width) ** 2, 0.0)
    return amp * env * np.cos(2.0 * np.pi * WAVE_HZ * x)


def fwhm(t_s, y) -> float:
    """Full width at half maximum of a single positive pulse (s)."""
    above = np.asarray(t_s)[np.asarray(y) >= 0.5 * np.max(y)]
    return float(above[-1] - above[0]) if above.size else 0.0


def directions(times, state: pd.DataFrame, b_gei) -> dict:
    """Unit vectors (n, 3) in GEI at ``times``: ``ew`` orbit normal, ``along`` the
    along-track direction (velocity without its orbit-normal part), ``b`` along ``b_gei``."""
    ts = (state.index.asi8 - times.asi8[0]) / 1e9
    tq = (times.asi8 - times.asi8[0]) / 1e9
    pos = np.column_stack([np.interp(tq, ts, state[f"pos_gei_{c}"]) for c in "xyz"])
    vel = np.column_stack([np.interp(tq, ts, state[f"vel_gei_{c}"]) for c in "xyz"])
    ew = np.cross(pos, vel)
    ew /= np.linalg.norm(ew, axis=1, keepdims=True)
    along = vel - np.sum(vel * ew, axis=1, keepdims=True) * ew
    along /= np.linalg.norm(along, axis=1, keepdims=True)
    b = np.asarray(b_gei, float)
    return {"ew": ew, "along": along, "b": b / np.linalg.norm(b, axis=1, keepdims=True)}


def signal_gei(kind: str, zone_field: pd.DataFrame, state: pd.DataFrame,
               centre: float = 0.5) -> np.ndarray:
    """Signal ``kind`` (n, 3) in GEI nT over one zone of a calibrated field.

    Centred at the fraction ``centre`` of the zone's used span (the current sheet starts
    rising there and lasts to the zone's end).
    """
    used = zone_field["used"].to_numpy() == 1
    t = (zone_field.index.asi8 - zone_field.index.asi8[0]) / 1e9
    t0 = t[used][0] + centre * (t[used][-1] - t[used][0])
    b = zone_field[["igrf_x_gei", "igrf_y_gei", "igrf_z_gei"]].to_numpy()
    u = directions(zone_field.index, state, b)[SIGNALS[kind][1]]
    return signal_shape(kind, t, t0)[:, None] * u


def inject_counts(fgs: pd.DataFrame, clean, signals: dict) -> pd.DataFrame:
    """FGS counts with GEI signals added through the inverse of a clean calibration.

    Parameters
    ----------
    fgs : DataFrame
        The counts that ``clean`` was calibrated from (same rows, in order).
    clean : ElfinCalibration
        Its linear calibration (``field`` with ``phase``, the spin axis and ``zone``;
        ``zones`` with each zone's ``coupling`` in nT per count).
    signals : dict
        Zone number -> (n_zone, 3) signal in GEI nT on that zone's rows.

    Returns
    -------
    DataFrame
        A copy of ``fgs`` with ``b1, b2, b3`` changed on the signals' zones.
    """
    from magcal.missions.elfin.phase import despun_basis
    from magcal.spin.despin import spin

    f = clean.field
    if len(f) != len(fgs):
        raise InputError(f"clean calibration has {len(f)} rows for {len(fgs)} FGS rows")
    body = np.zeros((len(fgs), 3))
    for k, dg in signals.items():
        rows = np.flatnonzero(f["zone"].to_numpy() == k)
        z = f.iloc[rows]
        basis = despun_basis(z[[f"spin_axis_gei_{c}" for c in "xyz"]].to_numpy())
        body[rows] = spin(np.einsum("nij,nj->ni", basis, np.asarray(dg, float)),
                          z["phase"].to_numpy())
    return add_body_field(fgs, clean, body)


def add_body_field(fgs: pd.DataFrame, clean, body_nT) -> pd.DataFrame:
    """FGS counts plus a field in the spinning body frame (nT, (len(fgs), 3)), turned
    into counts zone by zone through the inverse of ``clean``'s coupling.

    The common last step of :func:`inject_counts` (natural signals) and
    :func:`magcal.missions.elfin.noise.noisy_counts` (instrument noise).
    """
    body = np.asarray(body_nT, dtype=float)
    f = clean.field
    if len(f) != len(fgs) or body.shape != (len(fgs), 3):
        raise InputError(f"a field of shape {body.shape} and a clean calibration of "
                         f"{len(f)} rows do not match {len(fgs)} FGS rows")
    out = fgs.copy()
    counts = out[["b1", "b2", "b3"]].to_numpy(dtype=float, copy=True)
    zone = f["zone"].to_numpy()
    for i, k in enumerate(dict.fromkeys(zone.tolist())):
        rows = np.flatnonzero(zone == k)
        counts[rows] += np.linalg.solve(clean.zones[i].coupling, body[rows].T).T
    out[["b1", "b2", "b3"]] = counts
    return out


@dataclass(frozen=True)
class Kept:
    """How much of an injected signal a product keeps.

    Attributes
    ----------
    gain : float
        ``<recovered, signal> / <signal, signal>``: the signal's own shape kept.
    energy : float
        ``gain * |gain|``: the fraction of the signal's energy kept in its shape.
    distortion : float
        RMS of ``recovered - gain * signal`` over the RMS of the signal (what came back
        in another shape or direction, e.g. spread over the zone).
    """

    gain: float
    energy: float
    distortion: float


def kept(recovered, signal, used=None) -> Kept:
    """:class:`Kept` of ``recovered`` against ``signal`` (n, 3), on ``used`` samples.

    Examples
    --------
    >>> s = np.zeros((100, 3)); s[40:60, 0] = 1.0
    >>> k = kept(0.9 * s, s)
    >>> round(k.gain, 3), round(k.energy, 3), round(k.distortion, 3)
    (0.9, 0.81, 0.0)
    """
    r, s = np.asarray(recovered, float), np.asarray(signal, float)
    if used is not None:
        r, s = r[used], s[used]
    ss = float(np.sum(s * s))
    g = float(np.sum(r * s)) / ss
    dist = float(np.sqrt(np.sum((r - g * s) ** 2) / ss))
    return Kept(gain=g, energy=g * abs(g), distortion=dist)


def zone_mean_share(signal) -> float:
    """Share of a signal's energy in its mean over the samples given.

    A per-zone linear calibration against a model absorbs a zone-constant field in any
    direction (spin-axis: the offset; spin plane: it spins in the body frame like the
    model field, so the coupling takes it), so this share is lost by any such fit; the
    ``_ac`` measures of :func:`preservation` leave it out.

    Examples
    --------
    >>> round(zone_mean_share(np.array([[1.0, 0, 0], [1.0, 0, 0]])), 3)
    1.0
    """
    s = np.asarray(signal, float)
    return float(s.shape[0] * np.sum(s.mean(axis=0) ** 2) / np.sum(s * s))


def polynomial_share(signal, t_s, degree: int) -> float:
    """Share of a signal's energy in its projection on polynomials in time over the zone.

    What a per-zone drift of that degree fitted against a model takes of the signal
    when nothing else competes for it (the least-squares projection, component by
    component): degree 0 is :func:`zone_mean_share`; the gain drift is a cubic, the
    linear fit's phase and tilt quadratics. A signal whose share is large cannot be
    told from such a drift by the fit, whatever else the data hold.

    Examples
    --------
    >>> t = np.linspace(0.0, 360.0, 3601)
    >>> x = 2 * t / 360 - 1
    >>> s = np.column_stack([x ** 2, np.zeros_like(t), np.zeros_like(t)])
    >>> round(polynomial_share(s, t, 2), 6), round(polynomial_share(s, t, 1), 3)
    (1.0, 0.556)
    """
    s = np.asarray(signal, float)
    t = np.asarray(t_s, float)
    x = 2.0 * (t - t[0]) / max(t[-1] - t[0], 1e-12) - 1.0
    basis = np.polynomial.legendre.legvander(x, int(degree))
    fit = basis @ np.linalg.lstsq(basis, s, rcond=None)[0]
    return float(np.sum(fit * fit) / np.sum(s * s))


def preservation(clean_day, injected_day, signals: dict, kind: str) -> pd.DataFrame:
    """Per product and zone: what of the injected signal the product keeps.

    ``clean_day`` and ``injected_day`` are :class:`~magcal.missions.elfin.pipeline.ElfinDay`
    of the same rows and settings; rows are used where both products use them.

    Columns: ``energy_kept``, ``gain``, ``distortion`` (:func:`kept`, against the whole
    signal), the same against the signal and the recovered field with their zone means
    removed (``energy_kept_ac``, ``distortion_ac``: what a per-zone calibration against
    a model can keep at all), and ``zone_mean_share`` (:func:`zone_mean_share`). Where the
    injected run measured its bridge error (``ElfinSettings.bridge_trials``), also
    ``error_rms_nT`` (RMS of ``|recovered - signal|`` over the samples above 5 % of the
    signal's peak that the run left out of its fits) and ``bridge_rms_nT`` (the run's
    stated error there, :mod:`magcal.missions.elfin.bridge`).
    """
    cols = ["bx_gei", "by_gei", "bz_gei"]
    rows = []
    for name, inj in injected_day.products.items():
        fc, fi = clean_day.products[name].field, inj.field
        zone = fi["zone"].to_numpy()
        for k, dg in signals.items():
            sel = zone == k
            used = (fi["used"].to_numpy()[sel] == 1) & (fc["used"].to_numpy()[sel] == 1)
            rec = fi[cols].to_numpy()[sel] - fc[cols].to_numpy()[sel]
            kk = kept(rec, dg, used)
            dg_u = np.asarray(dg, float)[used]
            ac = kept(rec[used] - rec[used].mean(axis=0), dg_u - dg_u.mean(axis=0))
            row = {"signal": kind, "product": name, "zone": int(k),
                   "energy_kept": kk.energy, "gain": kk.gain,
                   "distortion": kk.distortion, "energy_kept_ac": ac.energy,
                   "distortion_ac": ac.distortion, "zone_mean_share": zone_mean_share(dg_u)}
            if "bridge_rms_nT" in fi.columns:
                size = np.linalg.norm(dg, axis=1)
                left = used & (fi["fit"].to_numpy()[sel] == 0) & (size > 0.05 * size.max())
                err = np.linalg.norm(rec - dg, axis=1)[left]
                stated = fi["bridge_rms_nT"].to_numpy()[sel][left]
                row["error_rms_nT"] = float(np.sqrt(np.mean(err ** 2))) if left.any() else np.nan
                row["bridge_rms_nT"] = float(np.nanmedian(stated)) \
                    if left.any() and np.isfinite(stated).any() else np.nan
            rows.append(row)
    return pd.DataFrame(rows)


def recovered_both(clean_field: pd.DataFrame, plus_field: pd.DataFrame,
                   minus_field: pd.DataFrame, sel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """On the rows ``sel`` of three calibrated fields of the same rows: where all three
    are used, and ``r+``, ``r-`` (GEI, nT), the plus and minus fields minus the clean
    one (:func:`polarity_parts`, :func:`~magcal.missions.elfin.injection_plot.plot_parts`).
    """
    cols = ["bx_gei", "by_gei", "bz_gei"]
    used = np.all([f["used"].to_numpy()[sel] == 1
                   for f in (clean_field, plus_field, minus_field)], axis=0)
    base = clean_field[cols].to_numpy(float)[sel]
    return (used, plus_field[cols].to_numpy(float)[sel] - base,
            minus_field[cols].to_numpy(float)[sel] - base)


def polarity_parts(clean_day, plus_day, minus_day, signals: dict, kind: str) -> pd.DataFrame:
    """Per product and zone: what came back split into the part that follows the
    signal's polarity and the part that does not.

    With ``r+`` and ``r-`` recovered from the signal and from its opposite
    (``calibrated(injected) - calibrated(clean)``), the odd part ``(r+ - r-) / 2`` is
    what the product makes of the signal itself, and the even part ``(r+ + r-) / 2``
    changes the same way for either polarity: once a signal makes the calibration leave
    its interval out, the product there shows the day's own field that the clean run
    gave to a drift (2022-01-12: a pulse along B comes back as its height minus
    10-33 nT for either sign). That part is a property of the clean product over the
    interval, which no ELFIN data can check (the model is the only reference); the
    product states its size as the bridge error (``bridge_rms_nT``).

    Columns: ``energy_kept_odd``, ``gain_odd``, ``distortion_odd`` (:func:`kept` of the
    odd part against the signal) and ``even_rms`` (RMS of the even part over the
    signal's RMS), on the samples all three products use. ``plus_day`` carries
    ``signals`` and ``minus_day`` their negatives.

    Examples
    --------
    >>> from types import SimpleNamespace as NS
    >>> t = np.arange(100.0)
    >>> sig = np.zeros((100, 3)); sig[40:60, 0] = 10.0
    >>> day = np.column_stack([np.sin(t), np.cos(t), t])
    >>> def product(field):
    ...     f = pd.DataFrame(field, columns=["bx_gei", "by_gei", "bz_gei"])
    ...     return NS(products={"p": NS(field=f.assign(zone=0, used=1))})
    >>> bump = np.zeros((100, 3)); bump[45:55, 1] = -3.0      # the same for either sign
    >>> out = polarity_parts(product(day), product(day + 0.9 * sig + bump),
    ...                      product(day - 0.9 * sig + bump), {0: sig}, "pulse")
    >>> out[["gain_odd", "distortion_odd", "even_rms"]].round(3).values.tolist()
    [[0.9, 0.0, 0.212]]
    """
    rows = []
    for name, plus in plus_day.products.items():
        fc, fp = clean_day.products[name].field, plus.field
        fm = minus_day.products[name].field
        zone = fp["zone"].to_numpy()
        for k, dg in signals.items():
            used, r_plus, r_minus = recovered_both(fc, fp, fm, zone == k)
            dg_u = np.asarray(dg, float)[used]
            odd = kept(0.5 * (r_plus - r_minus), dg, used)
            even = 0.5 * (r_plus + r_minus)[used]
            rows.append({"signal": kind, "product": name, "zone": int(k),
                         "energy_kept_odd": odd.energy, "gain_odd": odd.gain,
                         "distortion_odd": odd.distortion,
                         "even_rms": float(np.sqrt(np.sum(even ** 2) / np.sum(dg_u ** 2)))})
    return pd.DataFrame(rows)


def left_out_rows(field: pd.DataFrame) -> np.ndarray:
    """Rows of a calibrated field that some fit left out: not among the samples of the
    vector fits or of the ``|B|`` fits (:func:`~magcal.missions.elfin.drift.fit_samples`),
    i.e. the detected or given intervals and the unused rows.

    Examples
    --------
    >>> f = pd.DataFrame({"used": [1, 1, 1, 0], "fit": [1, 0, 1, 0],
    ...                   "fit_scalar": [1, 1, 0, 0]})
    >>> left_out_rows(f).tolist()
    [False, True, True, True]
    """
    from magcal.missions.elfin.drift import fit_samples

    return ~(fit_samples(field) & fit_samples(field, scalar=True))


def joined_parts(counts: tuple, state: pd.DataFrame, settings, clean_day, plus_day,
                 minus_day, signals: dict, kind: str, *, hold_phase=None) -> pd.DataFrame:
    """:func:`polarity_parts` once both polarities leave the same rows out of the fits.

    Where a detector draws a left-out interval's ends depends on the day's own field
    beside the signal, which adds to one polarity's excursion and subtracts from the
    other's: on 2022-01-12, an east-west 40 s pulse at 0.65 of zone 4 was left out to
    281 s for one sign and to 317 s for the other, and the fits (there the spin phase)
    differ over those 35 s. The odd part then carries the day's own field over them
    (distortion 19 %). Here both injected days (``plus_day``, ``minus_day``, calibrated
    with ``settings`` from ``counts``, the FGS frames that carry ``signals`` and their
    negatives) are calibrated again with the union of their left-out rows given
    (``fit_exclude``): what remains of the odd distortion is what the calibration does
    to the signal itself, the rest is the detector's polarity-dependent extent, which
    no ELFIN data can pin down (the model is the only reference for the own field
    there). Whole day, 36 places: east-west and along-track pulses at both targets on
    their own part in 24 and 25 as delivered, 36 and 36 joined. Not a fair test for a
    current sheet or a pulse along B, whose level step and shape are read on the
    fitted rows beside the interval that the union takes away.

    Returns
    -------
    DataFrame
        The :func:`polarity_parts` columns with the suffix ``_joined``, on ``signal``,
        ``product`` and ``zone``.
    """
    from magcal.missions.elfin.pipeline import calibrate_elfin_day

    union = left_out_rows(plus_day.calibration.field) | \
        left_out_rows(minus_day.calibration.field)
    if union.size != len(counts[0]):
        raise InputError(f"the calibrated field has {union.size} rows for {len(counts[0])} "
                         "FGS rows: a zone was skipped, so its rows cannot be matched")
    days = [calibrate_elfin_day(fgs, state, settings, hold_phase=hold_phase,
                                fit_exclude=union, diagnostics=False) for fgs in counts]
    parts = polarity_parts(clean_day, days[0], days[1], signals, kind)
    keys = ["signal", "product", "zone"]
    return parts.rename(columns={c: f"{c}_joined" for c in parts.columns if c not in keys})


#: The issue's targets for every signal: energy kept and distortion (RMS, of the signal's).
TARGET_ENERGY, TARGET_DISTORTION = 0.9, 0.1


def target_counts(delivered: pd.DataFrame, *, min_energy: float = TARGET_ENERGY,
                  max_distortion: float = TARGET_DISTORTION) -> pd.DataFrame:
    """How many cases of each signal meet the preservation targets, read two ways.

    Per case and polarity on the whole signal (``energy_kept`` at least ``min_energy``,
    ``distortion`` at most ``max_distortion``, and both), and, where both polarities ran
    (:func:`polarity_parts` columns), on the signal's own part: the odd part
    ``(r+ - r-) / 2`` without the day's own field that the clean run gave to a drift
    (``energy_kept_odd``, ``distortion_odd``; one case per zone and place).

    Parameters
    ----------
    delivered : DataFrame
        The delivered product's rows of :func:`run_injections` (``signal``, ``zone``,
        ``energy_kept``, ``distortion``; ``sign`` and the odd columns with both signs).

    Returns
    -------
    DataFrame
        Per signal: ``cases``, ``energy``, ``distortion``, ``both`` and, with the odd
        part, ``odd_cases``, ``odd_energy``, ``odd_distortion``, ``odd_both``; with the
        :func:`joined_parts` columns, ``joined_both`` (both targets on the odd part
        once both polarities leave the same rows out).

    Examples
    --------
    >>> tab = pd.DataFrame({"signal": ["a", "a", "b"], "zone": [1, 2, 1],
    ...                     "energy_kept": [0.95, 0.80, 1.20],
    ...                     "distortion": [0.05, 0.05, 0.30]})
    >>> target_counts(tab).to_dict(orient="records")[0]
    {'signal': 'a', 'cases': 2, 'energy': 1, 'distortion': 2, 'both': 1}
    """
    rows = []
    for kind, g in delivered.groupby("signal", sort=False):
        e, d = g["energy_kept"] >= min_energy, g["distortion"] <= max_distortion
        row = {"signal": kind, "cases": len(g), "energy": int(e.sum()),
               "distortion": int(d.sum()), "both": int((e & d).sum())}
        if "energy_kept_odd" in g.columns:
            one = g[g["sign"] == g["sign"].iloc[0]] if "sign" in g.columns else g
            eo = one["energy_kept_odd"] >= min_energy
            do = one["distortion_odd"] <= max_distortion
            row.update(odd_cases=len(one), odd_energy=int(eo.sum()),
                       odd_distortion=int(do.sum()), odd_both=int((eo & do).sum()))
            if "energy_kept_odd_joined" in one.columns:
                ej = one["energy_kept_odd_joined"] >= min_energy
                dj = one["distortion_odd_joined"] <= max_distortion
                row.update(joined_both=int((ej & dj).sum()))
        rows.append(row)
    return pd.DataFrame(rows)


def trial_places(field: pd.DataFrame, own: int, at, busy, n_trials: int) -> list[tuple]:
    """Where a signal that zone ``own`` holds at the times ``at`` is put for a trial:
    up to ``n_trials`` other zones of ``field`` not in ``busy`` and with used samples
    (the nearest in number first), each at the same fraction of its used span as the
    mean of ``at`` in zone ``own`` (the pulse and level trials of
    :mod:`magcal.missions.elfin.pulses` and :mod:`magcal.missions.elfin.levels`).

    Parameters
    ----------
    field : DataFrame
        A calibrated field (``zone``, ``used``, UTC index).
    own : int
        The zone holding the signal.
    at : sequence
        UTC times without a zone (as the listings write them) whose mean is the place.
    busy : collection of int
        Zones not to put a trial into (those with a signal of their own).

    Returns
    -------
    list of (k, rows, t_s, t0_s)
        Per trial zone: its number, its row positions in ``field``, their times from
        its first sample (s) and the place (s, same origin).

    Examples
    --------
    >>> idx = pd.date_range("2022-01-12", periods=6, freq="10s", tz="UTC")
    >>> f = pd.DataFrame({"zone": [0, 0, 0, 1, 1, 1], "used": 1}, index=idx)
    >>> [(int(k), rows.tolist(), float(t0)) for k, rows, _, t0 in
    ...  trial_places(f, 0, ["2022-01-12 00:00:10"], {0}, 3)]
    [(1, [3, 4, 5], 10.0)]
    """
    zone = field["zone"].to_numpy()
    used = field["used"].to_numpy() == 1
    ns = field.index.as_unit("ns").asi8
    mine = np.flatnonzero(zone == own)
    tu = (ns[mine][used[mine]] - ns[mine][0]) / 1e9
    when = np.mean([(pd.Timestamp(x, tz="UTC").value - ns[mine][0]) / 1e9 for x in at])
    share = (when - tu[0]) / max(tu[-1] - tu[0], 1e-9)
    quiet = [k for k in dict.fromkeys(zone) if k not in busy and used[zone == k].any()]
    out = []
    for k in sorted(quiet, key=lambda q: abs(q - own))[:n_trials]:
        rows = np.flatnonzero(zone == k)
        t = (ns[rows] - ns[rows][0]) / 1e9
        tk = t[used[rows]]
        out.append((k, rows, t, tk[0] + share * (tk[-1] - tk[0])))
    return out


def trial_day(fgs: pd.DataFrame, state: pd.DataFrame, settings, day, signals: dict, *,
              fit_exclude=None):
    """``day`` calibrated again with trial signals in its counts (the pulse and level
    trials of :mod:`magcal.missions.elfin.pulses` and :mod:`magcal.missions.elfin.levels`).

    The trial zones are calibrated together with the rest of the day, as ``day`` was
    (a zone alone would lack the day's spin-axis prior), with the same ``fit_exclude``
    (rows of ``fgs``) and ``settings`` without trials of their own.

    Parameters
    ----------
    signals : dict
        Zone number -> (n_zone, 3) signal in GEI nT, through the day's linear
        calibration (:func:`inject_counts`).

    Returns
    -------
    ElfinDay or None
        None when the day with the signals cannot be calibrated as delivered (e.g. a
        trial zone no longer calibrated): the trials then state no error.
    """
    from magcal.missions.elfin.pipeline import calibrate_elfin_day

    lin = day.linear
    keep = lin.kept_rows(len(fgs))
    exclude = None if fit_exclude is None else np.asarray(fit_exclude, bool)[keep]
    plain = settings.without_trials()
    try:
        return calibrate_elfin_day(inject_counts(fgs[keep], lin, signals), state, plain,
                                   fit_exclude=exclude, diagnostics=False)
    except InputError:
        return None


def signal_extent(signals: dict, zone, fraction: float) -> np.ndarray:
    """Rows where a zone's signal exceeds ``fraction`` of its peak (vector norm).

    ``signals`` maps a zone number to its signal (the zone's rows, in order) and
    ``zone`` is the zone number of every row of the day.

    Examples
    --------
    >>> sig = np.zeros((5, 3)); sig[1:4, 0] = [1.0, 10.0, 0.2]
    >>> signal_extent({7: sig}, np.array([3, 7, 7, 7, 7, 7]), 0.05).tolist()
    [False, False, True, True, False, False]
    """
    zone = np.asarray(zone)
    out = np.zeros(zone.size, bool)
    for k, dg in signals.items():
        size = np.linalg.norm(np.asarray(dg, float), axis=1)
        out[np.flatnonzero(zone == k)] = size > fraction * size.max()
    return out


def select_zones(fgs: pd.DataFrame, zones) -> pd.DataFrame:
    """The FGS rows of the zones numbered ``zones`` (0-based, in the day's order;
    zones are split at gaps over 60 s as the pipeline does)."""
    from magcal.missions.elfin.phase import split_zones

    ranges = split_zones((fgs.index.asi8 - fgs.index.asi8[0]) / 1e9, 60.0)
    bad = [k for k in zones if not 0 <= k < len(ranges)]
    if bad:
        raise InputError(f"zones {bad} not in the day (it has {len(ranges)})")
    keep = np.zeros(len(fgs), bool)
    for k in zones:
        keep[slice(*ranges[k])] = True
    return fgs[keep]


def run_injections(fgs: pd.DataFrame, state: pd.DataFrame, settings=None, *,
                   kinds=tuple(SIGNALS), zones=None, hold: bool = False,
                   mask_signal: float = 0.0, mask_clean: bool = True,
                   progress=None, plot_dir=None, centre: float = 0.5,
                   sign: float = 1.0, both_signs: bool = False,
                   joined: bool = False, scale: float = 1.0) -> tuple[pd.DataFrame, object]:
    """Inject each signal kind into each chosen zone and measure what every product keeps.

    Parameters
    ----------
    fgs, state : DataFrame
        The ELFIN day (:mod:`magcal.missions.elfin.files`).
    settings : ElfinSettings, optional
        The pipeline's settings (default: the delivered ones). With ``hold`` the phase
        refit is switched off and the linear fit keeps the clean phase. The bridge
        trials (``bridge_trials``) run on the injected runs only, where
        :func:`preservation` compares their stated error with the signal's; the pulse
        trials (``pulse_trials``) not at all (they state an error, the product is the
        same).
    kinds : sequence of str
        Keys of :data:`SIGNALS`; one run each, carrying that signal in every chosen zone.
    zones : sequence of int, optional
        Zone numbers (0-based, default all). Only the FGS rows of these zones are
        calibrated.
    hold : bool
        Hold the spin phase at the clean linear solution (the machinery check; no phase
        refit, no detection of disturbed intervals, no level steps and no pulses along
        B, so that only the linear fit can absorb).
    mask_signal : float
        If positive, leave the samples where the signal exceeds this fraction of its
        peak out of every fit (clean and injected runs alike): what a fit on quiet
        intervals only would keep, given where the signal is (an upper bound for a
        detected disturbance mask).
    mask_clean : bool
        With ``mask_signal``, also leave those samples out of the clean run's fits
        (default). False: only the injected run is fitted without them, as a detector
        would that flags exactly the signal and nothing on the clean day; the
        distortion is then the calibration's own change when that interval is left
        out, the floor of any detect-and-exclude scheme.
    progress : callable, optional
        Called with one line per run.
    centre : float
        Where in each zone the signals sit (``centre`` of :func:`signal_gei`).
    sign : float
        Polarity of every signal (+1 as :data:`SIGNALS` defines them, -1 the opposite
        field). What a product keeps is not odd in the signal: once a signal is found and
        kept, so is the day's own structure on its shape that the clean run gave to a
        drift (2022-01-12: 10-35 nT along B on a 90 s pulse), and a level step the
        detector finds for one polarity it may miss for the other.
    both_signs : bool
        Also inject each signal with the opposite polarity: the table then has the rows
        of both (column ``sign``) and, on every row, the :func:`polarity_parts` columns
        that split what came back into the part that follows the signal and the part
        that does not.
    plot_dir : str or Path, optional
        If given, one PNG per signal (``recovered_<kind>.png``) of what the delivered
        product kept, zone by zone
        (:func:`~magcal.missions.elfin.injection_plot.plot_recovered`), and with
        ``both_signs`` its two parts (``parts_<kind>.png``,
        :func:`~magcal.missions.elfin.injection_plot.plot_parts`).
    joined : bool
        With ``both_signs``, also the polarity parts once both polarities leave the
        union of their left-out rows out (:func:`joined_parts`; columns ending in
        ``_joined``; two more calibrations per signal): how much of the odd part's
        distortion is where the detector drew the intervals' ends.
    scale : float
        Amplitude of every signal in units of its :data:`SIGNALS` amplitude (positive;
        polarity is ``sign``). What leaving a pulse's rows out does to the calibration
        does not grow with the pulse (:mod:`magcal.missions.elfin.leave_out`), so its
        share of the signal falls as one over ``scale``.

    Returns
    -------
    table : DataFrame
        :func:`preservation` rows of every run (zones numbered as in ``zones``), with
        the signal's polarity (``sign``).
    clean : ElfinDay
        The clean run (its scores are the residual the settings buy).
    """
    from dataclasses import replace

    from magcal.missions.elfin.files import ns_index
    from magcal.missions.elfin.pipeline import ElfinSettings, calibrate_elfin_day

    if not scale > 0:
        raise InputError(f"scale must be positive (the polarity is sign), got {scale}")
    fgs, state = ns_index(fgs, "FGS frame"), ns_index(state, "state frame")
    # the kept fractions do not depend on the pulses' stated height errors
    s = (settings or ElfinSettings()).without_trials(keep_bridge=True)
    if zones is not None:
        fgs = select_zones(fgs, zones)
    # the clean run needs no bridge trials (they leave the product as it is)
    clean = calibrate_elfin_day(fgs, state, replace(s, bridge_trials=0), diagnostics=False)
    hold_phase = None
    if hold:
        s = replace(s, phase_refit=False, detect_disturbed=False, bridge_trials=0,
                    level_steps=False, pulses_b=False)
        hold_phase = clean.linear.field["phase"].to_numpy()
        clean = calibrate_elfin_day(fgs, state, s, hold_phase=hold_phase, diagnostics=False)
    f = clean.linear.field
    tables = []
    for kind in kinds:
        signals = {k: sign * scale * signal_gei(kind, f[f["zone"] == k], state,
                                                centre=centre)
                   for k in dict.fromkeys(f["zone"].to_numpy())}
        injected = inject_counts(fgs, clean.linear, signals)
        base, skip = clean, None
        if mask_signal > 0:
            skip = signal_extent(signals, f["zone"].to_numpy(), mask_signal)
            if mask_clean:
                base = calibrate_elfin_day(fgs, state, replace(s, bridge_trials=0),
                                           hold_phase=hold_phase,
                                           fit_exclude=skip, diagnostics=False)
        day = calibrate_elfin_day(injected, state, s, hold_phase=hold_phase,
                                  fit_exclude=skip, diagnostics=False)
        tab = preservation(base, day, signals, kind).assign(sign=sign)
        if both_signs:
            opposite = {k: -v for k, v in signals.items()}
            injected_opposite = inject_counts(fgs, clean.linear, opposite)
            other = calibrate_elfin_day(injected_opposite, state, s,
                                        hold_phase=hold_phase, fit_exclude=skip,
                                        diagnostics=False)
            parts = polarity_parts(base, day, other, signals, kind)
            if joined:
                parts = parts.merge(joined_parts((injected, injected_opposite), state, s,
                                                 base, day, other, signals, kind,
                                                 hold_phase=hold_phase),
                                    on=["signal", "product", "zone"])
            tab = pd.concat([tab, preservation(base, other, opposite, kind).assign(sign=-sign)],
                            ignore_index=True).merge(parts, on=["signal", "product", "zone"])
        if plot_dir is not None:
            from pathlib import Path

            from magcal.missions.elfin.injection_plot import plot_parts, plot_recovered

            Path(plot_dir).mkdir(parents=True, exist_ok=True)
            delivered = tab[(tab["product"] == tab["product"].iloc[-1]) & (tab["sign"] == sign)]
            plot_recovered(Path(plot_dir) / f"recovered_{kind}.png", base, day, signals, kind,
                           state, delivered, zones)
            if both_signs:
                plot_parts(Path(plot_dir) / f"parts_{kind}.png", base, day, other, signals,
                           kind, state, delivered, zones)
        if zones is not None:
            tab["zone"] = [list(zones)[k] for k in tab["zone"]]
        tables.append(tab)
        if progress is not None:
            last = tables[-1]
            last = last[(last["product"] == last["product"].iloc[-1]) & (last["sign"] == sign)]
            line = (f"{kind}: delivered product keeps {last['energy_kept'].median():.1%} "
                    "of the energy (zone median)")
            if both_signs:
                line += (f"; of the signal itself (odd part) {last['energy_kept_odd'].median():.1%}"
                         f", distortion {last['distortion_odd'].median():.1%}")
            progress(line)
    return pd.concat(tables, ignore_index=True), clean
