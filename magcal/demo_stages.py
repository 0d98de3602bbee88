"""The stages of ``magcal demo``, one function each, in chain order.

A stage takes ``(data_dir, stage_outdir, context)`` and returns ``(lines, products)``:
summary lines for the console and the product files it wrote. ``context`` carries
results from earlier stages (e.g. the corrected month for alignment).
"""

from __future__ import annotations

from pathlib import Path

from magcal.demo import require
from magcal.errors import NotYetAvailableError


def stage_ac(data: Path, out: Path, context: dict):
    require("magcal.ac.chain")
    raise NotYetAvailableError("this demo stage is not wired yet")


def stage_offsets(data: Path, out: Path, context: dict):
    require("magcal.offsets.windows")
    raise NotYetAvailableError("this demo stage is not wired yet")


def stage_alignment(data: Path, out: Path, context: dict):
    require("magcal.alignment.wahba")
    raise NotYetAvailableError("this demo stage is not wired yet")


def stage_spin(data: Path, out: Path, context: dict):
    require("magcal.spin.ripple")
    raise NotYetAvailableError("this demo stage is not wired yet")


def stage_discover(data: Path, out: Path, context: dict):
    require("magcal.discover.loop")
    raise NotYetAvailableError("this demo stage is not wired yet")


def stage_report(data: Path, out: Path, context: dict):
    require("magcal.report.html")
    raise NotYetAvailableError("this demo stage is not wired yet")


STAGES = [
    ("AC cleaning (PiCoG)", stage_ac),
    ("offsets against T89 (monthly product)", stage_offsets),
    ("alignment against the model", stage_alignment),
    ("spin calibration", stage_spin),
    ("discover model gaps", stage_discover),
    ("report", stage_report),
]
