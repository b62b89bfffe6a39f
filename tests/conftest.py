import logging
import os
import resource
import socket

import pytest

from mbgw.routing.queue import Inbox
from tests.harness import Gateway, Peer, PtyPair, factory
from tests.modbus import Client

# `mbgw slave` takes the values it is not given from /etc/mbgw/mbgw.toml when that exists (an
# installed mbgw.deb): the tests, and the gateways they start, read an empty file instead.
os.environ["MBGW_CONFIG"] = os.devnull


@pytest.fixture(autouse=True)
def mbgw_logger_as_found():
    """A command run in-process (CliRunner) sets up the "mbgw" logger as the daemon does: its
    own handler, no propagation, which would hide later tests' records from caplog."""
    logger = logging.getLogger("mbgw")
    saved = logger.handlers[:], logger.level, logger.propagate
    yield
    logger.handlers[:], logger.level, logger.propagate = saved


@pytest.fixture
def pty_pair(tmp_path):
    pair = PtyPair(tmp_path)
    yield pair
    pair.stop()


@pytest.fixture
def line(pty_pair):
    """The serial master's end of pty_pair (its device end) as a raw fd."""
    fd = os.open(pty_pair.device, os.O_RDWR | os.O_NOCTTY)
    yield fd
    os.close(fd)


@pytest.fixture
def start_gateway(tmp_path):
    """start_gateway(device, *options) -> a ready Gateway; stopped after the test."""
    yield from factory(lambda device, *args, **kwargs: Gateway(tmp_path, device, *args,
                                                               **kwargs), Gateway.stop)


@pytest.fixture
def start_peer():
    """start_peer(script, *args) -> a ready Peer from tests/peers; stopped after the test."""
    yield from factory(Peer, Peer.stop)


@pytest.fixture
def pty():
    """The slave path of a fresh pty; its master stays open during the test."""
    master, slave = os.openpty()
    path = os.ttyname(slave)
    os.close(slave)
    yield path
    os.close(master)


@pytest.fixture
def state_directory(tmp_path, monkeypatch):
    """The daemons' state directory ($STATE_DIRECTORY, as systemd sets it): the test's own,
    where table-persist files may be (and the table's file goes by default)."""
    monkeypatch.setenv("STATE_DIRECTORY", str(tmp_path))
    return tmp_path


@pytest.fixture
def many_fds():
    """The test process may hold thousands of sockets (RLIMIT_NOFILE raised meanwhile)."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    resource.setrlimit(resource.RLIMIT_NOFILE, (min(hard, 8192), hard))
    yield
    resource.setrlimit(resource.RLIMIT_NOFILE, (soft, hard))


@pytest.fixture
def recording_peer(pty_pair, start_peer, tmp_path):
    """recording_peer(script, *options) -> the path of the record a scripted slave from
    tests/peers (fault_slave.py, paced_slave.py) keeps of what it receives; the peer is ready
    on pty_pair's device end."""
    def start(script: str, *options: str):
        record = tmp_path / "record.txt"
        start_peer(script, pty_pair.device, "--record", str(record), *options)
        return record
    return start


@pytest.fixture
def client():
    """client(gw, timeout=REPLY_S) -> a raw tests.modbus.Client to the gateway; closed after
    the test."""
    yield from factory(lambda gw, **options: Client(gw.port, **options), Client.close)


@pytest.fixture
def socket_ends():
    """(the gateway's end of a client connection, non-blocking; the client's end), for the
    tests of the C paths that read and write client sockets."""
    ours, theirs = socket.socketpair()
    ours.setblocking(False)
    theirs.settimeout(1.0)
    yield ours, theirs
    ours.close()
    theirs.close()


@pytest.fixture
def wake_fd():
    """A thread's wake-up eventfd, as the daemon makes them."""
    fd = os.eventfd(0, os.EFD_NONBLOCK | os.EFD_CLOEXEC)
    yield fd
    os.close(fd)


@pytest.fixture
def inbox():
    """A target's Inbox (mbgw.routing.queue), for a test that plays the target."""
    box = Inbox()
    yield box
    box.close()
