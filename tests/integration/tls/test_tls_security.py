"""Modbus/TCP Security to the letter (issue 23), slave mode: what port 802 offers (openssl
s_client, sslscan), renegotiation refused, session resumption, role-less and revoked client
certificates (pymodbus's TLS client), the CRL and its reload, and refusals logged per address
and reason (a health check's connect and close hides nothing).  Certificates from
tests/pki.py (openssl, EC P-256); the serial slave is tests/peers/fault_slave.py, whose
record is the wire."""
import os
import signal
import socket
import ssl
import struct
import subprocess
import sys

import pytest
from pymodbus.client import ModbusTlsClient

from tests.harness import free_port
from tests.integration.ops.test_reload import recv_frame
from tests.integration.tls.test_tls import client_context, read, tls_client
from tests.ops import status, wait_for, wait_for_log
from tests.pki import Authority

pytestmark = pytest.mark.integration

REPLY_S = 3.0
UNIT = 1                        # fault_slave: holding register i holds 1000 + i


@pytest.fixture
def ca(tmp_path):
    return Authority(tmp_path)


@pytest.fixture
def secure(tmp_path, pty_pair, recording_peer, start_gateway, ca):
    """secure(extra file text) -> (gw, TLS port, the serial slave's record)."""
    record = recording_peer("fault_slave.py")

    def start(extra: str = ""):
        cert, key = ca.issue("server", server=True)
        port = free_port()
        path = tmp_path / "mbgw.toml"
        path.write_text(f'[serial]\nbaudrate = 19200\n[tls]\nport = {port}\ncert = "{cert}"\n'
                        f'key = "{key}"\nca = "{ca.cert}"\n{extra}')
        gw = start_gateway(pty_pair.gateway, "--config", str(path))
        return gw, port, record
    return start


def on_the_line(record) -> list[bytes]:
    """The PDUs the serial slave received."""
    return [bytes.fromhex(line.split(" ", 2)[2])[1:-2] for line in record.read_text().splitlines()
            if line.split(" ", 2)[1] == "rx"]


def s_client(port: int, ca: Authority, client, *options: str, stdin: str = "Q\n") -> str:
    cert, key = client
    done = subprocess.run(["openssl", "s_client", "-connect", f"127.0.0.1:{port}", "-CAfile",
                           str(ca.cert), "-cert", str(cert), "-key", str(key), *options],
                          input=stdin, capture_output=True, text=True, timeout=30)
    return done.stdout + done.stderr


@pytest.mark.parametrize("options, cipher", [
    (("-tls1_2", "-cipher", "ECDHE-ECDSA-AES128-CCM8"), "ECDHE-ECDSA-AES128-CCM8"),
    (("-tls1_3", "-ciphersuites", "TLS_AES_128_CCM_SHA256"), "TLS_AES_128_CCM_SHA256"),
])
def test_the_secure_sunspec_ccm_suites_are_offered(secure, ca, options, cipher):
    gw, port, _ = secure()
    out = s_client(port, ca, ca.issue("op", role="operator"), *options)
    assert f"Cipher is {cipher}" in out, out


def test_renegotiation_is_refused(secure, ca):
    """s_client renegotiates on R: the gateway answers with the no_renegotiation alert; the
    connection is not renegotiated."""
    gw, port, _ = secure()
    out = s_client(port, ca, ca.issue("op", role="operator"), "-tls1_2", stdin="R\n")
    assert "RENEGOTIATING" in out and "no renegotiation" in out, out


def test_sslscan_finds_no_old_protocol_no_cbc_and_no_rsa_key_exchange(secure, ca):
    gw, port, _ = secure()
    cert, key = ca.issue("scanner", role="operator")
    done = subprocess.run(["sslscan", "--no-colour", f"--certs={cert}", f"--pk={key}",
                           f"127.0.0.1:{port}"], capture_output=True, text=True, timeout=120)
    out = done.stdout
    protocols = dict(line.split()[:2] for line in out.splitlines()
                     if line.startswith(("SSLv", "TLSv")) and line.split()[1:2] in (
                         ["enabled"], ["disabled"]))
    assert protocols == {"SSLv2": "disabled", "SSLv3": "disabled", "TLSv1.0": "disabled",
                         "TLSv1.1": "disabled", "TLSv1.2": "enabled", "TLSv1.3": "enabled"}, out
    ciphers = [line.split()[4] for line in out.splitlines()
               if line.startswith(("Preferred", "Accepted"))]
    tls12 = [c for c in ciphers if not c.startswith("TLS_")]
    assert "ECDHE-ECDSA-AES128-CCM8" in tls12 and "TLS_AES_128_CCM_SHA256" in ciphers, out
    assert all(c.startswith("ECDHE-") for c in tls12), out          # no RSA key exchange
    assert not [c for c in tls12 if "CBC" in c or c.endswith("-SHA")], out
    assert "Session renegotiation not supported" in out, out


