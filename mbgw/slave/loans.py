"""Clients of the Modbus TCP face lent to a Modbus TCP remote line's thread, so that their
requests go to the device on one thread, from the client's socket to the device's and back,
in C.

A plain client (no TLS, no firewall rule) whose request went to such a line and that has
nothing else in the gateway once its reply is out is lent to the line (the face's
Router.deliver_completions, Connections.lend): the face stops polling it and the line's
thread polls it instead.  When its next request is one whole request for this line, to an
address that is not down, C takes it once the line is idle (csrc/remote.c
mbgw_remote_take, then mbgw_remote_reply: the reply goes to the client under its own
transaction id and unit before any Python runs); until then it waits in the client's socket.
The line's books of a request so taken are kept while the device works on the next one, or
once the line has been idle a moment (RemoteLineThread); the face's, as for any exchange,
through the exchange's done.

Anything else gives the client back to the face before a byte of it is read: input that is
not one request for this line (another unit, two requests, part of one, the connection's
end), a line with no connection (the face's way makes one), a take whose reply did not all
go out (the face answers it), a firewall rule a reload gave the client, the line stopping.
So only one thread at a time ever reads or writes a client, and a reply goes only to the
client whose request it answers.
"""
from collections import deque
from collections.abc import Callable
from functools import partial

from mbgw.routing.queue import Inbox
from mbgw.slave.connections import Client, Connections
from mbgw.slave.routes import ELSEWHERE, Hop


class Loans:
    """A remote line's lent clients.  lend() and route() are the face's (under its home);
    the rest is the line thread's."""

    def __init__(self, polls: Connections, wake: Callable[[], None],
                 take: Callable[[Client], bool]) -> None:
        """polls: the line thread's poll; wake: wakes that thread; take(client): the line's
        take of a lent client's input (False: give the client back; True: keep it, its
        input taken, or left to wait for the idle line)."""
        self.inbox: Inbox | None = None     # the line's (set by the line's use_inbox)
        self.units = bytearray(256)     # each unit id's address on the line (0: not its)
        self.open = False           # the line takes loans (no cache, no pause)
        self.idling = False         # the line thread waits for work: a take may go now
        self._polls = polls
        self._wake = wake
        self._take = take
        self._arriving: deque[tuple[Client, Connections, Callable]] = deque()
        self._held: dict[Client, tuple[Connections, Callable]] = {}

    # --- the face's side ---

    def lend(self, client: Client, home: Connections, done: Callable) -> None:
        """client is this line's to read until given back to home; done: the face's
        outcome of an exchange."""
        self._arriving.append((client, home, done))
        self._wake()

    def route(self, hops: list[Hop | None]) -> None:
        """The face's hops in force: the units whose requests go to this line as they are
        (no cache of the route's), with the address each has there."""
        units = self.units
        for unit, hop in enumerate(hops):
            address = 0
            if hop is not None and hop.kind is ELSEWHERE and hop.inbox is self.inbox and \
                    not hop.cache:
                address = hop.rewrite(unit)
                if not 1 <= address <= 255:
                    address = 0
            units[unit] = address

    # --- the line thread's side ---

    def adopt(self) -> None:
        """The clients lent since the last wake-up, polled from now on."""
        arriving = self._arriving
        while arriving:
            client, home, done = arriving.popleft()
            if not self.open:
                home.give_back(client)
                continue
            self._held[client] = (home, done)
            self._polls.poll_also(client.fd, partial(self._ready, client))

    def done_of(self, client: Client) -> Callable:
        return self._held[client][1]

    def holds(self, client: Client) -> bool:
        return client in self._held

    def in_turn_after(self, client: Client) -> list[Client]:
        """The clients held, each once, in turn from the one after client (client last)."""
        held = list(self._held)
        at = held.index(client) + 1 if client in self._held else 0
        return held[at:] + held[:at]

    def _ready(self, client: Client) -> None:
        if client.closed:           # by the face, closing all: nothing of it to read
            self._drop(client)
        elif not (self.open and client.guard is None and self._take(client)):
            self.give_back(client)

    def give_back(self, client: Client) -> None:
        home = self._drop(client)
        if home is not None:
            home.give_back(client)

    def give_all_back(self) -> None:
        """The line stops (or no longer takes loans): every client the face's again."""
        self.adopt()
        for client in list(self._held):
            self.give_back(client)

    def _drop(self, client: Client) -> Connections | None:
        held = self._held.pop(client, None)
        if held is None:
            return None
        self._polls.poll_no_more(client.fd)
        return held[0]
