"""Thin estimator around the PiCoG chain, for multi-sensor DataFrames.

Frames follow CONTRACTS §0: a UTC DatetimeIndex and columns ``<sensor>_x/_y/_z`` in one
common frame (nT). Fitting works on a uniform time grid (rows missing from the file
become NaN samples, so scan windows always span ``window_s`` seconds); applying works
row by row.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from magcal.ac.bandcheck import BandCheck, band_check
from magcal.ac.chain import ChainResult, Plan, apply_weights, run_chain
from magcal.ac.plan import plan_to_dict
from magcal.errors import InputError
from magcal.io.jsonio import product_dict
from magcal.timeconv import epoch_seconds

COMPONENTS = ("x", "y", "z")


def require_common_frame(frame: pd.DataFrame, sensors) -> None:
    """Refuse sensors that the reader says are in different frames.

    PiCoG combines sensors component by component, so they must share one frame.
    Readers of instrument files that deliver each sensor in its own frame (GOES-R L2)
    record it in ``frame.attrs["sensor_frames"]``; ``magcal run`` rotates them into a
    common frame first (``[frames]``).

    Examples
    --------
    >>> f = pd.DataFrame(columns=["ib_x"])
    >>> f.attrs["sensor_frames"] = {"ib": "inboard sensor", "ob": "outboard sensor"}
    >>> require_common_frame(f, ["ib", "ob"])
    Traceback (most recent call last):
    ...
    magcal.errors.InputError: sensors ib (inboard sensor), ob (outboard sensor) are in different
    frames: PiCoG needs one common frame (rotate them first, e.g. with magcal run and a ...)
    """
    frames = frame.attrs.get("sensor_frames") or {}
    seen = {s: frames[s] for s in sensors if s in frames}
    if len(set(seen.values())) > 1:
        listed = ", ".join(f"{s} ({f})" for s, f in seen.items())
        raise InputError(f"sensors {listed} are in different frames: PiCoG needs one common "
                         "frame (rotate them first, e.g. with magcal run and a [frames] "
                         "section)")


def sensors_in_frame(frame: pd.DataFrame) -> list[str]:
    """Sensor names with all three ``_x/_y/_z`` columns, in column order.

    Examples
    --------
    >>> sensors_in_frame(pd.DataFrame(columns=["a_x", "a_y", "a_z", "b_x", "t"]))
    ['a']
    """
    out = []
    for c in frame.columns:
        if str(c).endswith("_x"):
            name = str(c)[:-2]
            if all(f"{name}_{k}" in frame.columns for k in COMPONENTS) and name not in out:
                out.append(name)
    return out


def sensor_array(frame: pd.DataFrame, sensor: str) -> np.ndarray:
    """``(n, 3)`` float array of one sensor; InputError naming the missing column."""
    cols = [f"{sensor}_{k}" for k in COMPONENTS]
    for c in cols:
        if c not in frame.columns:
            src = frame.attrs.get("source")
            raise InputError(f"sensor {sensor!r} is missing from the input (have: "
                             f"{', '.join(sensors_in_frame(frame)) or 'none'})",
                             file=src, column=c)
    return frame[cols].to_numpy(dtype=float)


#: Time-stamp resolutions tried by :func:`stamp_resolution_s` (s), coarsest first.
STAMP_RESOLUTIONS_S = (1.0, 0.1, 0.01, 1e-3, 1e-4, 1e-5)


def stamp_resolution_s(t_s: np.ndarray) -> float:
    """Resolution of the time stamps: the coarsest of :data:`STAMP_RESOLUTIONS_S` that
    every time (relative to the first) is a multiple of, else 0.

    Examples
    --------
    >>> stamp_resolution_s(np.array([0.0, 0.008, 0.016, 0.023]))
    0.001
    """
    rel = np.asarray(t_s, dtype=float) - float(t_s[0])
    for r in STAMP_RESOLUTIONS_S:
        q = rel / r
        # epoch seconds as float64 carry about 0.2 us of rounding
        if np.all(np.abs(q - np.round(q)) * r < 1e-6 + 1e-9 * r):
            return r
    return 0.0


@dataclass(frozen=True)
class TimeGrid:
    """A uniform time grid fitted to sample times (least squares start and spacing).

    ``slots`` maps each sample to its grid index; ``jitter`` is sample time minus grid
    time. Samples are accepted when ``|jitter| <= tolerance_s``, with ``tolerance_s =
    resolution_s / 2 + tolerance_fraction * dt_s``: rounding the stamps to their
    resolution moves them by up to half of it, and the fraction of the spacing allows
    for clock jitter that cannot move a sample into the next slot.
    """

    slots: np.ndarray
    n_grid: int
    t0_s: float
    dt_s: float
    resolution_s: float
    tolerance_s: float
    jitter_rms_s: float
    jitter_max_s: float
    n_missing: int

    @property
    def times_s(self) -> np.ndarray:
        """Grid times (s, the same base as the input times)."""
        return self.t0_s + self.dt_s * np.arange(self.n_grid)

    def place(self, values) -> np.ndarray:
        """``values`` (one row per input sample) on the grid, NaN in the empty slots.

        Examples
        --------
        >>> grid = fit_time_grid(np.array([0.0, 1.0, 2.0, 4.0, 5.0, 6.0]))
        >>> grid.place(np.arange(6.0)[:, None]).ravel()
        array([ 0.,  1.,  2., nan,  3.,  4.,  5.])
        """
        values = np.asarray(values, dtype=float)
        out = np.full((self.n_grid,) + values.shape[1:], np.nan)
        out[self.slots] = values
        return out

    def to_dict(self) -> dict:
        """JSON-ready summary (kept as ``time_grid`` in PARAMS.json)."""
        return {"dt_s": self.dt_s, "rate_hz": 1.0 / self.dt_s, "n_samples": int(len(self.slots)),
                "n_grid": self.n_grid, "n_missing": self.n_missing,
                "stamp_resolution_s": self.resolution_s, "tolerance_s": self.tolerance_s,
                "jitter_rms_s": self.jitter_rms_s, "jitter_max_s": self.jitter_max_s}


def _slot_guess(t_s: np.ndarray) -> np.ndarray:
    """Grid indices from the spacing: consecutive samples one slot apart unless their
    spacing says more (gaps), with the spacing averaged over single-slot steps so
    rounded stamps do not bias it."""
    d = np.diff(t_s)
    med = float(np.median(d))
    if not med > 0:
        raise InputError("times must be strictly increasing")
    single = (d > 0.5 * med) & (d < 1.5 * med)
    dt = float(np.mean(d[single])) if single.any() else med
    steps = np.maximum(1, np.round(d / dt)).astype(np.int64)
    return np.concatenate([[0], np.cumsum(steps)])


def fit_time_grid(t_s: np.ndarray, tolerance: float = 0.05, *, n_iter: int = 5) -> TimeGrid:
    """Fit a uniform grid to sample times and check the jitter (see :class:`TimeGrid`).

    The start and spacing come from a least-squares line through (slot, time), with
    the slots re-assigned from the fitted grid until they no longer change, so the
    error of a rounded spacing does not accumulate along the record.

    Parameters
    ----------
    t_s : ndarray
        Strictly increasing sample times (s).
    tolerance : float
        Allowed jitter as a fraction of the spacing, on top of half the stamp resolution.

    Raises
    ------
    InputError
        A sample further than the tolerance from the grid (irregular sampling).

    Examples
    --------
    128 Hz stamped to the millisecond (spacings of 7 and 8 ms):

    >>> t = np.round(np.arange(5000) / 128.0, 3)
    >>> g = fit_time_grid(t)
    >>> round(g.dt_s, 7), g.n_grid, g.resolution_s, g.jitter_max_s < 0.0006
    (0.0078125, 5000, 0.001, True)
    """
    t_s = np.asarray(t_s, dtype=float)
    if t_s.size < 2:
        raise InputError("need at least two samples")
    rel = t_s - t_s[0]
    k = _slot_guess(rel)
    for _ in range(n_iter):
        slope, icpt = np.polyfit(k.astype(float), rel, 1)
        k_new = np.round((rel - icpt) / slope).astype(np.int64)
        k_new -= k_new[0]
        if np.array_equal(k_new, k):
            break
        k = k_new
    if np.any(np.diff(k) < 1):
        raise InputError("irregular sampling: two samples fall into one slot of the "
                         f"{slope:.6g} s grid; resample the input to one cadence")
    slope, icpt = np.polyfit(k.astype(float), rel, 1)
    jitter = rel - (icpt + slope * k)
    res = stamp_resolution_s(t_s)
    tol = 0.5 * res + tolerance * slope
    off = np.abs(jitter)
    if np.max(off) > tol:
        bad = int(np.argmax(off > tol))
        raise InputError(f"irregular sampling: sample {bad} is {off[bad]:.3g} s off the "
                         f"{slope:.6g} s grid (tolerance {tol:.3g} s: half the "
                         f"{res:g} s stamp resolution plus {tolerance:g} of the spacing); "
                         "resample the input to one cadence")
    return TimeGrid(slots=k, n_grid=int(k[-1]) + 1, t0_s=float(t_s[0] + icpt),
                    dt_s=float(slope), resolution_s=res, tolerance_s=float(tol),
                    jitter_rms_s=float(np.sqrt(np.mean(jitter ** 2))),
                    jitter_max_s=float(np.max(off)), n_missing=int(k[-1]) + 1 - len(k))


def uniform_grid(t_s: np.ndarray, tolerance: float = 0.05):
    """Map sample times onto a fitted uniform grid (:func:`fit_time_grid`).

    Returns
    -------
    slots : ndarray of int
        Grid index of each sample.
    n_grid : int
    dt : float
        Grid spacing (s).

    Raises
    ------
    InputError
        Samples further than the tolerance from the grid (irregular sampling).

    Examples
    --------
    >>> uniform_grid(np.array([0.0, 1.0, 2.0, 4.0]))[0].tolist()
    [0, 1, 2, 4]
    """
    g = fit_time_grid(t_s, tolerance)
    return g.slots, g.n_grid, g.dt_s


def _check_valid(data: dict) -> None:
    """InputError naming the first sensor column without a single valid sample."""
    for sensor, arr in data.items():
        for k, c in enumerate(COMPONENTS):
            if not np.isfinite(arr[:, k]).any():
                raise InputError(f"sensor {sensor!r} has no valid sample in this column",
                                 column=f"{sensor}_{c}")


class PiCoG:
    """Principal-component gradiometer AC cleaning (Constantinescu et al. 2020).

    Parameters
    ----------
    plan : Plan, optional
        Stages and orders to fit (see :mod:`magcal.ac.plan`). Required unless ``auto``.
    target : str, optional
        Target sensor for ``auto`` (with a plan, the plan's target is used).
    auto : bool
        Let :func:`magcal.ac.auto.auto_plan` choose references, pairs, windows, orders.
    alpha_method : {"decorrelate", "variance"}
    keep_scans : bool
        Keep per-window scan results in ``result_.scans`` (for plots).
    check_bands : bool
        Compare raw and cleaned spectra per band and component after the fit
        (:func:`magcal.ac.bandcheck.band_check`) and choose the delivered product
        (:func:`magcal.ac.bands.deliver`: band-selective, never worse than raw).
    robust : bool
        Leave samples that are glitches of one sensor (spikes, stuck runs that passed
        quality control) out of the fit (:mod:`magcal.ac.robust`).

    Attributes
    ----------
    result_ : ChainResult
    M_ : dict, G_ : ndarray, steps_ : tuple
    plan_ : Plan (the plan fitted; chosen by auto if ``auto``)
    auto_report_ : dict or None (why each automatic choice was made)
    time_grid_ : TimeGrid (fitted sample grid and the time-stamp jitter found)
    band_check_ : BandCheck or None (raw vs cleaned power per band and component)
    warnings_ : list of str (bands worse than raw, a large correction offset G)
    delivery_ : Delivery or None (the product delivered, never worse than raw)
    outliers_ : dict or None (samples left out of the fit as single-sensor glitches)
    slow_offsets_ : dict or None (``auto``: intervals left out of the fit where a sensor's
        own slow offset changes fast, :func:`magcal.ac.slow.offset_intervals`)

    Examples
    --------
    >>> from magcal.ac.chain import Plan, Stage
    >>> idx = pd.date_range("2019-03-04", periods=600, freq="1s", tz="UTC")
    >>> rng = np.random.default_rng(0); s = rng.normal(size=600)
    >>> df = pd.DataFrame({"o_x": 1 + 2 * s, "o_y": 2.0, "o_z": 3.0,
    ...                    "a_x": 1 + 40 * s, "a_y": 2.0, "a_z": 3.0}, index=idx)
    >>> model = PiCoG(Plan("o", (Stage("reference", ("o",), reference="a"),))).fit(df)
    >>> out = model.transform(df)          # sum_k M_k B_k + G: the target's mean kept
    >>> np.allclose(out[["x", "y", "z"]].to_numpy() - model.G_, [1.0, 2.0, 3.0])
    True
    """

    def __init__(self, plan: Plan | None = None, *, target: str | None = None,
                 auto: bool = False, alpha_method: str = "decorrelate",
                 keep_scans: bool = False, check_bands: bool = True, robust: bool = True):
        self.plan = plan
        self.target = target
        self.auto = auto
        self.alpha_method = alpha_method
        self.keep_scans = keep_scans
        self.check_bands = check_bands
        self.robust = robust

    def fit(self, frame: pd.DataFrame) -> "PiCoG":
        """Fit the chain on ``frame`` (all rows; plan intervals select sub-ranges)."""
        if len(frame) < 3:
            raise InputError("need at least 3 samples to fit")
        grid = fit_time_grid(epoch_seconds(frame.index))
        n_grid, grid_t = grid.n_grid, grid.times_s
        self.time_grid_ = grid
        self.slow_offsets_ = None
        names = sensors_in_frame(frame)

        def gridded(sensor):
            return grid.place(sensor_array(frame, sensor))

        if self.auto:
            from magcal.ac.auto import auto_plan

            target = self.target or (self.plan.target if self.plan else None)
            if target is None:
                raise InputError("--auto needs a target sensor")
            if target not in names:
                sensor_array(frame, target)  # raises naming the column
            data = {s: gridded(s) for s in names}
            require_common_frame(frame, names)
            _check_valid(data)
            fit_data = self._leave_out_offsets(self._screen(data), target, grid.dt_s)
            held = int(np.all(np.isfinite(data[target]), axis=1).sum())
            plan, report = auto_plan(fit_data, grid_t, target, alpha_method=self.alpha_method,
                                     n_record=held)
        else:
            if self.plan is None:
                raise InputError("give a plan or use auto")
            plan, report = self.plan, None
            data = {s: gridded(s) for s in plan.sensors}
            fit_data = None
        require_common_frame(frame, list(data))
        _check_valid(data)
        if fit_data is None:
            fit_data = self._screen(data)
        self.plan_ = plan
        self.auto_report_ = report
        self.result_: ChainResult = run_chain(fit_data, grid_t, plan,
                                              alpha_method=self.alpha_method,
                                              keep_scans=self.keep_scans)
        self.M_ = self.result_.M
        self.G_ = self.result_.G
        self.steps_ = self.result_.steps
        self.target_ = plan.target
        raw = data[plan.target]
        # on every sample, the glitches left out of the fit included
        onboard = apply_weights(data, self.M_) + self.G_
        self.band_check_ = self._band_check(raw, onboard, grid.dt_s)
        self.delivery_ = None
        if self.check_bands:
            from magcal.ac.bands import deliver

            self.delivery_ = deliver(raw, onboard, grid.dt_s,
                                     glitches=(_glitches(data, self.M_, plan.target)
                                               if self.robust else None))
        replaced = self.delivery_ is not None and self.delivery_.kind != "on_board"
        self.warnings_ = product_warnings(
            self.band_check_, self.G_, raw, plan.target,
            what=(f"the constant matrices' product of {plan.target}" if replaced else None))
        if replaced:
            check = self.delivery_.check
            left = ("" if check is None or self.delivery_.kind == "raw" else
                    "; its own band check passes in every band/component"
                    if not check.worse_than_raw else
                    f"; it is still worse than raw in {len(check.worse_than_raw)} "
                    "band/component(s)")
            self.warnings_.insert(0, f"delivered product: {self.delivery_.kind} "
                                     f"({self.delivery_.reason}){left}")
        if self.check_bands and self.band_check_ is None:
            self.warnings_.append(f"no band check of the product: the record ({n_grid} "
                                  "samples) is too short to compare spectra")
        return self

    def _leave_out_offsets(self, fit_data: dict, target: str, dt_s: float) -> dict:
        """``--auto`` on records of a day: the intervals where a sensor's own slow offset
        changes fast are left out of the fit (:func:`magcal.ac.slow.offset_intervals`)."""
        from magcal.ac.slow import bridge_intervals, offset_intervals

        mask, self.slow_offsets_ = offset_intervals(fit_data, target, dt_s)
        if not mask.any():
            return fit_data
        return {s: bridge_intervals(b, mask, dt_s) for s, b in fit_data.items()}

    def _screen(self, data: dict) -> dict:
        """Leave glitches of single sensors out of the fit (:mod:`magcal.ac.robust`)."""
        if not self.robust:
            self.outliers_ = self.screen_note_ = None
            return data
        from magcal.ac.robust import screen

        fit_data, self.outliers_ = screen(data)
        self.screen_note_ = None
        if self.outliers_["rows_left_out"]:
            flagged = ", ".join(f"{s} {n}" for s, n in self.outliers_["flagged"].items() if n)
            self.screen_note_ = (f"{self.outliers_['rows_left_out']} sample(s) left out of "
                                 f"the fit as glitches of one sensor ({flagged})")
        return fit_data

    def _band_check(self, raw, clean, dt_s) -> BandCheck | None:
        if not self.check_bands:
            return None
        try:
            return band_check(raw, clean, dt_s)
        except InputError:      # too short or a component without samples: no check
            return None

    def summary_lines(self) -> list[str]:
        """What a user should see after a fit: the automatic choices (with ``auto``) and
        the power reduction per band and component of the cleaned target."""
        lines = list((self.auto_report_ or {}).get("choices", []))
        if getattr(self, "screen_note_", None):
            lines.append(self.screen_note_)
        left = (getattr(self, "slow_offsets_", None) or {}).get("left_out_rows", 0)
        if left:
            lines.append(f"{left} sample(s) left out of the fit where a sensor's own slow "
                         f"offset changes fast ({', '.join(self.slow_offsets_['sensors'])})")
        if self.delivery_ is not None:
            lines.append(f"delivered product: {self.delivery_.kind} ({self.delivery_.reason})")
        check = self.band_check_
        if self.delivery_ is not None and self.delivery_.check is not None:
            check = self.delivery_.check
        if check is not None:
            lines.append(f"power reduction of {self.target_} per band (raw / delivered):")
            lines += ["  " + ln for ln in check.lines()]
        return lines

    def transform(self, frame: pd.DataFrame, *, pure_ac: bool = False,
                  keep_correction_offset: bool = False) -> pd.DataFrame:
        """Cleaned target ``sum_k M_k B_k + G`` as ``x, y, z, flag`` (see
        :func:`apply_upload`)."""
        return apply_upload(frame, self.M_, self.G_, pure_ac=pure_ac,
                            keep_correction_offset=keep_correction_offset)

    def to_params(self, provenance: dict | None = None) -> dict:
        """PARAMS.json payload (CONTRACTS §1) without the schema keys."""
        res = self.result_
        payload = {
            "target": self.target_,
            "M": {k: np.asarray(v).tolist() for k, v in res.M.items()},
            "G": np.asarray(res.G).tolist(),
            "steps": [s.to_dict() for s in res.steps],
            "identity_error": res.identity_error,
            "alpha_method": self.alpha_method,
            "plan": plan_to_dict(self.plan_),
            "time_grid": self.time_grid_.to_dict(),
            "worse_than_raw": ([] if self.band_check_ is None
                               else self.band_check_.worse_than_raw),
            "warnings": list(self.warnings_),
        }
        if self.outliers_ is not None:
            payload["outliers"] = self.outliers_
        if getattr(self, "slow_offsets_", None) is not None:
            payload["slow_offsets_left_out"] = self.slow_offsets_
        if self.band_check_ is not None:
            payload["band_check"] = self.band_check_.to_dict()
        payload["on_board"] = {
            "M": payload["M"], "G": payload["G"],
            "note": "constant matrices (Eq. 28, sum M = I) for an on-board upload, the same "
                    "as the top-level M and G; worse_than_raw and band_check describe "
                    "their product"}
        if self.delivery_ is not None:
            d = self.delivery_
            payload["ground"] = {**d.to_dict(), "worse_than_raw": (
                [] if d.check is None else d.check.worse_than_raw)}
            if d.check is not None:
                payload["ground"]["band_check"] = d.check.to_dict()
            payload["delivered"] = d.kind
            payload["delivered_reason"] = d.reason
        if self.auto_report_ is not None:
            payload["auto"] = self.auto_report_
        if provenance is not None:
            payload["provenance"] = provenance
        return payload

    def to_json(self, provenance: dict | None = None) -> dict:
        """The PARAMS.json product (with ``schema_version`` and ``magcal_version``)."""
        return product_dict(self.to_params(provenance))


#: |G| above this fraction of the target's mean |B| is reported (see :func:`offset_warning`)
LARGE_OFFSET_FRACTION = 0.5


def offset_warning(G, target_field: np.ndarray, target: str = "target") -> str | None:
    """A warning when the correction's DC offset ``G`` is large against the field.

    ``sum_k M_k B_k`` carries the steady fields of all sensors through the upload
    matrices (an inboard sensor near the spacecraft sees a large one); ``G`` (Eq. 31)
    is that offset. When ``|G|`` exceeds :data:`LARGE_OFFSET_FRACTION` of the target's
    mean ``|B|``, the output without ``G`` is not a field a user can read.

    Examples
    --------
    >>> offset_warning([300.0, 0.0, 0.0], np.array([[100.0, 0.0, 0.0]]), "bos")[:30]
    '|G| = 300 nT of the correction'
    >>> offset_warning([1.0, 0.0, 0.0], np.array([[100.0, 0.0, 0.0]])) is None
    True
    """
    if G is None:
        return None
    g = float(np.linalg.norm(np.asarray(G, dtype=float)))
    b = np.asarray(target_field, dtype=float)
    b = b[np.all(np.isfinite(b), axis=1)]
    if not b.size:
        return None
    field = float(np.mean(np.linalg.norm(b, axis=1)))
    if g <= LARGE_OFFSET_FRACTION * field:
        return None
    return (f"|G| = {g:.4g} nT of the correction is large against the {field:.4g} nT mean "
            f"|B| of {target}: the sensors' steady fields enter through the upload matrices, "
            "so the output is only a field estimate with G added back (the default; "
            "--keep-correction-offset leaves it out)")


def product_warnings(check: BandCheck | None, G, target_field, target: str, *,
                     recorded_in: str | None = "PARAMS.json worse_than_raw",
                     what: str | None = None) -> list[str]:
    """Warnings of a fitted product: bands worse than raw and a large offset ``G``.

    ``what`` names the product ``check`` judged (default "the cleaned <target>"): the
    fit's check is of the constant matrices, which a band-selective delivery replaces.
    """
    out = []
    if check is not None and check.worse_than_raw:
        worst = sorted(check.worse_than_raw, key=lambda w: w["reduction"])
        listed = ", ".join(f"{w['band_hz'][0]:.3g}-{w['band_hz'][1]:.3g} Hz {w['component']} "
                           f"({1 / w['reduction']:.2f}x the raw power)" for w in worst[:4])
        more = f" and {len(worst) - 4} more" if len(worst) > 4 else ""
        out.append(f"{what or f'the cleaned {target}'} is worse than raw (more power) in "
                   f"{len(worst)} band/component(s): "
                   f"{listed}{more}" + (f" ({recorded_in})" if recorded_in else ""))
    msg = offset_warning(G, target_field, target)
    if msg:
        out.append(msg)
    return out


def apply_upload(frame: pd.DataFrame, M: dict, G=None, *, pure_ac: bool = False,
                 keep_correction_offset: bool = False) -> pd.DataFrame:
    """Apply upload matrices to a multi-sensor frame: ``sum_k M_k B_k + G``.

    The DC offset ``G`` of the correction (Eq. 31) is added back by default, so the
    product keeps the target's mean field; ``keep_correction_offset=True`` leaves it
    out (the bare ``sum_k M_k B_k``, which carries the other sensors' steady fields).
    ``pure_ac=True`` is the former name of the default and is kept for compatibility.
    Without ``G`` (None) the bare sum is returned.

    Rows where a sensor with a non-zero matrix is missing get NaN and ``flag = 1``;
    good rows have ``flag = 0``.
    """
    if pure_ac and keep_correction_offset:
        raise InputError("--pure-ac adds G back and --keep-correction-offset leaves it out: "
                         "give one of them")
    if pure_ac and G is None:
        raise InputError("--pure-ac needs the DC offset G in the parameters")
    data = {k: sensor_array(frame, k) for k in M}
    clean = apply_weights(data, {k: np.asarray(v, dtype=float) for k, v in M.items()})
    if G is not None and not keep_correction_offset:
        clean = clean + np.asarray(G, dtype=float)
    bad = ~np.all(np.isfinite(clean), axis=1)
    clean[bad] = np.nan
    out = pd.DataFrame(clean, index=frame.index, columns=list(COMPONENTS))
    out["flag"] = bad.astype(int)
    return out


def apply_params(frame: pd.DataFrame, doc: dict, *, pure_ac: bool = False,
                 keep_correction_offset: bool = False, on_board: bool = False,
                 file=None) -> tuple[pd.DataFrame, list]:
    """Clean ``frame`` with a PARAMS.json document: (CLEAN frame, warnings).

    By default the product is the band-selective "ground" one of ``doc["ground"]``,
    re-checked on ``frame`` so that no band is worse than raw (:func:`deliver_frame`);
    ``on_board=True`` (or a PARAMS.json without ``ground``) gives the constant matrices'
    product, warned where it is worse than raw. See :func:`apply_upload` for the offset
    options; the warning says when ``G`` is large against the target's field
    (:func:`offset_warning`).
    """
    M, G, target = params_from_json(doc, file=file)
    out = apply_upload(frame, M, G, pure_ac=pure_ac,
                       keep_correction_offset=keep_correction_offset)
    if (not on_board and doc.get("ground") and target in sensors_in_frame(frame)
            and len(frame) > 2):
        out, _ = deliver_frame(frame, target, out, doc["ground"],
                               G if keep_correction_offset else None, sensors=list(M))
    return out, delivered_warnings(frame, target, out, G)


def deliver_frame(frame: pd.DataFrame, target: str, out: pd.DataFrame, ground: dict,
                  G=None, sensors=None):
    """The band-selective product of PARAMS.json ``ground`` on ``frame`` with the
    never-worse-than-raw rule re-checked on these data (:func:`magcal.ac.bands.deliver`).

    ``out`` is the on-board product (:func:`apply_upload`); ``G`` is given when it was
    left out of ``out`` (``--keep-correction-offset``): the check adds it back.
    ``sensors`` (default: every sensor in ``frame``) are those the correction combines:
    rows where one of them has a glitch of its own (or the target a suspect reading) are
    left out of the band filter's input and the check, and carry the constant matrices'
    product (:func:`magcal.ac.bands.deliver`).
    Returns ``(product frame, Delivery)``; the Delivery is None when the sample grid
    cannot be fitted (then ``out`` is returned unchanged).
    """
    from magcal.ac.bands import deliver

    onboard = out[list(COMPONENTS)].to_numpy(dtype=float)
    shift = np.zeros(3) if G is None else np.asarray(G, dtype=float)
    try:
        grid = fit_time_grid(epoch_seconds(frame.index))
    except InputError:
        return out, None
    names = dict.fromkeys([*(sensors if sensors is not None else sensors_in_frame(frame)),
                           target])
    data = {s: grid.place(sensor_array(frame, s)) for s in names}
    r, o = data[target], grid.place(onboard + shift)
    res = deliver(r, o, grid.dt_s, bands_hz=[tuple(b) for b in ground.get("bands_hz", [])],
                  weights=ground.get("weights"), kind=ground.get("delivered"),
                  slow=bool((ground.get("slow_offsets") or {}).get("removed", False)),
                  glitches=_glitches(data, data, target))
    new = out.copy()
    vals = res.product[grid.slots] - shift
    bad = ~np.all(np.isfinite(vals), axis=1)
    new[list(COMPONENTS)] = vals
    new["flag"] = np.maximum(new["flag"].to_numpy(), bad.astype(int))
    new.attrs["delivery"] = res.to_dict()
    return new, res


def _glitches(data: dict, sensors, target: str) -> np.ndarray | None:
    """Rows of a glitch of one of ``sensors`` (:func:`magcal.ac.robust.glitch_rows`) or
    of a suspect target reading (:func:`magcal.ac.robust.target_suspect`); None with
    fewer than two sensors (a glitch is told from a disturbance by the other sensor)."""
    from magcal.ac.robust import glitch_rows, target_suspect

    used = {s: data[s] for s in sensors if s in data}
    if len(used) < 2:
        return None
    rows = glitch_rows(used)
    return rows | target_suspect(used[target]) if target in used else rows


def delivered_warnings(frame: pd.DataFrame, target: str, out: pd.DataFrame, G) -> list[str]:
    """Warnings of a delivered product (:func:`product_warnings`) on the data it was
    applied to: the cleaned ``x, y, z`` against the raw target per band, and ``|G|``."""
    if target not in sensors_in_frame(frame) or len(frame) < 2:
        return []
    raw = sensor_array(frame, target)
    clean = out[list(COMPONENTS)].to_numpy(dtype=float)
    try:
        grid = fit_time_grid(epoch_seconds(frame.index))
        check = band_check(grid.place(raw), grid.place(clean), grid.dt_s)
    except InputError as exc:
        return product_warnings(None, G, raw, target) + [
            f"no band check of the product: {exc.message}"]
    return product_warnings(check, G, raw, target, recorded_in=None)


def _float_array(value, key: str, shape: tuple, file) -> np.ndarray:
    """``value`` as a finite float array of ``shape``; InputError naming ``key`` otherwise."""
    what = "x".join(map(str, shape)) + (" matrix" if len(shape) == 2 else " vector")
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        arr = None
    if isinstance(value, (str, bytes)) or arr is None or arr.shape != shape \
            or not np.all(np.isfinite(arr)):
        raise InputError(f"{key} must be a finite {what}, found {value!r:.60}", file=file)
    return arr


def params_from_json(doc: dict, *, file=None) -> tuple[dict, np.ndarray | None, str]:
    """(M, G, target) from a PARAMS.json document, validated.

    Raises
    ------
    InputError
        Naming the key: ``M`` missing, not an object of finite 3x3 matrices or not summing
        to the identity; ``G`` not a finite 3-vector; ``target`` not a sensor of ``M``.

    Examples
    --------
    >>> I = np.eye(3).tolist()
    >>> params_from_json({"M": {"a": I}, "target": "a", "G": [1, 2]})
    Traceback (most recent call last):
    ...
    magcal.errors.InputError: G must be a finite 3 vector, found [1, 2]
    >>> params_from_json({"M": {"a": I}, "target": "b"})
    Traceback (most recent call last):
    ...
    magcal.errors.InputError: target 'b' is not a sensor of M (have: a)
    """
    if not isinstance(doc, dict):
        raise InputError(f"expected a JSON object, found a {type(doc).__name__}", file=file)
    for key in ("M", "target"):
        if key not in doc:
            raise InputError(f"missing key {key!r}", file=file)
    if not isinstance(doc["M"], dict):
        raise InputError(f"M must be an object of sensor: 3x3 matrix, found "
                         f"{type(doc['M']).__name__} {doc['M']!r:.60}", file=file)
    M = {}
    for k, v in doc["M"].items():
        M[k] = _float_array(v, f"M[{k!r}]", (3, 3), file)
    if not M:
        raise InputError("M is empty", file=file)
    target = doc["target"]
    if not isinstance(target, str) or target not in M:
        raise InputError(f"target {target!r} is not a sensor of M (have: {', '.join(M)})",
                         file=file)
    if np.max(np.abs(sum(M.values()) - np.eye(3))) > 1e-6:
        raise InputError("the M matrices do not sum to the identity (Eq. 33)", file=file)
    G = doc.get("G")
    G = None if G is None else _float_array(G, "G", (3,), file)
    return M, G, target
