"""Model field along an orbit in Hpen: cadence grid, parallel processes, on-disk cache.

:func:`model_field_hpen` evaluates IGRF + a Tsyganenko model (through
:func:`magcal.models.irbem.evaluate_geo`) at the spacecraft, at the cadence of the
comparison (1 min by default: denser input times are served by linear interpolation of
the GEO field between grid points), in chunks shared between forked processes
(:mod:`magcal.models.parallel`; IRBEM is not thread safe), and rotates it to Hpen with
:func:`magcal.frames.hpen.geo_to_hpen`.

Results are cached on disk (one file per request) under a key made of the model, its
inputs, the positions, the times, the options and the IRBEM/spacepy/magcal versions; a
rerun with the same request reads the file instead of calling IRBEM, and the result
says so (``cache_hits``).
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass, field as dc_field
from pathlib import Path

import numpy as np

from magcal._version import __version__
from magcal.errors import InputError
from magcal.frames.hpen import geo_to_hpen, hpen_basis
from magcal.io.jsonio import product_dict
from magcal.models import irbem
from magcal.models.parallel import evaluate_parallel
from magcal.timeconv import as_datetime64

_CACHE_FORMAT = 2  # 2: plain .npy files (1 was one .npz per entry)


@dataclass(frozen=True)
class ModelFieldResult:
    """Model field in Hpen at the requested times.

    Attributes
    ----------
    times : ndarray of datetime64[ns], shape (n,)
    b_hpen_nT : ndarray, shape (n, 3)
        ``(Hp, He, Hn)`` in nT; NaN where the model could not be evaluated.
    invalid : ndarray of bool, shape (n,)
        True where ``b_hpen_nT`` is NaN.
    reasons : dict
        ``{reason: count}`` over the evaluation points (first reason per point), plus
        ``info:`` entries that do not invalidate anything.
    model : str
    cadence_s : float or None
        Evaluation cadence; None when evaluated at the given times.
    n_evaluated : int
        Number of IRBEM evaluations made (0 on a cache hit).
    cache_hits, cache_misses : int
        1/0 per request when a cache directory is used, else 0/0.
    backend : str
        ``ctypes`` or ``get_Bfield`` (``cache`` on a hit).
    provenance : dict
    """

    times: np.ndarray
    b_hpen_nT: np.ndarray
    invalid: np.ndarray
    reasons: dict
    model: str
    cadence_s: float | None
    n_evaluated: int
    cache_hits: int = 0
    cache_misses: int = 0
    backend: str = "ctypes"
    cache_key: str = ""
    provenance: dict = dc_field(default_factory=dict)

    @property
    def n_invalid(self) -> int:
        """Number of samples set to NaN."""
        return int(np.count_nonzero(self.invalid))

    def to_frame(self):
        """``pandas.DataFrame`` with a UTC index named ``time`` and columns Hp, He, Hn."""
        import pandas as pd

        idx = pd.DatetimeIndex(self.times, name="time")
        return pd.DataFrame(self.b_hpen_nT, index=idx, columns=["Hp", "He", "Hn"])

    def summary(self) -> dict:
        """JSON-ready report: counts, reasons, cache use."""
        return {"model": self.model, "n": int(len(self.times)), "n_invalid": self.n_invalid,
                "reasons": dict(self.reasons), "cadence_s": self.cadence_s,
                "n_evaluated": self.n_evaluated, "cache_hits": self.cache_hits,
                "cache_misses": self.cache_misses, "backend": self.backend,
                "cache_key": self.cache_key}

    def to_json(self) -> dict:
        """Summary with schema/magcal versions and provenance (no sample arrays)."""
        return product_dict({**self.summary(), "provenance": self.provenance})


# --------------------------------------------------------------------------- inputs
def _sample_step(series, times: np.ndarray) -> np.ndarray:
    """Value of a time-indexed pandas object valid at ``times`` (previous-value lookup)."""
    idx = as_datetime64(series.index)
    if idx.size and np.any(np.diff(idx.astype(np.int64)) <= 0):
        order = np.argsort(idx, kind="stable")
        idx, series = idx[order], series.iloc[order]
    values = np.asarray(series, dtype=float)
    pos = np.searchsorted(idx, times, side="right") - 1
    out = np.full((times.size,) + values.shape[1:], np.nan)
    ok = pos >= 0
    out[ok] = values[pos[ok]]
    return out


def _align(value, times: np.ndarray, name: str) -> np.ndarray:
    """Scalar, aligned array or time-indexed pandas object -> float array of len(times)."""
    if hasattr(value, "index") and hasattr(value, "iloc"):
        return _sample_step(value, times)
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 0:
        return np.full(times.size, float(arr))
    if arr.shape[0] != times.size:
        raise InputError(f"{name} has {arr.shape[0]} values for {times.size} times "
                         "(give a scalar, one value per time, or a time-indexed series)")
    return arr


def _model_inputs(model: str, times: np.ndarray, kp, drivers) -> dict:
    """IRBEM input dict aligned with ``times`` (only the inputs the model reads)."""
    needed = irbem.REQUIRED_INPUTS[model]
    inputs: dict[str, np.ndarray] = {}
    if kp is not None:
        inputs["Kp"] = _align(kp, times, "kp")
    if drivers is not None:
        keys = list(drivers.columns) if hasattr(drivers, "columns") else list(drivers)
        for key in keys:
            if key not in irbem.INPUT_KEYS:
                continue
            if key == "Kp" and "Kp" in inputs:
                continue
            inputs[key] = _align(drivers[key], times, key)
    missing = [k for k in needed if k not in inputs]
    if missing:
        what = "kp" if missing == ["Kp"] else "drivers with " + ", ".join(missing)
        raise InputError(f"model {model} needs {what}")
    return {k: inputs[k] for k in needed}


# --------------------------------------------------------------------------- cache key
def _is_regular(v: np.ndarray, block: int = 65536) -> bool:
    """True when the integer sequence ``v`` has one constant step (checked block-wise)."""
    if v.size < 3:
        return True
    step = v[1] - v[0]
    for a in range(0, v.size - 1, block):
        z = min(a + block, v.size - 1)
        if not np.all(v[a + 1:z + 1] - v[a:z] == step):
            return False
    return True


def _digest_array(h, name: str, arr: np.ndarray) -> None:
    """Feed a compact canonical form of ``arr`` to hash ``h`` (constant / regular / RLE)."""
    a = np.ascontiguousarray(arr)
    h.update(f"|{name}:{a.dtype.str}:{a.shape}|".encode())
    if a.size == 0:
        return
    if a.ndim > 1:
        flat = a.reshape(a.shape[0], -1)
        if np.array_equal(flat, np.broadcast_to(flat[:1], flat.shape),
                          equal_nan=a.dtype.kind == "f"):
            h.update(b"const")
            h.update(flat[:1].tobytes())
            return
        h.update(a.tobytes())
        return
    if a.dtype.kind in "iuM" and _is_regular(a.view(np.int64)):
        h.update(b"regular")
        h.update(a[:1].tobytes() + np.diff(a[:2].view(np.int64)).tobytes())
        return
    # one pass finds the runs: none -> constant, few -> run-length code, else raw bytes
    change = np.flatnonzero(a[1:] != a[:-1])
    if change.size == 0:
        h.update(b"const")
        h.update(a[:1].tobytes())
        return
    if change.size < a.size // 4:
        h.update(b"rle")
        h.update(change.tobytes())
        h.update(a[np.r_[0, change + 1]].tobytes())
        return
    h.update(a.tobytes())


def cache_key(model: str, times: np.ndarray, lon, lat, r, inputs: dict, options,
              cadence_s) -> str:
    """Hex key of a request (model, inputs, positions, times, options, versions)."""
    h = hashlib.blake2b(digest_size=20)
    h.update(json.dumps({"format": _CACHE_FORMAT, "model": model, "options": list(options),
                         "cadence_s": cadence_s, "magcal": __version__,
                         "irbem": irbem.library_version()}, sort_keys=True).encode())
    _digest_array(h, "times", times)
    for name, arr in (("lon", lon), ("lat", lat), ("r", r)):
        _digest_array(h, name, np.atleast_1d(np.asarray(arr, dtype=float)))
    for key in sorted(inputs):
        _digest_array(h, key, np.asarray(inputs[key], dtype=float))
    return h.hexdigest()


def _cache_parts(path: Path) -> tuple[Path, Path, Path]:
    """The three files of one cache entry: field (.npy), invalid mask (.npy), meta (.json).

    Plain .npy files load at disk speed (no zip container, no CRC pass) and the field is
    memory-mapped: a cached year of 1-min vectors is back in a few milliseconds. Entries
    are replaced with ``os.replace`` (a new file), never rewritten in place, so a mapped
    array stays valid.
    """
    return (path.with_suffix(".npy"), path.with_suffix(".invalid.npy"),
            path.with_suffix(".json"))


def _cache_load(path: Path):
    field_path, invalid_path, meta_path = _cache_parts(path)
    try:
        meta = json.loads(meta_path.read_text())
        invalid = np.load(invalid_path, allow_pickle=False)
        # mapped copy-on-write from the page cache: no copy, faulted in 64 kB at a time,
        # and still writable (writes stay private to this process)
        b_hpen = np.load(field_path, mmap_mode="c", allow_pickle=False).view(np.ndarray)
    except (OSError, KeyError, ValueError):
        return None
    if b_hpen.shape != (invalid.size, 3):
        return None
    return b_hpen, invalid, meta


def _cache_temp_names(path: Path) -> list[Path]:
    """Temporary names of the three files of an entry while it is being written."""
    return [q.with_name(f".{q.name}.{os.getpid()}.part") for q in _cache_parts(path)]


def _cache_open_field(path: Path, n: int) -> np.ndarray:
    """Writable file-backed (n, 3) array at the entry's temporary field name.

    Worker processes write their chunks straight into it (a shared file mapping), so
    storing the entry afterwards costs no pass over the data; see :func:`_cache_store`.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    return np.lib.format.open_memmap(_cache_temp_names(path)[0], mode="w+",
                                     dtype=np.float64, shape=(n, 3))


