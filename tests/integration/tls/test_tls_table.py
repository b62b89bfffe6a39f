"""Modbus/TCP Security on the exchange table's Modbus TCP server (mbgw.table.server): master
mode's table port and transparent mode's mdbport, pymodbus's TLS client as the peer,
certificates made by openssl (tests/pki.py)."""
import os
import signal
import socket
import struct
import subprocess
import sys
import time

import pytest
from pymodbus.exceptions import ModbusException

from mbgw.table.handshakes import HANDSHAKES_PER_ADDRESS
from tests.harness import free_port
from tests.integration.ops.test_reload import recv_frame
from tests.integration.tls.test_tls import (
    REPLY_S,
    client_context,
    closed_by_the_gateway,
    reload_an_expired_certificate,
    server_serial,
    status,
    tls_client,
    tls_options,
)
from tests.ops import wait_for_log

pytestmark = pytest.mark.integration

FREE = 0x1000                       # registers of the table no mode gives a meaning


@pytest.fixture
def master(start_master, pki):
    """master(*options) -> (gw, table-port, tls-port): `mbgw master` with the table served
    on a table port and TLS."""
    def start(*options: str):
        ca, _, server = pki
        port, tls_port = free_port(), free_port()
        gw = start_master("--table", "--table-address", "0", "--table-port", str(port),
                          *tls_options(ca, server, tls_port), *options)
        return gw, port, tls_port
    return start


def ask(sock: socket.socket, tid: int, unit: int, pdu: bytes) -> bytes:
    sock.sendall(struct.pack(">HHHB", tid, 0, len(pdu) + 1, unit) + pdu)
    return recv_frame(sock)


def read_free(sock: socket.socket, tid: int = 1) -> bytes:
    """The PDU replying to a read of 2 registers at FREE."""
    return ask(sock, tid, 1, struct.pack(">BHH", 3, FREE, 2))[7:]


def table_tcp(gw) -> dict:
    return status(gw)["table"]["tcp"]


def refused_tls(gw, at_least: int) -> None:
    deadline = time.monotonic() + REPLY_S
    while table_tcp(gw)["connections_refused_tls"] < at_least:
        assert time.monotonic() < deadline, table_tcp(gw)


def test_master_mode_table_port_over_tls_beside_plain_clients(master, pki):
    ca = pki[0]
    gw, port, tls_port = master()
    client = tls_client(tls_port, client_context(ca, ca.issue("op", role="operator")))
    try:
        assert not client.write_registers(FREE, [11, 22], device_id=1).isError()
        with socket.create_connection(("127.0.0.1", port)) as plain:
            assert read_free(plain) == bytes.fromhex("03 04 000b 0016")
            ask(plain, 2, 1, struct.pack(">BHH", 6, FREE + 1, 33))
        assert client.read_holding_registers(FREE, count=2, device_id=1).registers == [11, 33]
        tcp = table_tcp(gw)
        assert tcp["tls_port"] == tls_port and tcp["connections"] == 1
        assert f"0.0.0.0:{tls_port} (TLS)" in gw.log()
        shown = subprocess.run([sys.executable, "-m", "mbgw", "status", "--control",
                                gw.control], check=True, capture_output=True, text=True)
        assert f"TLS on port {tls_port}: 0 handshakes under way, 0 refused" in shown.stdout
    finally:
        client.close()


@pytest.mark.parametrize("which", ["no certificate", "another CA"])
def test_a_client_without_a_valid_certificate_is_refused(master, pki, which):
    ca, other, _ = pki
    cert = None if which == "no certificate" else other.issue("stranger", role="operator")
    gw, port, tls_port = master()
    client = tls_client(tls_port, client_context(ca, cert))
    try:
        with pytest.raises((ModbusException, OSError)):    # no connection, or no reply
            reply = client.read_holding_registers(FREE, count=2, device_id=1)
            assert not reply.isError()
    finally:
        client.close()
    wait_for_log(gw, "TLS handshake refused")
    refused_tls(gw, at_least=1)
    with socket.create_connection(("127.0.0.1", port)) as plain:
        assert read_free(plain)[:2] == b"\x03\x04"


