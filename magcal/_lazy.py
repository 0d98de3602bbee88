"""Public names of a package imported from its submodules on first use (PEP 562).

A package whose submodules need heavy imports (SciPy's statistics or signal modules,
0.5-1 s each) lists its public names and where they live; ``import magcal.offsets``
then costs nothing until one of them is used.
"""

from __future__ import annotations

import importlib


def lazy_exports(package: str, where: dict, namespace: dict):
    """``(__getattr__, __dir__, __all__)`` for ``package``.

    Parameters
    ----------
    package : str
        The package's ``__name__``.
    where : dict
        Public name -> submodule (relative to the package) that defines it.
    namespace : dict
        The package's ``globals()``, for ``dir()``.

    Examples
    --------
    >>> getattr_, dir_, all_ = lazy_exports("magcal", {"finite_rms": "stats"}, {})
    >>> getattr_("finite_rms").__name__, all_
    ('finite_rms', ['finite_rms'])
    """
    def __getattr__(name: str):
        if name in where:
            return getattr(importlib.import_module(f"{package}.{where[name]}"), name)
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    def __dir__() -> list[str]:
        return sorted(set(namespace) | set(where))

    return __getattr__, __dir__, sorted(where)
