"""What leaving a signal's interval out of the fits does to the ELFIN product, with no signal.

A natural field kept in the product is left out of the fits (detected or given), and
``recovered = calibrated(injected) - calibrated(clean)``
(:mod:`magcal.missions.elfin.injection`) then holds, besides the signal, the change of
the calibration itself between fitting those rows and not fitting them. That change
needs no signal to be measured: the clean counts are calibrated again with exactly the
rows a signal would occupy left out (:func:`leave_out_effect`), and the product's
change, read against the signal's shape, is the distortion that even a detector which
flagged exactly the signal would leave in the whole-signal reading. It does not scale
with the signal: its share of the signal falls as the amplitude rises, so each case
also says the amplitude at which it would be within the issue's 10 %.

On 2022-01-12 (delivered settings, detection on; a 200 nT, 40 s pulse's extent above
5 % of its peak, 83 s, at 0.35, 0.5 and 0.65 of every zone, 36 cases) the change is a
median 13.4 % of an east-west pulse's RMS (9 of 36 cases within 10 %; 12.6 % for an
along-track pulse, 9 of 36), while the delivered product's whole-signal distortion is
14.0 and 13.5 % (12 and 6 of 36 meet both targets): the 10 % target of the
whole-signal reading sits at the calibration's own response to which rows it fits. A
pulse would need 267 nT for the median case and 548 nT for 90 % of them. About half of
the change lies outside the left-out interval (median RMS 11.6 nT inside, 5.8 nT
outside), and there largely as a constant shift of the zone (median 3.9 nT), along the
spin axis in zones 1, 4, 7 and 10: the linear fit's offset is the mean spin-axis
residual over the fitted rows, and the day's own spin-axis field varies by +-40 nT
over a zone. Per case it predicts the delivered distortion only loosely (correlation
0.15-0.28): where a real detector ends its interval is another draw of the same size.

Only pulses across B are kept by leaving them out (:data:`KEPT_BY_LEAVING_OUT`). A
current sheet is kept by a level step, a pulse along B by its shape fitted with the
gain drift, a wave by not being flagged at all; leaving their extents out instead
changes the product by 4.1, 0.84 and 1.6 times their RMS (medians of 36), which is
why the product does not.

Data: ELFIN SOC (PI V. Angelopoulos, UCLA), "Open Data for Scientific Use".
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from magcal.errors import InputError
from magcal.missions.elfin.injection import (
    SIGNALS,
    TARGET_DISTORTION,
    kept,
    select_zones,
    signal_extent,
    signal_gei,
)
from magcal.missions.elfin.scalar import rms

_COLS = ["bx_gei", "by_gei", "bz_gei"]

#: Signals the delivered product keeps by leaving their rows out of the fits (the
#: detector's intervals), for which :func:`leave_out_effect` is the floor of the
#: whole-signal distortion.
KEPT_BY_LEAVING_OUT = ("gauss_ew", "gauss_along")


def effect_rows(clean_day, left_day, signals: dict, extent, kind: str,
                amplitude: float) -> list[dict]:
    """Per zone of ``signals`` (of peak ``amplitude``, nT): the delivered product's change
    between ``clean_day`` and ``left_day`` (the same counts with the rows ``extent`` left
    out), read against the signal (:func:`leave_out_effect`'s columns but ``centre``)."""
    name = list(clean_day.products)[-1]
    fc, fl = clean_day.products[name].field, left_day.products[name].field
    zone = fc["zone"].to_numpy()
    t = (fc.index.asi8 - fc.index.asi8[0]) / 1e9
    rows = []
    for k, dg in signals.items():
        sel = zone == k
        used = (fc["used"].to_numpy()[sel] == 1) & (fl["used"].to_numpy()[sel] == 1)
        delta = fl[_COLS].to_numpy(float)[sel] - fc[_COLS].to_numpy(float)[sel]
        dg = np.asarray(dg, float)
        k_ = kept(dg + delta, dg, used)
        inside = np.asarray(extent, bool)[sel] & used
        outside = used & ~inside
        ts = t[sel][inside]
        rows.append({
            "signal": kind, "product": name, "zone": int(k),
            "left_out_s": float(ts[-1] - ts[0]) if ts.size else 0.0,
            "gain": k_.gain, "distortion": k_.distortion,
            "inside_rms_nT": rms(np.linalg.norm(delta[inside], axis=1)),
            "outside_rms_nT": rms(np.linalg.norm(delta[outside], axis=1)),
            "zone_shift_nT": float(np.linalg.norm(delta[outside].mean(axis=0)))
            if outside.any() else np.nan,
            "amplitude_for_target_nT": amplitude * k_.distortion / TARGET_DISTORTION,
        })
    return rows


def leave_out_effect(fgs: pd.DataFrame, state: pd.DataFrame, settings=None, *,
                     kinds=("gauss_ew",), centres=(0.5,), zones=None,
                     fraction: float = 0.05, scale: float = 1.0, clean=None,
                     progress=None) -> pd.DataFrame:
    """The product's change when a signal's rows are left out of the fits, no signal added.

    The clean day is calibrated once; then, per place, again with the rows where each
    zone's signal (:func:`~magcal.missions.elfin.injection.signal_gei`) would exceed
    ``fraction`` of its peak given as ``fit_exclude`` (one calibration per place and
    distinct extent: pulses east-west and along-track share theirs). The change of the
    delivered product is read against the signal as
    :func:`~magcal.missions.elfin.injection.kept` reads ``signal + change``: what a
    detector that left out exactly the signal would add to the signal in the
    whole-signal reading.

    Parameters
    ----------
    fgs, state : DataFrame
        The ELFIN day (:mod:`magcal.missions.elfin.files`).
    settings : ElfinSettings, optional
        Default: the delivered ones (detection on, so the clean day's own disturbances
        stay out of both calibrations). Bridge, pulse and level trials are not run:
        they state errors and leave the product as it is.
    kinds : sequence of str
        Keys of :data:`~magcal.missions.elfin.injection.SIGNALS`.
    centres : sequence of float
        Places of the signals in each zone (fractions of its used span).
    zones : sequence of int, optional
        Zone numbers (0-based, default all).
    fraction : float
        Share of the signal's peak above which its rows are left out (as
        ``--mask-injected-only`` of ``workflows/elfin_preservation.py``).
    scale : float
        The signals' amplitude in units of their defined one: the rows left out do not
        change, the change is read against the larger signal.
    clean : ElfinDay, optional
        The clean day already calibrated with these settings (trials off) and zones,
        e.g. the one :func:`~magcal.missions.elfin.injection.run_injections` returns;
        calibrated here when not given.
    progress : callable, optional
        Called with one line per calibration.

    Returns
    -------
    DataFrame
        One row per signal, place and zone: ``signal``, ``centre``, ``zone``,
        ``product``, ``left_out_s`` (span of the rows left out, s), ``gain`` and
        ``distortion`` (of ``signal + change`` against the signal), ``inside_rms_nT``
        and ``outside_rms_nT`` (RMS of the change's norm over the left-out rows and
        over the zone's other used rows), ``zone_shift_nT`` (norm of the change's mean
        over those other rows), ``amplitude_for_target_nT`` (the amplitude at which the
        distortion, which falls as one over the amplitude, would be the issue's 10 %).
    """
    from magcal.missions.elfin.files import ns_index
    from magcal.missions.elfin.pipeline import ElfinSettings, calibrate_elfin_day

    fgs, state = ns_index(fgs, "FGS frame"), ns_index(state, "state frame")
    s = (settings or ElfinSettings()).without_trials()
    if zones is not None:
        fgs = select_zones(fgs, zones)
    if clean is None:
        clean = calibrate_elfin_day(fgs, state, s, diagnostics=False)
    elif len(clean.linear.field) != len(fgs):
        raise InputError(f"the clean day has {len(clean.linear.field)} rows for "
                         f"{len(fgs)} FGS rows of the zones asked for")
    f = clean.linear.field
    zone = f["zone"].to_numpy()
    rows = []
    for centre in centres:
        done: dict[bytes, object] = {}
        for kind in kinds:
            signals = {k: scale * signal_gei(kind, f[zone == k], state, centre=centre)
                       for k in dict.fromkeys(zone)}
            extent = signal_extent(signals, zone, fraction)
            key = np.packbits(extent).tobytes()
            if key not in done:
                done[key] = calibrate_elfin_day(fgs, state, s, fit_exclude=extent,
                                                diagnostics=False)
                if progress is not None:
                    progress(f"{kind} at {centre:g}: calibrated with its rows left out")
            for row in effect_rows(clean, done[key], signals, extent, kind,
                                   scale * SIGNALS[kind][0]):
                row["centre"] = float(centre)
                if zones is not None:
                    row["zone"] = list(zones)[row["zone"]]
                rows.append(row)
    cols = ["signal", "centre", "zone", "product", "left_out_s", "gain", "distortion",
            "inside_rms_nT", "outside_rms_nT", "zone_shift_nT", "amplitude_for_target_nT"]
    return pd.DataFrame(rows, columns=cols)
