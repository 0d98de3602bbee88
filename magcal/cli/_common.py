"""Helpers shared by the subcommand modules (argument types, output handling)."""

from __future__ import annotations

from pathlib import Path

from magcal.errors import InputError, not_a_file_error


def existing_file(path: str) -> Path:
    """Check that an input file exists; raise :class:`InputError` otherwise."""
    p = Path(path)
    if not p.is_file():
        raise not_a_file_error(p)
    return p


def add_output(parser, required: bool = True, help_text: str = "output file") -> None:
    """Add the standard ``-o/--output`` option (an output file, checked by
    :func:`check_output_files` before the verb runs)."""
    parser.add_argument("-o", "--output", required=required, help=help_text)
    parser.set_defaults(file_outputs=("output",))


def check_output_files(args) -> None:
    """Refuse output files that are existing directories, for every verb at once.

    ``args.file_outputs`` names the options that hold output *files* (set by
    :func:`add_output`; verbs writing a folder, like ``run`` and ``demo``, have none).

    Examples
    --------
    >>> import tempfile
    >>> from types import SimpleNamespace
    >>> d = tempfile.mkdtemp()
    >>> check_output_files(SimpleNamespace(file_outputs=("output",), output=d))
    Traceback (most recent call last):
    ...
    magcal.errors.InputError: ...: is a directory, expected an output file (give a file name)
    """
    for name in getattr(args, "file_outputs", ()):
        value = getattr(args, name, None)
        if value is not None and Path(value).is_dir():
            raise InputError("is a directory, expected an output file (give a file name)",
                             file=value)


def positive_float(text: str) -> float:
    """argparse type: a finite number > 0 (``nan``, ``inf`` and ``-5`` are usage errors).

    Examples
    --------
    >>> positive_float("28")
    28.0
    >>> positive_float("nan")
    Traceback (most recent call last):
    ...
    argparse.ArgumentTypeError: must be a finite number > 0, got 'nan'
    """
    import argparse
    import math

    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text!r}")
    return value


def add_model_arguments(p) -> None:
    """Options shared by ``model`` and ``offsets fit``."""
    from magcal.models.inputs import MODELS

    p.add_argument("--kp", required=True, metavar="KP_FILE",
                   help="Kp file: GFZ Kp_ap_Ap_SN_F107 text, GFZ Kp_def CSV, CelesTrak "
                        "space-weather text or CSV time,kp (format detected)")
    p.add_argument("--model", default="T89", type=str.upper, choices=MODELS,
                   help="field model: IGRF only, or IGRF + T89 (Kp), T96, T01, T04 = "
                        "TS04/TS05 (solar-wind drivers, --drivers); default T89")
    p.add_argument("--drivers", metavar="FILE",
                   help="Qin-Denton or OMNI2 hourly text, or CSV with IRBEM input columns "
                        "(needed by T96, T01, T04)")
    p.add_argument("--longitude", type=float, metavar="DEG",
                   help="geostationary longitude (deg east; r = 6.6 RE, latitude 0); "
                        "otherwise DATA.csv needs columns lon_deg,lat_deg,r_re")
    p.add_argument("--cache-dir", metavar="DIR",
                   help="on-disk cache of model evaluations (reruns are near free)")
    p.add_argument("--jobs", type=int, default=None,
                   help="worker processes for the model (default: all usable cores)")


def print_screened(prefix: str, screened: dict | None) -> None:
    """One stderr line with what the quality screen left out (nothing when none)."""
    import sys

    from magcal.spin.screen import describe_screened

    text = describe_screened(screened)
    if text:
        print(f"{prefix}: screened: {text}; --no-screen keeps them", file=sys.stderr)


def add_spin_arguments(p) -> None:
    """Options shared by ``spincal`` and ``flipper``: phase, units, spin sense and the
    quality screen."""
    from magcal.spin.inputs import SPIN_SENSES

    p.add_argument("--spin-period", type=float, default=None,
                   help="spin period S in seconds, used when there is no phase column")
    p.add_argument("--t0", default=None,
                   help="reference time (ISO-8601 UTC) of phase 0 with --spin-period "
                        "(default: the first sample)")
    p.add_argument("--scale", type=float, default=1.0, metavar="NT_PER_UNIT",
                   help="nT per input unit (e.g. nT per count for raw counts); the readings "
                        "are multiplied by it (default 1: input in nT)")
    p.add_argument("--spin-sense", choices=SPIN_SENSES, default="positive",
                   help="spin sense about sensor 3: positive (the contract's phase "
                        "2 pi (t - t0) / S, default), negative, or auto (taken from the "
                        "readings); input turning the other way is refused")
    p.add_argument("--no-screen", action="store_true",
                   help="take the readings as given: do not leave out fill values, "
                        "saturated or stuck runs and spikes (of the field magnitude) first")
