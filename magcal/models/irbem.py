"""IGRF + Tsyganenko field at given GEO positions through IRBEM (spacepy's ``libirbem.so``).

Fast path: IRBEM's ``get_field_multi_`` called through :mod:`ctypes` with whole arrays
(at most :data:`NTIME_MAX` points per call) on the very library spacepy ships. It is
about 30 times faster than ``spacepy.irbempy.get_Bfield`` (a Python loop over
``get_field1``) and gives identical numbers. If the library cannot be loaded the module
falls back to ``get_Bfield``.

IRBEM pitfalls handled here (see DEPENDENCY-NOTES):

* all 16 model inputs are passed (zeros for those the model ignores);
* Kp is given in Kp units and converted to OMNI one-decimal style (``Kp*10`` rounded to
  an integer: 2- = 17, 1+ = 13), because IRBEM selects the T89 activity level by integer
  thresholds on ``Kp*10`` (Kp = 5/3 would otherwise land in the wrong level);
* inputs outside a model's range (T96, T01), missing inputs (NaN) or IRBEM's fill value
  (-1e31) give NaN, never numbers; every such sample is counted under a reason.

The ``magcal`` model names map to IRBEM as ``IGRF`` -> internal field only (kext 0),
``T89`` -> 4, ``T96`` -> 7, ``T01`` -> 9 (T01 quiet, the range-checked T01),
``T04`` -> 11 (TS04/TS05 storm-time model, no range check in IRBEM).

This module is the thread-unsafe core (IRBEM keeps state in Fortran COMMON blocks):
parallel evaluation happens in processes, see :mod:`magcal.models.field`.
"""

from __future__ import annotations

import ctypes
import functools
import importlib.util
import os
import warnings
from dataclasses import dataclass, field as dc_field
from pathlib import Path

import numpy as np

from magcal.errors import InputError
from magcal.timeconv import as_datetime64

#: IRBEM's fill value for bad output.
IRBEM_FILL = -1e31
#: Points per IRBEM call in evaluate_geo: small enough that the (CHUNK, 25) input buffer
#: stays in cache and is faulted in once, large enough that the call overhead is nil.
CHUNK = 8192
_DAY_NS = 86_400 * 10**9
#: IRBEM's compile-time maximum number of points per array call.
NTIME_MAX = 100_000
#: The 16 IRBEM model inputs, in ``maginput`` order.
INPUT_KEYS = ("Kp", "Dst", "dens", "velo", "Pdyn", "ByIMF", "BzIMF", "G1", "G2", "G3",
              "W1", "W2", "W3", "W4", "W5", "W6")
#: magcal model name -> IRBEM ``kext``.
KEXT = {"IGRF": 0, "T89": 4, "T96": 7, "T01": 9, "T04": 11}
#: Inputs each model reads (the others are passed as zeros).
REQUIRED_INPUTS = {
    "IGRF": (),
    "T89": ("Kp",),
    "T96": ("Dst", "Pdyn", "ByIMF", "BzIMF"),
    "T01": ("Dst", "Pdyn", "ByIMF", "BzIMF", "G1", "G2"),
    "T04": ("Dst", "Pdyn", "ByIMF", "BzIMF", "W1", "W2", "W3", "W4", "W5", "W6"),
}
#: Validity ranges IRBEM enforces (``set_magfield_inputs`` in onera_desp_lib.f);
#: Kp for T89 is checked on the rounded ``Kp*10`` in [0, 90].
INPUT_RANGES = {
    "T89": {"Kp": (0.0, 9.0)},
    "T96": {"Dst": (-100.0, 20.0), "Pdyn": (0.5, 10.0), "ByIMF": (-10.0, 10.0),
            "BzIMF": (-10.0, 10.0)},
    "T01": {"Dst": (-50.0, 20.0), "Pdyn": (0.5, 5.0), "ByIMF": (-5.0, 5.0),
            "BzIMF": (-5.0, 5.0), "G1": (0.0, 10.0), "G2": (0.0, 10.0)},
}
#: Default IRBEM options: IGRF updated daily (options[1] = 1), IGRF internal field.
DEFAULT_OPTIONS = (0, 1, 0, 0, 0)
#: Last year covered by the IGRF coefficients compiled into IRBEM (IGRF-13).
IGRF_LAST_YEAR = 2025


