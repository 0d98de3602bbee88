"""Test configuration: offline, private caches, paths to the shared real data.

Network access fails the suite. From the import of this file on, ``socket.socket``
refuses to create internet (IPv4/IPv6) sockets and name look-ups of anything but the
local host raise :class:`NetworkBlockedError`; every attempt is recorded and fails the
test that made it (and the session, if made outside a test). Local ``AF_UNIX`` sockets
(multiprocessing, asyncio's self-pipe) keep working. A test marked
``@pytest.mark.loopback`` (or a module with ``pytestmark = pytest.mark.loopback``) may
open TCP/UDP sockets that connect, bind or send to loopback addresses only, as a
``dask.distributed`` ``LocalCluster`` needs (give it ``dashboard_address="127.0.0.1:0"``
and, with processes, ``host="127.0.0.1"``: by default it listens on all interfaces). A
UDP socket may be connected anywhere there (that sends nothing) but not send.
"""

from __future__ import annotations

import atexit
import ipaddress
import os
import shutil
import socket
import tempfile
from pathlib import Path

import pytest
from threadpoolctl import threadpool_limits

# spacepy reads SPACEPY at import time: set it before anything imports spacepy.
# (once per session, even if this file is imported a second time as tests.conftest)
_SPACEPY_DIR = Path(os.environ.get("MAGCAL_TEST_SPACEPY")
                    or tempfile.mkdtemp(prefix="magcal-test-spacepy-"))
if "MAGCAL_TEST_SPACEPY" not in os.environ:
    # made here, by the process that outlives the xdist workers and CLI subprocesses
    # that inherit it: removed at its exit (each session had left one behind)
    atexit.register(shutil.rmtree, _SPACEPY_DIR, ignore_errors=True)
os.environ["MAGCAL_TEST_SPACEPY"] = os.environ["SPACEPY"] = str(_SPACEPY_DIR)
os.environ.setdefault("MPLBACKEND", "Agg")
# One BLAS thread, here and in the CLI subprocesses tests start: the suite's matrices
# are small, and OpenBLAS's spinning threads made a loaded 2-core machine 2.3x slower
# on the alignment tests (73 s -> 32 s). NumPy is already loaded by pytest's plugins
# when this file runs, so the limit is set through threadpoolctl too. Results do not
# depend on it; set OPENBLAS_NUM_THREADS to override.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
_BLAS_LIMIT = threadpool_limits(int(os.environ["OPENBLAS_NUM_THREADS"]), user_api="blas")

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


# --- network guard -------------------------------------------------------------------

class NetworkBlockedError(RuntimeError):
    """Raised for network access from the test session (not an OSError, so that code
    which quietly falls back on connection errors cannot hide the attempt)."""


# This file may be imported twice (as ``conftest`` by pytest and as ``tests.conftest``
# by a test): the guard is installed once and its state shared through the socket module.
_INSTALLED = getattr(socket, "_magcal_test_guard", None)
if _INSTALLED is not None:
    NetworkBlockedError = _INSTALLED["error"]  # noqa: F811 - the first import's class
_REAL_SOCKET = socket.socket if _INSTALLED is None else _INSTALLED["socket"]
_REAL_GETADDRINFO = socket.getaddrinfo if _INSTALLED is None else _INSTALLED["getaddrinfo"]
_REAL_GETHOSTBYNAME = (socket.gethostbyname if _INSTALLED is None
                       else _INSTALLED["gethostbyname"])
_INTERNET = {socket.AF_INET, socket.AF_INET6}
_LOOPBACK_NAMES = {"localhost", "localhost.localdomain", "ip6-localhost", "ip6-loopback"}
_guard = {"loopback": False, "attempts": []} if _INSTALLED is None else _INSTALLED["state"]


def _blocked(what: str):
    _guard["attempts"].append(what)
    return NetworkBlockedError(f"network access blocked in the test suite: {what} (mark the "
                               "test @pytest.mark.loopback for loopback-only TCP)")


