"""Helpers shared by the subcommand modules (argument types, output handling)."""

from __future__ import annotations

from pathlib import Path

from magcal.errors import InputError


def existing_file(path: str) -> Path:
    """Check that an input file exists; raise :class:`InputError` otherwise."""
    p = Path(path)
    if not p.is_file():
        raise InputError("file not found", file=p)
    return p


def add_output(parser, required: bool = True, help_text: str = "output file") -> None:
    """Add the standard ``-o/--output`` option."""
    parser.add_argument("-o", "--output", required=required, help=help_text)
