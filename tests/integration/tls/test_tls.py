"""Modbus/TCP Security in slave mode: pymodbus's TLS client as the peer, certificates made by
openssl (tests/pki.py), a pymodbus RTU slave on the line."""
import json
import os
import signal
import socket
import ssl
import struct
import subprocess
import sys
import time

import pytest
from pymodbus.client import ModbusTlsClient

from tests.harness import free_port
from tests.integration.ops.test_reload import ask, config_set, recv_frame
from tests.ops import wait_for_log
from tests.pki import Authority

pytestmark = pytest.mark.integration

UNIT = 17
REPLY_S = 3.0


def reload_an_expired_certificate(gw, ca: Authority, cert, key) -> None:
    """A certificate that expired on 2021-01-01 put in place of the server's cert and key,
    then SIGHUP: the reload is refused, naming the file and the date."""
    expired, expired_key = ca.issue("server3", server=True, start="20200101000000Z",
                                    end="20210101000000Z")
    os.replace(expired, cert)
    os.replace(expired_key, key)
    os.kill(gw.proc.pid, signal.SIGHUP)
    wait_for_log(gw, f"{cert}: expired on 2021-01-01 00:00:00 UTC")


def tls_options(ca: Authority, server, port: int) -> list[str]:
    cert, key = server
    return ["--tls-port", str(port), "--tls-cert", str(cert), "--tls-key", str(key),
            "--tls-ca", str(ca.cert)]


def client_context(ca: Authority, cert=None) -> ssl.SSLContext:
    context = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
    context.check_hostname = False      # pymodbus wraps without a server name
    context.load_verify_locations(str(ca.cert))
    if cert is not None:
        context.load_cert_chain(str(cert[0]), str(cert[1]))
    return context


def tls_client(port: int, context: ssl.SSLContext) -> ModbusTlsClient:
    client = ModbusTlsClient("127.0.0.1", port=port, sslctx=context, timeout=REPLY_S,
                             retries=0)
    client.connect()
    return client


def read(client: ModbusTlsClient) -> list[int] | None:
    """Holding registers 0..1 of UNIT, or None when the request got no reply."""
    try:
        reply = client.read_holding_registers(0, count=2, device_id=UNIT)
    except Exception:               # pymodbus: ModbusIOException, ConnectionException
        return None
    return None if reply.isError() else list(reply.registers)


def status(gw) -> dict:
    done = subprocess.run([sys.executable, "-m", "mbgw", "status", "--json", "--control",
                           gw.control], check=True, capture_output=True, text=True)
    return json.loads(done.stdout)


def refused_tls(gw, at_least: int) -> None:
    """Wait until the gateway has counted at_least connections refused in the handshake."""
    deadline = time.monotonic() + REPLY_S
    while status(gw)["counters"]["connections_refused_tls"] < at_least:
        assert time.monotonic() < deadline, status(gw)["counters"]


def closed_by_the_gateway(sockets: list[socket.socket]) -> None:
    """Wait until the gateway has closed each of sockets (refused in its handshake)."""
    for sock in sockets:
        sock.settimeout(REPLY_S)
        try:
            while sock.recv(4096):
                pass
        except ConnectionResetError:
            pass


@pytest.fixture
def gateway(pty_pair, start_peer, start_gateway, pki):
    """gateway(*more options) -> (gw, tls port): slave mode with TLS, UNIT on the line."""
    start_peer("pymodbus_slave.py", pty_pair.device, str(UNIT), "--silent-unknown")

    def start(*options: str):
        ca, _, server = pki
        port = free_port()
        gw = start_gateway(pty_pair.gateway, "--baudrate", "19200",
                           *tls_options(ca, server, port), *options)
        return gw, port
    return start


