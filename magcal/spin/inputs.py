"""Spinning-spacecraft input: readings, units, spin phase and sense, and the model's checks.

The spin-ripple model (Kivelson et al. 1992) assumes readings in nT from a triad whose
sensor 3 lies nominally along the spin axis, so that the ambient field turns in the
plane of sensors 1 and 2 and sensor 3 sees the spin tone only through a small tilt.
Raw counts, or a triad mounted otherwise (all three sensors see the spin), give
numbers with no meaning; :func:`check_spin_assumptions` measures what the data show
and refuses such input with the reason.

Spin sense: the contract's phase ``p = 2 pi (t - t0) / S`` is a positive rotation
about sensor 3. A spacecraft spinning the other way is handled by turning the triad
by 180 degrees about sensor 1 (``b -> R b`` with ``R = diag(1, -1, -1)``, a proper
rotation), which makes the spin positive about the new third axis; the calibration is
turned back with ``C = R C' R``, ``O = R O'``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np

from magcal.errors import InputError
from magcal.spin.harmonics import block_harmonics, spin_blocks

#: Largest field magnitude or spin-tone amplitude taken as nT (Earth's surface field
#: is below 7e4 nT); larger values are read as counts needing a scale.
MAX_PLAUSIBLE_NT = 1.0e5
#: Largest angle between the spin axis seen in the data and the spin-axis sensor.
MAX_AXIS_TILT_DEG = 15.0
#: Spin-sense strength (|cos| of the angle between the rotation axis seen in the data
#: and sensor 3) below which the sense cannot be told from the data.
MIN_SENSE_STRENGTH = 0.5
#: Turns the triad by 180 degrees about sensor 1 (negative spin sense).
SENSE_FLIP = np.diag([1.0, -1.0, -1.0])
SPIN_SENSES = ("positive", "negative", "auto")


@dataclass(frozen=True)
class SpinAssumptions:
    """What the readings show about the model's assumptions.

    Attributes
    ----------
    tone_nT : ndarray, shape (3,)
        Median over spins of the 1x spin-tone amplitude of each sensor (input units
        times the scale).
    field_nT : float
        Median magnitude of the readings.
    spin_axis : ndarray, shape (3,)
        Unit vector, in sensor coordinates, about which the readings turn positively
        (the contract's sense); ``(0, 0, 1)`` for the ideal triad.
    axis_tilt_deg : float
        Angle between the spin axis seen in the data and the spin-axis sensor (the
        axis sensor's direction or its opposite, whichever is nearer).
    sense : int
        +1 (positive about the axis sensor), -1 (negative) or 0 (undetermined).
    n_spins : int
        Whole spins analysed.
    """

    tone_nT: np.ndarray
    field_nT: float
    spin_axis: np.ndarray
    axis_tilt_deg: float
    sense: int
    n_spins: int

    def as_dict(self) -> dict:
        """JSON-ready summary."""
        return {"tone_1x_nT": [float(x) for x in self.tone_nT], "field_nT": self.field_nT,
                "spin_axis_in_sensor_frame": [float(x) for x in self.spin_axis],
                "axis_tilt_deg": self.axis_tilt_deg, "sense": self.sense,
                "n_spins": self.n_spins}


def measure_spin_assumptions(t_s, b, phase_rad, *, axis: int = 2) -> SpinAssumptions:
    """Spin-tone amplitudes, spin axis and sense seen in the readings.

    Each sensor is fitted spin by spin with ``[1, t, cos p, sin p]``
    (:func:`magcal.spin.harmonics.block_harmonics`). With ``b_k ~ a_k cos p + c_k
    sin p`` the readings turn in the plane of the vectors ``a`` and ``c``; a field
    fixed in space and a triad turning positively about ``n`` give ``c x a`` along
    ``n``.

    Parameters
    ----------
    t_s, phase_rad : array_like, shape (n,)
        Times (s) and spin phase (increasing).
    b : array_like, shape (n, 3)
        Readings.
    axis : int
        Index of the sensor nominally along the spin axis (2 = sensor 3).

    Returns
    -------
    SpinAssumptions

    Examples
    --------
    >>> import numpy as np
    >>> from magcal.spin.despin import spin
    >>> p = np.linspace(0, 20 * 2 * np.pi, 2000, endpoint=False)
    >>> b = spin(np.tile([30.0, 0.0, 10.0], (p.size, 1)), p)
    >>> res = measure_spin_assumptions(p, b, p)
    >>> res.sense, round(res.axis_tilt_deg, 6), res.tone_nT.round(6).tolist()
    (1, 0.0, [30.0, 30.0, 0.0])
    """
    p = np.asarray(phase_rad, dtype=float)
    x = np.asarray(b, dtype=float)
    blocks = spin_blocks(p)
    coef = block_harmonics(t_s, p, x, blocks, n_harmonics=1)          # (nb, 2, 3)
    a, c = coef[:, 0, :], coef[:, 1, :]
    tone = np.median(np.hypot(a, c), axis=0)
    normal = np.sum(np.cross(c, a), axis=0)
    size = float(np.linalg.norm(normal))
    spin_axis = normal / size if size > 0 else np.zeros(3)
    strength = float(spin_axis[axis])
    tilt = float(np.degrees(np.arccos(min(abs(strength), 1.0)))) if size > 0 else 90.0
    sense = 0 if abs(strength) < MIN_SENSE_STRENGTH else int(np.sign(strength))
    return SpinAssumptions(tone_nT=tone, field_nT=float(np.median(np.linalg.norm(x, axis=1))),
                           spin_axis=spin_axis, axis_tilt_deg=tilt, sense=sense,
                           n_spins=int(blocks.n_blocks))


def check_spin_assumptions(found: SpinAssumptions, *, axis: int = 2, file=None) -> None:
    """Refuse readings that break the spin-ripple model (see the module docstring).

    Raises
    ------
    InputError
        Values implausible for nT (more than :data:`MAX_PLAUSIBLE_NT`), a spin axis
        more than :data:`MAX_AXIS_TILT_DEG` from the spin-axis sensor (the spin tone in
        all three sensors), or a sense that cannot be told.
    """
    big = max(found.field_nT, float(np.max(found.tone_nT)))
    if not big <= MAX_PLAUSIBLE_NT:
        raise InputError(
            f"readings of {found.field_nT:.3g} with a spin tone of "
            f"{np.max(found.tone_nT):.3g} are implausible for nT (more than "
            f"{MAX_PLAUSIBLE_NT:.0e}): they look like counts; give --scale NT_PER_COUNT",
            file=file, column="b1")
    name = f"b{axis + 1}"
    if found.axis_tilt_deg > MAX_AXIS_TILT_DEG:
        tones = ", ".join(f"b{k + 1} {v:.3g}" for k, v in enumerate(found.tone_nT))
        axis_txt = ", ".join(f"{v:.2f}" for v in found.spin_axis)
        raise InputError(
            f"the spin tone is not confined to the spin plane (1x amplitude {tones}): the "
            f"spin axis lies {found.axis_tilt_deg:.0f} deg from sensor {axis + 1} ({name}) "
            f"(direction [{axis_txt}] in sensor coordinates), more than "
            f"{MAX_AXIS_TILT_DEG:g} deg; the model needs {name} nominally along the spin "
            "axis: rotate the readings into such a frame first", file=file, column=name)
    if found.sense == 0:
        raise InputError("cannot tell the spin sense from the readings (no clear rotation "
                         "in the spin plane)", file=file, column=name)


@dataclass(frozen=True)
class SpinData:
    """A spinning-spacecraft record ready for calibration.

    Attributes
    ----------
    t_s : ndarray (n,)
        Seconds from the first kept row.
    b : ndarray (n, 3)
        Readings times ``scale``, turned by :data:`SENSE_FLIP` when ``sense == -1``.
    phase : ndarray (n,)
        Spin phase (unwrapped, positive about the third axis of ``b``).
    flip : ndarray of int or None
    sense : int
        +1 or -1: the spin sense about sensor 3 of the file.
    scale : float
        nT per input unit applied to the readings.
    phase_source : str
    phase_info : dict
    assumptions : SpinAssumptions or None
        What the readings showed (None when the record is too short to measure it).
    n_missing_rows : int
    source : str
    screened : dict or None
        Rows the quality screen left out (:func:`magcal.spin.screen.screen_spin`),
        None when it did not run.
    """

    t_s: np.ndarray
    b: np.ndarray
    phase: np.ndarray
    flip: np.ndarray | None
    sense: int
    scale: float
    phase_source: str
    phase_info: dict = field(default_factory=dict)
    assumptions: SpinAssumptions | None = None
    n_missing_rows: int = 0
    source: str = ""
    screened: dict | None = None

    def phase_record(self) -> dict:
        """The ``spin_phase`` block of CAL.json / FLIP.json."""
        out = {"source": self.phase_source, **self.phase_info,
               "sense": "positive" if self.sense > 0 else "negative",
               "input_scale_nT_per_unit": self.scale}
        if self.assumptions is not None:
            out["checks"] = self.assumptions.as_dict()
        return out


def unwrap_increasing(phase) -> np.ndarray:
    """Unwrap a spin phase that increases: add 2 pi at every fall of more than pi.

    Unlike :func:`numpy.unwrap` it leaves a forward jump alone, so an already unwrapped
    column keeps its turns across a gap (rows missing or screened out).

    Examples
    --------
    >>> unwrap_increasing([6.0, 0.2, 1.0, 40.0]).round(3).tolist()
    [6.0, 6.483, 7.283, 46.283]
    """
    p = np.asarray(phase, dtype=float)
    if p.size < 2:
        return p.copy()
    turns = np.concatenate([[0.0], np.cumsum(np.diff(p) < -np.pi)])
    return p + 2.0 * np.pi * turns


def _read_flip(frame, good, path):
    if "flip" not in frame.columns:
        return None
    f = frame["flip"].to_numpy()
    if np.isnan(f).any() or not np.all(np.isin(f, (0.0, 1.0))):
        bad = int(np.flatnonzero(np.isnan(f) | ~np.isin(f, (0.0, 1.0)))[0])
        raise InputError("flip must be 0 or 1", file=path, column="flip",
                         row=int(np.flatnonzero(good)[bad]) + 2)
    return f.astype(int)


def _phase(frame, t, b, flip, good, path, spin_period_s, t0):
    """Phase from the phase column, the period, or the rotation of the spin plane."""
    import pandas as pd

    from magcal.spin.despin import check_period_consistent, phase_from_data, phase_from_period

    # The two spin-plane sensors: b1, b2; with the flipper in position 1, b3 and b2.
    plane_x = b[:, 0] if flip is None else np.where(flip == 1, b[:, 2], b[:, 0])
    if "phase" in frame.columns:
        ph = frame["phase"].to_numpy()
        if np.isnan(ph).any():
            bad = int(np.flatnonzero(np.isnan(ph))[0])
            raise InputError("missing spin phase", file=path, column="phase",
                             row=int(np.flatnonzero(good)[bad]) + 2)
        return unwrap_increasing(ph), "phase column", {}
    if spin_period_s is None:
        phase, info = phase_from_data(t, plane_x, b[:, 1])
        return phase, "derived from the rotation of b1, b2", info
    t0_s = None
    if t0 is not None:
        try:
            ref = pd.Timestamp(t0)
        except ValueError:
            raise InputError(f"cannot parse --t0 {t0!r} as ISO-8601 UTC") from None
        ref = ref.tz_localize("UTC") if ref.tzinfo is None else ref.tz_convert("UTC")
        t0_s = (ref - frame.index[0]).total_seconds()
    phase = phase_from_period(t, spin_period_s, t0_s)
    try:
        derived, info = phase_from_data(t, plane_x, b[:, 1])
    except InputError:
        derived, info = None, {}
    if derived is not None:
        try:
            check_period_consistent(t, derived, spin_period_s)
        except InputError as exc:
            raise InputError(exc.message, file=path, column="time") from None
    return phase, f"spin period {spin_period_s:g} s", info


def load_spin_data(path: str | os.PathLike, spin_period_s: float | None = None,
                   t0: str | None = None, *, scale: float = 1.0,
                   spin_sense: str = "positive", flip_state: int | None = None,
                   check: bool = True, require_flip: bool = False,
                   screen: bool = True) -> SpinData:
    """Read a spinning-spacecraft CSV (CONTRACTS §4), resolve the phase and check it.

    Parameters
    ----------
    path : path-like
        ``time,b1,b2,b3[,phase][,flip]``.
    spin_period_s : float, optional
        Spin period used without a phase column.
    t0 : str, optional
        ISO time of phase 0 with ``spin_period_s`` (default the first row).
    scale : float
        nT per input unit (e.g. nT per count); the readings are multiplied by it.
    spin_sense : {"positive", "negative", "auto"}
        Sense of the spin about sensor 3: ``positive`` is the contract's phase,
        ``negative`` turns the triad (see the module docstring), ``auto`` takes the
        sense the readings show. A phase column fixes the sense itself.
    flip_state : int, optional
        Check the model's assumptions on the rows in this flipper position (default:
        position 0, or all rows without a flip column).
    check : bool
        Measure and check the assumptions (:func:`check_spin_assumptions`).
    require_flip : bool
        Refuse a file without a ``flip`` column (the flipper needs one).
    screen : bool
        Leave out fill values, saturated or stuck runs and spikes
        (:func:`magcal.spin.screen.screen_spin`) before the phase is resolved; the
        count is in ``SpinData.screened``.

    Returns
    -------
    SpinData

    Raises
    ------
    InputError
        Unreadable file or phase, bad scale, and every refusal of
        :func:`check_spin_assumptions`, including a sense opposite to the one given.
    """
    from magcal.io.formats import read_any

    if spin_sense not in SPIN_SENSES:
        raise InputError(f"spin sense {spin_sense!r}: expected one of {', '.join(SPIN_SENSES)}")
    if not (np.isfinite(scale) and scale > 0):
        raise InputError(f"scale {scale} must be a positive number of nT per input unit")
    frame = read_any(path, required=["b1", "b2", "b3"])
    good = frame[["b1", "b2", "b3"]].notna().all(axis=1).to_numpy()
    n_missing = int((~good).sum())
    if "phase" in frame.columns:  # unwrapped over every row, before rows are left out
        ph = frame["phase"].to_numpy(dtype=float)
        if np.isfinite(ph).all():
            frame = frame.assign(phase=unwrap_increasing(ph))
    screened = None
    if screen and len(frame) >= 3:
        from magcal.spin.screen import screen_spin

        t_all = (frame.index - frame.index[0]).total_seconds().to_numpy()
        bad, screened = screen_spin(t_all, frame[["b1", "b2", "b3"]].to_numpy(dtype=float)
                                    * float(scale))
        good = good & ~bad
    frame = frame[good]
    if len(frame) < 3:
        raise InputError("fewer than 3 rows with all of b1, b2, b3", file=path)
    t = (frame.index - frame.index[0]).total_seconds().to_numpy()
    b = frame[["b1", "b2", "b3"]].to_numpy() * float(scale)
    flip = _read_flip(frame, good, path)
    if require_flip and flip is None:
        raise InputError("no flip column: flipper intervals missing (need rows with flip = 1 "
                         "and flip = 0)", file=path, column="flip")
    has_phase = "phase" in frame.columns
    sense = -1 if spin_sense == "negative" else 1
    if sense < 0:
        b = b @ SENSE_FLIP
    try:
        phase, source, info = _phase(frame, t, b, flip, good, path, spin_period_s, t0)
    except InputError as exc:
        if spin_sense != "auto" or has_phase or "positive sense" not in exc.message:
            raise InputError(exc.message, file=exc.file or path, row=exc.row,
                             column=exc.column) from None
        sense, b = -1, b @ SENSE_FLIP
        phase, source, info = _phase(frame, t, b, flip, good, path, spin_period_s, t0)
    found = None
    if check:
        found = _checked(t, b, phase, flip, flip_state, path)
        if found is not None and found.sense < 0:
            if spin_sense != "auto" or has_phase:
                given = "the phase column" if has_phase else f"--spin-sense {spin_sense}"
                raise InputError(
                    f"the readings turn in the sense opposite to {given} (spin axis "
                    f"along -b3 of that frame); give --spin-sense "
                    f"{'negative' if sense > 0 else 'positive'} or auto", file=path,
                    column="phase" if has_phase else "b2")
            sense, b = -sense, b @ SENSE_FLIP
            phase, source, info = _phase(frame, t, b, flip, good, path, spin_period_s, t0)
            found = _checked(t, b, phase, flip, flip_state, path)
    return SpinData(t_s=t, b=b, phase=phase, flip=flip, sense=sense, scale=float(scale),
                    phase_source=source, phase_info=info, assumptions=found,
                    n_missing_rows=n_missing, source=str(path), screened=screened)


def _checked(t, b, phase, flip, flip_state, path) -> SpinAssumptions | None:
    """Measure and check the assumptions on the rows of one flipper position."""
    state = 0 if flip_state is None else int(flip_state)
    rows = np.ones(t.size, bool) if flip is None else flip == state
    # with the flipper in position 1, sensor 1 is on the spin axis and b3, b2 span the
    # plane: turn them into the (b1, b2, b3) roles of position 0 before measuring
    axis = 0 if (flip is not None and state == 1) else 2
    x = b[rows] if axis == 2 else b[rows][:, [2, 1, 0]] * [1.0, 1.0, -1.0]
    if rows.sum() < 16:
        return None
    try:
        found = measure_spin_assumptions(t[rows], x, phase[rows])
    except InputError:
        return None                       # too few whole spins: the fit says so itself
    check_spin_assumptions(found, file=path)
    return found
