"""Bad input on the control socket: each gets one JSON error line and the connection closed,
the daemon goes on serving, and its log holds nothing but one rate-limited warning.

The requests are written raw to the daemon's control socket (AF_UNIX), the way a broken
script or a curious user would; the daemon is slave mode with pymodbus's RTU server on its
line (tests/peers/pymodbus_slave.py), so a status after the abuse shows it still serves.
"""
import json
import socket

import pytest

from mbgw.ops import control

pytestmark = pytest.mark.integration

BAD_REQUESTS = {
    "line over 64 KiB": b'{"command": "' + b"s" * (70 * 1024) + b'"}\n',
    "command not a string": b'{"command": ["status"]}\n',
    "NUL bytes": b'{"command": "status\x00"}\x00\n',
    "invalid UTF-8": b'{"command": "\xff\xfe status"}\n',
    "nested 30,000 deep": b"[" * 30_000 + b"]" * 30_000 + b"\n",
    "not an object": b'["status"]\n',
    "a number": b"7\n",
    "no command": b"{}\n",
}


def exchange(path: str, raw: bytes) -> bytes:
    """Write raw, then read until the daemon closes the connection."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
        sock.settimeout(10)
        sock.connect(path)
        try:
            sock.sendall(raw)
        except (BrokenPipeError, ConnectionResetError):
            pass      # the daemon may answer and close before it has read a long line whole
        data = b""
        while chunk := sock.recv(65536):
            data += chunk
    return data


@pytest.fixture
def gateway(pty_pair, start_peer, start_gateway):
    start_peer("pymodbus_slave.py", pty_pair.device)
    return start_gateway(pty_pair.gateway, "--baudrate", "38400")


@pytest.mark.parametrize("what", BAD_REQUESTS)
def test_bad_request_gets_one_json_error_line_and_eof(gateway, what):
    reply = exchange(gateway.control, BAD_REQUESTS[what])
    assert reply.endswith(b"\n") and reply.count(b"\n") == 1, reply[:200]
    assert set(json.loads(reply)) == {"error"}, reply[:200]
    # the daemon is unharmed: the next, good, request is served
    assert control.call(gateway.control, {"command": "status"})["mode"] == "slave"


def test_bad_requests_leave_one_warning_in_the_log(gateway):
    for raw in BAD_REQUESTS.values():
        exchange(gateway.control, raw)
    assert control.call(gateway.control, {"command": "status"})["mode"] == "slave"
    log = gateway.log()
    assert "Traceback" not in log and "exception was never retrieved" not in log, log
    warnings = [line for line in log.splitlines() if "bad request" in line]
    assert len(warnings) == 1, log
    assert "WARNING" in warnings[0] or "warning" in warnings[0].lower(), warnings


def test_a_silent_client_does_not_stop_others(gateway):
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as idle:
        idle.connect(gateway.control)        # says nothing
        assert control.call(gateway.control, {"command": "status"})["mode"] == "slave"


def test_a_second_daemon_probing_the_socket_is_not_a_bad_request(gateway):
    """A second daemon started on the same control socket connects to see whether it is in
    use, and closes: the first logs no bad request, and the second is told it is in use."""
    import asyncio
    import errno
    second = control.ControlServer(gateway.control, {})
    with pytest.raises(OSError) as refused:
        asyncio.run(second.start())
    assert refused.value.errno == errno.EADDRINUSE
    assert control.call(gateway.control, {"command": "status"})["mode"] == "slave"
    assert "bad request" not in gateway.log(), gateway.log()
