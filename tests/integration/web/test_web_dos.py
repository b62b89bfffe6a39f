"""The web console under abuse: logins at once, bodies too big or too deep, sessions by the
thousand, plain HTTP beside HTTPS, idle connections by the thousand.  Slave mode with the
fault peer on the line, as in test_web_api; checked on the wire and in the log."""
import concurrent.futures
import http.client
import json
import socket
import ssl
import threading
import time

import pytest

from tests.harness import free_port, idle_connections
from tests.integration.scenarios.test_scenarios_serial import write_config
from tests.integration.tls.test_tls import client_context, tls_options
from tests.integration.web.test_web_api import (
    ADMIN_PASSWORD,
    USER_PASSWORD,
    Web,
    admin,
    listen_on,
    self_signed,
    set_passwords,
)
from tests.modbus import Client, holding_reply, mbap, read_holding
from tests.pki import Authority

pytestmark = pytest.mark.integration


@pytest.fixture
def console(tmp_path, pty_pair, start_gateway, recording_peer):
    """console(web_extra="", args=()) -> (gateway, Web): slave mode with the table, the fault
    peer on the line, the console on a free port with both passwords set; web_extra: more
    [web] keys; args: more options."""
    def start(web_extra: str = "", args=()):
        recording_peer("fault_slave.py")
        path = tmp_path / "mbgw.toml"
        write_config(path, [], stout=1000, enabled=True)    # the peer may be slow under load
        set_passwords(path, ("admin", ADMIN_PASSWORD), ("user", USER_PASSWORD))
        port = listen_on(path)
        path.write_text(path.read_text().replace("[web]\n", "[web]\n" + web_extra, 1))
        gw = start_gateway(pty_pair.gateway, "--config", str(path), *args)
        scheme = "https" if "https" in web_extra else "http"
        return gw, Web(f"{scheme}://127.0.0.1:{port}")
    return start


def port_of(web: Web) -> int:
    return int(web.base.rsplit(":", 1)[1])


def raw_post(port: int, path: str, body: bytes, headers: dict | None = None,
             timeout: float = 10) -> tuple[int, bytes]:
    """(status, body) of one POST on a connection of its own; status 0: the connection was
    closed without an answer, or none came in time (300 connections at once overflow the
    listener's backlog: the kernel lets some through only after its SYN-ACK retries)."""
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=timeout)
    try:
        conn.request("POST", path, body=body, headers={"Content-Type": "application/json",
                                                       **(headers or {})})
        response = conn.getresponse()
        return response.status, response.read()
    except (ConnectionError, TimeoutError, http.client.HTTPException):
        return 0, b""
    finally:
        conn.close()


def test_concurrent_wrong_logins_from_one_address_are_refused_after_the_fifth(console):
    gw, web = console()
    port = port_of(web)
    guess = json.dumps({"user": "admin", "password": "wrong-guess-1"}).encode()
    start = threading.Barrier(300)

    def attempt(_) -> int:
        start.wait()
        return raw_post(port, "/api/login", guess)[0]
    with concurrent.futures.ThreadPoolExecutor(300) as pool:
        codes = list(pool.map(attempt, range(300)))
    assert codes.count(401) == 5, sorted(set(codes))
    assert set(codes) <= {401, 429, 0} and codes.count(429) > 0
    assert gw.log().count("web login failed") == 5
    assert web.login("admin", ADMIN_PASSWORD) == 429       # the address waits its minute


def test_a_body_over_its_bound_is_refused_with_413_before_it_is_read(console):
    gw, web = console()
    port = port_of(web)
    # a login's Content-Length alone refuses it: the body never comes
    conn = socket.create_connection(("127.0.0.1", port), timeout=5)
    conn.sendall(b"POST /api/login HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
                 b"Content-Length: 1000000\r\n\r\n")
    assert conn.recv(100).startswith(b"HTTP/1.1 413 ")
    conn.close()
    # a chunked one, which says no length: refused once it is over, not read to the end
    conn = socket.create_connection(("127.0.0.1", port), timeout=5)
    conn.sendall(b"POST /api/login HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
                 b"Transfer-Encoding: chunked\r\n\r\n" + b"%x\r\n" % 5000 + b" " * 5000
                 + b"\r\n")
    assert conn.recv(100).startswith(b"HTTP/1.1 413 ")
    conn.close()
    web = admin(web)
    code, reply, _ = web.call("POST", "/api/table", raw=b"{" + b" " * 1_000_001 + b"}")
    assert code == 413, reply
    assert web.ok("GET", "/api/session")["role"] == "admin"


