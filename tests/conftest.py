"""Test configuration: offline, private caches, paths to the shared real data."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import pytest

# spacepy reads SPACEPY at import time: set it before anything imports spacepy.
_SPACEPY_DIR = Path(tempfile.mkdtemp(prefix="magcal-test-spacepy-"))
os.environ["SPACEPY"] = str(_SPACEPY_DIR)
os.environ.setdefault("MPLBACKEND", "Agg")

from magcal.offline import configure_offline  # noqa: E402

configure_offline(_SPACEPY_DIR)

REPO_ROOT = Path(__file__).resolve().parents[1]
REAL_DATA = REPO_ROOT.parent / "shared" / "real-data"


def real_data_path(*parts: str) -> Path:
    """Path inside ../shared/real-data; skip the calling test when it is absent."""
    path = REAL_DATA.joinpath(*parts)
    if not path.exists():
        pytest.skip(f"real data not available: {path} (needs ../shared/real-data beside the repo)")
    return path


@pytest.fixture
def real_data():
    """Fixture form of :func:`real_data_path`."""
    return real_data_path


@pytest.fixture
def rng():
    """A seeded generator; tests that need their own seed make their own."""
    import numpy as np

    return np.random.default_rng(20190304)
