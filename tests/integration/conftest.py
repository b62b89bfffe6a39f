"""The master-mode rig shared by the daemon-level tests of several folders: pymodbus Modbus TCP
servers on loopback addresses, `mbgw master` on a pty, its end of the line."""
import os

import pytest
from pymodbus.client import ModbusSerialClient
from pymodbus.framer import FramerType

from tests.harness import Gateway, Peer, PtyPair, factory, free_port
from tests.integration.master.test_master import BAUD, REPLY_S


@pytest.fixture
def servers_at():
    """servers_at(*hosts, silent=(), port=None) -> (port, Peer): pymodbus servers on these
    loopback addresses and on the silent ones (which never answer), all on one port;
    stopped after the test."""
    def start(*hosts: str, silent=(), port: int | None = None) -> tuple[int, Peer]:
        port = port or free_port()
        args = [str(port), *hosts, *silent]
        if silent:
            args += ["--silent", *silent]
        return port, Peer("pymodbus_tcp_servers.py", *args)

    yield from factory(start, lambda started: started[1].stop())


@pytest.fixture
def start_master(pty_pair, start_gateway):
    """start_master(*options) -> a ready `mbgw master` on the pty at BAUD; stopped after."""
    def start(*options: str) -> Gateway:
        return start_gateway(pty_pair.gateway, "--baudrate", BAUD, *options, mode="master",
                             listen=False)
    return start


@pytest.fixture
def second_pty(tmp_path):
    """A second pty pair (tmp_path/panel), for a second line."""
    directory = tmp_path / "panel"
    directory.mkdir()
    pair = PtyPair(directory)
    yield pair
    pair.stop()


@pytest.fixture
def open_line():
    """open_line(device) -> an fd on a pty's far end (a serial master's); closed after."""
    yield from factory(lambda device: os.open(device, os.O_RDWR | os.O_NOCTTY), os.close)


@pytest.fixture
def serial_client(pty_pair):
    """serial_client(framer) -> pymodbus's serial master on the line; closed after."""
    def connect(framer=FramerType.RTU) -> ModbusSerialClient:
        client = ModbusSerialClient(pty_pair.device, framer=framer, baudrate=int(BAUD),
                                    timeout=REPLY_S, retries=0)
        assert client.connect()
        return client

    yield from factory(connect, ModbusSerialClient.close)