def test_deeply_nested_json_is_a_400_never_a_traceback(console):
    gw, web = console()
    port = port_of(web)
    for depth in (40, 2000):            # within a login's 4096 bytes
        nested = b'{"user": ' + b"[" * depth + b"]" * depth + b', "password": "x"}'
        code, body = raw_post(port, "/api/login", nested)
        assert code == 400 and b"nested" in body, (depth, code, body)
    web = admin(web)
    depth = 200_000                     # far beyond Python's recursion limit
    code, reply, _ = web.call("POST", "/api/table", raw=b"[" * depth + b"]" * depth)
    assert code == 400 and "nested" in reply["error"], (code, reply)
    assert "Traceback" not in gw.log()


def test_one_role_opening_sessions_never_ends_the_others(console):
    gw, web = console()
    web = admin(web)
    first_user = Web(web.base)
    assert first_user.login("user", USER_PASSWORD) == 200
    for _ in range(40):
        assert Web(web.base).login("user", USER_PASSWORD) == 200
    assert web.ok("GET", "/api/session")["role"] == "admin"
    assert first_user.get("/api/session")[0] == 401     # the user's oldest went


def test_a_login_gets_a_new_session_id_and_the_old_one_ends(console):
    gw, web = console()
    web = admin(web)
    old = next(c.value for c in web.jar if c.name == "mbgw_session")
    stale = Web(web.base)
    stale.jar.set_cookie(next(c for c in web.jar if c.name == "mbgw_session"))
    assert web.login("admin", ADMIN_PASSWORD) == 200
    new = next(c.value for c in web.jar if c.name == "mbgw_session")
    assert new != old
    assert stale.get("/api/session")[0] == 401
    assert web.ok("GET", "/api/session")["role"] == "admin"


def test_https_only_redirects_plain_http_and_sets_hsts(console, tmp_path):
    cert, key = self_signed(tmp_path)
    gw, web = console(web_extra=f'cert = "{cert}"\nkey = "{key}"\nhttps-only = true\n')
    port = port_of(web)
    conn = socket.create_connection(("127.0.0.1", port), timeout=5)
    conn.sendall(b"GET /api/session?x=1 HTTP/1.1\r\nHost: 127.0.0.1:" + str(port).encode()
                 + b"\r\n\r\n")
    head = conn.recv(1000).decode()
    conn.close()
    assert head.startswith("HTTP/1.1 308 ")
    assert f"Location: https://127.0.0.1:{port}/api/session?x=1\r\n" in head
    secure = Web(f"https://127.0.0.1:{port}", ssl.create_default_context(cafile=cert))
    code, _, headers = secure.call("POST", "/api/login",
                                   {"user": "admin", "password": ADMIN_PASSWORD})
    assert code == 200 and "Secure" in headers["Set-Cookie"]
    assert headers["Strict-Transport-Security"] == "max-age=31536000"


def cpu_s(pid: int) -> float:
    """The process's user and system time so far (/proc/PID/stat utime + stime)."""
    fields = open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / __import__("os").sysconf("SC_CLK_TCK")


def open_fds(pid: int) -> int:
    import os
    return len(os.listdir(f"/proc/{pid}/fd"))


@pytest.mark.usefixtures("many_fds")
def test_idle_connections_by_the_thousand_cost_nothing_and_modbus_is_served(
        console, tmp_path):
    ca = Authority(tmp_path)
    tls_port = free_port()
    gw, web = console(args=tls_options(ca, ca.issue("server", server=True), tls_port))
    modbus = Client(gw.port)
    assert modbus.ask(1, read_holding(0, 2)) == holding_reply(0, 2)
    pid = gw.proc.pid
    before_fds = open_fds(pid)
    log_before = len(gw.log().splitlines())
    cpu_before = cpu_s(pid)
    held = idle_connections(port_of(web), 1500) + idle_connections(tls_port, 100) + \
        idle_connections(gw.port, 50)
    try:
        deadline = time.monotonic() + 5.0
        while time.monotonic() < deadline:          # the line's client keeps being served
            assert modbus.ask(1, read_holding(0, 2)) == holding_reply(0, 2)
            time.sleep(0.05)
        assert open_fds(pid) < before_fds + 64 + 64 + 16
        assert cpu_s(pid) - cpu_before < 2.5       # of 5 s: no spinning
        new_lines = gw.log().splitlines()[log_before:]
        assert len(new_lines) <= 12, "\n".join(new_lines)
        assert web.login("admin", ADMIN_PASSWORD) == 200    # the console still serves
        # a certificate holder from another address shakes hands beside the idle ones
        raw = socket.create_connection(("127.0.0.1", tls_port), timeout=5,
                                       source_address=("127.0.0.2", 0))
        with client_context(ca, ca.issue("op", role="operator")).wrap_socket(raw) as tls:
            tls.sendall(mbap(1, 1, read_holding(0, 2)))
            assert tls.recv(100) == mbap(1, 1, holding_reply(0, 2))
    finally:
        for sock in held:
            sock.close()
        modbus.close()