def test_a_client_that_reconnects_resumes_its_session(secure, ca):
    gw, port, _ = secure()
    for version in (ssl.TLSVersion.TLSv1_2, ssl.TLSVersion.TLSv1_3):
        context = client_context(ca, ca.issue(f"op{version.name}", role="operator"))
        context.maximum_version = version
        session = None
        for attempt in range(3):
            with context.wrap_socket(socket.create_connection(("127.0.0.1", port)),
                                     session=session) as sock:
                sock.sendall(struct.pack(">HHHBBHH", attempt, 0, 6, UNIT, 3, 0, 1))
                assert recv_frame(sock)[7:] == b"\x03\x02\x03\xe8"
                assert sock.session_reused is (attempt > 0), (version, attempt)
                session = sock.session


def test_a_certificate_without_a_role_gets_0x01_for_every_request(secure, ca):
    """[firewall] default allow and no rule: the role-less client still may do nothing; its
    session stays open, and nothing of it reaches the line.  The client with a role reads."""
    gw, port, record = secure()
    bad_role = ca.issue("bad-role", role_der="ASN1:SEQUENCE:roles\n[roles]\nr=UTF8:operator")
    for cert in (ca.issue("no-role"), bad_role):
        client = tls_client(port, client_context(ca, cert))
        try:
            for _ in range(2):
                reply = client.read_holding_registers(0, count=1, device_id=UNIT)
                assert reply.isError() and reply.exception_code == 0x01
            reply = client.write_register(5, 7, device_id=UNIT)
            assert reply.isError() and reply.exception_code == 0x01
        finally:
            client.close()
    with socket.create_connection(("127.0.0.1", port)) as raw, \
            client_context(ca, ca.issue("none2")).wrap_socket(raw) as sock:
        sock.sendall(struct.pack(">HHHBBHH", 9, 0, 6, 0, 6, 5, 7))      # a broadcast write
        assert recv_frame(sock) == struct.pack(">HHHBBB", 9, 0, 3, 0, 0x86, 0x01)
    client = tls_client(port, client_context(ca, ca.issue("op", role="operator")))
    try:
        assert client.read_holding_registers(0, count=1, device_id=UNIT).registers == [1000]
    finally:
        client.close()
    assert on_the_line(record) == [bytes.fromhex("03 0000 0001")]
    firewall = status(gw)["firewall"]
    assert firewall["require_role"] and firewall["refused_no_role"] == 7


def test_without_require_role_a_role_less_client_is_one_without_a_role(secure, ca):
    gw, port, record = secure("require-role = false\n")
    client = tls_client(port, client_context(ca, ca.issue("no-role")))
    try:
        assert client.read_holding_registers(0, count=1, device_id=UNIT).registers == [1000]
    finally:
        client.close()


def test_read_only_keeps_fc8_force_listen_only_off_the_line(secure, ca):
    """A read-only client's FC 8/4 (force listen only mode) and FC 8/1 get 0x01 and never
    reach the slave; its FC 8/0 and a read do.  A client under no rule sends FC 8/4 to the
    line: the test sees the wire."""
    gw, port, record = secure('[[rule]]\nrole = "viewer"\nread-only = true\n')
    client = tls_client(port, client_context(ca, ca.issue("viewer", role="viewer")))
    try:
        for sub in (4, 1):
            reply = client.diag_force_listen_only(device_id=UNIT, no_response_expected=False) \
                if sub == 4 else \
                client.diag_restart_communication(False, device_id=UNIT)
            assert reply.isError() and reply.exception_code == 0x01, reply
        reply = client.write_registers(0, [1, 2], device_id=UNIT)
        assert reply.isError() and reply.exception_code == 0x01
        assert client.read_holding_registers(0, count=1, device_id=UNIT).registers == [1000]
    finally:
        client.close()
    with socket.create_connection(("127.0.0.1", gw.port), timeout=REPLY_S) as plain:
        plain.sendall(struct.pack(">HHHBBHH", 1, 0, 6, UNIT, 8, 4, 0))
        recv_frame(plain)                       # fault_slave answers it with 0x01 itself
    assert on_the_line(record) == [bytes.fromhex("03 0000 0001"),
                                   bytes.fromhex("08 0004 0000")]


