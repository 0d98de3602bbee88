"""The ``spincal`` and ``flipper`` products from a checked :class:`~magcal.spin.inputs.SpinData`.

Both verbs read the record with :func:`magcal.spin.inputs.load_spin_data`, which
checks the model's assumptions and brings a negatively spinning triad into the
positive sense; the fits run in that frame and the calibration is turned back into
the file's sensor frame here.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from magcal.errors import InputError
from magcal.io.jsonio import product_dict
from magcal.spin.inputs import SENSE_FLIP, SpinData
from magcal.spin.ripple import PARAM_NAMES, SpinCalibration, fit_spin_ripple

#: Sign each of the 12 parameters takes under ``SENSE_FLIP`` (c_ij -> r_i r_j c_ij).
_R = np.diag(SENSE_FLIP)
_PARAM_SIGN = np.concatenate([np.outer(_R, _R).ravel(), _R])


#: A spin tone (one component, one harmonic) is worse after calibration when it exceeds
#: its value before by more than this many noise floors (the scatter the ambient field
#: alone gives the block average). One floor: on the Galileo-like sample with 0.5 %
#: unscreened spikes the 2x tone of BY rose from 0.46 to 0.76 nT on a 0.28 nT floor,
#: while on clean records every tone falls far below its value before.
WORSE_NOISE_FLOORS = 1.0


@dataclass(frozen=True)
class SpinCalProduct:
    """CAL.json: the calibration plus how the phase and units were resolved.

    ``delivery`` says which calibration CAL.json carries: the fitted one, or the prior
    (identity and zero offsets without ``--prior``) when the fitted one left a larger
    spin tone than the prior (never worse than the input; :func:`tone_worse`), with
    the fitted numbers kept for diagnosis. ``screened`` counts the rows the quality
    screen left out (:func:`magcal.spin.screen.screen_spin`).
    """

    calibration: SpinCalibration
    spin_phase: dict = field(default_factory=dict)
    n_rows_missing_values: int = 0
    screened: dict | None = None
    delivery: dict = field(default_factory=lambda: {"delivered": "fitted", "reason": None})

    @property
    def warnings(self) -> tuple:
        """Sentences the user must see (the prior delivered instead of the fit)."""
        if self.delivery.get("delivered") != "prior":
            return ()
        return (f"calibration not delivered, the prior is: {self.delivery['reason']}",)

    def to_json(self) -> dict:
        """CAL.json payload (CONTRACTS §4 keys, then ``spin_phase``, ``screened``,
        ``delivered``)."""
        out = self.calibration.to_json()
        out["spin_phase"] = self.spin_phase
        out["n_rows_missing_values"] = self.n_rows_missing_values
        if self.screened is not None:
            out["screened"] = self.screened
        out["delivered"] = self.delivery["delivered"]
        out["delivered_reason"] = self.delivery["reason"]
        if "fitted" in self.delivery:
            out["fitted"] = self.delivery["fitted"]
        out["warnings"] = list(self.warnings)
        return product_dict(out)


def tone_worse(before: dict, after: dict, noise: dict,
               n_floors: float = WORSE_NOISE_FLOORS) -> list:
    """The spin tones the calibration made worse: ``[(component, harmonic, before,
    after), ...]`` where ``after > before + n_floors * noise`` (harmonic 1 = 1x spin).

    Examples
    --------
    >>> tone_worse({"BX": [1.0, 0.05]}, {"BX": [0.01, 0.34]}, {"BX": [0.01, 0.29]})
    [('BX', 2, 0.05, 0.34)]
    >>> tone_worse({"BX": [1.0, 0.05]}, {"BX": [0.01, 0.30]}, {"BX": [0.01, 0.29]})
    []
    """
    out = []
    for comp, values in after.items():
        for h, (a, b0, fl) in enumerate(zip(values, before[comp], noise[comp]), start=1):
            floor = fl if np.isfinite(fl) else 0.0
            if a > b0 + n_floors * floor:
                out.append((comp, h, b0, a))
    return out


def _deliver(cal: SpinCalibration, c0, o0) -> tuple:
    """The calibration to deliver and the delivery record: the fitted one unless it
    leaves a spin tone worse than the prior's, then the prior (never worse than the
    input)."""
    worse = tone_worse(cal.spin_tone_before_nT, cal.spin_tone_after_nT,
                       cal.spin_tone_noise_nT)
    if not worse:
        return cal, {"delivered": "fitted", "reason": None}
    tones = ", ".join(f"{c} {h}x {b:.3g} -> {a:.3g} nT" for c, h, b, a in worse)
    reason = (f"the fitted calibration leaves a larger spin tone than the prior ({tones}; "
              f"beyond {WORSE_NOISE_FLOORS:g} noise floors): the data do not support it "
              "(unscreened disturbances, or a record the ripple model does not describe)")
    fitted = {"coupling": cal.coupling.tolist(), "offsets": cal.offsets_nT.tolist(),
              "determined": list(cal.determined), "std": dict(cal.std),
              "spin_tone_after_nT": cal.spin_tone_after_nT}
    prior = dataclasses.replace(
        cal, coupling=np.array(c0, dtype=float), offsets_nT=np.array(o0, dtype=float),
        determined=(), fixed=tuple(PARAM_NAMES), std={}, covariance=np.zeros((0, 0)),
        spin_tone_after_nT=cal.spin_tone_before_nT,
        notes=tuple(cal.notes) + ("prior delivered: " + reason,))
    return prior, {"delivered": "prior", "reason": reason, "fitted": fitted}


def _numbers(value, shape: tuple, what: str) -> np.ndarray:
    """``value`` as a finite float array of ``shape``; InputError naming ``what`` otherwise."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        arr = None
    if arr is None or arr.shape != shape or not np.all(np.isfinite(arr)):
        raise InputError(f"{what} must be {' x '.join(map(str, shape))} finite numbers",
                         column=what)
    return arr


