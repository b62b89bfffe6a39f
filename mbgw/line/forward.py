"""What the C core does on slave mode's client sockets for the line thread (csrc/forward.c):
where a reply goes straight from the line (Forward), a counter C counts down as it hands a
reply over, and reads dated by the kernel's receive timestamp."""
import os
from typing import Any, NamedTuple

from mbgw._ffi import ffi, lib

NO_COUNTER = ffi.NULL


class Forward(NamedTuple):
    """Where the C receive sends a reply that answers its request at once (struct
    mbgw_forward): the client's socket, as a Modbus TCP frame with the client's transaction
    and unit ids; yield_cpu: then the client woken runs first (nothing else waits for the
    line); in_flight: the client's counter(), which C counts down as it hands the reply
    over."""
    fd: int
    tid: int
    unit: int
    yield_cpu: bool
    in_flight: Any


# the reply goes nowhere before it is returned
NO_FORWARD = Forward(-1, 0, 0, False, NO_COUNTER)


def counter():
    """An int that C can count down (a client's requests in flight): c[0]."""
    return ffi.new("int *")


def stamp_arrivals(fd: int) -> None:
    """The kernel dates what arrives on socket fd (a listening socket: on each connection it
    accepts), for ClientReader.  Raises OSError."""
    err = lib.mbgw_stamp_arrivals(fd)
    if err < 0:
        raise OSError(-err, os.strerror(-err))


class ClientReader:
    """Reads a client's socket into one buffer and tells when what it read arrived: by the
    kernel's receive timestamp (stamp_arrivals), so that requests read together after a
    transaction are known in the order they came.  For one thread (the line thread)."""

    def __init__(self, size: int) -> None:
        self._size = size
        self._buf = ffi.new("uint8_t[]", size)
        self._arrived = ffi.new("int64_t *")
        self.data = memoryview(ffi.buffer(self._buf))   # read() put its bytes at the front

    def read(self, fd: int) -> int:
        """The bytes read into data, 0 at the connection's end, -EAGAIN when nothing waits,
        another -errno."""
        return lib.mbgw_client_recv(fd, self._buf, self._size, self._arrived)

    @property
    def arrived_ns(self) -> int:
        """When the newest of what read() read arrived (CLOCK_MONOTONIC); now if the kernel
        did not date it."""
        return self._arrived[0]
