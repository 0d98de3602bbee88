"""Which steps of the ELFIN calibration run, and what each trades in natural signal.

:class:`ElfinSettings` is the ``[spin.pipeline]`` table of a chain configuration and the
``--settings`` of the ELFIN workflows; :func:`magcal.missions.elfin.pipeline.calibrate_elfin_day`
runs the steps it names.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

from magcal.errors import InputError

#: Settings that buy a smaller residual against the model with natural signal lost
#: (each is a time-varying fit against IGRF; see :mod:`magcal.missions.elfin.injection`).
SIGNAL_TRADE = ("linear_phase_knot_s", "linear_phase_degree", "linear_axis_degree",
                "gain_drift", "gain_drift_2x", "gain_drift_robust_c", "vector_step",
                "vector_knot_s", "fast_drift", "fast_knot_s", "phase_refit", "refit_knot_s",
                "detect_disturbed", "level_steps", "pulses_b", "gain_drift_degree")
#: Settings that measure a stated error by calibrating the day again (0: not measured).
TRIAL_SETTINGS = ("bridge_trials", "pulse_trials", "level_trials", "perp_trials")


@dataclass(frozen=True)
class ElfinSettings:
    """Which steps of the ELFIN calibration run.

    Attributes
    ----------
    harmonic : bool
        The spin-harmonic correction of ``|B|`` after the linear fit (False: the linear
        calibration only, and no later step).
    gain_drift : bool
        The spin-plane gain drift after the harmonic correction (False also skips the
        vector step, which corrects what the drift leaves).
    gain_drift_2x : bool
        The gain drift follows the time shape of the 2x-spin harmonic's drift (a
        reference-free gain signature; two numbers per zone) instead of a free cubic
        against the model. Signal trade: the cubic also fits a natural field along B
        (which changes ``|B|``) as a gain drift.
    vector_step : bool
        The vector-only step: body-fixed spin harmonics and a spin-axis tilt.
    tilt_bound_deg : float
        Bound of the per-zone spin-axis tilt in the vector step (the attitude file's
        stated uncertainty, 0.2 deg; 0 fits no tilt).
    vector_knot_s : float
        Knot spacing (s) of the B-spline drift of the vector step's body-fixed harmonics
        (the spin-axis 1x coupling changes sign about every 100 s, faster than a cubic
        over the zone can follow); 0: a cubic in time over the zone.
    fast_drift : bool
        After the vector step, the 1x/2x spin harmonics of ``|B|`` with coefficients
        drifting on 30 s B-splines (the sunlit zones' 1x/2x terms change within a
        minute). Harmonics of ``|B|`` are instrumental: a natural field changes ``|B|``
        at the spin frequency only to second order.
    phase_refit : bool
        Last, the spin phase refitted on the calibrated field (``refit_knot_s`` knots).
        It makes no difference to ``|B|``; it removes the smooth phase error that the
        quadratic phase of the linear fit leaves (vector residual 74 -> 16 nT, zone
        median of zones 1, 4, 7, 10) and takes part of an along-track natural field
        with it (a 200 nT 40 s pulse: 42 -> 26 % of its energy kept).
    linear_phase_knot_s : float
        Knot spacing (s) of the spin-phase spline fitted with the linear calibration
        against IGRF (0: a quadratic phase only). Signal trade: a spline phase fitted
        against a model turns an along-track (spin-plane) natural field into a phase error
        and removes it (measured: ``workflows/elfin_preservation.py``). Default 0: the
        scalar residual does not depend on it (zones 1, 4, 7, 10: 7.19 nT, 7.12 with
        30 s knots); an along-track 200 nT 40 s pulse keeps 26 % of its energy after
        the refit instead of 0.2 %.
    linear_phase_degree : int
        With ``linear_phase_knot_s = 0``: the degree of the spin phase in time over the
        zone (2: the spin rate may change linearly; 1: a constant spin rate). Signal
        trade: every degree of freedom of the phase fitted against the model turns
        part of an along-track field into a phase error.
    linear_axis_degree : int
        Degree of the slow spin-axis tilt in the linear fit's spin-axis row (the
        calibrated spin-plane components times ``T^1..T^d``; 0: no tilt). Signal trade:
        with 45000 nT in the spin plane a tilt of 0.4 deg over the pass is 300 nT along
        the spin axis, so the tilt terms fit an east-west field (a current sheet) away.
    gain_drift_robust_c : float
        Tukey biweight (in robust sigmas) of the gain drift's fit
        (:func:`~magcal.missions.elfin.drift.fit_gain_drift`, ``robust_c``); 0: plain
        least squares. Signal trade: the plain cubic takes a natural field along B that
        lasts a minute or two as a gain drift.
    fast_knot_s : float
        Knot spacing (s) of the fast drift's B-splines.
    refit_knot_s : float
        Knot spacing (s) of the last phase refit. Default 240 s: about one cubic over a
        pass (zones 1, 4, 7, 10, after the quadratic linear phase: 120 s knots 16.3 nT
        vector residual and 25 % of the along-track pulse kept, 240 s 16.4 nT and 26 %;
        the 30 s linear splines and 60 s refit of before: 14.0 nT and 0.2 %).
    joint : bool
        Also the joint fit across zones (about 60 s); delivered only if no worse.
    scan : bool
        Also the timing-offset scan (the linear calibration with IGRF at ``t + shift``
        for each of :data:`SHIFTS_S`; diagnostic, 7 more linear fits).
    detect_disturbed : bool
        Locate disturbed intervals from the counts alone and leave them out of the fits
        (:func:`magcal.missions.elfin.disturbed.calibrate_detected`: localized excursions
        of the residual of a stiff calibration, not within 20 s of a zone end; ``|B|``
        flags out of every fit, vector flags out of the slow vector fits; a run is put
        back when leaving it out adds more spin tones than slow field). Signal trade:
        False fits every step on every sample and takes a localized field across B
        (zones 1, 4, 7, 10: an east-west 40 s pulse 108 % kept with detection, 65 %
        without; an along-track one 97 % against 26 %) for the same zone-median
        residual (7.20 / 5.14 / 15.09 against 7.20 / 5.16 / 14.83 nT scalar / fast /
        vector; the difference is the natural fields kept). About 2.5 times the
        calibration time (a stiff calibration from the same linear fit, one without
        flags for the bridge check, one or two with them).
    axis_prior_weight : float
        If positive, the linear fit draws the spin-axis row of the zones whose
        spin-axis field changes little over the pass (std below 500 nT) towards the
        median row of the others (``axis_prior_weight`` of
        :func:`~magcal.missions.elfin.linear.calibrate_elfin`); 0: each zone on its
        own. On 2022-01-12 (prior from zones 0, 1, 2, 11) zone 3's row goes from 2.5e-3
        to 8.2e-3 nT per count (the others 6.7-10.2e-3), an east-west pulse there comes
        back with the phase held at 0.75 of its energy instead of -0.09 and as
        delivered at 102 % instead of 54 %, and the whole day's vector residual goes
        from 17.0 to 16.6 nT.
    bridge_trials : int
        If positive, the error of the calibration over the intervals it left out of its
        fits (detected or given) is measured: this many quiet trial gaps per zone, as
        long as the zone's longest left-out run, each a calibration of the day
        (:func:`magcal.missions.elfin.bridge.bridge_trials`); the zone's RMS goes to the
        ``bridge_rms_nT`` column of the left-out rows and to ``bridge`` in the JSON. A
        natural field kept there carries that error (the injection tests'
        ``distortion``): on 2022-01-12, 40 s pulses across B injected at three places
        in every zone (67 cases), the error over their left-out samples was within the
        stated one in 81 % of cases and within twice it in all (largest ratio 1.98).
        Default 3 (each trial costs about one calibration without detection: whole day
        8.6 -> 14 s); 0: not measured.
    level_steps : bool
        Let the spin-axis (about east-west) field's level differ before and after an
        interval left out of the fits where the product without steps says it does
        (:func:`~magcal.missions.elfin.levels.level_step_rows`: a trend-plus-step fit of
        its spin-axis residual that the step improves threefold, a step of 30 nT or
        more, at least half the excursion inside and 0.4 of the level change next to
        the interval; also abrupt level changes of fitted samples the detector missed,
        :func:`~magcal.missions.elfin.levels.level_change_candidates`); the day is then
        calibrated again with a step there in the linear fit's spin-axis row and in
        the vector step's tilt, left in the field (``level_step`` column). Without it
        those slow terms take a current sheet's new level as an offset drift or a
        tilt. Signal trade on 2022-01-12, 300 nT east-west sheets at 0.35, 0.5 and 0.65
        of every zone (36 cases): kept 3 % -> 110 % (zone median; 28 of 36 at 90 % or
        more, 0.70-1.96 of the energy, size about its square root), distortion
        27 -> 7.8 %; 108 pulses and the clean day: no step, products unchanged.
        The bridge trials of a zone with a step put a step at their gaps too. Default
        True; False: no step (the product of before).
    pulses_b : bool
        Keep localized fields along B out of the gain drift
        (:mod:`magcal.missions.elfin.pulses`): Gaussian pulses found on top of a cubic
        in the product's ``|B|`` residual (each dividing its sum of squares tenfold or
        more) are fitted with the drift, those 30 nT or higher and narrower than 150 s
        FWHM left in the product as a natural field (``pulses_b`` in the JSON), the
        wider ones removed as part of the drift (a gain drift the cubic lacks). Signal
        trade on 2022-01-12 (delivered settings otherwise), 100 nT pulses along B of
        90 s FWHM at 0.35, 0.5 and 0.65 of every zone (36 cases): kept 2-8 % -> 93 %
        (median; 56 % of the cases at 90 % or more, 72 % within 0.5-2 times the
        energy, 0.33-2.98), distortion 37 -> 9 %; the size is poorly determined because
        the clean day itself holds -30 to +20 nT on a 90 s pulse's shape beyond the
        cubic, and the width the search picks amplifies that (``pulse_trials`` states
        it). Clean day: no natural pulse, wide drifts removed (now zones 9 and 10,
        stated in the JSON's ``pulses_b.search``; when measured, zones 3, 4, 9, 10,
        scalar residual 6.8 -> 6.3 nT, zone median). Default True: the drift alone keeps
        2-8 % of such a pulse, so leaving it out costs the science user the signal,
        while the size's uncertainty is stated; a day with pulses or drifts is
        calibrated once more (the clean day: 19 -> 23 s). False: the product of before.
    pulse_trials : int
        With ``pulses_b``: the error of each kept pulse's height, from this many other
        zones without a pulse, a pulse like it put into their counts at the same place
        and the day calibrated again with them together
        (:func:`~magcal.missions.elfin.pulses.pulse_trials`; ``height_error_nT`` in the
        JSON's ``pulses_b``). 0: not measured.
    pulses_perp : bool
        Fit a detected interval's pulse across B as a natural-field template instead of
        leaving its rows out (:mod:`magcal.missions.elfin.perp`): on the delivered
        product a Gaussian (free centre, FWHM and GEI amplitude on a linear baseline)
        fitted to each detected interval's residual, kept when it explains 80 % of it,
        is 10-150 s wide, 30 nT or higher, inside the zone and mostly across B; the day
        is then calibrated with those rows in the fits and the pulse added to IGRF, its
        shape refitted until settled (a zone that does not settle keeps the
        interval left out). Why: leaving rows out changes the calibration the fits
        bridge the gap with, a floor on the kept pulse's distortion that a fitted
        template does not have (2022-01-12, 40 s pulses across B at 36 places: whole-
        signal distortion 14 -> 9 %). Several more calibrations per day with a pulse;
        ``pulses_perp`` in the JSON. False: left out as detected.
    perp_trials : int
        With ``pulses_perp``: the error of each kept pulse across B, from this many
        other zones without one, a pulse like it put into their counts at the same
        place and the day calibrated again with them together
        (:func:`~magcal.missions.elfin.perp.perp_trials`; ``error_rms_nT`` in the
        JSON's ``pulses_perp``, the calibrated table's ``pulse_error_nT``). 0: not
        measured.
    level_trials : int
        With ``level_steps``: the error of each kept level step, from this many other
        zones without a step, a current sheet of the step's size put into their counts
        at the same place and the day calibrated again
        (:func:`~magcal.missions.elfin.levels.level_trials`; ``step_error_nT`` in the
        JSON's ``level_steps``). 0: not measured.
    gain_drift_degree : int
        Degree of the gain drift's polynomial in time per zone
        (:func:`~magcal.missions.elfin.drift.fit_gain_drift`) and of the trend the
        pulses along B are searched on (:func:`~magcal.missions.elfin.pulses.find_pulses`;
        the two must agree: a search on a cubic under a quintic drift takes the drift's
        own structure into the pulses, 1.45 of their energy). Default 4. On 2022-01-12
        the 2x-spin harmonic's drift, which a spin-plane gain change makes and a
        natural field does not, has 0.9-5.1 nT of structure beyond a cubic per zone
        (0.6-3.4 nT beyond a quartic, 0.3-1.3 nT beyond a quintic), and in 9 of the 12
        zones the ``|B|`` residual beyond a cubic follows it (correlation 0.61-0.97): a
        cubic leaves gain drift in the product, and a pulse along B found there carries
        it (whole day, 36 places, both polarities, zone medians of the energy kept:
        cubic 0.897 / 1.160, quartic 1.003 / 1.098, quintic 0.948 / 1.011; scalar
        residual 6.33 / 6.03 / 5.20 nT). The trade grows with the degree: a quartic
        over a 6 min pass is 90 % of a 90 s pulse along B (a cubic 71 %), so a pulse
        along B that is not found, or whose rows are left out of the fit, loses more
        (interval given, zone 1: 0.79 kept against 0.91), and a ``|B|`` structure a few
        minutes wide is taken by the drift before the search sees it (above a cubic it
        is stated from a search on the product with a cubic drift:
        :func:`~magcal.missions.elfin.pulses.taken_by_the_drift`).
    """

    harmonic: bool = True
    gain_drift: bool = True
    gain_drift_2x: bool = False
    vector_step: bool = True
    tilt_bound_deg: float = 0.2
    vector_knot_s: float = 30.0
    fast_drift: bool = True
    phase_refit: bool = True
    linear_phase_knot_s: float = 0.0
    linear_phase_degree: int = 2
    linear_axis_degree: int = 2
    gain_drift_robust_c: float = 0.0
    fast_knot_s: float = 30.0
    refit_knot_s: float = 240.0
    joint: bool = False
    scan: bool = False
    detect_disturbed: bool = True
    axis_prior_weight: float = 1.0
    bridge_trials: int = 3
    level_steps: bool = True
    pulses_b: bool = True
    pulse_trials: int = 6
    level_trials: int = 3
    pulses_perp: bool = True
    perp_trials: int = 3
    gain_drift_degree: int = 4

    @classmethod
    def from_mapping(cls, given: dict, where: str = "settings") -> ElfinSettings:
        """Settings from a mapping (e.g. a TOML table), checked key by key.

        Raises
        ------
        InputError
            An unknown key, a wrong type or a negative tilt bound, naming ``where``.

        Examples
        --------
        >>> ElfinSettings.from_mapping({"vector_step": False}).vector_step
        False
        >>> ElfinSettings.from_mapping({"tilt": 1})
        Traceback (most recent call last):
        ...
        magcal.errors.InputError: settings: unknown key 'tilt' (known: harmonic, gain_drift, ...)
        """
        known = {f.name: f for f in fields(cls)}
        out = {}
        for key, value in given.items():
            if key not in known:
                raise InputError(f"{where}: unknown key {key!r} (known: {', '.join(known)})")
            default = known[key].default
            if isinstance(default, bool):
                ok = isinstance(value, bool)
            elif isinstance(default, int):
                ok = float(value) == int(value) if isinstance(value, (int, float)) \
                    and not isinstance(value, bool) else False
                value = int(value) if ok else value
            else:
                ok = isinstance(value, (int, float)) and not isinstance(value, bool)
            if not ok:
                kind = ("true or false" if isinstance(default, bool) else
                        "a whole number" if isinstance(default, int) else "a number")
                raise InputError(f"{where}: {key} must be {kind}, got {value!r}")
            out[key] = float(value) if isinstance(default, float) else value
        settings = cls(**out)
        if settings.tilt_bound_deg < 0:
            raise InputError(f"{where}: tilt_bound_deg must not be negative")
        for key in ("vector_knot_s", "linear_phase_knot_s", "linear_axis_degree",
                    "linear_phase_degree", "gain_drift_robust_c", "axis_prior_weight",
                    "bridge_trials", "pulse_trials", "level_trials", "perp_trials",
                    "gain_drift_degree"):
            if getattr(settings, key) < 0:
                raise InputError(f"{where}: {key} must not be negative")
        for key in ("fast_knot_s", "refit_knot_s"):
            if getattr(settings, key) <= 0:
                raise InputError(f"{where}: {key} must be positive")
        return settings

    def without_trials(self, *, keep_bridge: bool = False) -> ElfinSettings:
        """These settings with no error trials (:data:`TRIAL_SETTINGS` 0; with
        ``keep_bridge`` the bridge trials stay): what a run whose stated errors are not
        read (a trial day, an injected day, the calibrations behind a trial) asks for.

        Examples
        --------
        >>> s = ElfinSettings().without_trials(keep_bridge=True)
        >>> s.bridge_trials, s.pulse_trials, s.level_trials, s.perp_trials
        (3, 0, 0, 0)
        """
        return replace(self, **{k: 0 for k in TRIAL_SETTINGS
                                if not (keep_bridge and k == "bridge_trials")})

    def steps(self) -> tuple:
        """Names of the products made, in order (the last is delivered unless joint wins)."""
        names = ["linear"]
        if self.harmonic:
            names.append("harmonic")
            if self.gain_drift:
                names.append("harmonic + gain drift")
                if self.vector_step:
                    names.append("+ vector step")
                    if self.fast_drift:
                        names.append("+ fast drift")
                    if self.phase_refit:
                        names.append("+ phase refit")
        return tuple(names)
