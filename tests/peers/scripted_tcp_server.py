"""A misbehaving Modbus TCP server, scripted by the test: a thread with one listening socket
(127.0.0.1 unless told) that answers each request as the next action of its script says, and records
every request it saw (unit id, PDU, and when) for the test to check the wire.  Replies are built
here from the spec, never by mbgw's code.

Actions: "ok" (FC 3: `count` registers holding `values`; FC 6/16: the echo), "silent" (no
answer), "close" (the connection closed without answer), "wrong-function" (an FC 4 reply),
"wrong-quantity" (one register fewer), ("exception", code).  With the script used up, every
request is answered as `default` says ("ok" unless the test sets another)."""
import socket
import struct
import threading
import time
from collections import deque


class ScriptedServer:
    def __init__(self, values=(0x1234,), script=(), port: int = 0,
                 host: str = "127.0.0.1") -> None:
        self.values = list(values)
        self.script: deque = deque(script)
        self.default = "ok"
        self.requests: list[tuple[int, bytes]] = []
        self.times: list[float] = []     # each request's arrival, time.monotonic()
        self.connections = 0
        self.disconnections = 0          # by the client
        self.seen = threading.Condition()
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        self._listener = socket.create_server((host, port), family=family)
        self.host = host
        self.port = self._listener.getsockname()[1]
        self._stopping = False
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    @property
    def server(self) -> str:
        return f"[{self.host}]:{self.port}" if ":" in self.host else f"{self.host}:{self.port}"

    def stop(self) -> None:
        """Stop listening (a new connection is then refused) and close the one open."""
        self._stopping = True
        try:
            socket.create_connection((self.host, self.port), timeout=1).close()
        except OSError:
            pass
        self._thread.join(5)
        self._listener.close()

    def wait_requests(self, n: int, timeout: float = 10.0) -> list[tuple[int, bytes]]:
        with self.seen:
            assert self.seen.wait_for(lambda: len(self.requests) >= n, timeout), self.requests
            return list(self.requests)

    def _serve(self) -> None:
        while not self._stopping:
            conn, _ = self._listener.accept()
            if self._stopping:
                conn.close()
                return
            self.connections += 1
            with conn:
                self._talk(conn)

    def _talk(self, conn: socket.socket) -> None:
        conn.settimeout(0.2)
        buf = b""
        while not self._stopping:
            try:
                chunk = conn.recv(4096)
            except socket.timeout:
                continue
            except OSError:
                return
            if not chunk:
                self.disconnections += 1
                return
            buf += chunk
            while len(buf) >= 6 and len(buf) >= 6 + struct.unpack(">H", buf[4:6])[0]:
                length = struct.unpack(">H", buf[4:6])[0]
                tid, unit, pdu = struct.unpack(">H", buf[:2])[0], buf[6], buf[7:6 + length]
                buf = buf[6 + length:]
                action = self.script.popleft() if self.script else self.default
                with self.seen:
                    self.times.append(time.monotonic())
                    self.requests.append((unit, pdu))
                    self.seen.notify_all()
                if action == "close":
                    return
                reply = self._reply(action, pdu)
                if reply is not None:
                    conn.sendall(struct.pack(">HHHB", tid, 0, len(reply) + 1, unit) + reply)

    def _reply(self, action, pdu: bytes) -> bytes | None:
        function = pdu[0]
        if action == "silent":
            return None
        if isinstance(action, tuple):
            return bytes([function | 0x80, action[1]])
        if function in (5, 6, 15, 16):
            return pdu[:5]
        count = struct.unpack(">H", pdu[3:5])[0]
        if action == "wrong-quantity":
            count -= 1
        values = (self.values * count)[:count]
        data = struct.pack(f">{count}H", *values)
        return bytes([4 if action == "wrong-function" else function, len(data)]) + data