class ModelRangeWarning(RuntimeWarning):
    """Some model samples were set to NaN (inputs out of range, missing, or IRBEM fill)."""


@dataclass(frozen=True)
class GeoFieldResult:
    """Model field in GEO cartesian components with the out-of-range report.

    Attributes
    ----------
    b_geo_nT : ndarray, shape (n, 3)
        Total field (IGRF + external) in GEO cartesian nT; NaN where invalid.
    invalid : ndarray of bool, shape (n,)
        True where ``b_geo_nT`` is NaN.
    reasons : dict
        ``{reason: count}`` for every invalid sample (a sample is counted once, under
        its first reason) plus informational counts that do not invalidate samples
        (keys starting with ``info:``).
    model : str
    backend : str
        ``"ctypes"`` (fast path) or ``"get_Bfield"`` (fallback).
    """

    b_geo_nT: np.ndarray
    invalid: np.ndarray
    reasons: dict = dc_field(default_factory=dict)
    model: str = "T89"
    backend: str = "ctypes"

    @property
    def n_invalid(self) -> int:
        """Number of samples set to NaN."""
        return int(np.count_nonzero(self.invalid))


# --------------------------------------------------------------------------- library
def irbem_library_path() -> Path:
    """Path of spacepy's ``libirbem.so`` (found without importing spacepy)."""
    spec = importlib.util.find_spec("spacepy")
    if spec is None or not spec.submodule_search_locations:
        raise ImportError("spacepy is not installed: IRBEM model fields are unavailable")
    folder = Path(list(spec.submodule_search_locations)[0]) / "irbempy"
    for name in ("libirbem.so", "libirbem.dylib", "irbem.dll", "libirbem.dll.a"):
        if (folder / name).exists():
            return folder / name
    candidates = sorted(folder.glob("libirbem*"))
    if candidates:
        return candidates[0]
    raise ImportError(f"no IRBEM library in {folder}")


@functools.lru_cache(maxsize=1)
def _multi_function():
    """Load ``get_field_multi_`` from spacepy's IRBEM library (cached per process)."""
    lib = ctypes.CDLL(str(irbem_library_path()))
    func = getattr(lib, "get_field_multi_")
    func.restype = None
    func.argtypes = [ctypes.c_void_p] * 13
    return func


def ctypes_available() -> bool:
    """True when the fast ``get_field_multi_`` path can be used."""
    try:
        _multi_function()
    except (OSError, AttributeError, ImportError):
        return False
    return True


# --------------------------------------------------------------------------- helpers
def kp_to_irbem(kp) -> np.ndarray:
    """Kp in Kp units -> IRBEM's ``maginput[0]``: ``Kp*10`` rounded, OMNI style.

    Examples
    --------
    >>> kp_to_irbem([5 / 3, 4 / 3, 2.0, 9.0])
    array([17., 13., 20., 90.])
    """
    return np.round(np.asarray(kp, dtype=float) * 10.0)