def test_a_handshake_flood_and_garbage_do_not_stall_plain_table_clients(master, pki):
    ca = pki[0]
    gw, port, tls_port = master("--request-timeout", "60000")   # idle handshakes stay
    plain = socket.create_connection(("127.0.0.1", port))
    garbage = [socket.create_connection(("127.0.0.1", tls_port)) for _ in range(20)]
    idle: list[socket.socket] = []
    try:
        for n, sock in enumerate(garbage):      # plain Modbus TCP on the TLS port
            sock.sendall(struct.pack(">HHHBBHH", 1, 0, 6, 1, 3, FREE, 2) * (n + 1))
            assert read_free(plain, n)[:2] == b"\x03\x04"
        closed_by_the_gateway(garbage)
        refused_tls(gw, at_least=20)
        # connections that never shake hands: more than the server takes from one address
        idle = [socket.create_connection(("127.0.0.1", tls_port)) for _ in range(80)]
        for n in range(20):
            assert read_free(plain, 100 + n)[:2] == b"\x03\x04"
        refused_tls(gw, at_least=20 + 80 - HANDSHAKES_PER_ADDRESS)
        assert table_tcp(gw)["tls_handshakes"] == HANDSHAKES_PER_ADDRESS
        for sock in idle:
            sock.close()
        client = tls_client(tls_port, client_context(ca, ca.issue("op", role="operator")))
        try:
            assert client.read_holding_registers(FREE, count=2, device_id=1).registers \
                == [0, 0]
        finally:
            client.close()
        assert read_free(plain, 99)[:2] == b"\x03\x04"
        log = gw.log()          # logged once a minute at most per address and reason
        assert log.count("refused: TLS handshake refused") == 1, log
        assert log.count(f"refused: {HANDSHAKES_PER_ADDRESS} TLS handshakes of this address "
                         f"under way already") == 1, log
    finally:
        for sock in idle + garbage:
            sock.close()
        plain.close()


def test_requests_in_one_tls_record_larger_than_a_read_are_all_answered(master, pki):
    """16 writes of 123 registers (4,144 bytes) in one TLS record: the first read takes 4,096
    bytes, the rest waits decrypted inside the SSL object, where poll() does not see it."""
    ca = pki[0]
    _, _, tls_port = master()
    context = client_context(ca, ca.issue("op", role="operator"))
    values = struct.pack(">123H", *range(123))
    requests = b"".join(struct.pack(">HHHBBHHB", tid, 0, 7 + len(values), 1, 16, FREE, 123,
                                    len(values)) + values for tid in range(16))
    assert len(requests) > 4096
    with context.wrap_socket(socket.create_connection(("127.0.0.1", tls_port))) as sock:
        sock.settimeout(REPLY_S)
        sock.sendall(requests)
        for tid in range(16):
            assert recv_frame(sock) == struct.pack(">HHHBBHH", tid, 0, 6, 1, 16, FREE, 123)


def test_the_firewall_applies_the_role_in_the_certificate(tmp_path, start_master, pki):
    """Role operator reads only: its write gets 0x01 and the table is unchanged; a plain
    client, no rule selecting it, writes."""
    ca, _, (cert, key) = pki
    port, tls_port = free_port(), free_port()
    path = tmp_path / "mbgw.toml"
    path.write_text(f'[table]\nenabled = true\naddress = 0\nport = {port}\n'
                    f'[tls]\nport = {tls_port}\ncert = "{cert}"\nkey = "{key}"\n'
                    f'ca = "{ca.cert}"\n'
                    '[[rule]]\nrole = "operator"\nlistener = "tls"\nread-only = true\n')
    start_master("--config", str(path))
    client = tls_client(tls_port, client_context(ca, ca.issue("op", role="operator")))
    try:
        reply = client.write_register(FREE, 7, device_id=1)
        assert reply.isError() and reply.exception_code == 0x01
        assert client.read_holding_registers(FREE, count=1, device_id=1).registers == [0]
        with socket.create_connection(("127.0.0.1", port)) as plain:
            assert read_free(plain) == bytes.fromhex("03 04 0000 0000")
            ask(plain, 2, 1, struct.pack(">BHH", 6, FREE, 9))
        assert client.read_holding_registers(FREE, count=1, device_id=1).registers == [9]
    finally:
        client.close()


def test_reload_loads_a_renewed_certificate_for_new_connections_only(tmp_path, start_master,
                                                                    pki):
    ca, _, (cert, key) = pki
    port, tls_port = free_port(), free_port()
    path = tmp_path / "mbgw.toml"
    path.write_text(f'[table]\nenabled = true\naddress = 0\nport = {port}\n'
                    f'[tls]\nport = {tls_port}\ncert = "{cert}"\nkey = "{key}"\n'
                    f'ca = "{ca.cert}"\n')
    gw = start_master("--config", str(path))
    context = client_context(ca, ca.issue("op", role="operator"))
    first = server_serial(tls_port, context)
    client = tls_client(tls_port, context)
    try:
        assert client.read_holding_registers(FREE, count=1, device_id=1).registers == [0]
        renewed, renewed_key = ca.issue("server2", server=True)
        renewed_cert, renewed_key_copy = (tmp_path / "renewed.pem", tmp_path / "renewed.key")
        renewed_cert.write_bytes(renewed.read_bytes())
        renewed_key_copy.write_bytes(renewed_key.read_bytes())
        os.replace(renewed, cert)
        os.replace(renewed_key, key)
        os.kill(gw.proc.pid, signal.SIGHUP)
        wait_for_log(gw, "TLS certificate loaded for new connections")
        assert server_serial(tls_port, context) != first
        assert client.read_holding_registers(FREE, count=1, device_id=1).registers == [0]
    finally:
        client.close()
    reload_an_expired_certificate(gw, ca, cert, key)
    # the renewed one again, on another port: the TLS listener moves, the plain one stays
    os.replace(renewed_cert, cert)
    os.replace(renewed_key_copy, key)
    new_port = free_port()
    path.write_text(path.read_text().replace(f"[tls]\nport = {tls_port}\n",
                                             f"[tls]\nport = {new_port}\n"))
    os.kill(gw.proc.pid, signal.SIGHUP)
    wait_for_log(gw, f"0.0.0.0:{new_port} (TLS)")
    client = tls_client(new_port, context)
    try:
        assert client.read_holding_registers(FREE, count=1, device_id=1).registers == [0]
    finally:
        client.close()
    with pytest.raises(ConnectionRefusedError):
        socket.create_connection(("127.0.0.1", tls_port), timeout=REPLY_S)
    with socket.create_connection(("127.0.0.1", port)) as plain:
        assert read_free(plain)[:2] == b"\x03\x04"


