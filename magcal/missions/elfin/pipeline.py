"""One ELFIN day calibrated from counts through every step: which step runs, the scores.

The steps live in their own modules; this one orchestrates them for one day of FGS
counts and its state file (``workflows/elfin_calibration.py`` and ``magcal run`` with
``[spin] units = "counts"`` both call :func:`calibrate_elfin_day`)::

    disturbed intervals located from the counts, left out of the fits (detect)
    linear per-zone fit against IGRF (magcal.missions.elfin.linear)
    -> spin-ripple cross-check, no model field (diagnostics.ripple)
    -> spin-harmonic correction of |B| (harmonic)        "harmonic"
    -> spin-plane gain drift within each pass (drift)      "harmonic + gain drift"
    -> vector-only body-fixed harmonics and tilt (vector)  "+ vector step"
    -> 1x/2x terms of |B| drifting within a minute (harmonic) "+ fast drift"
    -> spin phase refitted on the calibrated field (vector) "+ phase refit"
    -> optional joint fit across zones, delivered only if no worse (joint)

Which steps run is :class:`~magcal.missions.elfin.settings.ElfinSettings`, importable
from here too.

Every product is scored with :func:`magcal.missions.elfin.joint.score_field`; the last
step run is delivered (or the joint fit when it wins), and a step that makes a zone
median worse than the step before is named in :meth:`ElfinDay.worse_steps` so that a
caller can warn rather than stay silent.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pandas as pd

from magcal.missions.elfin.settings import SIGNAL_TRADE, ElfinSettings  # noqa: F401

#: Reference time shifts (s) of the optional timing-offset scan.
SHIFTS_S = (-0.4, -0.2, -0.1, 0.0, 0.1, 0.2, 0.4)
#: Columns of the calibrated table (the first five after ``time`` are the issue's contract).
CALIBRATED_COLUMNS = ("zone", "used", "bx_gei", "by_gei", "bz_gei", "bx_despun", "by_despun",
                      "bz_despun", "igrf_x_gei", "igrf_y_gei", "igrf_z_gei", "phase", "fit",
                      "bridge_rms_nT", "level_step", "level_error_nT", "pulse_error_nT")
#: Zone medians compared from one step to the next (:meth:`ElfinDay.worse_steps`).
SCORED = ("scalar_rms_nT", "scalar_fast_nT", "scalar_slow_nT", "vector_rms_nT")
#: Relative (and absolute, nT) growth of a zone median below which it is rounding.
ROUNDING = 1e-9


@dataclass(frozen=True)
class ElfinDay:
    """One day calibrated by :func:`calibrate_elfin_day`.

    Attributes
    ----------
    calibration : ElfinCalibration
        The delivered product (its ``field`` holds the calibrated series).
    linear : ElfinCalibration
        The linear per-zone calibration every later step starts from.
    settings : ElfinSettings
    ripple : DataFrame
        The spin-ripple cross-check per zone.
    steps : dict
        Step name -> its per-zone table (``spin_harmonic_correction``, ``gain_drift``,
        ``drift_agreement``, ``vector_correction``) for the steps that ran.
    scores : dict
        Product name -> :func:`~magcal.missions.elfin.joint.score_field` table, in step
        order (``joint`` last when it ran).
    joint : dict or None
        The joint fit's record (without its product) when it ran.
    scan : dict
        Shift (``"+0.1"``) -> per-zone RMS of the linear calibration, when scanned.
    stability : dict
        Which parameters are stable across zones, with block-sandwich errors
        (:func:`magcal.missions.elfin.diagnostics.stability.parameter_stability`).
    products : dict
        Product name -> its calibration, in step order (what each step made; the
        injection tests compare them step by step).
    """

    calibration: object
    linear: object
    settings: ElfinSettings
    ripple: pd.DataFrame
    steps: dict = field(default_factory=dict)
    scores: dict = field(default_factory=dict)
    joint: dict | None = None
    scan: dict = field(default_factory=dict)
    stability: dict = field(default_factory=dict)
    products: dict = field(default_factory=dict, repr=False, compare=False)

    @property
    def delivered(self) -> str:
        """Name of the delivered product."""
        if self.joint is not None and self.joint["delivered"] == "joint":
            return "joint"
        return self.settings.steps()[-1]

    def medians(self) -> dict:
        """Product name -> zone medians of its scores (nT)."""
        return {name: s.drop(columns="zone").median().to_dict() for name, s in
                self.scores.items()}

    def _pairs(self) -> list[tuple]:
        """(step before, step) for each step after the linear one; the joint fit is
        compared with the product it competes with."""
        steps = self.settings.steps()
        pairs = list(zip(steps[:-1], steps[1:]))
        return pairs + ([(steps[-1], "joint")] if "joint" in self.scores else [])

    def worse_measures(self) -> dict:
        """Step -> the measures of :data:`SCORED` whose zone median it makes worse than
        the step before (steps that make none worse are left out).

        Worse means larger by more than rounding (:data:`ROUNDING`, relative): a step
        that turns the field about the spin axis leaves ``|B|`` unchanged but for
        1e-14 nT, which is not a change to warn about; any real growth is named.
        """
        med = self.medians()
        out = {}
        for before, after in self._pairs():
            worse = tuple(m for m in SCORED
                          if med[after][m] > med[before][m] * (1.0 + ROUNDING) + ROUNDING)
            if worse:
                out[after] = worse
        return out

    def worse_steps(self) -> list[str]:
        """One line per step that makes a zone median of :data:`SCORED` worse than the
        step before, with both medians and the increase (however small: never silent)."""
        med, worse = self.medians(), self.worse_measures()
        return [f"{after!r} is worse than {before!r} (zone medians): " + "; ".join(
                    f"{m.removesuffix('_nT').replace('_', ' ')} {med[before][m]:.2f} -> "
                    f"{med[after][m]:.2f} nT (+{med[after][m] - med[before][m]:.2g})"
                    for m in worse[after])
                for before, after in self._pairs() if after in worse]

    def calibrated_table(self) -> pd.DataFrame:
        """The delivered series: ``time`` index, :data:`CALIBRATED_COLUMNS` (nT, rad).

        The rows of zones that could not be calibrated are there too, ``used = 0``
        and NaN (:attr:`ElfinCalibration.skipped`): nothing read is dropped.
        """
        cols = list(CALIBRATED_COLUMNS)
        f = self.calibration.field
        if "bridge_rms_nT" not in f.columns:
            f = f.assign(bridge_rms_nT=np.nan)
        if "fit" not in f.columns:
            f = f.assign(fit=f["used"])
        if "level_step" not in f.columns:
            f = f.assign(level_step=0)
        from magcal.missions.elfin.perp import pulse_error_column

        f = f.assign(level_error_nT=self.level_error_column(),
                     pulse_error_nT=pulse_error_column(self))
        table = f[cols].astype(float)
        if not self.calibration.skipped:
            return table
        return pd.concat([table, self.calibration.skipped_rows(cols)]).sort_index()

    def data_warnings(self) -> list[str]:
        """One line per zone not calibrated (with the reason), per zone whose detected
        disturbed intervals were not left out because the fit cannot do without them,
        per zone whose left-out samples reach a zone end (the calibration extrapolated
        there) and per zone with clipped counts (saturation; left out, so the fit rests
        on the other spin phases)."""
        lines = [f"zone {z.zone} ({z.start} - {z.end}, {z.n_samples} samples) not "
                 f"calibrated: {z.reason}; its rows are delivered with used = 0"
                 for z in self.calibration.skipped]
        det = self.steps.get("disturbed_detection")
        if det is not None and "drop_reason" in det.columns:
            from magcal.missions.elfin.disturbed import UNFITTABLE_WITHOUT_FLAGS

            for row in det.drop_duplicates("zone", keep="last").itertuples():
                if row.drop_reason.startswith(UNFITTABLE_WITHOUT_FLAGS):
                    lines.append(f"zone {row.zone}: disturbed intervals detected but not "
                                 f"left out of the fits, {row.drop_reason}; a natural "
                                 "field there may be absorbed")
        if "bridge" in self.steps:
            for row in self.steps["bridge"].itertuples():
                if row.at_zone_end:
                    lines.append(f"zone {row.zone}: samples left out of the fits reach "
                                 "within 20 s of the zone's end, where the calibration is "
                                 "extrapolated; bridge_rms_nT understates the error there")
        for k, z in zip(self.linear.zone_numbers, self.linear.zones):
            if z.n_clipped:
                lines.append(f"zone {k} ({z.start}): {z.n_clipped} of {z.n_samples} samples "
                             f"({z.n_clipped / z.n_samples:.0%}) read a clipped extreme "
                             "(saturation) and are not used")
        return lines

    def level_step_intervals(self) -> list[dict]:
        """The delivered field's level steps: per run of its ``level_step`` rows, the
        ``zone``, ``start`` and ``end`` (UTC, ISO) and ``step_nT``, the change of the
        spin-axis residual's median over the 30 s of fitted samples either side (the
        kept level change, nT)."""
        from magcal.missions.elfin.levels import level_change
        from magcal.missions.elfin.timing import true_runs

        f = self.calibration.field
        if "level_step" not in f.columns:
            return []
        out = []
        resid = (f["bz_despun"] - f["igrf_z_despun"]).to_numpy(float)
        ts = f.index.as_unit("ns").asi8 / 1e9
        fit = (f["used"].to_numpy() == 1) & (f["fit"].to_numpy() == 1)
        zone = f["zone"].to_numpy()
        for a, b in true_runs(f["level_step"].to_numpy() == 1):
            step = level_change(ts, resid, fit & (zone == zone[a]), ts[a], ts[b - 1])
            out.append({"zone": int(zone[a]), "start": str(f.index[a].tz_convert(None)),
                        "end": str(f.index[b - 1].tz_convert(None)), "step_nT": step})
        return out

    def level_error_column(self) -> np.ndarray:
        """Per row of the delivered field: the stated error of the kept level it
        carries, NaN elsewhere (no step before it in its zone, or not measured).

        The level at a row is the sum of the zone's kept steps up to it (a step's own
        rows count as after it), so its error is the root sum of squares of their
        ``step_error_nT`` (``level_trials``): on 2022-01-12 a sheet of the opposite
        polarity in zone 8 at 0.65 got its own step (+228 +- 108 nT for 300) and one
        across the real disturbance before it (-199 +- 60 nT for none), and the level
        after the sheet is off by the two together. A step without a stated error makes
        the rows after it NaN."""
        f = self.calibration.field
        out = np.full(len(f), np.nan)
        if "level_trials" not in self.steps or "level_step" not in f.columns:
            return out
        from magcal.missions.elfin.timing import true_runs

        errors = self.steps["level_trials"]["step_error_nT"].to_numpy(float)
        zone = f["zone"].to_numpy()
        square = np.zeros(len(f))
        stepped = np.zeros(len(f), bool)
        for (a, _), err in zip(true_runs(f["level_step"].to_numpy() == 1), errors):
            after = (np.arange(len(f)) >= a) & (zone == zone[a])
            square[after] += err ** 2
            stepped |= after
        out[stepped] = np.sqrt(square[stepped])
        return out

    def level_step_listing(self) -> list[dict]:
        """The kept level steps as delivered: with their errors
        (``steps["level_trials"]``) where measured, else :meth:`level_step_intervals`;
        and per step its zone's ``axis_field_std_nT`` (the model's spin-axis field over
        the pass) and ``axis_row_prior`` (the zone's spin-axis row drawn towards the
        day's, :func:`~magcal.missions.elfin.linear.axis_row_prior`). Where that field
        hardly changes, the kept level trades with the spin-axis gain, which no ELFIN
        data fix (2022-01-12 zone 10, 405 nT: a 300 nT sheet kept at 0.88 of its level,
        the row 12 % lower with the step than without)."""
        from magcal.missions.elfin.linear import AXIS_PRIOR_MIN_STD_NT

        prior = self.linear.parameters.get("axis_prior")
        f = self.linear.field
        numbers = self.linear.zone_numbers
        out = []
        for rec in self._with_trials("level_trials", self.level_step_intervals):
            k = rec["zone"]
            if prior is not None and k in numbers:
                std = float(prior["axis_field_std_nT"][numbers.index(k)])
                drawn = k not in prior["zones"]
            else:
                sel = (f["zone"] == k) & (f["used"] == 1)
                std = float(np.std(f.loc[sel, "igrf_z_despun"]))
                drawn = False
            out.append({**rec, "axis_field_std_nT": std, "axis_row_prior": bool(drawn),
                        "axis_field_small": bool(std < AXIS_PRIOR_MIN_STD_NT)})
        return out

    def _with_trials(self, key: str, plain) -> list[dict]:
        """``steps[key]``'s records where the trials ran, else ``plain()``."""
        if key in self.steps:
            return self.steps[key].to_dict(orient="records")
        return plain()

    def pulses_along_b(self) -> list[dict]:
        """The delivered field's pulses along B kept as a natural field
        (``ElfinSettings.pulses_b``): per ``pulse_b_<j>`` shape of a zone, the ``zone``,
        its ``centre`` (UTC, ISO), ``fwhm_s`` and ``height_nT`` (the amplitude fitted
        with the gain drift: what the product keeps)."""
        from magcal.missions.elfin.pulses import NATURAL_COLUMNS, shape_columns

        f = self.calibration.field
        every = shape_columns(f, NATURAL_COLUMNS)
        if not every.shape[1] or "gain_drift" not in self.steps:
            return []
        drift = self.steps["gain_drift"].set_index("zone")
        out = []
        zones = f["zone"].to_numpy()
        for k in dict.fromkeys(zones):
            z = f[zones == k]
            shapes = every[zones == k]
            live = [j for j in range(shapes.shape[1]) if np.any(shapes[:, j] != 0.0)]
            heights = list(drift.loc[k, "natural_amplitudes"]) if k in drift.index else []
            ts = z.index.as_unit("ns").asi8 / 1e9
            for i, j in enumerate(live):
                half = ts[shapes[:, j] >= 0.5]
                out.append({"zone": int(k),
                            "centre": str(z.index[int(np.argmax(shapes[:, j]))].tz_convert(None)),
                            "fwhm_s": float(half[-1] - half[0]) if half.size else 0.0,
                            "height_nT": float(heights[i]) if i < len(heights) else float("nan")})
        return out

    def level_step_judged(self) -> list[dict]:
        """Every left-out interval judged for a level step, kept or not
        (``steps["level_search"]``, :func:`~magcal.missions.elfin.levels.
        level_step_decision`): ``zone``, ``start`` and ``end`` (UTC, ISO), ``step_nT``,
        ``share``, ``local_nT``, ``gain``, ``kept``, ``why`` (the tests it fails) and
        ``judged_on`` (the product without steps, or, in a zone that wants several,
        with the strongest kept): so that a current sheet the slow terms took shows as
        an interval judged and not kept, with how far it was from a step."""
        judged = self.steps.get("level_search")
        if judged is None or not len(judged):
            return []
        return [{"zone": int(r.zone), "start": _utc(r.start, r.start_s),
                 "end": _utc(r.start, r.end_s), "step_nT": float(r.step_nT),
                 "share": float(r.share), "local_nT": float(r.local_nT),
                 "gain": float(r.gain), "kept": bool(r.kept), "why": str(r.why),
                 "judged_on": str(r.judged_on)} for r in judged.itertuples()]

    def pulse_search_listing(self) -> list[dict]:
        """What the search for pulses along B found (``steps["pulse_search"]``,
        :func:`~magcal.missions.elfin.pulses.zone_pulses`): per shape the ``zone``, its
        ``centre`` (UTC, ISO), ``fwhm_s``, ``height_nT`` (as found on the product
        without pulses), ``gain``, ``natural`` (kept in the product) and ``why`` (the
        reason it is removed with the drift instead): so that a wide ``|B|`` structure
        the drift removes is stated, not lost silently."""
        found = self.steps.get("pulse_search")
        if found is None or not len(found):
            return []
        return [{"zone": int(r.zone), "centre": _utc(r.start, r.centre_s),
                 "fwhm_s": float(r.fwhm_s), "height_nT": float(r.height_nT),
                 "gain": float(r.gain), "natural": bool(r.natural), "why": str(r.why)}
                for r in found.itertuples()]

    def pulse_listing(self) -> list[dict]:
        """The kept pulses along B as delivered: with their height errors
        (``steps["pulse_trials"]``) where measured, else :meth:`pulses_along_b`."""
        return self._with_trials("pulse_trials", self.pulses_along_b)

    def to_json(self) -> dict:
        """The calibration document (the keys of ``elfin_calibration.json``)."""
        from dataclasses import asdict

        s = self.settings
        payload = self.calibration.to_json()
        payload["settings"] = asdict(s)
        payload["signal_trade"] = {
            "note": "steps fitted against IGRF with time-varying freedom can absorb a "
                    "natural field; measured by injecting synthetic signals into the raw "
                    "counts (workflows/elfin_preservation.py, magcal.missions.elfin."
                    "injection). Settings that trade kept signal for residual:",
            "switches": {k: getattr(s, k) for k in SIGNAL_TRADE}}
        payload["table"] = self.linear.table().to_dict(orient="records")
        payload["ripple_crosscheck"] = {
            "note": "spin-ripple calibration (Kivelson et al. 1992, no model field) on the "
                    "same zones vs the IGRF one: spin-plane anisotropy a = (G11-G22)/"
                    "(G11+G22), b = 2 G12/(G11+G22) and the effective spin-plane offset (nT)",
            "zones": self.ripple.to_dict(orient="records")}
        if self.joint is not None:
            payload["joint_fit"] = self.joint
        f = self.calibration.field
        if "fit" in f.columns:
            payload["fit_excluded"] = {
                "note": "samples calibrated but left out of every fit (calibrate_elfin_day "
                        "fit_exclude; [spin] disturbed): a natural field there is kept",
                "n_samples": int(((f["used"] == 1) & (f["fit"] == 0)).sum())}
            if "fit_scalar" in f.columns:
                payload["fit_excluded"]["n_samples_scalar_fits"] = int(
                    ((f["used"] == 1) & (f["fit_scalar"] == 0)).sum())
                payload["fit_excluded"]["note_scalar"] = (
                    "the steps that fit |B| alone (spin harmonics, gain drift, fast drift) "
                    "leave out only the samples flagged from |B|: a field across B leaves "
                    "|B| alone to first order")
        if s.level_steps or "level_step" in f.columns:
            payload["level_steps"] = {
                "note": "left-out intervals across which the product keeps a new level of "
                        "the spin-axis field (a current sheet crossed there; magcal.missions."
                        "elfin.levels, the level_step column): a step fitted with the "
                        "linear fit's spin-axis row and the vector step's tilt, left in the "
                        "field",
                "intervals": self.level_step_listing()}
            payload["level_steps"]["note_axis"] = (
                "axis_field_std_nT: standard deviation of the model's spin-axis field over "
                "the zone's pass; axis_field_small (under 500 nT): the zone's spin-axis "
                "gain is set only by that change and a kept level trades with it (no "
                "ELFIN data tell them apart; 2022-01-12 zone 10, 405 nT: a 300 nT sheet "
                "kept at 0.88); axis_row_prior: the zone's spin-axis row drawn towards "
                "the day's (axis_prior_weight)")
            if "level_search" in self.steps:
                from magcal.missions.elfin.levels import JUDGED_NOTE

                payload["level_steps"]["judged"] = self.level_step_judged()
                payload["level_steps"]["note_judged"] = JUDGED_NOTE
            if "level_trials" in self.steps:
                payload["level_steps"]["note_error"] = (
                    "step_error_nT: RMS error of the levels kept when a current sheet of "
                    "the step's size is put into the counts of other zones at the same "
                    "place (level_trials of them, trial_levels_nT: the level each kept)")
        if s.pulses_b:
            payload["pulses_b"] = {
                "note": "localized fields along B (Gaussian pulses on top of the gain "
                        "drift's cubic in the |B| residual, magcal.missions.elfin.pulses) "
                        "fitted with the gain drift and left in the product; height_nT is "
                        "what the product keeps",
                "pulses": self.pulse_listing()}
            if "pulse_trials" in self.steps:
                payload["pulses_b"]["note_error"] = (
                    "height_error_nT: RMS error of the heights found when a pulse like "
                    "it is put into the counts of other zones at the same place "
                    "(pulse_trials of them, trial_heights_nT)")
            if "pulse_search" in self.steps:
                from magcal.missions.elfin.pulses import SEARCH_NOTE

                payload["pulses_b"]["search"] = self.pulse_search_listing()
                payload["pulses_b"]["note_search"] = SEARCH_NOTE
        if s.pulses_perp:
            from magcal.missions.elfin.perp import perp_listing

            payload["pulses_perp"] = {
                "note": "detected intervals where a Gaussian pulse across B (free centre, "
                        "width and GEI amplitude on a linear baseline) explains the "
                        "residual: kept in the fits with the pulse added to the reference "
                        "and its shape backfitted with the calibration (magcal."
                        "missions.elfin.perp); kept false: left out as delivered (why)",
                "pulses": perp_listing(self)}
            if "perp_trials" in self.steps:
                payload["pulses_perp"]["trials"] = self.steps["perp_trials"].to_dict(
                    orient="records")
                payload["pulses_perp"]["note_error"] = (
                    "error_rms_nT: RMS over the rows within 1.5 FWHM of the place of "
                    "|product with the trial pulse - product - trial pulse| (GEI nT), a "
                    "pulse like the kept one put into the counts of other zones at the "
                    "same place (perp_trials of them, trial_errors_nT; trials_kept: how "
                    "many were kept as templates); the calibrated table's "
                    "pulse_error_nT on the kept pulse's rows")
        if "disturbed_detection" in self.steps:
            payload["disturbed_detection"] = {
                "note": "intervals located from the counts alone (magcal.missions.elfin."
                        "detect: localized excursions of the residual of a stiff calibration "
                        "with the 2x-tied gain drift, not within edge_s of a zone end) and "
                        "left out of the fits (|B| flags out of every fit, vector flags out "
                        "of the vector fits): it keeps localized fields across B, not a "
                        "pulse along B nor a lasting sheet (README, preservation table)",
                "zones": self.steps["disturbed_detection"].to_dict(orient="records")}
            if "disturbed_runs" in self.steps:
                payload["disturbed_detection"]["runs"] = self.steps[
                    "disturbed_runs"].to_dict(orient="records")
                payload["disturbed_detection"]["runs_note"] = (
                    "each flagged run: RMS change of the product's spin mean (slow, a "
                    "natural field kept) and of its spin tones (calibration errors where "
                    "the fits could not bridge the run) against the day fitted with it; a "
                    "run is kept out of the fits only when the slow change is at least the "
                    "tone change (kept_share per zone)")
        if "bridge" in self.steps:
            payload["bridge"] = {
                "note": "error of the calibration over the intervals it left out of its "
                        "fits, measured on quiet trial gaps of the same length in the same "
                        "zone (magcal.missions.elfin.bridge): a natural field kept there "
                        "carries it. bridge_rms_nT: RMS of |delta B| over the gaps (also "
                        "the bridge_rms_nT column of the left-out rows of the calibrated "
                        "series); outside_rms_nT: what leaving a gap out moved elsewhere",
                "zones": self.steps["bridge"].to_dict(orient="records")}
        if "spin_harmonic_correction" in self.steps:
            payload["spin_harmonic_correction"] = self.steps[
                "spin_harmonic_correction"].to_dict(orient="records")
        if "gain_drift" in self.steps:
            payload["gain_drift"] = {
                "note": "isotropic spin-plane gain (1 + g(T)), g cubic in time per zone, "
                        "fitted to |B| - |IGRF| after the spin-harmonic correction (the slow "
                        "part); evidence that it is the instrument: the 2x-spin harmonic (a "
                        "gain ratio change no smooth reference error can make) drifts with "
                        "the same time shape (agreement: correlation and ratio per zone, on "
                        "the linear calibration), reference errors screened in workflows/"
                        "elfin_scalar_floor.py --slow"
                        + (f"; Tukey-weighted (c = {s.gain_drift_robust_c:g}) from the "
                           "residual of the 2x-spin shape" if s.gain_drift_robust_c > 0
                           else ""),
                "zones": self.steps["gain_drift"].to_dict(orient="records"),
                "agreement": self.steps["drift_agreement"].to_dict(orient="records")}
        if "vector_correction" in self.steps:
            payload["vector_correction"] = {
                "note": "in the spinning frame: spin-plane e^{-i psi}, e^{3i psi} and "
                        "spin-axis 1x terms with drifts ("
                        + (f"B-splines, knots every {s.vector_knot_s:g} s" if s.vector_knot_s
                           else "cubic in time") + "; body-fixed spin harmonics that "
                        "no reference, attitude or natural field makes), then a spin-axis "
                        f"tilt per zone within {s.tilt_bound_deg} deg",
                "zones": self.steps["vector_correction"].to_dict(orient="records")}
        if "fast_drift" in self.steps:
            payload["fast_drift"] = {
                "note": f"1x/2x spin harmonics of |B| with coefficients on {s.fast_knot_s:g} s "
                        "B-splines, "
                        "removed as vectors (the sunlit zones' terms change within a minute; "
                        "a Sun-locked term is not what the data support: workflows/"
                        "elfin_scalar_floor.py --sun)",
                "zones": self.steps["fast_drift"].to_dict(orient="records")}
        if "phase_refit" in self.steps:
            payload["phase_refit"] = {
                "note": "spin phase refitted last against IGRF's spin-plane angle on the "
                        f"calibrated field (cubic B-spline, {s.refit_knot_s:g} s knots; the first "
                        f"phase fit, {s.linear_phase_knot_s:g} s knots (0: quadratic), was "
                        "made on the linear calibration)",
                "zones": self.steps["phase_refit"].to_dict(orient="records")}
        payload["scores"] = {"note": "zone medians of magcal.missions.elfin.joint.score_field "
                                     "(nT) for each product; the last one before 'joint' is "
                                     "delivered unless joint_fit says otherwise",
                             "medians": self.medians()}
        if self.stability:
            payload["parameter_stability"] = self.stability
        payload["timing_scan"] = {"shifts_s": list(SHIFTS_S), "note": "IGRF evaluated at t + "
                                  "shift; the per-zone RMS for each shift", "by_shift": self.scan}
        return payload


def disturbed_rows(index, intervals) -> np.ndarray:
    """Rows of a UTC time index inside any ``(start, end)`` interval (inclusive).

    For ``fit_exclude`` of :func:`calibrate_elfin_day`: intervals with a natural field
    known from elsewhere (particle precipitation, ground stations, a first look) are
    left out of every fit, so that no step fitted against the model absorbs it.

    Examples
    --------
    >>> idx = pd.date_range("2022-01-12T05:00:00", periods=5, freq="1min", tz="UTC")
    >>> disturbed_rows(idx, [("2022-01-12T05:01:00", "2022-01-12T05:02:30")]).tolist()
    [False, True, True, False, False]
    """
    times = pd.DatetimeIndex(index)
    out = np.zeros(len(times), bool)
    for start, end in intervals:
        lo, hi = pd.Timestamp(start), pd.Timestamp(end)
        if times.tz is not None:
            lo = lo.tz_localize("UTC") if lo.tz is None else lo
            hi = hi.tz_localize("UTC") if hi.tz is None else hi
        out |= (times >= lo) & (times <= hi)
    return out


def calibrate_elfin_day(fgs: pd.DataFrame, state: pd.DataFrame,
                        settings: ElfinSettings | None = None, *,
                        provenance: dict | None = None, hold_phase=None,
                        fit_exclude=None, fit_exclude_scalar=None,
                        diagnostics: bool = True, linear=None,
                        zone_numbers=None, level_step_rows=None,
                        pulse_templates=None, drift_templates=None) -> ElfinDay:
    """Calibrate one day of ELFIN FGS counts against IGRF through the configured steps.

    Parameters
    ----------
    fgs, state : DataFrame
        From :func:`~magcal.missions.elfin.files.read_elfin_fgs` and
        :func:`~magcal.missions.elfin.files.read_elfin_state`.
    settings : ElfinSettings, optional
        Which steps run (default: every step except the joint fit and the scan).
    provenance : dict, optional
        Carried by the delivered calibration (and so by :meth:`ElfinDay.to_json`).
    hold_phase : array_like (len(fgs),), optional
        Spin phase per FGS row held by the linear fit instead of fitted (see
        :func:`~magcal.missions.elfin.linear.calibrate_elfin`); for the injection tests.
    fit_exclude : array_like (len(fgs),) of bool, optional
        FGS rows left out of every step's fit but calibrated (intervals with a natural
        field the model lacks; see :func:`~magcal.missions.elfin.linear.calibrate_elfin`).
    fit_exclude_scalar : array_like (len(fgs),) of bool, optional
        Rows left out of the steps that fit ``|B|`` alone (spin harmonics, gain drift,
        fast drift) instead of ``fit_exclude`` (whose rows the vector fits still leave
        out): a field across B leaves ``|B|`` alone to first order.
    diagnostics : bool
        Also the spin-ripple cross-check and the parameter stability (False: the
        calibration only, e.g. for repeated injection runs).
    linear : ElfinCalibration, optional
        The linear calibration of these rows with the same ``hold_phase``,
        ``fit_exclude`` and linear settings, to continue from instead of fitting it
        again (the linear fit is about two thirds of the time; the detection of
        disturbed intervals calibrates the same rows with two settings).
    zone_numbers : sequence of int, optional
        The zone numbers of the rows given (``zone_numbers`` of
        :func:`~magcal.missions.elfin.linear.calibrate_elfin`); set by the call itself
        when zones are taken out.
    level_step_rows : array_like (len(fgs),) of bool, optional
        Rows of left-out intervals across which the spin-axis level may change, fitted
        as steps by the linear fit and the vector step's tilt and left in the field
        (``level_step`` column). Default: none, or with ``settings.level_steps`` those
        :func:`~magcal.missions.elfin.levels.level_step_rows` finds on the day
        calibrated without steps (then calibrated again with them).
    pulse_templates, drift_templates : array_like (len(fgs), m), optional
        Unit-height time shapes of localized ``|B|`` changes fitted with the gain
        drift: the first left in the product (natural fields along B; field columns
        ``pulse_b_<j>``), the second removed with the drift (``drift_b_<j>``).
        Default: none, or with ``settings.pulses_b`` those
        :func:`~magcal.missions.elfin.pulses.zone_pulses` finds on the day calibrated
        without them (decided with the level steps).

    Returns
    -------
    ElfinDay
        A zone the linear fit cannot calibrate (too few usable samples, no attitude) is
        taken out before the later steps and listed in ``calibration.skipped``; its
        rows are delivered with ``used = 0`` (:meth:`ElfinDay.calibrated_table`).

    Raises
    ------
    InputError
        Frames without the ELFIN columns, or a zone without orbit and attitude.
    """
    from magcal.missions.elfin.files import ns_index
    from magcal.missions.elfin.linear import ZonesNotCalibratedError, calibrate_elfin, with_igrf
    from magcal.missions.elfin.joint import score_field
    from magcal.missions.elfin.diagnostics.ripple import ripple_crosscheck

    s = settings or ElfinSettings()
    fgs, state = ns_index(fgs, "FGS frame"), ns_index(state, "state frame")
    # the reference once for every fit of the day (the calls below pass this state on)
    state = with_igrf(state, fgs)
    pulses_tried = s.pulses_b and s.pulse_trials > 0
    levels_tried = s.level_steps and s.level_trials > 0
    perp_tried = s.pulses_perp and s.detect_disturbed and s.perp_trials > 0
    # what the trials' and the pulses' runs below pass on unchanged
    passed = dict(provenance=provenance, hold_phase=hold_phase, fit_exclude=fit_exclude,
                  fit_exclude_scalar=fit_exclude_scalar, diagnostics=diagnostics,
                  linear=linear, level_step_rows=level_step_rows,
                  pulse_templates=pulse_templates, drift_templates=drift_templates)
    if (pulses_tried or levels_tried or perp_tried) and zone_numbers is None:
        from magcal.missions.elfin.levels import level_trials
        from magcal.missions.elfin.perp import perp_trials
        from magcal.missions.elfin.pulses import pulse_trials

        day = calibrate_elfin_day(fgs, state, s.without_trials(keep_bridge=True), **passed)
        steps = dict(day.steps)
        if pulses_tried:
            steps["pulse_trials"] = pulse_trials(fgs, state, s, day, s.pulse_trials,
                                                 fit_exclude=fit_exclude)
        if levels_tried:
            steps["level_trials"] = level_trials(fgs, state, s, day, s.level_trials,
                                                 fit_exclude=fit_exclude)
        if perp_tried:
            steps["perp_trials"] = perp_trials(fgs, state, s, day, s.perp_trials,
                                               fit_exclude=fit_exclude)
        return replace(day, settings=s, steps=steps)
    if s.pulses_perp and s.detect_disturbed and zone_numbers is None:
        from magcal.missions.elfin.perp import calibrate_perp

        return calibrate_perp(fgs, state, s, **passed)
    if s.bridge_trials > 0:
        day = calibrate_elfin_day(fgs, state, replace(s, bridge_trials=0),
                                  provenance=provenance, hold_phase=hold_phase,
                                  fit_exclude=fit_exclude,
                                  fit_exclude_scalar=fit_exclude_scalar,
                                  diagnostics=diagnostics, linear=linear,
                                  zone_numbers=zone_numbers)
        return _with_bridge(fgs, state, s, day, hold_phase=hold_phase)

    def fit_linear(exclude):
        return calibrate_elfin(fgs, state, provenance=provenance, hold_phase=hold_phase,
                               fit_exclude=exclude, phase_knot_s=s.linear_phase_knot_s or None,
                               axis_degree=s.linear_axis_degree,
                               phase_degree=s.linear_phase_degree,
                               axis_prior_weight=s.axis_prior_weight,
                               zone_numbers=zone_numbers, level_step_rows=level_step_rows)

    if zone_numbers is None:
        # the first call: the plain linear fit decides which zones can be calibrated
        linear = linear or fit_linear(fit_exclude)
        if linear.skipped:
            return _without_skipped(fgs, state, s, linear, provenance=provenance,
                                    hold_phase=hold_phase, fit_exclude=fit_exclude,
                                    fit_exclude_scalar=fit_exclude_scalar,
                                    level_step_rows=level_step_rows,
                                    pulse_templates=pulse_templates,
                                    drift_templates=drift_templates,
                                    diagnostics=diagnostics)
        zone_numbers = linear.zone_numbers
    if s.detect_disturbed:
        from magcal.missions.elfin.disturbed import calibrate_detected

        return calibrate_detected(fgs, state, s, provenance=provenance, hold_phase=hold_phase,
                                  fit_exclude=fit_exclude, diagnostics=diagnostics,
                                  linear=linear, zone_numbers=zone_numbers)
    if (s.level_steps and level_step_rows is None) or (s.pulses_b and pulse_templates is None):
        return _with_level_steps(fgs, state, s, provenance=provenance, hold_phase=hold_phase,
                                 fit_exclude=fit_exclude,
                                 fit_exclude_scalar=fit_exclude_scalar,
                                 diagnostics=diagnostics, linear=linear,
                                 zone_numbers=zone_numbers, level_step_rows=level_step_rows,
                                 pulse_templates=pulse_templates,
                                 drift_templates=drift_templates)
    if linear is None:
        linear = fit_linear(fit_exclude)
        if linear.skipped:
            raise ZonesNotCalibratedError(
                "with the samples left out of the fit, a zone that the plain fit "
                "calibrates has too few: " + "; ".join(z.reason for z in linear.skipped),
                skipped=linear.skipped)
    if pulse_templates is not None or drift_templates is not None:
        from magcal.missions.elfin.pulses import (DRIFT_COLUMNS, NATURAL_COLUMNS,
                                                  with_shape_columns)

        lf = linear.field
        for prefix, shapes in ((NATURAL_COLUMNS, pulse_templates),
                               (DRIFT_COLUMNS, drift_templates)):
            if shapes is not None:
                lf = with_shape_columns(lf, prefix, shapes)
        linear = replace(linear, field=lf)
    if fit_exclude_scalar is not None:
        # e.g. flagged across B only: still fitted by the steps that fit |B| alone
        lf = linear.field
        fit_scalar = (lf["used"].to_numpy() == 1) & ~np.asarray(fit_exclude_scalar, bool)
        linear = replace(linear, field=lf.assign(fit_scalar=fit_scalar.astype(int)))
    ripple = ripple_crosscheck(linear, fgs) if diagnostics else pd.DataFrame()
    products, steps = {"linear": linear}, {}
    cal = linear
    if s.harmonic:
        from magcal.missions.elfin.harmonic import correct_elfin_calibration

        cal, steps["spin_harmonic_correction"] = correct_elfin_calibration(cal)
        products["harmonic"] = cal
        if s.gain_drift:
            from magcal.missions.elfin.drift import correct_gain_drift, drift_agreement_table

            cal, steps["gain_drift"] = correct_gain_drift(
                cal, shape_from=linear if s.gain_drift_2x else None,
                robust_start_from=linear if s.gain_drift_robust_c > 0 else None,
                robust_c=s.gain_drift_robust_c, degree=s.gain_drift_degree)
            steps["drift_agreement"] = drift_agreement_table(linear)
            products["harmonic + gain drift"] = cal
            if s.vector_step:
                from magcal.missions.elfin.vector import correct_vector

                knot = s.vector_knot_s or None
                cal, steps["vector_correction"] = correct_vector(
                    cal, bound_deg=s.tilt_bound_deg, knot_s=knot)
                products["+ vector step"] = cal
                if s.fast_drift:
                    from magcal.missions.elfin.harmonic import correct_fast_drift

                    cal, steps["fast_drift"] = correct_fast_drift(cal, knot_s=s.fast_knot_s)
                    products["+ fast drift"] = cal
                if s.phase_refit:
                    from magcal.missions.elfin.vector import correct_phase

                    cal, steps["phase_refit"] = correct_phase(cal, knot_s=s.refit_knot_s)
                    products["+ phase refit"] = cal
    scores = {name: score_field(p.field) for name, p in products.items()}
    from magcal.missions.elfin.diagnostics.stability import parameter_stability

    stability = parameter_stability(linear, products, steps) if diagnostics else {}
    joint = None
    if s.joint:
        cal, joint, scores["joint"] = _joint(linear, cal, scores)
    scan = {}
    if s.scan:
        for shift in SHIFTS_S:
            t = calibrate_elfin(fgs, state, time_shift_s=shift,
                                zone_numbers=zone_numbers).table()
            scan[f"{shift:+.1f}"] = {"rms_vector_nT": t["rms_vector_nT"].tolist(),
                                     "rms_scalar_nT": t["rms_scalar_nT"].tolist()}
    return ElfinDay(calibration=cal, linear=linear, settings=s, ripple=ripple, steps=steps,
                    scores=scores, joint=joint, scan=scan, stability=stability,
                    products=products)


def _without_skipped(fgs, state, settings, linear, *, hold_phase, fit_exclude,
                     fit_exclude_scalar, level_step_rows=None, pulse_templates=None,
                     drift_templates=None, **kw) -> ElfinDay:
    """The day calibrated on the zones ``linear`` could calibrate, their numbers kept,
    with ``linear.skipped`` carried by every product."""
    keep = linear.kept_rows(len(fgs))

    def rows(a):
        return None if a is None else np.asarray(a)[keep]

    day = calibrate_elfin_day(fgs[keep], state, settings, hold_phase=rows(hold_phase),
                              fit_exclude=rows(fit_exclude),
                              fit_exclude_scalar=rows(fit_exclude_scalar), linear=linear,
                              zone_numbers=linear.zone_numbers,
                              level_step_rows=rows(level_step_rows),
                              pulse_templates=rows(pulse_templates),
                              drift_templates=rows(drift_templates), **kw)
    products = {k: replace(v, skipped=linear.skipped) for k, v in day.products.items()}
    return replace(day, calibration=replace(day.calibration, skipped=linear.skipped),
                   linear=replace(day.linear, skipped=linear.skipped), products=products)


def _with_bridge(fgs, state, settings, day: ElfinDay, *, hold_phase) -> ElfinDay:
    """``day`` with the bridge trials of its left-out rows
    (:func:`magcal.missions.elfin.bridge.bridge_trials`): ``steps["bridge"]`` and the
    delivered field's ``bridge_rms_nT`` column."""
    from magcal.missions.elfin.bridge import bridge_column, bridge_trials

    f = day.calibration.field
    used = f["used"].to_numpy() == 1
    left = used & (f["fit"].to_numpy() == 0)
    if not left.any():
        return replace(day, settings=settings)
    left_scalar = used & (f["fit_scalar"].to_numpy() == 0) if "fit_scalar" in f.columns \
        else left
    keep = day.calibration.kept_rows(len(fgs))
    held = None if hold_phase is None else np.asarray(hold_phase)[keep]
    plain = replace(settings, detect_disturbed=False, bridge_trials=0, joint=False,
                    scan=False)
    # the trials keep the day's level steps; in a zone with one, a trial gap gets a
    # step too, so that the stated error holds the uncertainty of a kept level
    levels = f["level_step"].to_numpy() == 1 if "level_step" in f.columns \
        else np.zeros(len(f), bool)
    zone = f["zone"].to_numpy()
    stepped = np.isin(zone, np.unique(zone[levels]))

    # ... and its pulses along B
    from magcal.missions.elfin.pulses import DRIFT_COLUMNS, NATURAL_COLUMNS, shape_columns

    pulses, drifts = shape_columns(f, NATURAL_COLUMNS), shape_columns(f, DRIFT_COLUMNS)

    def calibrate(extra):
        return calibrate_elfin_day(fgs[keep], state, plain, hold_phase=held,
                                   fit_exclude=left | extra,
                                   fit_exclude_scalar=left_scalar | extra,
                                   diagnostics=False,
                                   level_step_rows=levels | (extra & stepped),
                                   pulse_templates=pulses, drift_templates=drifts,
                                   zone_numbers=day.calibration.zone_numbers).calibration.field

    table = bridge_trials(calibrate, f, left, settings.bridge_trials)
    cal = replace(day.calibration, field=f.assign(bridge_rms_nT=bridge_column(f, left, table)))
    products = {k: (cal if v is day.calibration else v) for k, v in day.products.items()}
    return replace(day, calibration=cal, settings=settings, products=products,
                   steps={**day.steps, "bridge": table})


def _with_level_steps(fgs, state, settings, *, linear, level_step_rows=None,
                      pulse_templates=None, drift_templates=None, **kw) -> ElfinDay:
    """The day calibrated without level steps and pulses along B, and again with those
    :func:`~magcal.missions.elfin.levels.level_step_rows` and
    :func:`~magcal.missions.elfin.pulses.zone_pulses` find on it (if any): both are
    decided on the delivered product (its spin-axis and ``|B|`` residuals), once, but
    for a zone that wants more than one level step (the strongest is kept first and
    the others judged on the day calibrated with it)."""
    from magcal.missions.elfin.levels import level_step_decision as decide
    from magcal.missions.elfin.drift import correct_gain_drift
    from magcal.missions.elfin.pulses import (PULSE_TREND_DEGREE, taken_by_the_drift,
                                              zone_pulses)
    from magcal.missions.elfin.pulses import pulse_templates as shapes

    none = np.zeros((len(fgs), 0))
    first = calibrate_elfin_day(
        fgs, state, settings, linear=linear,
        level_step_rows=np.zeros(len(fgs), bool) if level_step_rows is None
        else level_step_rows,
        pulse_templates=none if pulse_templates is None else pulse_templates,
        drift_templates=none if drift_templates is None else drift_templates, **kw)
    f = first.calibration.field
    rows = level_step_rows
    searched = {}
    if rows is None:
        rows = np.zeros(len(f), bool)
        if settings.level_steps:
            rows, judged = decide(f)
            searched["level_search"] = judged.assign(judged_on="without steps")
    natural, drift = (none if x is None else x for x in (pulse_templates, drift_templates))
    if pulse_templates is None and settings.pulses_b:
        found = zone_pulses(f, degree=settings.gain_drift_degree)
        with_cubic = found.iloc[:0]
        if settings.gain_drift_degree > PULSE_TREND_DEGREE and "harmonic" in first.products \
                and settings.gain_drift:
            # what the cubic's search would have stated, on the product with a cubic drift
            cubic, _ = correct_gain_drift(first.products["harmonic"],
                                          degree=PULSE_TREND_DEGREE)
            with_cubic = zone_pulses(cubic.field)
        found = taken_by_the_drift(found, with_cubic, settings.gain_drift_degree)
        kept = found["natural"].astype(bool)
        fitted = found["fitted"].astype(bool)
        natural, drift = shapes(f, found[kept]), shapes(f, found[~kept & fitted])
        searched["pulse_search"] = found
    if not rows.any() and not np.size(natural) and not np.size(drift):
        return replace(first, steps={**first.steps, **searched})
    # a kept level change found on fitted samples is left out of the fits from now on
    given = kw.pop("fit_exclude", None)
    given_rows = np.zeros(len(fgs), bool) if given is None else np.asarray(given, bool)
    first_steps = np.zeros(len(fgs), bool) if level_step_rows is None \
        else np.asarray(level_step_rows, bool)

    def again(steps):
        exclude = given_rows | steps
        fit_exclude = exclude if exclude.any() else given
        # with the rows left out and the step rows of the first calibration, its linear
        # fit is this one's (the shapes along B come after it): not fitted again
        same = np.array_equal(exclude, given_rows) and np.array_equal(steps, first_steps)
        return calibrate_elfin_day(fgs, state, settings, level_step_rows=steps,
                                   fit_exclude=fit_exclude,
                                   linear=first.linear if same else None,
                                   pulse_templates=natural, drift_templates=drift, **kw)

    if level_step_rows is None and _several_steps_in_a_zone(rows, f["zone"].to_numpy()):
        # a sheet bends the product without steps, and a real disturbance before it
        # may then look like a level change too (2022-01-12 zone 8, a sheet of the
        # opposite polarity at 0.65: a false -199 nT step): the strongest step of each
        # zone first, the others judged on the product with it
        strongest, first_judged = decide(f, max_steps=1)
        rows, then_judged = decide(again(strongest).calibration.field)
        rows = strongest | rows
        searched["level_search"] = pd.concat(
            [first_judged.assign(judged_on="without steps"),
             then_judged.assign(judged_on="with the strongest")], ignore_index=True)
    day = again(rows)
    return replace(day, steps={**day.steps, **searched})


def _utc(start: pd.Timestamp, seconds: float) -> str:
    """UTC (ISO, no zone suffix) of ``seconds`` after a zone's first row ``start``: the
    times of the search listings (:meth:`ElfinDay.level_step_judged`,
    :meth:`ElfinDay.pulse_search_listing`)."""
    return str((start + pd.to_timedelta(seconds, unit="s")).tz_convert(None))


def _several_steps_in_a_zone(rows, zone) -> bool:
    """Whether any zone has more than one run of ``rows``."""
    from magcal.missions.elfin.timing import true_runs

    starts = [zone[a] for a, _ in true_runs(np.asarray(rows, bool))]
    return len(starts) != len(set(starts))


def _joint(linear, incumbent, scores: dict) -> tuple:
    """Joint fit across zones, scored against the linear and incumbent products; returns
    the delivered calibration, the fit's record and the joint product's scores."""
    from magcal.missions.elfin.joint import calibrate_joint, choose_product, score_field

    product, fit = calibrate_joint(linear)
    names = list(scores)
    compared = {"linear": scores["linear"]}
    if names[-1] != "linear":
        compared[names[-1]] = scores[names[-1]]
    compared["joint"] = score_field(product.field)
    chosen, reason = choose_product(compared, incumbent=names[-1])
    record = {
        "note": "one fit across zones: shared coupling, sensor tilt and cubic non-linearity; "
                "per zone relative gains, drifting offsets and spin-plane anisotropy, "
                "attitude within 0.2 deg, spline spin phase; std from the Jacobian sandwich "
                "over 30 s blocks (std_naive ignores the autocorrelation), conditional on "
                "the phases",
        "delivered": chosen, "reason": reason,
        "shared": fit.shared(), "per_zone": fit.per_zone().to_dict(orient="records"),
        "spread_over_zones": fit.spread(), "attitude_at_bound": fit.at_bound,
        "cost_history_nT": fit.cost_history,
        "scores": {k: v.to_dict(orient="records") for k, v in compared.items()},
        "score_medians": {k: v.drop(columns="zone").median().to_dict()
                          for k, v in compared.items()}}
    return (product if chosen == "joint" else incumbent), record, compared["joint"]


def plot_residuals(path: str | Path, cal, title: str = "ELFIN: calibrated minus IGRF") -> Path:
    """Calibrated minus IGRF per zone in the despun frame (one panel a zone), as PNG.

    ``title`` heads the figure, followed by "(despun frame, nT)" and the data credit.
    """
    import matplotlib

    from magcal.missions.elfin.linear import CREDIT

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    f = cal.field
    zones = sorted(f["zone"].unique())
    fig, axes = plt.subplots(len(zones), 1, figsize=(10, 1.6 * len(zones)), sharey=True)
    for ax, k in zip(np.atleast_1d(axes), zones):
        z = f[(f["zone"] == k) & (f["used"] == 1)]
        ts = (z.index - z.index[0]).total_seconds()
        for c, col in zip("xyz", ("C0", "C1", "C2")):
            ax.plot(ts, z[f"b{c}_despun"] - z[f"igrf_{c}_despun"], lw=0.4, color=col,
                    label=f"d{c.upper()}")
        ax.set_ylim(-400, 400)
        ax.text(0.01, 0.8, str(z.index[0])[:19], transform=ax.transAxes, fontsize=7)
    np.atleast_1d(axes)[0].legend(loc="upper right", fontsize=7, ncol=3)
    np.atleast_1d(axes)[-1].set_xlabel("s from zone start")
    fig.suptitle(f"{title} (despun frame, nT)\n{CREDIT}", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return Path(path)
