"""One request on its way from a face to a target, and back."""
from typing import Callable, Hashable

# done(exchange, reply, outcome): called once, on the target's thread.  reply is the PDU
# answered (an exception reply included), or None when nothing is to be sent (a broadcast,
# or silence where `exception` is off).  outcome is the trace's word for what happened.
Done = Callable[["Exchange", "bytes | None", str], None]


class Exchange:
    """What a face hands a target: the address on the target (the unit after the route's
    rewrite), the PDU, when it arrived, who is owed the answer."""
    __slots__ = ("source", "address", "pdu", "received_ns", "done", "context")

    def __init__(self, source: Hashable, address: int, pdu: bytes, received_ns: int,
                 done: Done, context: object = None) -> None:
        self.source = source          # fairness: one turn in the target's ring per source
        self.address = address        # serial address (line) or unit id (server)
        self.pdu = pdu
        self.received_ns = received_ns
        self.done = done
        self.context = context        # the face's own (its client, tid, unit): never read here
