"""JSON products with a schema version (CONTRACTS §0).

Every JSON file magcal writes carries ``schema_version`` (int) and ``magcal_version``.
NumPy scalars and arrays, dataclasses, paths and timestamps are converted on the way.
NaN is written as ``null`` so the files are strict JSON.
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from magcal._version import __version__
from magcal.errors import InputError, not_a_file_error
from magcal.io.atomic import atomic_path

SCHEMA_VERSION = 1


def to_jsonable(obj: Any) -> Any:
    """Convert ``obj`` recursively into plain JSON types (NaN and inf become ``None``)."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: to_jsonable(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist())
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        value = float(obj)
        return value if math.isfinite(value) else None
    if isinstance(obj, (str, type(None))):
        return obj
    if isinstance(obj, os.PathLike):
        return str(obj)
    if isinstance(obj, (_dt.datetime, _dt.date)) or hasattr(obj, "isoformat"):
        return obj.isoformat()
    if isinstance(obj, np.datetime64):
        return str(obj)
    raise TypeError(f"cannot convert {type(obj).__name__} to JSON")


def product_dict(payload: dict, schema_version: int = SCHEMA_VERSION) -> dict:
    """Return ``payload`` as JSON types with ``schema_version`` and ``magcal_version`` first."""
    out = {"schema_version": int(schema_version), "magcal_version": __version__}
    out.update(to_jsonable(payload))
    return out


def dumps(payload: dict, schema_version: int = SCHEMA_VERSION) -> str:
    """Serialise a product dictionary (see :func:`product_dict`) to an indented string."""
    return json.dumps(product_dict(payload, schema_version), indent=2, allow_nan=False)


def write_json(path: str | os.PathLike, payload: dict,
               schema_version: int = SCHEMA_VERSION) -> Path:
    """Write a product JSON file atomically; return its path."""
    text = dumps(payload, schema_version)
    with atomic_path(path) as tmp:
        tmp.write_text(text + "\n")
    return Path(path)


def read_json(path: str | os.PathLike, required: tuple[str, ...] = ()) -> dict:
    """Read a product JSON file, checking ``schema_version`` and required keys.

    Raises
    ------
    InputError
        If the file is missing, not JSON, lacks ``schema_version`` or a required key.
    """
    p = Path(path)
    if not p.is_file():
        raise not_a_file_error(p)
    try:
        data = json.loads(p.read_text())
    except json.JSONDecodeError as exc:
        raise InputError(f"not valid JSON ({exc.msg} at line {exc.lineno})", file=p) from None
    if not isinstance(data, dict) or "schema_version" not in data:
        raise InputError("not a magcal product: no schema_version key", file=p)
    missing = [k for k in required if k not in data]
    if missing:
        raise InputError(f"missing key(s) {', '.join(missing)}", file=p)
    return data
