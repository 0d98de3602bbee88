"""Keep spacepy and astropy offline and out of the user's home directory.

spacepy creates ``$HOME/.spacepy`` at import and astropy may try to download IERS
tables. :func:`configure_offline` points spacepy at a private directory (via the
``SPACEPY`` environment variable, which must be set before spacepy is imported) and
turns astropy's IERS auto-download off. The CLI, the tests (conftest) and the
workflows call it; library code calls :func:`ensure_spacepy_dir` just before importing
spacepy so that a bare ``import magcal`` never writes anything.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path


def _default_spacepy_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME")
    root = Path(base) if base else Path(tempfile.gettempdir())
    return root / "magcal-spacepy"


def ensure_spacepy_dir(path: str | os.PathLike | None = None) -> Path:
    """Set ``SPACEPY`` to a writable private directory unless the user already set it.

    Parameters
    ----------
    path : path-like, optional
        Directory to use; default ``$XDG_CACHE_HOME/magcal-spacepy`` or the system
        temporary directory.

    Returns
    -------
    pathlib.Path
        The directory spacepy will use (its ``.spacepy`` folder lives inside).
    """
    if "SPACEPY" in os.environ and path is None:
        return Path(os.environ["SPACEPY"])
    target = Path(path) if path is not None else _default_spacepy_dir()
    target.mkdir(parents=True, exist_ok=True)
    os.environ["SPACEPY"] = str(target)
    return target


def configure_offline(spacepy_dir: str | os.PathLike | None = None) -> None:
    """Configure spacepy and astropy for offline use.

    Safe to call more than once. Imports astropy only if it is installed.
    """
    ensure_spacepy_dir(spacepy_dir)
    try:
        from astropy.utils import iers
    except ImportError:  # pragma: no cover - astropy is a core dependency
        return
    iers.conf.auto_download = False
    iers.conf.auto_max_age = None
