"""Keep spacepy and astropy offline and out of the user's home directory.

spacepy creates ``$HOME/.spacepy`` at import and astropy may try to download IERS
tables. :func:`configure_offline` points spacepy at a private directory (via the
``SPACEPY`` environment variable, which must be set before spacepy is imported) and
turns astropy's IERS auto-download off. The CLI, the tests (conftest) and the
workflows call it; library code calls :func:`ensure_spacepy_dir` just before importing
spacepy so that a bare ``import magcal`` never writes anything.
"""

from __future__ import annotations

import importlib.abc
import importlib.util
import os
import sys
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

    Safe to call more than once. astropy's IERS auto-download is turned off as soon
    as ``astropy.utils.iers`` is imported: now if it already is, otherwise by a one-shot
    import hook when something (spacepy) first imports it. A process that never uses
    astropy, such as a chain worker, then does not pay its import (0.25 s).
    """
    ensure_spacepy_dir(spacepy_dir)
    module = sys.modules.get(_IERS)
    if module is not None:
        _offline_iers(module)
    elif not any(isinstance(finder, _IersHook) for finder in sys.meta_path):
        sys.meta_path.insert(0, _IersHook())


_IERS = "astropy.utils.iers"


def _offline_iers(iers) -> None:
    iers.conf.auto_download = False
    iers.conf.auto_max_age = None


class _IersHook(importlib.abc.MetaPathFinder):
    """Finds ``astropy.utils.iers`` with the other finders and hands it over with a
    loader that configures it right after it runs; then leaves ``sys.meta_path``."""

    def find_spec(self, fullname, path, target=None):
        if fullname != _IERS:
            return None
        sys.meta_path[:] = [f for f in sys.meta_path if f is not self]
        spec = importlib.util.find_spec(fullname)
        if spec is None or spec.loader is None:  # pragma: no cover - astropy is a dependency
            return spec
        spec.loader = _ConfiguringLoader(spec.loader)
        return spec


class _ConfiguringLoader(importlib.abc.Loader):
    """A module's own loader, plus :func:`_offline_iers` once the module has run."""

    def __init__(self, loader):
        self._loader = loader

    def create_module(self, spec):
        return self._loader.create_module(spec)

    def exec_module(self, module) -> None:
        self._loader.exec_module(module)
        _offline_iers(module)

    def __getattr__(self, name):  # resource readers, get_data, ...: the real loader's
        return getattr(self._loader, name)