def _is_loopback(host) -> bool:
    if host is None:
        return False
    name = host.decode() if isinstance(host, bytes) else str(host)
    name = name.split("%", 1)[0].strip("[]").lower()
    if name in _LOOPBACK_NAMES:
        return True
    try:
        return ipaddress.ip_address(name).is_loopback
    except ValueError:
        return False


class _GuardedSocket(_REAL_SOCKET):
    """``socket.socket`` that refuses internet sockets outside loopback-marked tests."""

    def __init__(self, family=-1, type=-1, proto=-1, fileno=None):
        fam = socket.AF_INET if family == -1 else family
        if fileno is None and fam in _INTERNET and not _guard["loopback"]:
            raise _blocked(f"socket({socket.AddressFamily(fam).name})")
        super().__init__(family, type, proto, fileno)

    def _check(self, what: str, address) -> None:
        if self.family in _INTERNET and not _is_loopback(address[0]):
            raise _blocked(f"{what}({address!r})")

    def connect(self, address):
        # connecting a UDP socket sends nothing (dask finds its own address that way);
        # what it sends afterwards is checked in send()
        if not (self.type == socket.SOCK_DGRAM and _guard["loopback"]):
            self._check("connect", address)
        return super().connect(address)

    def send(self, data, *args):
        if self.type == socket.SOCK_DGRAM and self.family in _INTERNET:
            self._check("send", self.getpeername())
        return super().send(data, *args)

    def connect_ex(self, address):
        self._check("connect_ex", address)
        return super().connect_ex(address)

    def bind(self, address):
        self._check("bind", address)
        return super().bind(address)

    def sendto(self, data, *args):
        self._check("sendto", args[-1])
        return super().sendto(data, *args)


def _guarded_getaddrinfo(host, *args, **kwargs):
    if host is not None and not _is_loopback(host):
        raise _blocked(f"getaddrinfo({host!r})")
    return _REAL_GETADDRINFO(host, *args, **kwargs)


def _guarded_gethostbyname(host):
    if not _is_loopback(host):
        raise _blocked(f"gethostbyname({host!r})")
    return _REAL_GETHOSTBYNAME(host)


if _INSTALLED is None:
    socket._magcal_test_guard = {"error": NetworkBlockedError, "state": _guard,
                                 "socket": _REAL_SOCKET, "getaddrinfo": _REAL_GETADDRINFO,
                                 "gethostbyname": _REAL_GETHOSTBYNAME}
    socket.socket = _GuardedSocket
    socket.getaddrinfo = _guarded_getaddrinfo
    socket.gethostbyname = _guarded_gethostbyname


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    """Allow loopback sockets through setup, call and teardown of marked tests."""
    _guard["loopback"] = item.get_closest_marker("loopback") is not None
    try:
        yield
    finally:
        _guard["loopback"] = False


@pytest.fixture(autouse=True)
def _no_network_attempts():
    """Fail the test that tried to reach the network, even if it caught the error."""
    before = len(_guard["attempts"])
    yield
    new = _guard["attempts"][before:]
    if new:
        pytest.fail(f"test tried network access: {'; '.join(new)}", pytrace=False)


class expect_blocked:
    """Context manager for tests of the guard: the block must happen, and the attempt it
    records is not held against the test."""

    def __enter__(self):
        self._before = len(_guard["attempts"])
        return self

    def __exit__(self, exc_type, exc, tb):
        assert exc_type is NetworkBlockedError, f"expected a blocked attempt, got {exc_type}"
        assert len(_guard["attempts"]) == self._before + 1
        del _guard["attempts"][self._before:]
        return True


def pytest_sessionfinish(session, exitstatus):
    if _guard["attempts"] and exitstatus == 0:
        session.exitstatus = pytest.ExitCode.TESTS_FAILED