def _unflip(cal: SpinCalibration) -> SpinCalibration:
    """Turn a calibration fitted in the ``SENSE_FLIP`` frame back into the file's frame."""
    sign = dict(zip(PARAM_NAMES, _PARAM_SIGN))
    cov_sign = np.array([sign[n] for n in cal.determined])
    note = ("negative spin sense: fitted with the triad turned 180 deg about sensor 1 "
            "(b2, b3 negated); C and O are given in the file's sensor frame, the spin "
            "tones about -b3")
    return dataclasses.replace(
        cal, coupling=SENSE_FLIP @ cal.coupling @ SENSE_FLIP,
        offsets_nT=SENSE_FLIP @ cal.offsets_nT,
        covariance=np.asarray(cal.covariance) * np.outer(cov_sign, cov_sign),
        bias_correction={n: sign[n] * v for n, v in cal.bias_correction.items()},
        bias_estimate={n: sign[n] * v for n, v in cal.bias_estimate.items()},
        leakage_correction={n: sign[n] * v for n, v in cal.leakage_correction.items()},
        notes=tuple(cal.notes) + (note,))


def spincal(data: SpinData, *, coupling0=None, offsets0=None, n_harmonics: int = 2,
            spins_per_block: int = 1, flip_state: int = 0,
            provenance: dict | None = None) -> SpinCalProduct:
    """Spin-ripple calibration of a checked record (``magcal spincal``).

    Parameters
    ----------
    data : SpinData
        From :func:`magcal.spin.inputs.load_spin_data`.
    coupling0, offsets0 : array_like, optional
        Priors in the file's sensor frame (nT after the data's scale).
    n_harmonics, spins_per_block : int
        See :func:`magcal.spin.ripple.fit_spin_ripple`.
    flip_state : int
        With a flip column, the rows calibrated.
    provenance : dict, optional

    Returns
    -------
    SpinCalProduct
    """
    c0 = np.eye(3) if coupling0 is None else _numbers(coupling0, (3, 3), "coupling")
    o0 = np.zeros(3) if offsets0 is None else _numbers(offsets0, (3,), "offsets")
    c0_file, o0_file = c0, o0
    if data.sense < 0:
        c0, o0 = SENSE_FLIP @ c0 @ SENSE_FLIP, SENSE_FLIP @ o0
    sel = np.ones(data.t_s.size, dtype=bool)
    if data.flip is not None:
        sel = data.flip == flip_state
        if not sel.any():
            raise InputError(f"no rows with flip = {flip_state}", file=data.source,
                             column="flip")
    try:
        cal = fit_spin_ripple(data.t_s[sel], data.b[sel], data.phase[sel], coupling0=c0,
                              offsets0=o0, n_harmonics=n_harmonics,
                              spins_per_block=spins_per_block, provenance=provenance)
    except InputError as exc:
        raise InputError(exc.message, file=data.source, column=exc.column) from None
    if data.sense < 0:
        cal = _unflip(cal)
    cal, delivery = _deliver(cal, c0_file, o0_file)
    return SpinCalProduct(calibration=cal, spin_phase=data.phase_record(),
                          n_rows_missing_values=data.n_missing_rows,
                          screened=data.screened, delivery=delivery)


