"""The ``magcal`` command: one entry point dispatching to thin subcommand modules.

Each verb lives in ``magcal/cli/<module>.py`` and exposes ``register(subparsers)``, which
adds its parser and sets ``func`` to a callable ``run(args) -> int``. Exit status follows
CONTRACTS §0: 0 success, 2 bad input or usage (one message on stderr naming the file,
row or column), 1 anything else.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import traceback

from magcal._version import __version__
from magcal.errors import InputError, NotYetAvailableError

# verb -> (module, one-line help). Order is the order of the processing chain.
VERBS: dict[str, tuple[str, str]] = {
    "qc": ("magcal.cli.qc", "per-sample quality flags (spikes, saturation, fills, time) of "
                            "any input files"),
    "picog": ("magcal.cli.picog", "AC cleaning of multi-sensor data with PiCoG (fit, apply)"),
    "model": ("magcal.cli.model", "Tsyganenko/IGRF model field at the spacecraft in Hpen"),
    "offsets": ("magcal.cli.offsets", "DC offsets against the model on quiet days (fit, apply)"),
    "align": ("magcal.cli.align", "rotation angles about Hp, He, Hn against a reference"),
    "spincal": ("magcal.cli.spincal", "spin-ripple calibration of a spinning spacecraft"),
    "flipper": ("magcal.cli.flipper", "spin-axis offset from flipper measurements"),
    "discover": ("magcal.cli.discover", "find, name and add what the model is missing"),
    "report": ("magcal.cli.report", "uncertainty report (HTML and PDF) for a processed data set"),
    "run": ("magcal.cli.run", "run the whole chain from a CHAIN.toml configuration"),
    "convert": ("magcal.cli.convert", "convert instrument files (CSV, GOES-R netCDF, CDF) to "
                                      "CSV or CDF"),
    "demo": ("magcal.cli.demo", "run the whole chain on data_samples/ (the main job)"),
}


class _Parser(argparse.ArgumentParser):
    """ArgumentParser whose usage errors exit with status 2 and one clear line."""

    def error(self, message):  # noqa: D401 - argparse API
        self.exit(2, f"{self.prog}: error: {message}\n")


def _not_available(verb: str, help_text: str, subparsers) -> None:
    parser = subparsers.add_parser(verb, help=f"{help_text} [not yet available]",
                                   description=f"{help_text}. Not yet available in this version.")
    parser.add_argument("rest", nargs=argparse.REMAINDER, help=argparse.SUPPRESS)

    def run(args):
        raise NotYetAvailableError(f"magcal {verb}: not yet available in magcal {__version__}")

    parser.set_defaults(func=run)


def build_parser() -> argparse.ArgumentParser:
    """Build the top-level parser with every verb registered."""
    parser = _Parser(prog="magcal", description=(
        "magcal turns raw multi-sensor spacecraft magnetometer data into calibrated "
        "magnetic field products. Field values are in nT, times in UTC."))
    parser.add_argument("--version", action="version", version=f"magcal {__version__}")
    parser.add_argument("--debug", action="store_true",
                        help="print the full traceback of an internal error (any verb, "
                             "anywhere on the line; or set MAGCAL_DEBUG=1)")
    subparsers = parser.add_subparsers(dest="verb", metavar="VERB", parser_class=_Parser)
    for verb, (module_name, help_text) in VERBS.items():
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as exc:
            if exc.name != module_name:
                raise
            _not_available(verb, help_text, subparsers)
            continue
        module.register(subparsers)
    return parser


def debug_requested(argv: list[str], environ=None) -> tuple[list[str], bool]:
    """``argv`` without ``--debug`` (accepted after any verb) and whether it or
    ``MAGCAL_DEBUG`` (any value but empty or 0) asks for tracebacks.

    Examples
    --------
    >>> debug_requested(["run", "CHAIN.toml", "--debug"], environ={})
    (['run', 'CHAIN.toml'], True)
    """
    rest = [a for a in argv if a != "--debug"]
    env = str((os.environ if environ is None else environ).get("MAGCAL_DEBUG", "")).strip()
    return rest, len(rest) != len(argv) or env not in ("", "0")


def main(argv: list[str] | None = None) -> int:
    """Run the ``magcal`` command; return the exit status."""
    from magcal.cli._common import check_output_files
    from magcal.offline import configure_offline

    parser = build_parser()
    argv, debug = debug_requested(sys.argv[1:] if argv is None else list(argv))
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help(sys.stderr)
        return 2
    configure_offline()
    try:
        check_output_files(args)
        status = args.func(args)
    except InputError as exc:
        print(f"magcal {args.verb}: error: {exc}", file=sys.stderr)
        return 2
    except NotYetAvailableError as exc:
        print(str(exc), file=sys.stderr)
        return 1
    except BrokenPipeError:  # the reader of stdout went away (| head): not an error
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except KeyboardInterrupt:
        print("magcal: interrupted", file=sys.stderr)
        return 1
    except Exception as exc:  # noqa: BLE001 - the CLI boundary reports everything
        if debug:
            traceback.print_exc(file=sys.stderr)
        print(f"magcal {args.verb}: internal error: {type(exc).__name__}: {exc}"
              + ("" if debug else " (run again with --debug or MAGCAL_DEBUG=1 for the "
                                  "traceback)"), file=sys.stderr)
        return 1
    return int(status or 0)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