def _cache_store(path: Path, b_hpen, invalid, meta: dict) -> None:
    """Write an entry atomically; ``b_hpen=None`` when its field file was filled in place."""
    path.parent.mkdir(parents=True, exist_ok=True)
    parts = _cache_parts(path)
    tmps = _cache_temp_names(path)
    try:
        tmps[2].write_text(json.dumps(meta))
        with open(tmps[1], "wb") as handle:
            np.save(handle, np.asarray(invalid, dtype=bool))
        if b_hpen is not None:
            with open(tmps[0], "wb") as handle:
                np.save(handle, np.ascontiguousarray(b_hpen, dtype=np.float64))
        # the field file last: an entry counts only once its field file exists
        for tmp, final in zip(tmps[::-1], parts[::-1]):
            os.replace(tmp, final)
    finally:
        for tmp in tmps:
            if tmp.exists():
                tmp.unlink()


# --------------------------------------------------------------------------- evaluation
def _grid_plan(times: np.ndarray, cadence_s):
    """Evaluation grid for ``times`` at ``cadence_s``, or None to evaluate at ``times``.

    Returns ``(grid, k, w)``: grid times, the index of the grid point at or before each
    time, and the linear weight of the next grid point.
    """
    if cadence_s is None or times.size < 2:
        return None
    step = np.int64(round(float(cadence_s) * 1e9))
    if step <= 0:
        raise InputError("cadence_s must be positive")
    ns = times.astype(np.int64)
    spacing = ns[1] - ns[0] if _is_regular(ns) else np.median(np.diff(ns))
    if spacing >= step * 0.999:
        return None
    base = (ns[0] // step) * step
    cell = (ns - base) // step
    frac = ((ns - base) - cell * step) / step
    need = np.unique(np.concatenate([cell, cell[frac > 0] + 1]))
    k = np.searchsorted(need, cell)
    grid = (base + need * step).astype("datetime64[ns]")
    return grid, k, frac


def _evaluation_points(t, lon, lat, r, inputs: dict, plan):
    """Times, GEO positions (RE) and model inputs at which IRBEM is called: the output
    times, or the grid of :func:`_grid_plan` (inputs of the nearest output time,
    positions interpolated)."""
    n = t.size
    if plan is None:
        t_eval, lon_e, lat_e, r_e, inp_e = t, lon, lat, r, inputs
    else:
        t_eval = plan[0]
        nearest = np.clip(np.searchsorted(t, t_eval), 0, n - 1)
        prev = np.clip(nearest - 1, 0, n - 1)
        closer = np.abs(t[prev] - t_eval) < np.abs(t[nearest] - t_eval)
        nearest = np.where(closer, prev, nearest)
        inp_e = {name: v[nearest] for name, v in inputs.items()}
        te = t_eval.astype(np.int64).astype(float)
        ts = t.astype(np.int64).astype(float)
        lon_e = (np.interp(te, ts, np.rad2deg(np.unwrap(np.deg2rad(lon))))
                 if lon.ndim else lon)
        lat_e = np.interp(te, ts, lat) if lat.ndim else lat
        r_e = np.interp(te, ts, r) if r.ndim else r
    xyz = irbem.geo_position_re(lon_e, lat_e, r_e)
    if xyz.shape[0] != t_eval.size:
        xyz = np.broadcast_to(xyz, (t_eval.size, 3))
    return t_eval, xyz, inp_e


def _worker_hpen_transform(lon, lat, plan):
    """The GEO -> Hpen rotation a worker applies to its chunk, or None.

    Done by the worker that computed each chunk when it is the same at the evaluation
    points as at the output times (one position, or no grid): the parent then never
    makes another pass over the whole array.
    """
    if lon.ndim == 0 and lat.ndim == 0:
        rows = hpen_basis(lon, lat)[0].T

        def to_hpen(idx, b):
            # plain ufuncs, no BLAS call inside a forked worker
            return b[:, :1] * rows[0] + b[:, 1:2] * rows[1] + b[:, 2:] * rows[2]
        return to_hpen
    if plan is None:
        def to_hpen(idx, b):
            return geo_to_hpen(b, lon[idx] if lon.ndim else lon, lat[idx] if lat.ndim else lat)
        return to_hpen
    return None


def model_field_hpen(times, lon_deg, lat_deg, r_re, model: str = "T89", kp=None,
                     drivers=None, cadence_s: float | None = 60, n_jobs: int | None = None,
                     cache_dir=None, options=None) -> ModelFieldResult:
    """IGRF + Tsyganenko field at the spacecraft in Hpen.

    Parameters
    ----------
    times : array_like, shape (n,)
        UTC sample times (datetime64, DatetimeIndex, ISO strings).
    lon_deg, lat_deg, r_re : float or array_like, shape (n,)
        Geographic (geocentric) longitude, latitude in degrees and radius in Earth
        radii; scalars for a geostationary spacecraft (e.g. 128.2, 0, 6.6).
    model : {"IGRF", "T89", "T96", "T01", "T04"}
    kp : float, array_like (n,) or time-indexed pandas Series, optional
        Kp in Kp units (``1+`` = 4/3); a Series is read as a step function (each value
        valid from its time stamp to the next). Needed by T89.
    drivers : dict or DataFrame, optional
        Solar-wind inputs named as IRBEM inputs (``Dst, Pdyn, ByIMF, BzIMF, G1..G3,
        W1..W6``); scalars, aligned arrays, or a time-indexed DataFrame (step function).
    cadence_s : float or None
        Evaluation cadence (default 60 s). Times denser than this are served by linear
        interpolation of the GEO field between grid points; None evaluates at ``times``.
    n_jobs : int, optional
        Worker processes (default: the usable CPU cores). 1 runs in-process.
    cache_dir : path-like, optional
        Directory of the on-disk cache; None disables caching.
    options : sequence of 5 int, optional
        IRBEM options (default :data:`magcal.models.irbem.DEFAULT_OPTIONS`).

    Returns
    -------
    ModelFieldResult

    Examples
    --------
    >>> import numpy as np
    >>> t = np.datetime64("2019-11-01T00:00", "ns") + np.arange(3) * np.timedelta64(60, "s")
    >>> res = model_field_hpen(t, 128.2, 0.0, 6.6, "T89", kp=1.0, n_jobs=1)
    >>> res.b_hpen_nT.shape, res.n_invalid, bool(90 < res.b_hpen_nT[0, 0] < 130)
    ((3, 3), 0, True)
    """
    from magcal.provenance import make_provenance

    model = str(model).upper()
    model = "T04" if model in ("TS04", "TS05", "T05") else model
    if model not in irbem.KEXT:
        raise InputError(f"unknown model {model!r}; choose one of {', '.join(irbem.KEXT)}")
    t = as_datetime64(times)
    n = t.size
    if n and np.any(t[1:] <= t[:-1]):
        raise InputError("times must be strictly increasing")
    opts = tuple(int(o) for o in (options if options is not None else irbem.DEFAULT_OPTIONS))
    lon, lat, r = (np.asarray(v, dtype=float) for v in (lon_deg, lat_deg, r_re))
    for name, v in (("lon_deg", lon), ("lat_deg", lat), ("r_re", r)):
        if v.ndim and v.shape[0] != n:
            raise InputError(f"{name} has {v.shape[0]} values for {n} times")
    inputs = _model_inputs(model, t, kp, drivers)
    params = {"model": model, "cadence_s": cadence_s, "options": list(opts),
              "n": int(n), "irbem": irbem.library_version()}

    key = ""
    path = None
    if cache_dir is not None:
        key = cache_key(model, t, lon, lat, r, inputs, opts, cadence_s)
        path = Path(cache_dir) / f"{model}-{key}.npy"
        hit = _cache_load(path) if path.exists() else None
        if hit is not None:
            b_hpen, invalid, meta = hit
            return ModelFieldResult(
                times=t, b_hpen_nT=b_hpen, invalid=invalid, reasons=meta["reasons"],
                model=model, cadence_s=cadence_s, n_evaluated=0, cache_hits=1,
                cache_misses=0, backend="cache", cache_key=key,
                provenance=make_provenance("model field", {**params, "cache": "hit"}))

    plan = _grid_plan(t, cadence_s)
    t_eval, xyz, inp_e = _evaluation_points(t, lon, lat, r, inputs, plan)
    to_hpen = _worker_hpen_transform(lon, lat, plan)
    # With no grid, the workers' output is the product: write it straight into the cache
    direct = path is not None and plan is None and to_hpen is not None and n > 0
    target = _cache_open_field(path, n) if direct else None
    try:
        b_hpen, bad, reasons, backend = evaluate_parallel(t_eval, xyz, model, inp_e, opts,
                                                          n_jobs, transform=to_hpen, out=target)
    except BaseException:
        if direct:  # leave no half-written entry behind
            del target
            _cache_temp_names(path)[0].unlink(missing_ok=True)
        raise
    if plan is not None:
        _, k, w = plan
        k1 = np.minimum(k + 1, t_eval.size - 1)
        b_hpen = b_hpen[k] * (1 - w)[:, None] + b_hpen[k1] * w[:, None]
        bad = bad[k] | (bad[k1] & (w > 0))
        if to_hpen is None:
            b_hpen = geo_to_hpen(b_hpen, lon, lat)
        b_hpen[bad] = np.nan
    n_eval = int(t_eval.size)
    if path is not None:
        meta = {"reasons": reasons, "n_evaluated": n_eval}
        if direct:
            target.flush()
            del target, b_hpen  # drop the shared, writable mapping of the cache file
            _cache_store(path, None, bad, meta)
            hit = _cache_load(path)  # private copy-on-write view, pages still cached
            if hit is None:
                raise OSError(f"model field cache entry {path} unreadable after writing it")
            b_hpen = hit[0]
        else:
            _cache_store(path, b_hpen, bad, meta)
    return ModelFieldResult(
        times=t, b_hpen_nT=b_hpen, invalid=bad, reasons=reasons, model=model,
        cadence_s=cadence_s, n_evaluated=n_eval, cache_hits=0,
        cache_misses=1 if path is not None else 0, backend=backend, cache_key=key,
        provenance=make_provenance("model field", params))