@dataclass(frozen=True)
class FlipperProduct:
    """FLIP.json: the flipper result plus how the phase and units were resolved."""

    result: object
    spin_phase: dict = field(default_factory=dict)
    screened: dict | None = None

    def to_json(self) -> dict:
        """FLIP.json payload (CONTRACTS §4 keys, then ``spin_phase`` and ``screened``)."""
        out = self.result.to_json()
        out["spin_phase"] = self.spin_phase
        if self.screened is not None:
            out["screened"] = self.screened
        return product_dict(out)


def flipper(data: SpinData, *, coupling=None, offsets=None, covariance=None, determined=(),
            provenance: dict | None = None) -> FlipperProduct:
    """Spin-axis offset ``O3`` from the flipper intervals of a checked record.

    ``covariance`` and ``determined`` (CAL.json's) carry the calibration's errors into
    ``O3_std`` (:func:`magcal.spin.flipper.flipper_offset`).

    Raises
    ------
    InputError
        No flip column, or a record spinning negatively about sensor 3 (the flipper
        geometry of :data:`magcal.spin.flipper.FLIP_MATRIX` assumes the positive sense).
    """
    from magcal.spin.flipper import flipper_offset

    if data.flip is None:
        raise InputError("no flip column: flipper intervals missing (need rows with flip = 1 "
                         "and flip = 0)", file=data.source, column="flip")
    if data.sense < 0:
        raise InputError("the flipper analysis assumes a positive spin about sensor 3; "
                         "this record spins the other way", file=data.source, column="b3")
    if coupling is not None:
        coupling = _numbers(coupling, (3, 3), "coupling")
        offsets = None if offsets is None else _numbers(offsets, (3,), "offsets")
    determined = tuple(determined or ())
    if determined:
        covariance = _numbers(covariance, (len(determined), len(determined)), "covariance")
    try:
        res = flipper_offset(data.t_s, data.b, data.phase, data.flip, coupling=coupling,
                             offsets=offsets, covariance=covariance if determined else None,
                             determined=determined, provenance=provenance)
    except InputError as exc:
        raise InputError(exc.message, file=data.source, column=exc.column) from None
    return FlipperProduct(result=res, spin_phase=data.phase_record(), screened=data.screened)


def complete_calibration(cal_doc: dict, o3: float, o3_std: float, source: str) -> dict:
    """A CAL.json document completed with the flipper's ``O3``.

    ``O1, O2`` move so that ``C (b - O)`` stays the same in the spin plane.
    """
    c = _numbers(cal_doc["coupling"], (3, 3), "coupling")
    o = _numbers(cal_doc["offsets"], (3,), "offsets")
    if abs(np.linalg.det(c[:2, :2])) < 1e-12:
        raise InputError("coupling's spin-plane block is singular", column="coupling")
    from magcal.spin.flipper import offsets_with_o3

    o_new = offsets_with_o3(c, o, o3)
    done = dict(cal_doc)
    done["offsets"] = o_new.tolist()
    done["determined"] = list(cal_doc.get("determined", [])) + ["O3"]
    done["fixed"] = [n for n in cal_doc.get("fixed", []) if n != "O3"]
    done["std"] = dict(cal_doc.get("std", {}), O3=o3_std)
    done["notes"] = list(cal_doc.get("notes", [])) + [
        f"O3 from the flipper ({source}): O1, O2 adjusted to keep the spin plane"]
    return done
