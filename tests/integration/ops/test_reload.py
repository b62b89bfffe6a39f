"""SIGHUP (systemctl reload): the configuration file is applied again without dropping the
connections the change does not concern."""
import os
import signal
import socket
import struct
import subprocess
import sys

import pytest

from tests.ops import wait_for_log

pytestmark = pytest.mark.integration

REPLY_S = 3.0


def read_holding(tid: int, unit: int, address: int = 0, count: int = 2) -> bytes:
    return struct.pack(">HHHBBHH", tid, 0, 6, unit, 3, address, count)


def recv_frame(sock: socket.socket) -> bytes:
    sock.settimeout(REPLY_S)
    head = b""
    while len(head) < 6:
        chunk = sock.recv(6 - len(head))
        if not chunk:
            raise EOFError("connection closed")
        head += chunk
    length = struct.unpack(">H", head[4:6])[0]
    body = b""
    while len(body) < length:
        body += sock.recv(length - len(body))
    return head + body


def ask(sock: socket.socket, tid: int, unit: int) -> bytes:
    sock.sendall(read_holding(tid, unit))
    return recv_frame(sock)


def config_set(path, *words: str) -> None:
    subprocess.run([sys.executable, "-m", "mbgw", "config", "set", "--config", str(path),
                    *words], check=True, capture_output=True)


def reload(gw, expected: str, count: int = 1) -> None:
    os.kill(gw.proc.pid, signal.SIGHUP)
    wait_for_log(gw, expected, count)


@pytest.fixture
def setup(tmp_path, pty_pair, start_peer, start_gateway):
    start_peer("pymodbus_slave.py", pty_pair.device, "17", "--silent-unknown")
    path = tmp_path / "mbgw.toml"
    config_set(path, "serial", "baudrate", "19200")
    config_set(path, "serial", "stout", "300")
    config_set(path, "net", "exception", "on")
    gw = start_gateway(pty_pair.gateway, "--config", str(path))
    client = socket.create_connection(("127.0.0.1", gw.port))
    yield gw, path, client
    client.close()


def test_reload_applies_new_routing_on_the_same_connection(setup):
    gw, path, client = setup
    assert ask(client, 1, 17)[7:9] == b"\x03\x04"
    assert ask(client, 2, 77)[7:] == b"\x83\x0b"          # no device 77: 0x0B
    config_set(path, "net", "slaveid", "17")
    reload(gw, "configuration reloaded: slaveid changed")
    reply = ask(client, 3, 77)                             # same connection, now forced to 17
    assert reply[:2] == b"\x00\x03" and reply[6] == 77 and reply[7:9] == b"\x03\x04"
    assert gw.proc.poll() is None


def test_reload_closes_only_the_clients_authip_no_longer_allows(setup):
    gw, path, client = setup
    config_set(path, "net", "authip", "1", "127.0.0.2")
    reload(gw, "configuration reloaded: authip changed")
    with pytest.raises((EOFError, ConnectionResetError)):
        ask(client, 1, 17)
    other = socket.socket()
    other.bind(("127.0.0.2", 0))
    other.connect(("127.0.0.1", gw.port))
    with other:
        assert ask(other, 2, 17)[7:9] == b"\x03\x04"


def test_a_bad_file_is_refused_and_the_gateway_keeps_serving(setup):
    gw, path, client = setup
    path.write_text(path.read_text().replace("stout = 300", "stout = 0"))
    reload(gw, "reload refused, the running configuration stays")
    assert "stout" in gw.log().split("reload refused")[1].splitlines()[0]
    assert ask(client, 1, 17)[7:9] == b"\x03\x04"
    assert ask(client, 2, 77)[7:] == b"\x83\x0b"          # exception still on


def test_new_line_settings_reopen_the_line_and_clients_stay(setup):
    gw, path, client = setup
    config_set(path, "serial", "baudrate", "38400")
    reload(gw, "serial line settings changed: reopening")
    wait_for_log(gw, "is back")
    assert ask(client, 1, 17)[7:9] == b"\x03\x04"
    status = subprocess.run([sys.executable, "-m", "mbgw", "status", "--json", "--control",
                             gw.control], capture_output=True, text=True, check=True)
    assert '"baudrate": 38400' in status.stdout


def test_a_port_another_program_holds_is_not_applied_said_once_and_tried_again(
        tmp_path, pty_pair, start_peer, start_gateway):
    """The one outcome of a reload that cannot move the listener: logged once, with what
    and why, no "mdbport changed"; the gateway stays on its port (the wire says so), and the
    next reload, with the port free, moves it."""
    from tests.harness import free_port
    start_peer("pymodbus_slave.py", pty_pair.device, "17", "--silent-unknown")
    path = tmp_path / "mbgw.toml"
    port, wanted = free_port(), free_port()
    for words in (("serial", "baudrate", "19200"), ("net", "bind", "127.0.0.1"),
                  ("net", "mdbport", str(port))):
        config_set(path, *words)
    gw = start_gateway(pty_pair.gateway, "--config", str(path), port=port, listen=False)
    holder = socket.socket()
    holder.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    holder.bind(("127.0.0.1", wanted))
    holder.listen()
    config_set(path, "net", "mdbport", str(wanted))
    line = (f"configuration reloaded: nothing changed; not applied: mdbport: cannot listen "
            f"on 127.0.0.1 port {wanted} (Address already in use): still on port {port}")
    try:
        reload(gw, line)
        assert "mdbport changed" not in gw.log() and gw.log().count("configuration reloaded") == 1
        with socket.create_connection(("127.0.0.1", port)) as client:
            assert ask(client, 1, 17)[7:9] == b"\x03\x04"
    finally:
        holder.close()
    reload(gw, "configuration reloaded: mdbport changed")
    with socket.create_connection(("127.0.0.1", wanted)) as client:
        assert ask(client, 2, 17)[7:9] == b"\x03\x04"