def test_a_client_with_a_certificate_reads_over_tls_beside_plain_clients(gateway, pki):
    ca = pki[0]
    gw, port = gateway()
    client = tls_client(port, client_context(ca, ca.issue("op", role="operator")))
    plain = socket.create_connection(("127.0.0.1", gw.port))
    try:
        assert read(client) == [100, 101]
        assert ask(plain, 7, UNIT)[7:] == b"\x03\x04\x00\x64\x00\x65"
        assert read(client) == [100, 101]
        clients = {c["listener"]: c for c in status(gw)["clients"]}
        assert clients["tls"]["role"] == "operator" and clients["tls"]["requests"] == 2
        assert clients["plain"]["role"] is None
    finally:
        client.close()
        plain.close()


def test_tls_only_with_mdbport_0(gateway, pki):
    ca = pki[0]
    gw, port = gateway("--mdbport", "0")
    client = tls_client(port, client_context(ca, ca.issue("op", role="operator")))
    try:
        assert read(client) == [100, 101]
        assert [a for a in status(gw)["listening"] if "TLS" not in a] == []
    finally:
        client.close()
    with pytest.raises(ConnectionRefusedError):
        socket.create_connection(("127.0.0.1", gw.port), timeout=REPLY_S)


@pytest.mark.parametrize("which", ["no certificate", "another CA", "expired"])
def test_a_client_without_a_valid_certificate_is_refused(gateway, pki, which):
    ca, other, _ = pki
    cert = {"no certificate": None,
            "another CA": other.issue("stranger", role="operator"),
            "expired": ca.issue("old", role="operator", start="20200101000000Z",
                                end="20210101000000Z")}[which]
    gw, port = gateway()
    client = tls_client(port, client_context(ca, cert))
    try:
        assert read(client) is None
    finally:
        client.close()
    wait_for_log(gw, "TLS handshake refused")
    refused_tls(gw, at_least=1)
    plain = socket.create_connection(("127.0.0.1", gw.port))
    try:
        assert ask(plain, 1, UNIT)[7:9] == b"\x03\x04"
    finally:
        plain.close()


def test_a_handshake_flood_and_garbage_do_not_disturb_plain_clients(gateway, pki):
    ca = pki[0]
    gw, port = gateway()
    plain = socket.create_connection(("127.0.0.1", gw.port))
    garbage = [socket.create_connection(("127.0.0.1", port)) for _ in range(20)]
    idle: list[socket.socket] = []
    try:
        for n, sock in enumerate(garbage):      # plain Modbus TCP on the TLS port
            sock.sendall(b"\x00\x01\x00\x00\x00\x06\x11\x03\x00\x00\x00\x02" * (n + 1))
            assert ask(plain, n, UNIT)[7:9] == b"\x03\x04"
        closed_by_the_gateway(garbage)
        wait_for_log(gw, "TLS handshake refused")
        # connections that never shake hands: more than the gateway takes at once
        idle = [socket.create_connection(("127.0.0.1", port)) for _ in range(80)]
        for n in range(20):
            assert ask(plain, 100 + n, UNIT)[7:9] == b"\x03\x04"
        # the 64 the gateway takes at once wait; the others are refused at once (not logged:
        # one refusal of an address is logged a minute)
        refused_tls(gw, at_least=20 + 80 - 64)
        # a client with a certificate gets in once they have gone
        for sock in idle:
            sock.close()
        client = tls_client(port, client_context(ca, ca.issue("op", role="operator")))
        try:
            assert read(client) == [100, 101]
        finally:
            client.close()
        assert ask(plain, 99, UNIT)[7:9] == b"\x03\x04"
    finally:
        for sock in idle + garbage:
            sock.close()
        plain.close()


def server_serial(port: int, context: ssl.SSLContext) -> int:
    with socket.create_connection(("127.0.0.1", port)) as raw:
        with context.wrap_socket(raw) as sock:
            der = sock.getpeercert(binary_form=True)
    from cryptography import x509
    return x509.load_der_x509_certificate(der).serial_number


