import logging
import os

import pytest

from tests.harness import Gateway, Peer, PtyPair

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
def start_gateway(tmp_path):
    """start_gateway(device, *options) -> a ready Gateway; stopped after the test."""
    started = []

    def start(device, *args, **kwargs):
        gw = Gateway(tmp_path, device, *args, **kwargs)
        started.append(gw)
        return gw

    yield start
    for gw in started:
        gw.stop()


@pytest.fixture
def start_peer():
    """start_peer(script, *args) -> a ready Peer from tests/peers; stopped after the test."""
    started = []

    def start(script, *args):
        peer = Peer(script, *args)
        started.append(peer)
        return peer

    yield start
    for peer in started:
        peer.stop()


@pytest.fixture
def pty():
    """The slave path of a fresh pty; its master stays open during the test."""
    master, slave = os.openpty()
    path = os.ttyname(slave)
    os.close(slave)
    yield path
    os.close(master)
