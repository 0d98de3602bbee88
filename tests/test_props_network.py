"""The test session is offline: the socket guard of ``conftest.py`` (issue 13).

Every internet socket, connection and name look-up outside the loopback interface
raises, local AF_UNIX sockets work, and a test marked ``loopback`` may talk TCP to
127.0.0.0/8 and ::1 only.
"""

from __future__ import annotations

import ipaddress
import socket
import threading

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from conftest import NetworkBlockedError, expect_blocked

# 0.0.0.0/8 means "this host": Linux sends to it over the loopback interface
NOT_LOOPBACK = st.ip_addresses(v=4).filter(
    lambda a: not a.is_loopback and a not in ipaddress.ip_network("0.0.0.0/8"))


def test_internet_sockets_and_lookups_are_refused():
    with expect_blocked():
        socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    with expect_blocked():
        socket.socket()
    with expect_blocked():
        socket.socket(socket.AF_INET6, socket.SOCK_DGRAM)
    with expect_blocked():
        socket.getaddrinfo("example.com", 443)
    with expect_blocked():
        socket.gethostbyname("pypi.org")
    with expect_blocked():
        socket.create_connection(("127.0.0.1", 9))     # no socket even to loopback


def test_blocked_is_not_an_oserror():
    """Code that falls back quietly on OSError must not swallow the block."""
    assert not issubclass(NetworkBlockedError, OSError)


def test_local_unix_sockets_work():
    a, b = socket.socketpair()
    with a, b:
        a.sendall(b"magcal")
        assert b.recv(6) == b"magcal"
    assert a.family == socket.AF_UNIX


def _echo_server():
    srv = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    srv.bind(("127.0.0.1", 0))
    srv.listen(1)

    def serve():
        conn, _ = srv.accept()
        with conn:
            conn.sendall(conn.recv(16))

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    return srv, thread


@pytest.mark.loopback
def test_loopback_marker_allows_local_tcp():
    srv, thread = _echo_server()
    with srv, socket.create_connection(srv.getsockname(), timeout=5) as c:
        c.sendall(b"ping")
        assert c.recv(16) == b"ping"
    thread.join(5)


@pytest.mark.loopback
@settings(max_examples=25, deadline=None, derandomize=True, database=None)
@given(address=NOT_LOOPBACK, port=st.integers(1, 65535))
def test_loopback_marker_still_refuses_other_hosts(address, port):
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        with expect_blocked():
            s.connect((str(address), port))
        with expect_blocked():
            s.bind((str(address), 0))
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as u:
        with expect_blocked():
            u.sendto(b"x", (str(address), port))
        u.connect((str(address), port))               # a route look-up: nothing is sent
        with expect_blocked():
            u.send(b"x")


@pytest.mark.loopback
@settings(max_examples=10, deadline=None, derandomize=True, database=None)
@given(last=st.integers(1, 254))
def test_loopback_marker_allows_all_of_127_8(last):
    address = f"127.0.0.{last}"
    assert ipaddress.ip_address(address).is_loopback
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((address, 0))
        assert s.getsockname()[0] == address


@pytest.mark.loopback
@pytest.mark.slow
def test_dask_local_cluster_runs_under_the_loopback_marker():
    distributed = pytest.importorskip("distributed")
    # the scheduler's and workers' HTTP servers listen on all interfaces unless told
    local = {"dashboard_address": "127.0.0.1:0", "worker_dashboard_address": "127.0.0.1:0"}
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                                  **local) as cluster, \
            distributed.Client(cluster) as client:
        assert client.submit(sum, [1, 2, 3]).result(timeout=30) == 6


@pytest.mark.loopback
def test_a_second_import_of_conftest_shares_the_guard():
    """``from tests.conftest import ...`` imports the file again under another name."""
    import importlib
    import os

    import conftest

    again = importlib.import_module("tests.conftest")
    assert again is not conftest
    assert again.NetworkBlockedError is NetworkBlockedError
    assert again._guard is conftest._guard
    assert os.environ["SPACEPY"] == str(conftest._SPACEPY_DIR) == str(again._SPACEPY_DIR)
    srv, thread = _echo_server()                  # loopback still allowed in this test
    with srv, socket.create_connection(srv.getsockname(), timeout=5) as c:
        c.sendall(b"once")
        assert c.recv(16) == b"once"
    thread.join(5)