def test_reload_loads_a_renewed_certificate_for_new_connections_only(
        tmp_path, pty_pair, start_peer, start_gateway, pki):
    ca = pki[0]
    start_peer("pymodbus_slave.py", pty_pair.device, str(UNIT), "--silent-unknown")
    cert, key = ca.issue("server", server=True)
    path = tmp_path / "mbgw.toml"
    port = free_port()
    config_set(path, "serial", "baudrate", "19200")
    config_set(path, "tls", "port", str(port))
    config_set(path, "tls", "cert", str(cert))
    config_set(path, "tls", "key", str(key))
    config_set(path, "tls", "ca", str(ca.cert))
    gw = start_gateway(pty_pair.gateway, "--config", str(path))
    context = client_context(ca, ca.issue("op", role="operator"))
    first = server_serial(port, context)
    client = tls_client(port, context)
    try:
        assert read(client) == [100, 101]
        renewed, renewed_key = ca.issue("server2", server=True)
        os.replace(renewed, cert)
        os.replace(renewed_key, key)
        os.kill(gw.proc.pid, signal.SIGHUP)
        wait_for_log(gw, f"TLS: certificate {cert} loaded for new connections")
        assert server_serial(port, context) != first
        assert read(client) == [100, 101]          # the connection open before stays
    finally:
        client.close()
    # an expired certificate is refused at reload, naming the file and the date
    reload_an_expired_certificate(gw, ca, cert, key)
    assert "reload refused" in gw.log()
    client = tls_client(port, context)
    try:
        assert read(client) == [100, 101]
    finally:
        client.close()


def test_an_expired_server_certificate_is_refused_at_start_and_by_check_config(
        tmp_path, pty, pki):
    ca = pki[0]
    cert, key = ca.issue("server", server=True, start="20990101000000Z",
                         end="21000101000000Z")
    done = subprocess.run([sys.executable, "-m", "mbgw", "slave", "--device", pty,
                           "--tls-cert", str(cert), "--tls-key", str(key),
                           "--tls-ca", str(ca.cert)], capture_output=True, text=True,
                          timeout=30)
    assert done.returncode != 0
    assert f"{cert}: not valid before 2099-01-01 00:00:00 UTC" in done.stderr
    path = tmp_path / "mbgw.toml"
    path.write_text(f'[serial]\ndevice = "{pty}"\n[tls]\ncert = "{cert}"\nkey = "{key}"\n'
                    f'ca = "{ca.cert}"\n')
    done = subprocess.run([sys.executable, "-m", "mbgw", "check-config", str(path)],
                          capture_output=True, text=True, timeout=30)
    assert done.returncode != 0
    assert f"{cert}: not valid before 2099-01-01" in done.stderr + done.stdout


def test_requests_in_one_tls_record_larger_than_a_read_are_all_answered(gateway, pki):
    """16 writes of 123 registers (4,144 bytes) in one TLS record: the first read takes 4,096
    bytes, the rest waits decrypted inside the SSL object, where poll() does not see it."""
    ca = pki[0]
    gw, port = gateway("--table", "--table-units", "247")
    context = client_context(ca, ca.issue("op", role="operator"))
    values = struct.pack(">123H", *range(123))
    requests = b"".join(struct.pack(">HHHBBHHB", tid, 0, 7 + len(values), 247, 16, 0x1000,
                                    123, len(values)) + values for tid in range(16))
    assert len(requests) > 4096
    with context.wrap_socket(socket.create_connection(("127.0.0.1", port))) as sock:
        sock.sendall(requests)
        for tid in range(16):
            assert recv_frame(sock) == struct.pack(">HHHBBHH", tid, 0, 6, 247, 16, 0x1000, 123)


