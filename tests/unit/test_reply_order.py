"""Replies written straight from the line thread (Client.write_now) and from the event loop
(Client.send) reach the client in the order they were written, also when the socket is full
and writes have to wait in the loop."""
import asyncio
import socket
import struct
import threading

from mbgw import mbap
from mbgw.counters import Counters
from mbgw.tcp_server import Client
from mbgw.trace import TraceHub


class Server:
    """What a Client needs of its TcpServer."""

    def __init__(self) -> None:
        self.counters = Counters()
        self.trace = TraceHub()

    def admit(self, client, host) -> bool:
        return True

    def forget(self, client) -> None:
        pass


def frames_from(data: bytes) -> list[int]:
    tids = []
    while data:
        length = struct.unpack(">H", data[4:6])[0]
        tids.append(struct.unpack(">H", data[:2])[0])
        data = data[6 + length:]
    return tids


def test_replies_keep_their_order_when_the_socket_fills_up():
    async def scenario() -> list[int]:
        loop = asyncio.get_running_loop()
        listener = socket.create_server(("127.0.0.1", 0))
        reader = socket.create_connection(listener.getsockname())
        accepted, _ = listener.accept()
        listener.close()
        accepted.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4096)
        reader.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        client = Client(Server())
        await loop.connect_accepted_socket(lambda: client, sock=accepted)
        payload = bytes(250)                    # big replies fill the socket quickly
        written: list[int] = []

        def line_thread() -> None:              # as LineWorker's deliver does
            for tid in range(0, 400, 2):
                client.write_now(mbap.frame(tid, 1, b"\x03" + payload))
                written.append(tid)

        worker = threading.Thread(target=line_thread)
        worker.start()
        for tid in range(1, 400, 2):            # the loop thread writes in between
            client.send(tid, 1, b"\x03" + payload)
            written.append(tid)
            await asyncio.sleep(0)
        await asyncio.to_thread(worker.join)
        assert client._queued_writes > 0 or client.transport.get_write_buffer_size() > 0, \
            "the socket never filled: the test did not exercise the queued path"

        reader.setblocking(False)
        received = b""
        expected = sum(len(mbap.frame(t, 1, b"\x03" + payload)) for t in written)
        while len(received) < expected:
            try:
                received += reader.recv(65536)
            except BlockingIOError:
                await asyncio.sleep(0.001)      # let the loop flush its queue
        reader.close()
        client.transport.close()
        return frames_from(received), written

    received, written = asyncio.run(scenario())
    # Each writer's own replies stay in order, and nothing is lost or duplicated
    assert sorted(received) == sorted(written)
    assert [t for t in received if t % 2 == 0] == list(range(0, 400, 2))
    assert [t for t in received if t % 2] == list(range(1, 400, 2))
