"""The table reader (mbgw.slave.table_reader) over real sockets: its name in the OS, and
the clients it polls following their readability as Connections does."""
import threading
from pathlib import Path

import pytest

from mbgw.slave.table_reader import THREAD_NAME, Gate, TableReader
from tests.unit.slave.test_connections import Rig
from tests.wait import until

WAIT_S = 5.0


@pytest.fixture
def rig():
    r = Rig()
    yield r
    r.close()


class Reader:
    """A TableReader over rig's connections, started with the gate held by the test (as the
    line thread holds it): what it reads is recorded; the test lets it serve with serve()."""

    def __init__(self, rig: Rig) -> None:
        self.gate = Gate()
        self.gate.take()
        self.read: list = []
        self.served = threading.Event()
        self.thread = TableReader(self.gate, rig.connections, rig.wake_fd, self._on_request,
                                  None)
        self.thread.start()

    def _on_request(self, client, tid, unit, pdu, responder) -> None:
        self.read.append((client.id, tid, unit, pdu))
        self.served.set()

    def stop(self) -> None:
        self.thread.stop()
        self.gate.release()
        self.thread.join(WAIT_S)
        assert not self.thread.is_alive()


def test_the_reader_has_its_name_in_ps_and_top(rig):
    reader = Reader(rig)
    try:
        comm = Path(f"/proc/self/task/{reader.thread.native_id}/comm")
        assert until(lambda: comm.read_text().strip() == THREAD_NAME,
                     lambda: f"the reader named {THREAD_NAME}, not {comm.read_text()!r}",
                     WAIT_S)
        assert THREAD_NAME.startswith("mbgw-") and len(THREAD_NAME) <= 15
    finally:
        reader.stop()