def test_the_firewall_applies_the_role_in_the_certificate(tmp_path, pty_pair, recording_peer,
                                                          start_gateway, pki):
    """Role operator reads only: its write gets 0x01 and never reaches the serial slave (its
    record is the wire); a plain client, no rule selecting it, writes."""
    ca, _, (cert, key) = pki
    record = recording_peer("fault_slave.py")
    port = free_port()
    path = tmp_path / "mbgw.toml"
    path.write_text(f'[serial]\nbaudrate = 19200\n[tls]\nport = {port}\ncert = "{cert}"\n'
                    f'key = "{key}"\nca = "{ca.cert}"\n'
                    '[[rule]]\nrole = "operator"\nlistener = "tls"\nread-only = true\n')
    gw = start_gateway(pty_pair.gateway, "--config", str(path))
    client = tls_client(port, client_context(ca, ca.issue("op", role="operator")))
    try:
        reply = client.write_register(5, 7, device_id=1)
        assert reply.isError() and reply.exception_code == 0x01
        assert client.read_holding_registers(5, count=1, device_id=1).registers == [1005]
    finally:
        client.close()
    with socket.create_connection(("127.0.0.1", gw.port)) as plain:
        plain.sendall(struct.pack(">HHHBBHH", 9, 0, 6, 1, 6, 5, 7))
        assert recv_frame(plain) == struct.pack(">HHHBBHH", 9, 0, 6, 1, 6, 5, 7)
    seen = [line.split(" ", 2)[2] for line in record.read_text().splitlines()
            if line.split(" ", 2)[1] == "rx"]
    assert [bytes.fromhex(s)[1:-2] for s in seen] == [bytes.fromhex("03 0005 0001"),
                                                      bytes.fromhex("06 0005 0007")]


def test_a_tls_change_that_cannot_be_applied_is_said_once_and_truthfully(
        tmp_path, pty_pair, start_peer, start_gateway, pki):
    """Issue 22: "TLS settings not applied" then "configuration reloaded: tls changed" no
    more.  A key that does not go with the certificate: the reload is refused, naming the key;
    a tls-port another program holds: the rest is applied, TLS stays as it was.  Either way a
    new connection still gets the running certificate."""
    ca = pki[0]
    start_peer("pymodbus_slave.py", pty_pair.device, str(UNIT), "--silent-unknown")
    cert, key = ca.issue("server", server=True)
    _, other_key = ca.issue("other", server=True)
    path = tmp_path / "mbgw.toml"
    port, held = free_port(), free_port()
    for words in (("serial", "baudrate", "19200"), ("tls", "port", str(port)),
                  ("tls", "cert", str(cert)), ("tls", "key", str(key)),
                  ("tls", "ca", str(ca.cert))):
        config_set(path, *words)
    gw = start_gateway(pty_pair.gateway, "--config", str(path))
    context = client_context(ca, ca.issue("op", role="operator"))
    first = server_serial(port, context)
    path.write_text(path.read_text().replace(str(key), str(other_key)))
    os.kill(gw.proc.pid, signal.SIGHUP)
    refused = (f"reload refused, the running configuration stays: {path}: tls.key: "
               f"{other_key} does not match tls.cert {cert}")
    wait_for_log(gw, refused)
    path.write_text(path.read_text().replace(str(other_key), str(key))
                    .replace(f"port = {port}", f"port = {held}")
                    .replace("baudrate = 19200", "baudrate = 19200\nstout = 700"))
    with socket.socket() as holder:
        holder.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        holder.bind(("0.0.0.0", held))
        holder.listen()
        os.kill(gw.proc.pid, signal.SIGHUP)
        partly = ("configuration reloaded: serial.stout_ms changed; not applied: tls: cannot "
                  f"listen on tls-port {held} (Address already in use); the running TLS "
                  "settings stay")
        wait_for_log(gw, partly)
    log = gw.log()
    assert log.count("reload") == 2 and log.count(refused) == log.count(partly) == 1
    assert "tls changed" not in log and "TLS settings not applied" not in log
    assert status(gw)["serial"]["stout_ms"] == 700
    assert server_serial(port, context) == first          # TLS as it was, on its port
    client = tls_client(port, context)
    try:
        assert read(client) == [100, 101]
    finally:
        client.close()