def test_a_revoked_client_is_refused_and_a_reloaded_crl_applies(tmp_path, secure, ca):
    crl = tmp_path / "ca.crl"
    revoked = ca.issue("revoked", role="operator")
    later = ca.issue("later", role="operator")
    ca.revoke(revoked[0])
    ca.crl(crl)
    gw, port, _ = secure(f'crl = "{crl}"\n')
    assert read(tls_client(port, client_context(ca, revoked))) is None
    wait_for_log(gw, "refused: TLS handshake refused (client certificate: certificate revoked)")
    wait_for(gw, lambda s: s["counters"]["connections_refused_tls"] >= 1, "refused")
    client = tls_client(port, client_context(ca, later))
    try:
        assert client.read_holding_registers(0, count=1, device_id=UNIT).registers == [1000]
    finally:
        client.close()
    ca.revoke(later[0])                         # revoked now: a new CRL and a reload
    ca.crl(crl)
    os.kill(gw.proc.pid, signal.SIGHUP)
    wait_for_log(gw, "loaded for new connections")
    assert read(tls_client(port, client_context(ca, later))) is None
    wait_for(gw, lambda s: s["counters"]["connections_refused_tls"] >= 2, "refused again")


def test_an_out_of_date_crl_is_logged_as_an_error(tmp_path, secure, ca):
    crl = ca.crl(tmp_path / "ca.crl", hours=-1)
    gw, port, _ = secure(f'crl = "{crl}"\n')
    log = wait_for_log(gw, f"tls-crl {crl}: past its next update")
    assert "ERROR" in log.split(f"tls-crl {crl}: past")[0].splitlines()[-1]


def test_check_config_checks_the_crl(tmp_path, pty, ca):
    cert, key = ca.issue("server", server=True)
    other = Authority(tmp_path, "other")
    for crl, problem in ((tmp_path / "missing.crl", "cannot be read"),
                         (cert, "not a PEM certificate revocation list"),
                         (other.crl(tmp_path / "other.crl"), "not signed by a CA of tls-ca")):
        path = tmp_path / "mbgw.toml"
        path.write_text(f'[serial]\ndevice = "{pty}"\n[tls]\ncert = "{cert}"\nkey = "{key}"\n'
                        f'ca = "{ca.cert}"\ncrl = "{crl}"\n')
        done = subprocess.run([sys.executable, "-m", "mbgw", "check-config", str(path)],
                              capture_output=True, text=True, timeout=30)
        assert done.returncode != 0, done
        assert f"{crl}: {problem}" in done.stderr, done.stderr


def test_a_health_check_hides_no_certificate_refusal(secure, ca):
    """A probe's connect and close, a connect and reset, then a real handshake with a
    certificate of another CA from the same address: the probes are counted, not logged as
    refused handshakes, nothing is logged as a traceback, and the real refusal is logged."""
    gw, port, _ = secure()
    socket.create_connection(("127.0.0.1", port)).close()
    reset = socket.create_connection(("127.0.0.1", port))
    reset.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
    reset.close()
    wait_for(gw, lambda s: s["counters"]["connections_tls_probes"] == 2, "probes counted")
    stranger = Authority(ca.dir.parent, "other")
    client = ModbusTlsClient("127.0.0.1", port=port, timeout=REPLY_S, retries=0,
                             sslctx=client_context(ca, stranger.issue("x", role="operator")))
    client.connect()
    client.close()
    log = wait_for_log(gw, "TLS handshake refused (client certificate: unable to get local "
                           "issuer certificate)")
    assert "Traceback" not in log and log.count("connection from 127.0.0.1 refused") == 1, log
    assert status(gw)["counters"]["connections_refused_tls"] == 1
