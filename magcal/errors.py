"""Exception types shared by every stage.

:class:`InputError` is raised for bad input or usage; the CLI turns it into exit status
2 with one message naming the file, row or column, and what is wrong. Anything else is
an internal failure (exit status 1).
"""

from __future__ import annotations


class MagcalError(Exception):
    """Base class of all magcal errors."""


class InputError(MagcalError, ValueError):
    """Bad input data or usage.

    Parameters
    ----------
    message : str
        What is wrong, in words a user can act on.
    file : str or path-like, optional
        The offending file.
    row : int, optional
        Data row number (1-based, counting the header as row 0 for CSV files).
    column : str, optional
        The offending column or variable name.

    Examples
    --------
    >>> str(InputError("time not increasing", file="a.csv", row=12, column="time"))
    'a.csv: row 12: column time: time not increasing'

    A list of files (a reader's ``attrs["source"]``) is named as paths, not a list:

    >>> str(InputError("no sensor 'b'", file=["a.csv"], column="b_x"))
    "a.csv: column b_x: no sensor 'b'"
    """

    def __init__(self, message: str, *, file=None, row: int | None = None,
                 column: str | None = None):
        self.message = message
        if isinstance(file, (list, tuple)):
            file = ", ".join(str(f) for f in file) if file else None
        self.file = None if file is None else str(file)
        self.row = row
        self.column = column
        super().__init__(str(self))

    def __str__(self) -> str:
        parts = []
        if self.file is not None:
            parts.append(self.file)
        if self.row is not None:
            parts.append(f"row {self.row}")
        if self.column is not None:
            parts.append(f"column {self.column}")
        parts.append(self.message)
        return ": ".join(parts)


def not_a_file_error(path) -> InputError:
    """The :class:`InputError` for an input ``path`` that is not a file: a directory
    ("is a directory, expected a file") or nothing at all ("file not found").

    Examples
    --------
    >>> import tempfile
    >>> d = tempfile.mkdtemp()
    >>> not_a_file_error(d).message, not_a_file_error(d + "/nope.csv").message
    ('is a directory, expected a file', 'file not found')
    """
    from pathlib import Path

    if Path(path).is_dir():
        return InputError("is a directory, expected a file", file=path)
    return InputError("file not found", file=path)


class NotYetAvailableError(MagcalError):
    """A stage of the chain that is not implemented yet."""
