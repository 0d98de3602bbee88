"""Provenance records carried by every magcal product.

A provenance record says which magcal version made a product, when, from which input
files (with their SHA-256 checksums), with which parameters, and through which
processing steps. Records are plain JSON-ready dictionaries so they can be embedded in
JSON, CSV headers or CDF global attributes alike.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import os
import platform
from pathlib import Path
from typing import Any, Iterable, Mapping

from magcal._version import __version__


def file_sha256(path: str | os.PathLike, chunk_size: int = 1 << 20) -> str:
    """SHA-256 hex digest of a file, read in chunks."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(chunk_size), b""):
            digest.update(block)
    return digest.hexdigest()


def files_sha256(paths) -> list[str]:
    """:func:`file_sha256` of each path, in order, on one thread per core (hashlib and
    file reads release the GIL: a chain run checks hundreds of MB of daily files)."""
    from concurrent.futures import ThreadPoolExecutor

    paths = list(paths)
    if len(paths) < 2:
        return [file_sha256(p) for p in paths]
    with ThreadPoolExecutor(min(len(paths), max(1, len(os.sched_getaffinity(0))))) as pool:
        return list(pool.map(file_sha256, paths))


def utc_now_iso() -> str:
    """Current UTC time as ISO-8601 with a trailing ``Z`` (seconds resolution)."""
    return _dt.datetime.now(_dt.timezone.utc).replace(microsecond=0).strftime(
        "%Y-%m-%dT%H:%M:%SZ")


def make_provenance(step: str, parameters: Mapping[str, Any] | None = None,
                    inputs: Iterable[str | os.PathLike] = (),
                    history: Iterable[Mapping[str, Any]] = (), *,
                    wall_clock: bool = True) -> dict:
    """Build a provenance record for a product.

    Parameters
    ----------
    step : str
        Name of the processing step that made the product (e.g. ``"picog fit"``).
    parameters : mapping, optional
        The parameters of that step (JSON-serialisable).
    inputs : iterable of path-like
        Input files; each is listed with its SHA-256 checksum and size in bytes.
    history : iterable of mapping
        Earlier processing steps (e.g. a series' own provenance) to carry along.
    wall_clock : bool
        Record when the product was made (``created_utc``). False leaves out every
        wall-clock time (also the :data:`WALL_CLOCK_KEYS` of ``history``), so the same
        inputs give a byte-identical product on every run (the chain's products).

    Returns
    -------
    dict
        ``{"magcal_version", "created_utc", "step", "parameters", "inputs", "history",
        "platform"}`` (without ``created_utc`` when ``wall_clock`` is False).

    Examples
    --------
    >>> rec = make_provenance("demo", {"window_days": 28})
    >>> rec["step"], rec["parameters"]["window_days"]
    ('demo', 28)
    >>> "created_utc" in make_provenance("demo", wall_clock=False)
    False
    """
    files = []
    for path in inputs:
        p = Path(path)
        files.append({"path": str(p), "sha256": file_sha256(p), "bytes": p.stat().st_size})
    record = {
        "magcal_version": __version__,
        "created_utc": utc_now_iso(),
        "step": step,
        "parameters": dict(parameters or {}),
        "inputs": files,
        "history": [dict(h) for h in history],
        "platform": {"python": platform.python_version(), "machine": platform.machine()},
    }
    return record if wall_clock else without_wall_clock(record)


#: Keys of provenance records that hold wall-clock times (``wall_clock=False`` records,
#: and the chain's products, carry none of them).
WALL_CLOCK_KEYS = ("created_utc", "time_utc")


def without_wall_clock(obj):
    """``obj`` (nested dicts and lists) without the :data:`WALL_CLOCK_KEYS`.

    Examples
    --------
    >>> without_wall_clock({"step": "x", "created_utc": "2026-01-01T00:00:00Z",
    ...                     "history": [{"step": "validate", "time_utc": "..."}]})
    {'step': 'x', 'history': [{'step': 'validate'}]}
    """
    if isinstance(obj, dict):
        return {k: without_wall_clock(v) for k, v in obj.items() if k not in WALL_CLOCK_KEYS}
    if isinstance(obj, (list, tuple)):
        return type(obj)(without_wall_clock(v) for v in obj)
    return obj
