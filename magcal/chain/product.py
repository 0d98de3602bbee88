"""What a chain stage returns: a frozen product that knows how to write itself.

A stage function computes; :meth:`StageProduct.write` puts its tables (CSV), documents
(JSON) and figures into the stage's folder, atomically, and returns the paths for the
manifest. Every document carries ``schema_version``, ``magcal_version`` and the
stage's provenance (parameters and input checksums).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable

import pandas as pd

from magcal.io.jsonio import to_jsonable, write_json
from magcal.provenance import WALL_CLOCK_KEYS, without_wall_clock  # noqa: F401 - re-exported

@dataclass(frozen=True)
class StageProduct:
    """The outcome of one chain stage.

    Attributes
    ----------
    stage : str
        Stage name (also the product folder: ``ac``, ``offsets``, ...).
    summary : dict
        The numbers a user reads first (JSON-ready), written as ``<STAGE>.json``
        unless a document of that name is given.
    lines : tuple of str
        Console summary lines.
    tables : dict
        ``file name -> DataFrame`` written as CSV (time index as the first column).
    documents : dict
        ``file name -> dict`` written as JSON.
    writers : dict
        ``file name -> callable(path)`` for products with their own writer (figures,
        OFFSETS.csv).
    provenance : dict
    warnings : tuple of str
        Things the user must know (a result that could not be determined, a product
        worse than doing nothing); printed on stderr by the CLI.
    """

    stage: str
    summary: dict = field(default_factory=dict)
    lines: tuple = ()
    tables: dict = field(default_factory=dict)
    documents: dict = field(default_factory=dict)
    writers: dict = field(default_factory=dict)
    provenance: dict = field(default_factory=dict)
    warnings: tuple = ()

    def to_json(self) -> dict:
        """The stage summary with its warnings and provenance."""
        return to_jsonable({"stage": self.stage, **self.summary,
                            "warnings": list(self.warnings), "provenance": self.provenance})

    def write(self, folder: str | Path) -> list[Path]:
        """Write every product file into ``folder``; return their paths in order."""
        from magcal.io.csv import write_csv_frame

        out = Path(folder)
        out.mkdir(parents=True, exist_ok=True)
        paths: list[Path] = []
        for name, doc in self.documents.items():
            paths.append(write_json(out / name, without_wall_clock(to_jsonable(doc))))
        summary_name = f"{self.stage.upper()}.json"
        if summary_name not in self.documents:
            paths.append(write_json(out / summary_name, without_wall_clock(self.to_json())))
        for name, table in self.tables.items():
            paths.append(_write_table(write_csv_frame, out / name, table,
                                      without_wall_clock(self.provenance)))
        for name, writer in self.writers.items():
            written = writer(out / name)
            paths.append(Path(written) if written is not None else out / name)
        return paths


    def with_tables_written(self, folder: str | Path) -> StageProduct:
        """Write the tables into ``folder`` now; return the product with writers that
        only name the written files in their place.

        A worker writes a stage's large tables (a year of 1-min samples is seconds of
        CSV formatting) while the driver goes on; :meth:`write` in the driver then lists
        the same files in the same order.
        """
        from magcal.io.csv import write_csv_frame

        out = Path(folder)
        out.mkdir(parents=True, exist_ok=True)
        prov = without_wall_clock(self.provenance)
        done = {name: Written(_write_table(write_csv_frame, out / name, table, prov))
                for name, table in self.tables.items()}
        return replace(self, tables={}, writers={**done, **self.writers})


@dataclass(frozen=True)
class Written:
    """A writer of a file already written (:meth:`StageProduct.with_tables_written`):
    returns its path."""

    path: Path

    def __call__(self, path) -> Path:
        if Path(path) != self.path:
            raise ValueError(f"{self.path} was written, not {path}")
        return self.path


def _write_table(writer: Callable, path: Path, table: pd.DataFrame, provenance: dict) -> Path:
    written = writer(path, table, provenance=provenance or None, float_format="%.6f")
    return Path(written) if written is not None else path