def time_parts(times) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Year, day of year and seconds of day (UTC) of ``times``.

    Parameters
    ----------
    times : array_like of datetime64, datetime or ISO strings, or pandas DatetimeIndex

    Examples
    --------
    >>> y, d, s = time_parts(np.array(["2019-11-01T01:00:30"], dtype="datetime64[ns]"))
    >>> int(y[0]), int(d[0]), float(s[0])
    (2019, 305, 3630.0)
    """
    t = as_datetime64(times)
    ns = t.view(np.int64)
    if t.size and not np.isnat(t).any():
        # calendar arithmetic once per distinct day (datetime64 unit casts are slow)
        day = ns // _DAY_NS
        lo, hi = int(day.min()), int(day.max())
        if hi - lo < 4 * t.size + 1000:
            table = np.arange(lo, hi + 1).astype("datetime64[D]")
            years = table.astype("datetime64[Y]")
            year = (years.astype(np.int64) + 1970).astype(np.int32)[day - lo]
            doy = ((table - years.astype("datetime64[D]")).astype(np.int64) + 1
                   ).astype(np.int32)[day - lo]
            return year, doy, (ns - day * _DAY_NS) / 1e9
    years = t.astype("datetime64[Y]")
    days = t.astype("datetime64[D]")
    year = years.astype(np.int64) + 1970
    doy = (days - years.astype("datetime64[D]")).astype(np.int64) + 1
    sec = (t - days).astype("timedelta64[ns]").astype(np.int64) / 1e9
    return year.astype(np.int32), doy.astype(np.int32), sec.astype(np.float64)


def build_maginput(inputs, n: int, model: str) -> tuple[np.ndarray, np.ndarray, dict]:
    """Build the (n, 25) IRBEM input array, checking ranges (see :func:`maginput_columns`)."""
    columns, bad, reasons = maginput_columns(inputs, n, model)
    mag = np.zeros((n, 25), dtype=np.float64)
    for i, values in columns.items():
        mag[:, i] = values
    if bad.any():
        mag[bad] = 0.0
    return mag, bad, reasons


def maginput_columns(inputs, n: int, model: str) -> tuple[dict, np.ndarray, dict]:
    """Check the IRBEM inputs and return them column by column.

    Returns
    -------
    columns : dict
        ``{column index: (n,) values}`` of the IRBEM input array, Kp already converted to
        ``Kp*10``. The full (n, 25) array is assembled chunk by chunk by the caller:
        touching 200 bytes per point up front costs as much as a third of the IRBEM call.
    bad : ndarray of bool, shape (n,)
        Samples not to evaluate.
    reasons : dict
        ``{reason: count}`` of the bad samples (first reason per sample).
    """
    inputs = dict(inputs or {})
    unknown = sorted(set(inputs) - set(INPUT_KEYS))
    if unknown:
        raise InputError(f"unknown IRBEM input(s) {', '.join(unknown)}; "
                         f"expected names from {', '.join(INPUT_KEYS)}")
    columns: dict[int, np.ndarray] = {}
    bad = np.zeros(n, dtype=bool)
    reasons: dict[str, int] = {}

    def flag(mask, reason):
        new = mask & ~bad
        count = int(np.count_nonzero(new))
        if count:
            reasons[reason] = reasons.get(reason, 0) + count
            bad[new] = True

    for key in REQUIRED_INPUTS[model]:
        if key not in inputs:
            raise InputError(f"model {model} needs input {key!r} "
                             f"(needs {', '.join(REQUIRED_INPUTS[model])})")
    for i, key in enumerate(INPUT_KEYS):
        if key not in inputs:
            continue
        try:
            values = np.broadcast_to(np.asarray(inputs[key], dtype=float), (n,))
        except ValueError:
            raise InputError(f"input {key!r} has {np.size(inputs[key])} values for {n} "
                             "samples (give a scalar or one value per sample)") from None
        required = key in REQUIRED_INPUTS[model]
        if required:
            # IRBEM's fill is -1e31; anything at or below -1e30 is a fill, not a number
            flag(~(values > -1e30), f"{key} missing")  # also catches NaN
        values = np.where(np.isfinite(values), values, 0.0)
        if key == "Kp":
            values = kp_to_irbem(values)
            if model == "T89":
                flag((values < 0) | (values > 90), "Kp outside [0, 9] (T89)")
        elif required and key in INPUT_RANGES.get(model, {}):
            lo, hi = INPUT_RANGES[model][key]
            flag((values < lo) | (values > hi), f"{key} outside [{lo:g}, {hi:g}] ({model})")
        columns[i] = values
    return columns, bad, reasons


# --------------------------------------------------------------------------- evaluation
def _call_multi(kext, options, year, doy, sec, xyz, mag) -> np.ndarray:
    """One ``get_field_multi_`` call on at most NTIME_MAX points; returns (n, 3)."""
    func = _multi_function()
    n = len(year)
    i4 = ctypes.c_int32
    year = np.ascontiguousarray(year, dtype=np.int32)
    doy = np.ascontiguousarray(doy, dtype=np.int32)
    sec = np.ascontiguousarray(sec, dtype=np.float64)
    x1, x2, x3 = (np.ascontiguousarray(xyz[:, k], dtype=np.float64) for k in range(3))
    mag = np.ascontiguousarray(mag, dtype=np.float64)  # (n, 25) C order == (25, n) Fortran
    bgeo = np.zeros((n, 3), dtype=np.float64)
    blocal = np.zeros(n, dtype=np.float64)
    opts = (i4 * 5)(*options)
    ptr = [a.ctypes.data_as(ctypes.c_void_p)
           for a in (year, doy, sec, x1, x2, x3, mag, bgeo, blocal)]
    func(ctypes.byref(i4(n)), ctypes.byref(i4(kext)), opts, ctypes.byref(i4(1)), *ptr)
    return bgeo


def _call_get_bfield(kext, options, times, xyz, mag) -> np.ndarray:
    """Fallback through ``spacepy.irbempy.get_Bfield`` (slow Python loop)."""
    from magcal.offline import ensure_spacepy_dir

    ensure_spacepy_dir()
    import spacepy.coordinates as spc
    import spacepy.irbempy as ib
    import spacepy.time as spt

    ext = {0: "0", 4: "T89", 7: "T96", 9: "T01QUIET", 11: "T05"}[kext]
    omni = {key: mag[:, i].copy() for i, key in enumerate(INPUT_KEYS)}
    omni["Kp"] = omni["Kp"] / 10.0
    iso = [str(t)[:26] for t in np.asarray(times, dtype="datetime64[us]")]
    ticks = spt.Ticktock(iso, "ISO")
    loci = spc.Coords(xyz, "GEO", "car", use_irbem=True)
    out = ib.get_Bfield(ticks, loci, extMag=ext, options=list(options), omnivals=omni)
    return np.asarray(out["Bvec"], dtype=float)


def evaluate_geo(times, pos_geo_re, model: str = "T89", inputs=None, options=None,
                 backend: str = "auto") -> GeoFieldResult:
    """Total model field (IGRF + external) in GEO cartesian nT, with a validity report.

    Parameters
    ----------
    times : array_like, shape (n,)
        UTC times (datetime64, datetimes, ISO strings or a DatetimeIndex).
    pos_geo_re : array_like, shape (n, 3) or (3,)
        Positions in GEO cartesian coordinates, Earth radii.
    model : {"IGRF", "T89", "T96", "T01", "T04"}
        ``IGRF`` is the internal field only; ``T04`` is IRBEM's TS04/TS05.
    inputs : dict, optional
        IRBEM inputs by name (:data:`INPUT_KEYS`), scalars or arrays of length n. Kp in
        Kp units (``1+`` = 4/3); missing keys the model does not read default to 0.
    options : sequence of 5 int, optional
        IRBEM options; default :data:`DEFAULT_OPTIONS` (IGRF updated daily).
    backend : {"auto", "ctypes", "get_Bfield"}
        ``auto`` uses the ctypes fast path and falls back to ``get_Bfield``.

    Returns
    -------
    GeoFieldResult

    Examples
    --------
    >>> import numpy as np
    >>> t = np.array(["2019-11-01T00:00"], dtype="datetime64[ns]")
    >>> res = evaluate_geo(t, [6.6, 0.0, 0.0], "T89", {"Kp": 1.0})
    >>> res.b_geo_nT.shape, res.n_invalid
    ((1, 3), 0)
    """
    plan = prepare(times, pos_geo_re, model, inputs, options, backend)
    out = np.full((plan.n, 3), np.nan)
    fill = np.zeros(plan.n, dtype=bool)
    buffer = plan.buffer()
    for idx in plan.chunks():
        plan.compute(idx, out, buffer, fill)
    return plan.finish(out, fill)


@dataclass(frozen=True)
class EvaluationPlan:
    """A checked request, split into IRBEM calls: what :func:`evaluate_geo` does in steps.

    :func:`prepare` validates the inputs and counts the samples it excludes;
    :meth:`compute` fills one chunk of the output (any process may do any chunk);
    :meth:`finish` flags IRBEM fill values and returns the :class:`GeoFieldResult`.
    :func:`magcal.models.parallel.evaluate_parallel` shares the chunks between processes.
    """

    model: str
    kext: int
    options: tuple
    n: int
    xyz: np.ndarray
    times: np.ndarray
    columns: dict
    bad: np.ndarray
    good: np.ndarray
    reasons: dict
    backend: str

    def chunks(self, step: int = CHUNK) -> list:
        """Index of each IRBEM call: contiguous slices when nothing is excluded."""
        step = min(step, NTIME_MAX)
        if self.good.size == self.n:
            return [slice(a, min(a + step, self.n)) for a in range(0, self.n, step)]
        return [self.good[a:a + step] for a in range(0, self.good.size, step)]

    def buffer(self) -> np.ndarray:
        """Reusable (CHUNK, 25) input array: assembled chunk by chunk, few page faults."""
        return np.zeros((min(CHUNK, max(self.good.size, 1)), 25))

    def compute(self, idx, out: np.ndarray, buffer: np.ndarray, fill: np.ndarray,
                transform=None) -> None:
        """Evaluate the points ``idx`` (one item of :meth:`chunks`) into ``out[idx]``.

        ``fill[idx]`` (all False on entry) is set True where IRBEM returned its fill value
        (or NaN/inf).
        ``transform(idx, b)``, if given, maps the chunk's GEO vectors before they are
        stored (e.g. to Hpen), so that a worker process does that work too.
        """
        year, doy, sec = time_parts(self.times[idx])
        mag = buffer[:len(year)]
        for i, values in self.columns.items():
            mag[:, i] = values[idx]
        if self.backend == "ctypes":
            b = _call_multi(self.kext, self.options, year, doy, sec, self.xyz[idx], mag)
        else:
            b = _call_get_bfield(self.kext, self.options, self.times[idx], self.xyz[idx],
                                 mag.copy())
        # IRBEM marks failures with -1e31; |B| of any real field is far below 1e30 nT
        if not np.abs(b).max() < 1e30:  # also catches NaN and inf (rarely true: then per row)
            fill[idx] = ~np.all(np.abs(b) < 1e30, axis=1)
        out[idx] = b if transform is None else transform(idx, b)

    def finish(self, out: np.ndarray, fill: np.ndarray) -> GeoFieldResult:
        """Set excluded and IRBEM-fill samples to NaN (in place) and build the result."""
        reasons = dict(self.reasons)
        fill = ~self.bad & fill
        if np.any(fill):
            reasons["IRBEM fill or NaN"] = int(np.count_nonzero(fill))
        invalid = self.bad | fill
        out[invalid] = np.nan
        return GeoFieldResult(b_geo_nT=out, invalid=invalid, reasons=reasons,
                              model=self.model, backend=self.backend)


def prepare(times, pos_geo_re, model: str = "T89", inputs=None, options=None,
            backend: str = "auto") -> EvaluationPlan:
    """Check a request and plan its IRBEM calls (arguments as :func:`evaluate_geo`)."""
    model = str(model).upper()
    if model in ("TS04", "TS05", "T05"):
        model = "T04"
    if model not in KEXT:
        raise InputError(f"unknown model {model!r}; choose one of {', '.join(KEXT)}")
    opts = tuple(int(o) for o in (options if options is not None else DEFAULT_OPTIONS))
    if len(opts) != 5:
        raise InputError("IRBEM options must have 5 integers")
    if backend not in ("auto", "ctypes", "get_Bfield"):
        raise InputError(f"unknown backend {backend!r}")
    t = as_datetime64(times)
    n = t.size
    xyz = np.asarray(pos_geo_re, dtype=float)
    if xyz.ndim == 1:
        xyz = np.broadcast_to(xyz, (n, 3))
    if xyz.shape != (n, 3):
        raise InputError(f"positions have shape {xyz.shape}, expected ({n}, 3)")
    columns, bad, reasons = maginput_columns(inputs, n, model)
    nat = np.isnat(t)
    badpos = ~(np.isfinite(xyz[:, 0]) & np.isfinite(xyz[:, 1]) & np.isfinite(xyz[:, 2])) | nat
    new = badpos & ~bad
    if np.any(new):
        reasons["position or time missing"] = int(np.count_nonzero(new))
        bad |= badpos
    late = np.count_nonzero(~bad & (t >= np.datetime64(f"{IGRF_LAST_YEAR + 1}-01-01")))
    if late:
        reasons[f"info: IGRF extrapolated beyond {IGRF_LAST_YEAR}"] = int(late)
    if model == "T89":
        top = np.count_nonzero(~bad & (columns[0] >= 57)) if 0 in columns else 0
        if top:
            reasons["info: T89 top activity level (Kp >= 6-)"] = int(top)
    used = "ctypes"
    if backend != "get_Bfield" and not ctypes_available():
        if backend == "ctypes":
            raise RuntimeError("IRBEM ctypes path unavailable (libirbem.so not loadable)")
        used = "get_Bfield"
    elif backend == "get_Bfield":
        used = "get_Bfield"
    return EvaluationPlan(model=model, kext=KEXT[model], options=opts, n=n, xyz=xyz, times=t,
                          columns=columns, bad=bad,
                          good=np.flatnonzero(~bad), reasons=reasons, backend=used)


def field_geo(times, pos_geo_re, model: str = "T89", inputs=None, options=None) -> np.ndarray:
    """Total model field (IGRF + external) at GEO positions, GEO cartesian nT.

    Same as :func:`evaluate_geo` but returns only the ``(n, 3)`` array. Samples that
    could not be evaluated are NaN and a :class:`ModelRangeWarning` names the count
    and reason; use :func:`evaluate_geo` to get that report as data.

    Examples
    --------
    >>> import numpy as np
    >>> t = np.array(["2019-11-01T00:00", "2019-11-01T00:01"], dtype="datetime64[ns]")
    >>> field_geo(t, [[6.6, 0, 0], [6.6, 0, 0]], "T89", {"Kp": [1.0, 1.0]}).shape
    (2, 3)
    """
    res = evaluate_geo(times, pos_geo_re, model=model, inputs=inputs, options=options)
    if res.n_invalid:
        detail = ", ".join(f"{k}: {v}" for k, v in res.reasons.items()
                           if not k.startswith("info:"))
        warnings.warn(f"{res.n_invalid} of {len(res.invalid)} {res.model} samples set to "
                      f"NaN ({detail})", ModelRangeWarning, stacklevel=2)
    return res.b_geo_nT


def geo_position_re(lon_deg, lat_deg, r_re) -> np.ndarray:
    """GEO cartesian position (RE) from geocentric longitude, latitude (deg), radius (RE).

    Examples
    --------
    >>> geo_position_re(90.0, 0.0, 6.6).round(12) + 0.0
    array([[0. , 6.6, 0. ]])
    """
    lon = np.deg2rad(np.atleast_1d(np.asarray(lon_deg, dtype=float)))
    lat = np.deg2rad(np.atleast_1d(np.asarray(lat_deg, dtype=float)))
    r = np.atleast_1d(np.asarray(r_re, dtype=float))
    lon, lat, r = np.broadcast_arrays(lon, lat, r)
    return np.stack([r * np.cos(lat) * np.cos(lon), r * np.cos(lat) * np.sin(lon),
                     r * np.sin(lat)], axis=-1)


@functools.lru_cache(maxsize=1)
def library_version() -> str:
    """Version tag of the IRBEM build in use (spacepy version + library size and mtime)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        sp = version("spacepy")
    except PackageNotFoundError:  # pragma: no cover
        sp = "unknown"
    try:
        st = os.stat(irbem_library_path())
        lib = f"{st.st_size}-{int(st.st_mtime)}"
    except (OSError, ImportError):
        lib = "none"
    return f"spacepy-{sp}/libirbem-{lib}"
