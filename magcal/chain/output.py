"""The chain's products in the format of ``[output] format`` (CONTRACTS §7.1).

``format = "auto"`` (the default) writes the input's family: GOES-R netCDF4 or netCDF
inputs give CF-1.8 netCDF4 products, CDF inputs ISTP CDF, CSV inputs CSV. The corrected
daily files are written in that format (``corrected/CORRECTED_YYYYMMDD.csv|.nc|.cdf``);
the offset product is written in it beside ``offsets/OFFSETS.csv``, which every run
keeps (CONTRACTS §7 names it, and the report reads it).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from magcal.chain.config import ChainConfig
from magcal.io.products import FAMILY, SUFFIX, write_product

#: Values of ``[output] format``.
OUTPUT_FORMATS = ("auto", "csv", "netcdf", "cdf")


def product_format(cfg: ChainConfig, files=None) -> str:
    """The products' format of a run: ``[output] format``, or the family of the input
    (``[input] format`` or the first input file's content) when ``auto``."""
    chosen = cfg.sections.get("output", {}).get("format", "auto")
    if chosen != "auto":
        return chosen
    given = cfg["input"]["format"]
    if given == "auto":
        from magcal.io.formats import detect_format

        files = files if files is not None else cfg.input_files()
        if not files:
            return "csv"
        given = detect_format(files[0])
    return FAMILY.get(given, "csv")


def corrected_name(day: str, fmt: str) -> str:
    """``CORRECTED_YYYYMMDD`` with the format's suffix."""
    return f"CORRECTED_{day.replace('-', '')}{SUFFIX[fmt]}"


def other_formats(folder: Path, day: str, fmt: str) -> list[Path]:
    """The files of ``day`` in the other product formats (left by an earlier run)."""
    return [folder / corrected_name(day, f) for f in SUFFIX if f != fmt
            and (folder / corrected_name(day, f)).is_file()]


def write_day_product(path: str | Path, fmt: str, times: pd.DatetimeIndex,
                      columns: dict, provenance: dict | None = None) -> Path:
    """One corrected day in a binary format: ``columns`` (name -> array, any number:
    ``Hp,He,Hn``, ``offset_flag``, ``quality``...) on the day's times."""
    index = times if times.tz is not None else times.tz_localize("UTC")
    frame = pd.DataFrame({k: np.asarray(v) for k, v in columns.items()},
                         index=index.rename("time"))
    if "offset_flag" in frame:
        frame["offset_flag"] = frame["offset_flag"].astype(np.int8)
    return write_product(path, frame, fmt, provenance=provenance,
                         title="magcal corrected magnetic field (Hpen), one UTC day")


def write_offsets_product(path: str | Path, table, fmt: str) -> Path:
    """The offset product (the columns of ``OFFSETS.csv``) in a binary format, on the
    window centres; parameters, warnings and provenance in its global attributes."""
    from magcal.io.jsonio import to_jsonable

    frame = table.to_frame()
    index = pd.DatetimeIndex(frame.pop("center"), name="center").tz_localize("UTC")
    frame.index = index
    for c in ("start", "end"):
        frame[c] = pd.DatetimeIndex(frame[c]).tz_localize("UTC")
    payload = {"parameters": table.parameters, "warnings": list(table.warnings),
               "provenance": table.provenance, **table.levels_json()}
    return write_product(path, frame, fmt, provenance=to_jsonable(payload),
                         title="magcal DC offsets per sliding window (data minus model, Hpen)")