def test_transparent_mode_tls_only_with_mdbport_0(pty_pair, start_gateway, pki):
    ca, _, server = pki
    tls_port = free_port()
    gw = start_gateway(pty_pair.gateway, "--bind", "127.0.0.1", "--mdbport", "0",
                       *tls_options(ca, server, tls_port), mode="transparent", listen=False)
    client = tls_client(tls_port, client_context(ca, ca.issue("op", role="operator")))
    try:
        assert not client.write_registers(FREE, [5, 6], device_id=1).isError()
        assert client.read_holding_registers(FREE, count=2, device_id=1).registers == [5, 6]
        assert status(gw)["table"]["tcp"]["port"] is None
    finally:
        client.close()
    assert "cannot listen" not in gw.log()


@pytest.mark.parametrize("mode", ["master", "transparent"])
def test_an_expired_server_certificate_is_refused_at_start(pty, pki, mode):
    ca = pki[0]
    cert, key = ca.issue("server", server=True, start="20200101000000Z",
                         end="20210101000000Z")
    done = subprocess.run([sys.executable, "-m", "mbgw", mode, "--device", pty,
                           *(["--table"] if mode == "master" else []),
                           "--tls-cert", str(cert), "--tls-key", str(key),
                           "--tls-ca", str(ca.cert)], capture_output=True, text=True,
                          timeout=30)
    assert done.returncode != 0
    assert f"{cert}: expired on 2021-01-01 00:00:00 UTC" in done.stderr


def test_transparent_mdbport_0_needs_tls(pty):
    done = subprocess.run([sys.executable, "-m", "mbgw", "transparent", "--device", pty,
                           "--mdbport", "0"], capture_output=True, text=True, timeout=30)
    assert done.returncode != 0
    assert "'--mdbport': 0 turns plain Modbus TCP off: it needs TLS (--tls-cert)" in \
        done.stderr


def test_the_table_server_refuses_a_role_less_client_and_counts_a_probe(master, pki):
    """Master mode's table over TLS: a certificate without a role gets 0x01 for every request
    (a broadcast write's too), its session open, the table unchanged; a connect and reset
    before a byte is a probe, counted, not a refused handshake, and no traceback."""
    ca = pki[0]
    gw, port, tls_port = master()
    reset = socket.create_connection(("127.0.0.1", tls_port))
    reset.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
    reset.close()
    socket.create_connection(("127.0.0.1", tls_port)).close()
    with socket.create_connection(("127.0.0.1", tls_port)) as raw, \
            client_context(ca, ca.issue("no-role")).wrap_socket(raw) as sock:
        assert ask(sock, 1, 1, struct.pack(">BHH", 6, FREE, 5))[7:] == b"\x86\x01"
        assert ask(sock, 2, 0, struct.pack(">BHH", 6, FREE, 5))[7:] == b"\x86\x01"
        assert ask(sock, 3, 1, struct.pack(">BHH", 3, FREE, 1))[7:] == b"\x83\x01"
    with socket.create_connection(("127.0.0.1", port)) as plain:
        assert read_free(plain) == bytes.fromhex("03 04 0000 0000")
    tcp = table_tcp(gw)
    assert tcp["connections_tls_probes"] == 2 and tcp["connections_refused_tls"] == 0, tcp
    assert status(gw)["firewall"]["refused_no_role"] == 3
    assert "Traceback" not in gw.log() and "handshake" not in gw.log()


def test_master_modes_bind_holds_the_tls_port_too(master):
    gw, port, tls_port = master("--bind", "127.0.0.2")
    for listening in (port, tls_port):
        with pytest.raises(ConnectionRefusedError):
            socket.create_connection(("127.0.0.1", listening), timeout=REPLY_S)
        socket.create_connection(("127.0.0.2", listening), timeout=REPLY_S).close()
    assert f"127.0.0.2:{tls_port} (TLS)" in gw.log()
