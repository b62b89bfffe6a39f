"""Slave mode's listener (mbgw.slave.listener) on real sockets: a port it cannot have is an
errors.ListenError naming mdbport, before anything is left listening; a reload to such a port
is refused with the reason and the running port stays."""
import asyncio
import socket

import pytest

from mbgw.config.model import SerialConfig, SlaveConfig
from mbgw.errors import ListenError
from mbgw.firewall.guard import Firewall
from mbgw.ops.counters import Counters
from mbgw.ops.reload import ReloadReport
from mbgw.slave.listener import Listener


class Adopted:
    """What the line thread's Connections is to the listener: the clients it adopts."""

    def __init__(self) -> None:
        self.clients: list = []

    def adopt(self, client) -> None:
        self.clients.append(client)


@pytest.fixture
def held_port():
    """A port another socket listens on (IPv4 loopback)."""
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    sock.listen()
    yield sock.getsockname()[1]
    sock.close()


def listener_on(port: int) -> Listener:
    cfg = SlaveConfig(SerialConfig("/dev/null"), mdbport=port, bind="127.0.0.1")
    return Listener(cfg, Counters(), Adopted(), Firewall(None))  # type: ignore[arg-type]


def test_a_port_held_by_another_program_is_a_listen_error_naming_mdbport(held_port):
    async def run() -> None:
        listener = listener_on(held_port)
        with pytest.raises(ListenError) as raised:
            await listener.start()
        assert (raised.value.option, raised.value.port) == ("mdbport", held_port)
        assert str(raised.value) == \
            f"mdbport {held_port}: cannot listen there: Address already in use"
        listener.close()
    asyncio.run(run())


def test_a_reload_to_a_held_port_keeps_the_running_one_and_says_why(held_port):
    async def run() -> None:
        free = socket.socket()
        free.bind(("127.0.0.1", 0))
        port = free.getsockname()[1]
        free.close()
        listener = listener_on(port)
        await listener.start()
        report = ReloadReport()
        new = SlaveConfig(SerialConfig("/dev/null"), mdbport=held_port, bind="127.0.0.1")
        await listener.reconfigure(new, report)
        assert listener.addresses() == [f"127.0.0.1:{port}"]
        assert report.not_applied == {
            "mdbport": f"cannot listen on 127.0.0.1 port {held_port} (Address already in "
                       f"use): still on port {port}"}
        with socket.create_connection(("127.0.0.1", port), timeout=5):
            pass                        # still listening there
        listener.close()
    asyncio.run(run())
