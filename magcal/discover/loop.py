"""The discovery loop: measure the gap, name the missing effect, add it, refit, repeat.

Each round fits every candidate of the vocabulary (:mod:`magcal.discover.effects`)
jointly with the effects already added and judges it by one criterion, the same for
every effect: its held-out gain over contiguous blocks in time (leave-one-day-out
cross-validation, :mod:`magcal.discover.selection`), which counts only if it is beyond
chance under the correlated-noise model, i.e. the Wald test of the candidate's
coefficients (block-jackknife covariance floored by the model-based one from the
residual's autocorrelation) reaches ``z_min`` (Bonferroni-corrected over the step times,
drift breaks or periods scanned). The candidate with the largest gain among those is
added. The offset, when beyond chance, comes first and is free in every component, so
that every other term is judged with the level free. Per-component terms are restricted
to the components (rotations to the axes) where they pass ``z_component``. Steps and
changes of drift rate are searched in every component with ``ruptures``
(:func:`magcal.discover.scan.change_points`); a step time or drift break is then tried
in every component (the components that pass the look-elsewhere threshold at it
establish it, the others are tested at that fixed time), and a step several components
share is also tried at the time they place together
(:func:`magcal.discover.scan.joint_step_time`); rotations and scale errors are tested
against the field's own variation (their columns are ``e_j x B_model`` and
``B_model,i``). Candidates whose fitted signals are strongly correlated with the winner
(``|corr| >= confound_corr``) are reported as ``ambiguous_with`` when the data cannot
tell them apart (paired ``z < z_ambiguous``), and as ``preferred_over`` otherwise. A
scale or rotation added before a local-time term on its components is also tested beside
one (``z_beside_local_time``): at a fixed position the model varies mostly with local
time, and if it adds nothing beyond chance to that field it is reported ambiguous with
``diurnal``. A candidate whose columns lie in the span of the effects already in
(:func:`~magcal.discover.selection.orthogonal_share` below ``min_orthogonal``, such as a
scale on a component whose model is constant) is not scored but listed in the round's
``skipped`` with the reason. The loop stops when no candidate's gain is beyond chance or
after ``max_effects`` effects. Every step is then re-tested in the final joint fit and
retracted (the last round's ``retracted``) if its Wald z no longer reaches the
look-elsewhere threshold: in a greedy loop a step can win its round by standing in for a
drift named after it.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from magcal.discover.break_time import break_time_interval
from magcal.discover.effects import (
    DAY_S, EFFECT_NAMES, Activity, Diurnal, Drift, Effect, EffectInputs, Offset, Periodic,
    Rotation, Scale, SpinTone, Step, Temperature, available, make_activity)
from magcal.discover.gap import profile_gap
from magcal.discover.scan import (change_points, joint_step_time, n_period_trials, n_step_trials,
                                  scan_periods)
from magcal.discover.selection import (
    BlockedGram, Comparison, CVScore, compare, delta_bic_eff, wald_test,
    model_covariance, orthogonal_share, paired_z, regression_n_eff, time_blocks)
from magcal.discover.step_time import step_time_interval
from magcal.io.jsonio import product_dict


@dataclass(frozen=True)
class DiscoverySettings:
    """Thresholds of the discovery loop (defaults tuned on simulated months).

    Parameters
    ----------
    max_effects : int
        Most effects to add.
    z_min : float
        Significance (Wald test under the correlated-noise model, as a normal z) an
        effect's held-out gain needs to count as beyond chance. Scanned terms (step,
        drift break, periodic) need more (Bonferroni over the times/periods tried).
    z_component : float
        Same, for including one component of a per-component effect.
    z_variant : float
        A richer variant (more diurnal harmonics) must beat the simpler one by this.
    z_ambiguous : float
        Confounded candidates closer than this to the winner are reported as ambiguous.
    confound_corr : float
        Correlation of fitted signals above which two candidates count as confounded.
    block_s : float
        Length of the held-out blocks (one day).
    diurnal_harmonics : tuple of int
        Diurnal variants tried.
    spin_harmonics : int
        Harmonics of the spin tone.
    n_periods : int
        Periodogram peaks tried as ``periodic`` candidates per round.
    vocabulary : tuple of str
        Effect names to try (subset of :data:`EFFECT_NAMES`).
    max_scale : float
        Largest scale-factor error (dimensionless) named as ``scale``: a sanity bound,
        not a prior. A working fluxgate's scale errors are of order 1e-3 to 1e-2; a
        fitted ``s`` of half the field means the model-proportional signature stands in
        for something else (a short record, an unmodelled field that varies with the
        model, such as a storm-time field) and is not named. The bound sits above the
        detectability thresholds of a month of 1-min geostationary data (0.07-0.2, see
        the README), so detectable errors are still named.
    max_rotation_deg : float
        Largest rotation angle named as ``rotation``, for the same reason (mounting
        errors are of order a degree; the detectability thresholds are 5-7 deg).
    min_orthogonal : float
        Smallest relative norm of the part of a candidate's columns orthogonal to the
        effects already in (:func:`orthogonal_share`). Below it the candidate adds no
        direction of its own (a scale on a component whose model field is constant is
        the offset's column): its joint fit is rank-deficient, its coefficient and
        significance are set by round-off, and it is skipped, the round's ``skipped``
        saying so. At ``1e-3`` the coefficient's variance is inflated a million-fold
        by the collinearity and its distinct signal is a thousandth of its size.
    """

    max_effects: int = 8
    z_min: float = 3.0
    z_component: float = 2.0
    z_variant: float = 2.0
    z_ambiguous: float = 2.0
    confound_corr: float = 0.7
    block_s: float = DAY_S
    diurnal_harmonics: tuple[int, ...] = (1, 2, 3)
    spin_harmonics: int = 2
    n_periods: int = 3
    vocabulary: tuple[str, ...] = EFFECT_NAMES
    max_scale: float = 0.5
    max_rotation_deg: float = 20.0
    min_orthogonal: float = 1e-3

    def as_dict(self) -> dict:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in self.__dict__.items()}


@dataclass(frozen=True)
class FittedEffect:
    """One added effect with its final (jointly refitted) parameters.

    Attributes
    ----------
    effect : Effect
        The term (name, components, hyper-parameters).
    beta, beta_std : ndarray
        Coefficients of its columns and their block-jackknife standard errors.
    rms_before_nT, rms_after_nT : float
        RMS of the residual over all components before and after it was added.
    evidence : dict
        Cross-validation gain and t-statistic, ESS-corrected BIC, runner-up,
        confounded alternatives.
    gap_before : dict
        :func:`~magcal.discover.gap.profile_gap` of the residual it was fitted to.
    amplitude : dict
        ``amplitude_nT`` and ``amplitude_se_nT`` per component
        (:func:`magcal.discover.amplitude.effect_amplitudes`: rms of the contribution
        over the record, standard error under the OU + white noise model).
    beta_dof : ndarray or None
        Degrees of freedom of each ``beta_std``
        (:meth:`~magcal.discover.selection.BlockedGram.jackknife_dof`): the report's
        ``parameters.ci95`` takes Student's t with them, because a jackknife over few
        blocks is itself scattered and the normal 1.96 covers less often than 95 %.
    time_ci95_s : tuple of float or None
        A step's 95 % confidence interval for its time, ``(after, at or before)`` in
        seconds since 1970 (:func:`magcal.discover.step_time.step_time_interval`), or a
        drift break's for the time of its rate change
        (:func:`magcal.discover.break_time.break_time_interval`): the report's
        ``parameters.time_ci95`` (ISO times) and ``time_ci95_s``.
    """

    effect: Effect
    beta: np.ndarray
    beta_std: np.ndarray
    rms_before_nT: float
    rms_after_nT: float
    evidence: dict
    gap_before: dict = field(default_factory=dict, repr=False, compare=False)
    amplitude: dict = field(default_factory=dict, compare=False)
    beta_dof: np.ndarray | None = field(default=None, compare=False)
    time_ci95_s: tuple[float, float] | None = field(default=None, compare=False)

    @property
    def name(self) -> str:
        return self.effect.name

    @property
    def components(self) -> tuple[str, ...]:
        return self.effect.components

    @property
    def parameters(self) -> dict:
        out = self.effect.describe(self.beta, self.beta_std, self.beta_dof)
        if self.time_ci95_s is not None:
            import pandas as pd

            out["time_ci95"] = [pd.Timestamp(v, unit="s", tz="UTC").isoformat()
                                for v in self.time_ci95_s]
            out["time_ci95_s"] = [float(v) for v in self.time_ci95_s]
        return out

    def to_dict(self) -> dict:
        comps = list(self.effect.components)
        return {"name": self.name, "components": comps, "parameters": self.parameters,
                "rms_before_nT": self.rms_before_nT, "rms_after_nT": self.rms_after_nT,
                "evidence": self.evidence, **self.amplitude}


@dataclass(frozen=True)
class DiscoveryResult:
    """What the discovery loop found (CONTRACTS §5).

    Use :meth:`to_json` for REPORT.json, :meth:`account` for the human-readable lines,
    :meth:`augmented_model` to evaluate ``model + effects`` on new data and
    :func:`magcal.discover.plots.plot_gap` for the before/after figure.
    """

    components: tuple[str, ...]
    gap_initial: dict
    effects: tuple[FittedEffect, ...]
    gap_final: dict
    stopped_because: str
    settings: dict
    longitude_deg: float | None = None
    rounds: tuple[dict, ...] = ()
    provenance: dict = field(default_factory=dict)
    times_s: np.ndarray = field(default=None, repr=False, compare=False)
    local_time_h: np.ndarray | None = field(default=None, repr=False, compare=False)
    residual_initial: np.ndarray = field(default=None, repr=False, compare=False)
    residual_final: np.ndarray = field(default=None, repr=False, compare=False)
    #: Noise model of the effects' amplitude standard errors (OU + white per component).
    amplitude_noise: dict = field(default_factory=dict)
    #: What :func:`discover_gap` left out before the loop: spikes and other bad samples
    #: (``by_test``) and samples where a used covariate is unknown (``covariate_unknown``).
    screened: dict = field(default_factory=dict)
    #: Per covariate column: used or not and why, samples it covers, values out of range.
    covariates: dict = field(default_factory=dict)
    #: Columns of measured and model that are not components, and components without data.
    columns_not_used: dict = field(default_factory=dict)

    @property
    def names(self) -> list[str]:
        """Effect names in the order they were added."""
        return [e.name for e in self.effects]

    def effect(self, name: str) -> FittedEffect:
        """The first added effect called ``name``."""
        for e in self.effects:
            if e.name == name:
                return e
        raise KeyError(f"no effect {name!r} was added (added: {', '.join(self.names) or 'none'})")

    def to_json(self) -> dict:
        """REPORT.json content: schema_version, gap_initial, effects, gap_final, ..."""
        return product_dict({
            "components": list(self.components),
            "gap_initial": self.gap_initial,
            "effects": [e.to_dict() for e in self.effects],
            "gap_final": self.gap_final,
            "stopped_because": self.stopped_because,
            "account": self.account(),
            "settings": self.settings,
            "longitude_deg": self.longitude_deg,
            "rounds": list(self.rounds),
            "amplitude_noise": self.amplitude_noise,
            "screened": self.screened,
            "covariates": self.covariates,
            "columns_not_used": self.columns_not_used,
            "provenance": self.provenance,
        })

    def account(self) -> list[str]:
        """Short human-readable account of the discovery, one line per step."""
        from magcal.discover.account import account_lines

        return account_lines(self)

    def with_provenance(self, provenance: dict) -> "DiscoveryResult":
        import dataclasses

        return dataclasses.replace(self, provenance=dict(provenance))

    def effects_sum(self, inputs: EffectInputs) -> np.ndarray:
        """Sum of the added effects on some inputs, shape (n, m)."""
        out = np.zeros((inputs.n, inputs.m))
        for e in self.effects:
            out += e.effect.evaluate(inputs, e.beta)
        return out

    def augmented_model(self, times, model, covariates=None, longitude_deg=None):
        """Evaluate ``model + effects`` on new times and covariates.

        Parameters
        ----------
        times : pandas.DatetimeIndex, array of datetime64, or array of float
            Sample times (floats are seconds since 1970-01-01 UTC); ``None`` to use the
            index of a DataFrame ``model``.
        model : pandas.DataFrame or ndarray (n, m)
            Model field with the result's components.
        covariates : pandas.DataFrame or mapping, optional
            Covariates the effects need (``temperature``, ``kp``, ``dst``, ``phase``,
            ``lon_deg``), on ``times`` or interpolated onto them.
        longitude_deg : float, optional
            Longitude for local time; defaults to the one used in the discovery.

        Returns
        -------
        Same type as ``model``: the augmented model.
        """
        from magcal.discover.inputs import build_inputs

        lon = self.longitude_deg if longitude_deg is None else longitude_deg
        inputs, index = build_inputs(times, model, self.components, covariates, lon)
        total = inputs.model + self.effects_sum(inputs)
        if index is not None:
            import pandas as pd

            return pd.DataFrame(total, index=index, columns=list(self.components))
        return total


# ----------------------------------------------------------------------------------
@dataclass
class _Candidate:
    effect: Effect
    columns: tuple[int, ...]
    score: CVScore
    comparison: Comparison
    component_z: dict
    family: str
    z_needed: float = 0.0
    delta_bic: float = float("nan")
    n_eff: float = float("nan")
    trials: float = 1.0
    implausible: str = ""

    @property
    def name(self) -> str:
        return self.effect.name

    @property
    def significant(self) -> bool:
        """Positive held-out gain, beyond chance: the Wald test of its coefficients under
        the correlated-noise model reaches ``z_needed``."""
        return self.comparison.gain > 0 and self.comparison.z >= self.z_needed

    @property
    def passes(self) -> bool:
        return self.significant and not self.implausible

    @property
    def log_p_corrected(self) -> float:
        """Log p-value after the look-elsewhere (Bonferroni) correction of scanned terms."""
        return float(self.comparison.log_p + np.log(max(self.trials, 1.0)))


def _look_elsewhere(z: float, trials: float) -> float:
    """z threshold after a Bonferroni correction for ``trials`` scanned hyper-parameters."""
    if trials <= 1:
        return float(z)
    from scipy import stats

    return float(stats.norm.isf(stats.norm.sf(z) / trials))


def _static_families(inputs: EffectInputs, settings: DiscoverySettings):
    """(family name, variants) with each variant a list of (effect on one component)."""
    t = inputs.times_s
    comps = inputs.components
    fam = []
    vocab = settings.vocabulary
    if "offset" in vocab:
        fam.append(("offset", [[Offset(components=(c,)) for c in comps]]))
    if "drift" in vocab:
        t_ref = float(0.5 * (t[0] + t[-1]))
        fam.append(("drift", [[Drift(components=(c,), t_ref_s=t_ref) for c in comps]]))
    if "diurnal" in vocab and available(Diurnal, inputs):
        fam.append(("diurnal", [[Diurnal(components=(c,), harmonics=k) for c in comps]
                                for k in settings.diurnal_harmonics]))
    if "temperature" in vocab and available(Temperature, inputs):
        ref = float(np.nanmean(inputs.covariates["temperature"]))
        fam.append(("temperature", [[Temperature(components=(c,), t_ref_degC=ref)
                                     for c in comps]]))
    if "scale" in vocab:
        fam.append(("scale", [[Scale(components=(c,)) for c in comps]]))
    if "rotation" in vocab and available(Rotation, inputs):
        # each axis alone against the field's own variation; the passing axes are merged
        fam.append(("rotation", [[Rotation(components=comps, axes=(a,)) for a in comps]]))
    if "activity" in vocab and available(Activity, inputs):
        fam.append(("activity", [[make_activity(inputs, (c,)) for c in comps]]))
    if "spin_tone" in vocab and available(SpinTone, inputs):
        fam.append(("spin_tone", [[SpinTone(components=(c,), harmonics=k) for c in comps]
                                  for k in range(1, settings.spin_harmonics + 1)]))
    return fam


def _distinct_times(points, most: int = 3, min_sep_s: float = 3 * 3600.0):
    """The ``most`` strongest change times of :func:`change_points` with the components
    they were found in, a time found in several components counted once (merged when
    closer than ``min_sep_s``): a list of ``(t_s, set of component indices)``."""
    out: list[tuple[float, set]] = []
    for t, c, _ in sorted(points, key=lambda p: -p[2]):
        near = [u for u in out if abs(t - u[0]) <= min_sep_s]
        if near:
            near[0][1].add(c)
        elif len(out) < most:
            out.append((t, {c}))
    return out


def _key(effect: Effect) -> str:
    """What a per-component (or per-axis) variant is selected by."""
    if isinstance(effect, Rotation):
        return effect.fitted_axes()[0] if len(effect.fitted_axes()) == 1 else "all"
    return effect.components[0]


def _merge(effects: list[Effect]) -> Effect:
    if isinstance(effects[0], Rotation):
        import dataclasses

        return dataclasses.replace(effects[0], axes=tuple(a for e in effects
                                                          for a in e.fitted_axes()))
    comps = tuple(c for e in effects for c in e.components)
    return effects[0].with_components(comps)


class _Loop:
    """State of one discovery run (private; use :func:`discover`)."""

    def __init__(self, inputs: EffectInputs, y: np.ndarray, settings: DiscoverySettings):
        self.inputs = inputs
        self.settings = settings
        self.blocks = time_blocks(inputs.times_s, settings.block_s)
        self.gram = BlockedGram(y, self.blocks)
        self.cols: dict[Effect, tuple[int, ...]] = {}
        self.families = _static_families(inputs, settings)
        for _, variants in self.families:
            for variant in variants:
                for eff in variant:
                    self.cols[eff] = self.gram.add(eff.columns(inputs))
        self.added: list[tuple[Effect, tuple[int, ...]]] = []
        self.covered: dict[str, set] = {}
        #: candidates of the current round left out as degenerate (see :meth:`_degenerate`)
        self.skipped: list[dict] = []

    def _compare(self, base: CVScore, score: CVScore, effect: Effect | None = None
                 ) -> Comparison:
        params = list(range(len(base.columns), len(score.columns)))
        if effect is not None:
            mask = effect.tested()
            if len(mask) == len(params) and not all(mask):
                params = [p for p, keep in zip(params, mask) if keep]
        return compare(base, score, params, self._se(score, params))

    def _se(self, score: CVScore, params):
        return model_covariance(self.gram, score, params, self.blocks)

    # -- scoring ---------------------------------------------------------------------
    @property
    def base_cols(self) -> list[int]:
        return [c for _, cols in self.added for c in cols]

    def _variant(self, family: str, effects: list[Effect], base: CVScore, trials: float = 1.0):
        z_comp, z_need = _look_elsewhere(self.settings.z_component, trials), \
            _look_elsewhere(self.settings.z_min, trials)
        base_cols = self.base_cols
        comp_cmp = {}
        chosen = []
        tried = []
        degenerate = set()
        for eff in effects:
            comp = _key(eff)
            if comp == "all":
                chosen.append(eff)
                continue
            if comp in self.covered.get(family, set()):
                continue
            if self._degenerate(eff, base_cols):
                degenerate.add(comp)
                continue
            s = self.gram.score(base_cols + list(self.cols[eff]))
            cmp = self._compare(base, s, eff)
            comp_cmp[comp] = cmp.z
            tried.append((eff, cmp))
            if cmp.z >= z_comp:
                chosen.append(eff)
        if chosen and family == "offset":
            # the level is free in every component: every other term is judged with it
            chosen = [eff for eff in effects if _key(eff) not in self.covered.get(family, set())
                      and _key(eff) not in degenerate]
        if chosen and trials > 1:
            # the scanned hyper-parameter (step time, period) is established by the
            # components that passed the look-elsewhere threshold: the others are tested
            # at that fixed value
            chosen = [eff for eff, cmp in tried if cmp.z >= self.settings.z_component]
        if not chosen:
            return None
        cols = tuple(c for e in chosen for c in self.cols[e])
        merged = _merge(chosen)
        if self._degenerate(merged, base_cols, cols):
            return None
        score = self.gram.score(base_cols + list(cols))
        return _Candidate(merged, cols, score, self._compare(base, score, merged), comp_cmp,
                          family, z_need, trials=trials,
                          implausible=self._implausible(merged, score.beta[len(base_cols):]))

    def _degenerate(self, effect: Effect, base_cols, cols=None) -> bool:
        """Whether the effect's columns add no direction of their own to ``base_cols``
        (:func:`~magcal.discover.selection.orthogonal_share` below ``min_orthogonal``);
        if so it is noted in :attr:`skipped` with the share."""
        cols = list(self.cols[effect] if cols is None else cols)
        share = orthogonal_share(self.gram, base_cols, cols)
        if share >= self.settings.min_orthogonal:
            return False
        entry = {"name": effect.name, "components": list(effect.components),
                 **effect.hyper(), "orthogonal_share": share,
                 "reason": (f"its columns lie in the span of the effects already in (the "
                            f"part orthogonal to them is {share:.1e} of their norm, below "
                            f"{self.settings.min_orthogonal:g}): the joint fit cannot tell "
                            "it from them")}
        if entry not in self.skipped:
            self.skipped.append(entry)
        return True

    def _beside(self, family: str, effect: Effect) -> list[int]:
        """Columns of the local-time (diurnal) field, richest variant, on the components
        a model-proportional term (scale, rotation) touches and where no diurnal term is
        in yet: at a fixed position the model field varies mostly with local time, so
        ``s * B_model`` is largely a local-time term and can stand in for a field the
        model lacks (or the reverse)."""
        if family not in ("scale", "rotation") or "diurnal" not in self.settings.vocabulary:
            return []
        comps = (self.inputs.components if isinstance(effect, Rotation)
                 else effect.components)
        have = self.covered.get("diurnal", set())
        out: list[int] = []
        for fam, variants in self.families:
            if fam == "diurnal":
                out += [c for eff in variants[-1]
                        if eff.components[0] in comps and eff.components[0] not in have
                        for c in self.cols[eff]]
        return out

    def _z_beside(self, beside: list[int], cand: _Candidate) -> float:
        """Significance (z) of the candidate's coefficients in the fit with the
        ``beside`` columns free too: what it adds beyond a local-time field (0 when its
        columns lie in their span)."""
        cols = list(cand.columns)
        base = self.base_cols + list(beside)
        if orthogonal_share(self.gram, base, cols) < self.settings.min_orthogonal:
            return 0.0
        return self._compare(self.gram.score(base), self.gram.score(base + cols),
                             cand.effect).z

    def _implausible(self, effect: Effect, beta) -> str:
        """Why fitted values are outside what the effect can physically be ('' if not)."""
        beta = np.abs(np.asarray(beta, dtype=float))
        if isinstance(effect, Scale) and beta.size and beta.max() > self.settings.max_scale:
            return (f"scale {beta.max():.3g} beyond the plausible {self.settings.max_scale:g} "
                    "(the model-proportional signature stands in for something else)")
        if isinstance(effect, Rotation) and beta.size and \
                np.rad2deg(beta.max()) > self.settings.max_rotation_deg:
            return (f"rotation {np.rad2deg(beta.max()):.3g} deg beyond the plausible "
                    f"{self.settings.max_rotation_deg:g} deg")
        return ""

    def _family(self, family: str, variants, base: CVScore):
        if family in ("rotation",) and family in self.covered:
            return None
        cands = [c for c in (self._variant(family, v, base) for v in variants) if c is not None]
        if not cands:
            return None
        passing = [c for c in cands if c.significant]
        if not passing:
            return max(cands, key=lambda c: c.comparison.z)
        pick = passing[0]
        k = len(self.base_cols)
        for richer in passing[1:]:
            # the richer variant's extra coefficients (e.g. higher harmonics) must be significant
            have = set(pick.effect.labels())
            extra = [k + i for i, lab in enumerate(richer.effect.labels()) if lab not in have]
            if wald_test(richer.score, extra, self._se(richer.score, extra))[0] \
                    >= self.settings.z_variant:
                pick = richer
        return pick

    def _dynamic(self, residual: np.ndarray, base: CVScore):
        """Step and periodic candidates whose hyper-parameters are scanned now."""
        inputs = self.inputs
        out = []
        span = float(inputs.times_s[-1] - inputs.times_s[0])
        vocab = self.settings.vocabulary
        fams = []
        comps = inputs.components
        if "step" in vocab:
            # change points of level searched in every component (ruptures); each time
            # is tried in every component: those that pass the look-elsewhere threshold
            # at it establish it, the others are tested at that fixed time (:meth:`_variant`)
            steps = [self._scanned("step", [Step(components=(c,), t_step_s=t_step)
                                            for c in comps], base, n_step_trials(span))
                     for t_step, _ in _distinct_times(change_points(inputs.times_s, residual,
                                                                    kind="step"))]
            out += [c for c in steps if c is not None]
            shared = max((c for c in out if len(c.effect.components) > 1),
                         key=lambda c: c.comparison.gain, default=None)
            if shared is not None:
                # a step several components share is placed by all of them together: tried
                # at that time too, the held-out gain chooses
                cols = [comps.index(c) for c in shared.effect.components]
                t_joint = joint_step_time(inputs.times_s, residual[:, cols])
                if t_joint is not None and t_joint != shared.effect.t_step_s:
                    cand = self._scanned("step", [Step(components=(c,), t_step_s=t_joint)
                                                  for c in comps], base, n_step_trials(span))
                    if cand is not None:
                        out.append(cand)
        if "drift" in vocab:
            t_ref = float(0.5 * (inputs.times_s[0] + inputs.times_s[-1]))
            drifting = self.covered.get("drift", set())
            for t_break, _ in _distinct_times(change_points(inputs.times_s, residual,
                                                            kind="slope"), most=2):
                # tried in every component, as a step time is; those with a drift already
                # get the hinge alone, the others the hinge beside a rate (one family
                # each: a family's columns are uniform)
                for with_rate in (True, False):
                    group = [c for c in comps if (c not in drifting) == with_rate]
                    if group:
                        fams.append(("drift_break", [
                            Drift(components=(c,), t_ref_s=t_ref, t_break_s=t_break,
                                  with_rate=with_rate) for c in group], n_step_trials(span)))
        if "periodic" in vocab:
            peaks = scan_periods(inputs.times_s, residual,
                                 exclude_daily=inputs.local_time_h is not None,
                                 n_peaks=self.settings.n_periods)
            for period_s, _ in peaks:
                fams.append(("periodic", [Periodic(components=(c,), period_s=period_s)
                                          for c in inputs.components], n_period_trials(span)))
        for family, effects, trials in fams:
            cand = self._scanned(family, effects, base, trials)
            if cand is not None:
                out.append(cand)
        return out

    def _scanned(self, family: str, effects: list[Effect], base: CVScore, trials: float):
        """:meth:`_variant` of per-component effects at a scanned hyper-parameter value,
        their columns added to the Gram matrix in one chunk (crossed with each other and
        with the base only)."""
        blocks = [eff.columns(self.inputs) for eff in effects]
        idx = self.gram.add(np.concatenate(blocks, axis=0), against=self.base_cols)
        start = 0
        for eff, blk in zip(effects, blocks):
            self.cols[eff] = idx[start:start + len(blk)]
            start += len(blk)
        return self._variant(family, effects, base, trials)

    def _signal(self, cand: _Candidate, centred: bool = True) -> np.ndarray:
        k = len(self.base_cols)
        f = self.gram.fitted(cand.columns, cand.score.beta[k:])
        mask = self.gram.mask
        if not centred:
            return np.where(mask, f, 0.0)
        mean = np.where(mask, f, 0).sum(axis=0) / np.maximum(mask.sum(axis=0), 1)
        return np.where(mask, f - mean, 0.0)  # centred: offsets do not make signals alike

    # -- the loop ----------------------------------------------------------------------
    def run(self):
        s = self.settings
        gram = self.gram
        n_valid = gram.n_valid
        base = gram.score([])
        residual = gram.residual([], [])
        effects_log = []
        rounds = []
        stopped = None
        while True:
            if len(self.added) >= s.max_effects:
                stopped = f"max_effects ({s.max_effects}) reached"
                break
            cands = []
            self.skipped = []
            for family, variants in self.families:
                c = self._family(family, variants, base)
                if c is not None:
                    cands.append(c)
            cands += self._dynamic(residual, base)
            rounds.append({"round": len(rounds) + 1, "candidates": [
                {"name": c.name, "components": list(c.effect.components),
                 "n_params": len(c.columns), "trials": c.trials,
                 "log_p_corrected": c.log_p_corrected,
                 **({"implausible": c.implausible} if c.implausible else {}),
                 **c.effect.hyper(), **c.comparison.as_dict()}
                for c in sorted(cands, key=lambda c: -c.comparison.gain)]})
            if self.skipped:
                rounds[-1]["skipped"] = list(self.skipped)
            passing = [c for c in cands if c.passes]
            if not passing:
                named = [c for c in cands if c.significant and c.implausible]
                if named:
                    best = max(named, key=lambda c: c.comparison.z)
                    stopped = (f"the only candidates beyond chance are implausible: "
                               f"{best.name}, {best.implausible}")
                elif cands:
                    best = max(cands, key=lambda c: c.comparison.z - c.z_needed)
                    stopped = (f"no candidate's held-out gain is beyond chance (best "
                               f"remaining: {best.name}, z = {best.comparison.z:.1f}, needs "
                               f"{best.z_needed:.1f})")
                else:
                    stopped = "no candidate's held-out gain is beyond chance"
                break
            # one criterion for every effect: the held-out gain over contiguous blocks;
            # among the candidates whose gain is beyond chance (Wald test under the
            # correlated-noise model), the largest
            win = max(passing, key=lambda c: c.comparison.gain)
            if not self.added:
                # the level comes first: every other term is judged with the offset free
                win = next((c for c in passing if c.name == "offset"), win)
            # reported beside the criterion: the BIC with the effective sample size (the
            # level's signal is all mean: centred, nothing of it was left)
            level = win.family == "offset"
            win.n_eff = regression_n_eff(residual, self._signal(win, centred=not level),
                                         centre_signal=not level)
            win.delta_bic = delta_bic_eff(base.sse_in, win.score.sse_in, len(win.columns),
                                          win.n_eff)
            evidence = self._evidence(win, cands, base, residual, n_valid)
            if win.family in ("step", "periodic", "drift_break"):
                # scanned candidates were crossed with the base only: add them in full
                cols = gram.add(win.effect.columns(self.inputs))
                win = dataclasses.replace(win, columns=cols,
                                          score=gram.score(self.base_cols + list(cols)))
            gap_before = profile_gap(self.inputs, residual, spectrum=False)
            rms_before = float(np.sqrt(base.sse_in / n_valid))
            self.added.append((win.effect, win.columns))
            if not win.effect.coupled:
                self.covered.setdefault(win.family, set()).update(win.effect.components)
                if win.family == "drift_break":  # the rate came with it
                    self.covered.setdefault("drift", set()).update(win.effect.components)
            else:
                self.covered.setdefault(win.family, set()).add("all")
            base = win.score
            residual = gram.residual(self.base_cols, base.beta)
            rms_after = float(np.sqrt(base.sse_in / n_valid))
            effects_log.append((win.effect, win.columns, rms_before, rms_after, evidence,
                                gap_before))
            dropped = self._drop_implausible(base)
            if dropped:
                # a scale or rotation whose value in the joint fit left the plausible
                # range was standing in for the effect just added (or for one another):
                # it is taken out and not tried again
                effects_log, base, residual = self._after_removal(effects_log, n_valid)
                rounds[-1]["dropped"] = dropped
        if stopped is None:  # pragma: no cover - the loop always sets it
            stopped = "stopped"
        retracted = self._retract_steps(base)
        if retracted:
            # a step that won its round by standing in for effects added after it (a drift
            # its components shared, then unmodelled) is not beyond chance beside them
            effects_log, base, residual = self._after_removal(effects_log, n_valid)
            rounds.append({"round": len(rounds) + 1, "candidates": [],
                           "retracted": retracted})
        fitted = []
        k = 0
        dof = gram.jackknife_dof(self.base_cols)
        for eff, cols, rb, ra, ev, gb in effects_log:
            q = len(cols)
            when = None
            if isinstance(eff, Step):  # how well the data place it in time
                when = step_time_interval(self.inputs.times_s, self._own(residual, eff),
                                          eff.t_step_s, base.beta[k:k + q])
            elif isinstance(eff, Drift) and eff.t_break_s is not None:  # and a drift's break
                change = [b for (_, lab), b in zip(eff.labels(), base.beta[k:k + q])
                          if lab == "rate_change_nT_per_day"]
                when = break_time_interval(self.inputs.times_s, self._own(residual, eff),
                                           eff.t_break_s, change)
            fitted.append(FittedEffect(eff, base.beta[k:k + q], base.beta_std[k:k + q],
                                       rb, ra, ev, gb, beta_dof=dof[k:k + q],
                                       time_ci95_s=when))
            k += q
        return fitted, residual, stopped, rounds

    def _own(self, residual: np.ndarray, eff) -> np.ndarray:
        """The columns of ``residual`` of the effect's own components."""
        return residual[:, [self.inputs.components.index(c) for c in eff.components]]

    def _restate(self, log: list, n_valid: int) -> list:
        """The RMS before and after each kept effect, recomputed without the dropped ones."""
        out = []
        cols: list[int] = []
        rms = float(np.sqrt(self.gram.score([]).sse_in / n_valid))
        for eff, c, _, _, ev, gb in log:
            cols += list(c)
            after = float(np.sqrt(self.gram.score(cols).sse_in / n_valid))
            out.append((eff, c, rms, after, ev, gb))
            rms = after
        return out

    def _after_removal(self, effects_log: list, n_valid: int) -> tuple:
        """The log restated for the effects still in, and their joint fit and residual,
        once effects were taken out (implausible ones, retracted steps)."""
        keep = {id(e) for e, _ in self.added}
        effects_log = self._restate([entry for entry in effects_log if id(entry[0]) in keep],
                                    n_valid)
        base = self.gram.score(self.base_cols)
        return effects_log, base, self.gram.residual(self.base_cols, base.beta)

    def _retract_steps(self, base: CVScore) -> list[dict]:
        """Re-test every added step in the final joint fit, weakest first, and remove
        those whose Wald z no longer reaches the look-elsewhere threshold they were named
        at; return what was removed and why.

        The loop is greedy: a step can win its round by absorbing a trend its
        components still had (a linear drift is half a step's signal), and the drift
        named a round later then takes that part back. Judged beside everything named,
        such a step is no longer beyond chance.
        """
        out = []
        span = float(self.inputs.times_s[-1] - self.inputs.times_s[0])
        z_need = _look_elsewhere(self.settings.z_min, n_step_trials(span))
        while True:
            weakest = None
            k = 0
            for eff, cols in self.added:
                q = len(cols)
                if isinstance(eff, Step):
                    params = list(range(k, k + q))
                    z = wald_test(base, params, self._se(base, params))[0]
                    if z < z_need and (weakest is None or z < weakest[1]):
                        weakest = (eff, z)
                k += q
            if weakest is None:
                return out
            eff, z = weakest
            out.append({"name": eff.name, "components": list(eff.components),
                        **eff.hyper(), "z_joint": float(z), "z_needed": float(z_need),
                        "reason": "beside the effects named after it, not beyond chance"})
            self.added = [(e, c) for e, c in self.added if e is not eff]
            base = self.gram.score(self.base_cols)

    def _drop_implausible(self, base: CVScore) -> list[dict]:
        """Remove added effects whose coefficients in the joint fit ``base`` are outside
        the plausible range; return what was removed and why."""
        out = []
        k = 0
        kept = []
        for eff, cols in self.added:
            why = self._implausible(eff, base.beta[k:k + len(cols)])
            k += len(cols)
            if why:
                out.append({"name": eff.name, "components": list(eff.components),
                            "reason": f"in the joint fit: {why}"})
                self.covered.setdefault(eff.name, set()).update(
                    {"all"} if eff.coupled else set(eff.components))
            else:
                kept.append((eff, cols))
        self.added = kept
        return out

    def _evidence(self, win: _Candidate, cands, base: CVScore, residual, n_valid) -> dict:
        s = self.settings
        n_eff = win.n_eff
        ev = {"criterion": "leave-one-block-out cross-validation gain, beyond chance by the "
                           "Wald test under the correlated-noise model",
              "block_s": s.block_s,
              **win.comparison.as_dict(),
              "cv_rms_before_nT": float(np.sqrt(base.sse_cv / n_valid)),
              "cv_rms_after_nT": float(np.sqrt(win.score.sse_cv / n_valid)),
              "z_needed": win.z_needed,
              "n_params": len(win.columns),
              "n_eff": n_eff,
              "delta_bic_eff": win.delta_bic,
              "component_z": win.component_z,
              "ambiguous": False, "ambiguous_with": [], "preferred_over": {}}
        beside = self._beside(win.family, win.effect)
        if beside:
            # a model-proportional term that adds nothing beyond a local-time field could
            # be that field: on a short record (the model varies mostly with local time)
            # or whenever the record cannot separate them. Named by the criterion, but
            # said to be ambiguous with it
            z_lt = self._z_beside(beside, win)
            ev["z_beside_local_time"] = z_lt
            if z_lt < s.z_min:
                ev["ambiguous_with"].append("diurnal")
                ev.setdefault("ambiguous_detail", {})["diurnal"] = {
                    "z_beside_local_time": z_lt,
                    "reason": "adds nothing beyond chance to a local-time field fitted "
                              "beside it"}
        others = sorted((c for c in cands if c is not win),
                        key=lambda c: -c.comparison.gain)
        # the best candidate of another effect: the same effect at another step time or
        # period (the scans try several) says nothing about what else could explain it
        ru = next((c for c in others if c.name != win.name), None)
        if ru is not None:
            ev["runner_up"] = {"name": ru.name, "components": list(ru.effect.components),
                               **ru.comparison.as_dict()}
        f_win = self._signal(win)
        n_win = np.sqrt(f_win.reshape(-1) @ f_win.reshape(-1))
        for c in others:
            if c.name == win.name or c.comparison.gain <= 0 or \
                    c.comparison.z < s.z_component:
                continue
            f_c = self._signal(c)
            n_c = np.sqrt(f_c.reshape(-1) @ f_c.reshape(-1))
            if n_win == 0 or n_c == 0:
                continue
            corr = float(f_win.reshape(-1) @ f_c.reshape(-1) / (n_win * n_c))
            if abs(corr) < s.confound_corr:
                continue
            z_pair = paired_z(c.score, win.score)
            if z_pair < s.z_ambiguous:
                if c.name not in ev["ambiguous_with"]:
                    ev["ambiguous_with"].append(c.name)
                    ev.setdefault("ambiguous_detail", {})[c.name] = {
                        "signal_corr": corr, "z_vs_winner": z_pair}
            else:
                prev = ev["preferred_over"].get(c.name)
                if prev is None or z_pair < prev["z_vs_winner"]:
                    ev["preferred_over"][c.name] = {"signal_corr": corr, "z_vs_winner": z_pair}
        ev["ambiguous"] = bool(ev["ambiguous_with"])
        return ev


def discover(inputs: EffectInputs, measured, settings: DiscoverySettings | None = None,
             longitude_deg: float | None = None) -> DiscoveryResult:
    """Run the discovery loop on arrays.

    Parameters
    ----------
    inputs : EffectInputs
        Times, model field, components, covariates, local time.
    measured : ndarray, shape (n, m)
        Measured field in nT on the same samples (NaN where missing).
    settings : DiscoverySettings, optional
    longitude_deg : float, optional
        Kept in the result for :meth:`DiscoveryResult.augmented_model`.

    Returns
    -------
    DiscoveryResult
    """
    settings = settings or DiscoverySettings()
    y = np.asarray(measured, dtype=float) - inputs.model
    loop = _Loop(inputs, y, settings)
    residual0 = loop.gram.residual([], [])
    fitted, residual, stopped, rounds = loop.run()
    from magcal.discover.amplitude import effect_amplitudes

    amps, amp_noise = effect_amplitudes(inputs, measured, fitted)
    fitted = [dataclasses.replace(f, amplitude=a) for f, a in zip(fitted, amps)]
    gap0 = profile_gap(inputs, residual0)
    gap1 = profile_gap(inputs, residual)
    return DiscoveryResult(
        components=tuple(inputs.components), gap_initial=gap0, effects=tuple(fitted),
        gap_final=gap1, stopped_because=stopped, settings=settings.as_dict(),
        longitude_deg=longitude_deg, rounds=tuple(rounds), times_s=inputs.times_s,
        local_time_h=inputs.local_time_h, residual_initial=residual0,
        residual_final=residual, amplitude_noise=amp_noise)


def discover_gap(measured, model, covariates=None, longitude_deg=None, max_effects: int = 8,
                 rng=None, settings: DiscoverySettings | None = None,
                 screen: bool = True) -> DiscoveryResult:
    """Find, name and add what a model is missing (CONTRACTS §5).

    Parameters
    ----------
    measured, model : pandas.DataFrame
        UTC time index and the same component columns (e.g. ``Hp, He, Hn``); joined
        on their common times.
    covariates : pandas.DataFrame, optional
        Any of ``temperature`` (deg C), ``kp``, ``dst`` (nT), ``lon_deg``, ``phase`` (rad),
        on the measured times or interpolated onto them.
    longitude_deg : float, optional
        Spacecraft east longitude for local time (else the ``lon_deg`` covariate).
    max_effects : int
        Most effects to add.
    rng : numpy.random.Generator, optional
        Not used: the loop is deterministic. Accepted for a uniform call signature.
    settings : DiscoverySettings, optional
        Thresholds; ``max_effects`` overrides its field.
    screen : bool
        Leave out the spikes of measured - model, magnitudes implausible against the
        model (fills), clipped and stuck runs first
        (:func:`magcal.discover.inputs.screen_samples`); the result's ``screened`` says
        how many by test and where the first was.

    Returns
    -------
    DiscoveryResult

    Notes
    -----
    Covariates are checked (:func:`magcal.discover.inputs.prepare_covariates`): values
    outside their physical range are missing; a covariate is not extrapolated beyond its
    span nor bridged over its long holes, and the samples it does not cover are left out
    (``screened["covariate_unknown"]``), unless it covers fewer than three quarters of
    them and less than two weeks of data
    (:data:`~magcal.discover.inputs.MIN_COVARIATE_SHARE`, ``MIN_COVARIATE_DAYS``): it is
    then not used.
    ``covariates`` and ``columns_not_used`` of the result say what was used.

    Examples
    --------
    >>> import pandas as pd
    >>> t = pd.date_range("2019-11-01", periods=14 * 1440, freq="1min", tz="UTC")
    >>> g = np.random.default_rng(0)
    >>> model = pd.DataFrame({"Hp": 100.0 + 0 * t.hour, "He": 0.0 * t.hour}, index=t)
    >>> lt = (t.hour + t.minute / 60 + 128.2 / 15) % 24
    >>> meas = model + np.column_stack([3 * np.cos(2 * np.pi * (lt - 12) / 24),
    ...                                 0 * lt]) + g.normal(0, 1, (len(t), 2))
    >>> res = discover_gap(meas, model, longitude_deg=128.2)
    >>> res.names[0], res.effect("diurnal").components
    ('diurnal', ('Hp',))
    """
    import dataclasses

    from magcal.discover.inputs import (align_frames, build_inputs, columns_not_used,
                                        prepare_covariates, screen_samples, to_unix_seconds)

    settings = dataclasses.replace(settings or DiscoverySettings(), max_effects=int(max_effects))
    meas, mod, comps = align_frames(measured, model)
    screened = {}
    if screen:
        meas, screened = screen_samples(meas, mod)
    # rows of one file at times the other lacks (a 5-min model beside 1-min data) are
    # not used: counted, not dropped unsaid
    unmatched = {"measured": int(len(measured.index.difference(meas.index))),
                 "model": int(len(model.index.difference(meas.index)))}
    if any(unmatched.values()):
        screened = dict(screened, no_common_time=unmatched)
    lon = longitude_deg
    cov, unknown, cov_report = prepare_covariates(to_unix_seconds(meas.index), covariates, lon)
    if unknown.any():
        # the rows go: a made-up covariate value must not enter any column of any
        # candidate (their correlations and scans use every row, not only the
        # finite residuals)
        had = np.isfinite(meas.to_numpy(dtype=float)).any(axis=1)
        screened = dict(screened, covariate_unknown=int((unknown & had).sum()))
        meas, mod = meas[~unknown], mod[~unknown]
        cov = {name: v[~unknown] for name, v in cov.items()}
    inputs, _ = build_inputs(meas.index, mod, comps, cov or None, lon)
    result = discover(inputs, meas[list(comps)].to_numpy(dtype=float), settings,
                      longitude_deg=lon)
    return dataclasses.replace(result, screened=screened, covariates=cov_report,
                               columns_not_used=columns_not_used(measured, model, comps))
