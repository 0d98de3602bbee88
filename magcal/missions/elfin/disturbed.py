"""An ELFIN day calibrated without its disturbed intervals, and the check that it may be.

:func:`calibrate_detected` is what ``ElfinSettings.detect_disturbed`` runs: the
intervals located from the counts (:func:`magcal.missions.elfin.detect.locate_disturbed`)
are left out of the fits (``|B|`` flags out of every fit, vector flags out of the slow
vector fits), and each flagged run is checked against the day fitted with it
(:func:`bridge_check`): a natural field the fits no longer absorb comes back slow in
the despun frame, while a calibration error where the fits cannot bridge the run comes
back as spin tones (:func:`spin_split`). A run that brings back more tones than slow
field is put back.

Data: ELFIN SOC (PI V. Angelopoulos, UCLA), "Open Data for Scientific Use".
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pandas as pd

from magcal.missions.elfin.detect import DetectSettings, locate_disturbed, zone_shares
from magcal.missions.elfin.timing import true_runs


def spin_split(field: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """Despun field of each zone split into its mean over one spin and the rest.

    A natural field is slow in the despun frame; calibration errors of the spin-plane
    sensors (offsets, gains, coupling) make spin tones there. The window is the zone's
    spin period from its ``phase`` column.

    Returns
    -------
    slow, tone : ndarray (n, 3)
        ``bx_despun ..`` as running mean over one spin, and the field minus it (nT).
    """
    from scipy.ndimage import uniform_filter1d

    b = field[["bx_despun", "by_despun", "bz_despun"]].to_numpy(float)
    slow = np.empty_like(b)
    zone = field["zone"].to_numpy()
    for k in dict.fromkeys(zone):
        sel = np.flatnonzero(zone == k)
        t = (field.index.asi8[sel] - field.index.asi8[sel][0]) / 1e9
        dt = float(np.median(np.diff(t))) if t.size > 1 else 1.0
        rate = np.median(np.abs(np.diff(field["phase"].to_numpy(float)[sel])) / max(dt, 1e-9))
        width = max(1, round(2.0 * np.pi / max(rate, 1e-9) / dt))
        slow[sel] = uniform_filter1d(b[sel], width, axis=0, mode="nearest")
    return slow, b - slow


def bridge_check(flagged_field: pd.DataFrame, plain_field: pd.DataFrame, flags
                 ) -> pd.DataFrame:
    """What leaving each flagged run out of the fits changed: slow field or spin tones.

    Parameters
    ----------
    flagged_field, plain_field : DataFrame
        The same rows calibrated without and with the flagged rows in the fits.
    flags : array_like of bool (n,)
        The rows left out (detected).

    Returns
    -------
    DataFrame
        One row per run of ``flags``: ``zone``, ``start_s``, ``end_s`` (from the zone's
        first sample), ``slow_change_nT`` and ``tone_change_nT`` (RMS over the run of
        the product's change in its spin mean and in its spin tones), and ``kept``:
        True when the slow change is at least the tone change. A natural field that
        the fits no longer absorb comes back slow; spin tones grow when the fits
        cannot bridge the run (2022-01-12 zone 11, before the vector step's tones were
        fitted on every sample: 116 nT of tones for 22 nT of slow field over 100 s),
        and such a run is not worth flagging.
    """
    flags = np.asarray(flags, bool)
    s1, t1 = spin_split(flagged_field)
    s0, t0 = spin_split(plain_field)
    zone = flagged_field["zone"].to_numpy()
    ts = flagged_field.index.asi8 / 1e9
    rows = []
    for a, b in true_runs(flags):
        first = ts[np.flatnonzero(zone == zone[a])[0]]
        slow = float(np.sqrt(np.mean(np.sum((s1[a:b] - s0[a:b]) ** 2, axis=1))))
        tone = float(np.sqrt(np.mean(np.sum((t1[a:b] - t0[a:b]) ** 2, axis=1))))
        rows.append({"zone": int(zone[a]), "start_s": float(ts[a] - first),
                     "end_s": float(ts[b - 1] - first), "slow_change_nT": slow,
                     "tone_change_nT": tone, "kept": slow >= tone})
    return pd.DataFrame(rows, columns=["zone", "start_s", "end_s", "slow_change_nT",
                                       "tone_change_nT", "kept"])


#: Start of ``drop_reason`` for a zone fitted with its flags because its linear fit
#: fails without them (:func:`calibrate_detected`; a warning of the day).
UNFITTABLE_WITHOUT_FLAGS = "the linear fit fails without the flagged rows"


def _run_keeping_zones(run, vector, scalar, known, diagnostics):
    """``run(vector, scalar, diagnostics)``; a zone whose linear fit fails once its
    flagged rows are left out is fitted with them (flags of that zone reset to
    ``known``) rather than the day failing.

    Returns the day, the flags used and ``{zone: reason}`` of the zones so treated.
    """
    from magcal.missions.elfin.linear import ZonesNotCalibratedError

    lost = {}
    while True:
        try:
            return run(vector, scalar, diagnostics), vector, scalar, lost
        except ZonesNotCalibratedError as err:
            new = [z for z in err.skipped if z.zone not in lost]
            if not new:
                raise
            vector, scalar = vector.copy(), scalar.copy()
            for z in new:
                a, b = z.rows
                vector[a:b], scalar[a:b] = known[a:b], known[a:b]
                lost[z.zone] = z.reason


def calibrate_detected(fgs: pd.DataFrame, state: pd.DataFrame, settings, *, provenance=None,
                       hold_phase=None, fit_exclude=None, diagnostics: bool = True,
                       detect: DetectSettings | None = None, linear=None, zone_numbers=None):
    """The day calibrated without the disturbed intervals found from the counts.

    :func:`locate_disturbed`, then the day calibrated with the flagged rows left out
    of the fits (the ``|B|`` flags out of every fit, the vector flags out of the slow
    vector fits only) and, for comparison, with them in; a flagged run where that
    changed the product more in spin tones than in its slow field is put back
    (:func:`bridge_check`) and the day calibrated again. ``linear`` (the plain linear
    calibration of these rows, to reuse) and ``zone_numbers`` are passed to
    :func:`~magcal.missions.elfin.pipeline.calibrate_elfin_day`.

    Returns
    -------
    ElfinDay
        With ``settings`` as given and ``steps["disturbed_detection"]`` (per zone and
        pass, :func:`locate_disturbed`; ``kept_share``: the share of each zone's used
        samples left out after the check; ``dropped`` and ``drop_reason``: a zone whose
        flags were dropped, because more than ``max_share`` of it was flagged or
        because its linear fit fails without the flagged rows, and is fitted on every
        sample instead) and ``steps["disturbed_runs"]`` (:func:`bridge_check`).
    """
    from magcal.missions.elfin.pipeline import calibrate_elfin_day

    base = replace(settings, detect_disturbed=False)
    known = np.zeros(len(fgs), bool) if fit_exclude is None else np.asarray(fit_exclude, bool)

    def run(vector, scalar, diag=False, linear=None):
        return calibrate_elfin_day(fgs, state, base, provenance=provenance,
                                   hold_phase=hold_phase,
                                   fit_exclude=(vector | scalar) if (vector | scalar).any()
                                   else None,
                                   fit_exclude_scalar=scalar, diagnostics=diag, linear=linear,
                                   zone_numbers=zone_numbers)

    plain = run(known, known, linear=linear)
    # the stiff calibration starts from ``linear`` (or fits its own), not from
    # plain.linear: a plain day with level steps or pulses along B has its linear fit
    # refitted with them and their rows left out
    found = locate_disturbed(fgs, state, settings, detect=detect, fit_exclude=known,
                             hold_phase=hold_phase, linear=linear,
                             zone_numbers=zone_numbers)
    vector, scalar = found.vector, found.scalar
    day, vector, scalar, lost = _run_keeping_zones(run, vector, scalar, known, diagnostics)
    left_out = (vector | scalar) & ~known
    runs = bridge_check(day.calibration.field, plain.calibration.field, left_out)
    drop = np.zeros(len(fgs), bool)
    for (a, b), kept in zip(true_runs(left_out), runs["kept"]):   # one row per run
        drop[a:b] = not kept
    if drop.any():
        vector, scalar = (vector & ~drop) | known, (scalar & ~drop) | known
        day, vector, scalar, more = _run_keeping_zones(run, vector, scalar, known,
                                                       diagnostics)
        lost = {**lost, **more}
    table = found.table.copy()
    table["drop_reason"] = np.where(table["dropped"], "flagged share above max_share", "")
    for k, reason in lost.items():
        mine = table["zone"] == k
        table.loc[mine, "dropped"] = True
        table.loc[mine, "drop_reason"] = (f"{UNFITTABLE_WITHOUT_FLAGS} ({reason}): fitted "
                                          "on every sample")
    used = day.calibration.field["used"].to_numpy() == 1
    zone = day.calibration.field["zone"].to_numpy()
    table["kept_share"] = zone_shares(vector | scalar, used, zone, table["zone"])
    steps = {**day.steps, "disturbed_detection": table, "disturbed_runs": runs}
    return replace(day, settings=settings, steps=steps)

