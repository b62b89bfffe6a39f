"""The web console's JSON API (issue 18), against a running gateway on a socat pty with the
fault peer (tests/peers/fault_slave.py) on the line, through a plain HTTP client (urllib,
with its cookie jar as a browser keeps the session cookie).  What the API says is checked
against the wire: the Modbus client's bytes, the frames the peer saw, the file on disk.
The fault peer's registers i hold 1000 + i; the table answers unit 247."""
import http.cookiejar
import json
import signal
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request

import pytest

from tests.harness import CHECKOUT, free_port
from tests.integration.scenarios.test_scenarios_serial import WAIT_S, frames_to, poll, write_config
from tests.modbus import Client, holding_reply, read_holding
from tests.ops import status, wait_for_log
from tests.wait import until

pytestmark = pytest.mark.integration

TABLE_UNIT = 247
ADMIN_PASSWORD = "admin-secret-1"
USER_PASSWORD = "user-secret-1"
IDLE_S = 1.0           # the sessions' idle time in the expiry test (MBGW_WEB_IDLE_S)


class Web:
    """A browser's view of the API: a cookie jar, the CSRF token of the last login."""

    def __init__(self, base: str, context=None) -> None:
        self.base = base
        self.jar = http.cookiejar.CookieJar()
        handlers = [urllib.request.HTTPCookieProcessor(self.jar)]
        if context is not None:
            handlers.append(urllib.request.HTTPSHandler(context=context))
        self.opener = urllib.request.build_opener(*handlers)
        self.csrf: str | None = None

    def call(self, method: str, path: str, data=None, csrf: bool = True, raw: bytes | None = None,
             timeout: float = 10) -> tuple[int, object, dict]:
        """(status, the JSON body or the text, the headers)."""
        body = raw if raw is not None else None if data is None else json.dumps(data).encode()
        request = urllib.request.Request(self.base + path, data=body, method=method)
        if data is not None:
            request.add_header("Content-Type", "application/json")
        if csrf and self.csrf:
            request.add_header("X-CSRF-Token", self.csrf)
        try:
            with self.opener.open(request, timeout=timeout) as response:
                return response.status, _decoded(response), dict(response.headers)
        except urllib.error.HTTPError as err:
            return err.code, _decoded(err), dict(err.headers)

    def get(self, path: str):
        return self.call("GET", path)

    def post(self, path: str, data=None, **options):
        return self.call("POST", path, {} if data is None and "raw" not in options else data,
                         **options)

    def login(self, user: str, password: str) -> int:
        code, reply, _ = self.call("POST", "/api/login", {"user": user, "password": password})
        if code == 200:
            self.csrf = reply["csrf"]
        return code

    def ok(self, method: str, path: str, data=None):
        code, reply, _ = self.call(method, path, data)
        assert code == 200, (method, path, code, reply)
        return reply


def _decoded(response):
    text = response.read().decode()
    if response.headers.get("Content-Type", "").startswith("application/json"):
        return json.loads(text)
    return text


def set_passwords(path, *roles) -> None:
    for role, password in roles:
        done = subprocess.run([sys.executable, "-m", "mbgw", "config", "password", role,
                               "--stdin", "--config", str(path)], input=password + "\n",
                              capture_output=True, text=True, timeout=30, cwd=CHECKOUT)
        assert done.returncode == 0, done.stderr
        assert password not in done.stdout and "scrypt" not in done.stdout


@pytest.fixture
def console(tmp_path, pty_pair, start_gateway, recording_peer):
    """console(scenarios, mode_options=(), env=None) -> (gateway, its file, Web, the peer's
    record): slave mode with the exchange table, the fault peer on the line, the console on a
    free port with both passwords set."""
    def start(scenarios=(), env=None, **config):
        record = recording_peer("fault_slave.py")
        path = tmp_path / "mbgw.toml"
        write_config(path, list(scenarios), enabled=True, **config)
        set_passwords(path, ("admin", ADMIN_PASSWORD), ("user", USER_PASSWORD))
        port = listen_on(path)
        gw = start_gateway(pty_pair.gateway, "--config", str(path), env=env)
        return gw, path, Web(f"http://127.0.0.1:{port}"), record
    return start


def listen_on(path) -> int:
    """Turn the console on in the file (its [web] group holds the passwords): the port."""
    port = free_port()
    path.write_text(path.read_text().replace("[web]\n", f'[web]\nlisten = "127.0.0.1:{port}"\n',
                                             1))
    return port


def admin(web: Web) -> Web:
    assert web.login("admin", ADMIN_PASSWORD) == 200
    return web


# --- the admin's session: every endpoint ---------------------------------------------------

def test_login_sets_a_strict_httponly_cookie_and_the_session_tells_role_and_csrf(console):
    gw, _, web, _ = console()
    code, reply, headers = web.call("POST", "/api/login",
                                    {"user": "admin", "password": ADMIN_PASSWORD})
    assert code == 200 and reply["role"] == "admin" and len(reply["csrf"]) >= 32
    cookie = headers["Set-Cookie"]
    assert cookie.startswith("mbgw_session=") and "HttpOnly" in cookie
    assert "SameSite=Strict" in cookie and "Secure" not in cookie     # plain HTTP
    web.csrf = reply["csrf"]
    assert web.ok("GET", "/api/session") == {"role": "admin", "csrf": reply["csrf"]}
    assert "web login: admin from 127.0.0.1" in wait_for_log(gw, "web login: admin")
    assert web.ok("POST", "/api/logout", {}) == {"ok": True}
    assert web.get("/api/session")[0] == 401
    assert web.get("/api/status")[0] == 401


def test_status_is_the_control_sockets_document_and_the_page_is_served(console):
    gw, _, web, _ = console()
    assert web.get("/api/status")[0] == 401            # not logged in
    admin(web)
    mine = web.ok("GET", "/api/status")
    theirs = status(gw)
    assert mine["mode"] == theirs["mode"] == "slave"
    assert set(mine) == set(theirs) and mine["pid"] == theirs["pid"]
    assert mine["table"]["units"] == theirs["table"]["units"]
    code, page, headers = web.get("/")
    assert code == 200 and "<html" in page and headers["X-Frame-Options"] == "DENY"
    assert "default-src 'self'" in headers["Content-Security-Policy"]


def close_the_only_client(web: Web, c: Client) -> None:
    """c, the one client listed, having sent one request, closed through the API: the
    gateway ends its connection, and a second close finds no such client."""
    clients = web.ok("GET", "/api/clients")["clients"]
    assert len(clients) == 1 and clients[0]["requests"] == 1
    client_id = clients[0]["id"]
    assert web.ok("POST", f"/api/clients/{client_id}/close", {}) == {"ok": True}
    c.sock.settimeout(5)
    assert c.sock.recv(1) == b""                   # the gateway closed it
    assert web.post(f"/api/clients/{client_id}/close")[0] == 404


def test_a_client_is_listed_and_closed_from_the_console(console):
    gw, _, web, _ = console()
    admin(web)
    c = Client(gw.port)
    try:
        assert c.ask(1, read_holding(0, 1)) == holding_reply(0, 1)    # a marker: it is served
        close_the_only_client(web, c)
    finally:
        c.close()
    devices = web.ok("GET", "/api/devices")["devices"]
    assert [d["address"] for d in devices] == [1]


def test_the_table_is_written_from_the_console_and_read_back_by_a_modbus_client(console):
    gw, _, web, _ = console()
    admin(web)
    assert web.ok("POST", "/api/table", {"address": 100, "values": [0x1234, 7]})
    c = Client(gw.port)
    try:
        assert c.ask(TABLE_UNIT, read_holding(100, 2)) == bytes.fromhex("03 04 1234 0007")
    finally:
        c.close()
    assert web.ok("GET", "/api/table?address=0x64&count=2") == \
        {"address": 100, "bits": False, "values": [0x1234, 7]}
    bits = web.ok("GET", "/api/table?address=1600&count=4&bits=1")   # 100 * 16: 0x1234's bits
    assert bits["bits"] and bits["values"] == [0, 0, 1, 0]
    code, reply, _ = web.post("/api/table", {"address": 65535, "values": [1, 2]})
    assert code == 400 and "run past" in reply["error"]
    assert web.get("/api/table?address=x")[0] == 400


def test_scenarios_are_listed_disabled_enabled_and_tested(console):
    gw, path, web, record = console([poll("a", 50, 3, 0, 1, 0), poll("b", 51, 3, 0, 1, 1)])
    admin(web)
    until(lambda: {s["name"]: s["state"] for s in web.ok("GET", "/api/scenarios")["scenarios"]}
          == {"a": "running", "b": "running"}, "both running", WAIT_S)
    assert web.ok("POST", "/api/scenarios/a/disable", {})["ok"]
    assert {s["name"]: s["state"] for s in web.ok("GET", "/api/scenarios")["scenarios"]}["a"] \
        == "disabled"
    count = len(frames_to(record, 50))
    until(lambda: len(frames_to(record, 51)) >= len(frames_to(record, 50)) + 3,
          "b going on", WAIT_S)
    assert len(frames_to(record, 50)) <= count + 1           # one may have been on its way
    assert "enabled = false" not in path.read_text()
    assert "scenario a disabled by web admin@127.0.0.1 until the next reload" in gw.log()
    assert "by uid web" not in gw.log()
    assert web.ok("POST", "/api/scenarios/a/enable", {})["ok"]
    until(lambda: len(frames_to(record, 50)) > count + 1, "a running again", WAIT_S)
    assert web.post("/api/scenarios/nope/enable")[0] == 400
    result = web.ok("POST", "/api/scenarios/test", {"slave": 60, "function": 3, "address": 4,
                                                    "quantity": 2, "table": 80})
    assert result["ok"] and result["data"] == [1004, 1005]
    assert frames_to(record, 60)[0][:6] == bytes.fromhex("3c 03 0004 0002")
    code, reply, _ = web.post("/api/scenarios/test", {"slave": 60})
    assert code == 400 and reply["error"]


def test_statistics_and_their_reset(console):
    gw, _, web, _ = console()
    admin(web)
    c = Client(gw.port)
    try:
        assert c.ask(1, read_holding(0, 1)) == holding_reply(0, 1)
    finally:
        c.close()
    stats = web.ok("GET", "/api/stats")
    assert stats["counters"]["requests"] == 1 and "line_utilisation_pct" in stats
    assert web.ok("POST", "/api/stats/reset", {}) == {"ok": True}
    assert web.ok("GET", "/api/stats")["counters"]["requests"] == 0
    assert status(gw)["counters"]["requests"] == 0


def trace_events(stream, count: int) -> list[dict]:
    """The next `count` events of an /api/trace stream."""
    events: list[dict] = []
    while len(events) < count:
        line = stream.readline().decode()
        if line.startswith("data: "):
            events.append(json.loads(line[6:]))
    return events


def test_the_trace_streams_each_transaction_as_a_server_sent_event(console):
    gw, _, web, _ = console()
    admin(web)
    request = urllib.request.Request(web.base + "/api/trace")
    with web.opener.open(request, timeout=10) as stream:
        assert stream.headers["Content-Type"].startswith("text/event-stream")
        assert stream.readline() == b": trace\n"       # subscribed: what follows is traced
        c = Client(gw.port)
        try:
            assert c.ask(1, read_holding(3, 2)) == holding_reply(3, 2)
        finally:
            c.close()
        events = trace_events(stream, 2)
    assert [e["direction"] for e in events] == ["request", "reply"]
    assert events[0]["unit"] == 1 and events[0]["pdu"] == read_holding(3, 2).hex()
    assert events[1]["pdu"] == holding_reply(3, 2).hex()
    assert "web trace ended" in wait_for_log(gw, "web trace ended")


def test_the_trace_filters_by_unit_and_refuses_a_bad_filter(console):
    gw, _, web, _ = console()
    admin(web)
    code, reply, _ = web.get("/api/trace?unit=300")
    assert (code, reply) == (400, {"error": "trace: unit 300: expected 0..255"})
    request = urllib.request.Request(web.base + "/api/trace?unit=1")
    with web.opener.open(request, timeout=10) as stream:
        assert stream.readline() == b": trace\n"
        c = Client(gw.port)
        try:
            assert c.ask(11, read_holding(0, 1)) == bytes.fromhex("83 02")    # not shown
            assert c.ask(1, read_holding(3, 2)) == holding_reply(3, 2)
        finally:
            c.close()
        events = trace_events(stream, 2)
    assert [(e["direction"], e["unit"]) for e in events] == [("request", 1), ("reply", 1)]


def test_a_setting_is_checked_like_config_set_and_applied_with_a_reload(console):
    gw, path, web, _ = console()
    admin(web)
    shown = web.ok("GET", "/api/config")
    assert shown["mode"] == "slave" and shown["groups"]["serial"]["stout"]["value"] == 100
    assert shown["groups"]["web"]["listen"]["value"].startswith("127.0.0.1:")
    assert not any("password" in key for key in shown["groups"]["web"])
    before = path.read_text()
    code, reply, _ = web.post("/api/config", {"group": "serial", "key": "stout",
                                              "value": "99999999"})
    assert code == 400 and reply["field"] == "serial.stout" and "stout" in reply["error"]
    assert path.read_text() == before                      # nothing written
    code, reply, _ = web.post("/api/config", {"group": "web", "key": "admin-password",
                                              "value": "x"})
    assert code == 400 and reply["field"] == "web.admin-password"
    reply = web.ok("POST", "/api/config", {"group": "serial", "key": "stout", "value": 700})
    assert reply["ok"] is True and reply["changed"] == {"serial.stout": 700}
    assert reply["reload"]["status"] == "applied"
    assert reply["reload"]["message"] == "configuration reloaded: serial.stout_ms changed"
    assert "stout = 700" in path.read_text()
    assert status(gw)["serial"]["stout_ms"] == 700          # in force when answered
    assert gw.log().count("configuration reloaded: serial.stout_ms changed") == 1
    assert "configuration changed from the web console (web admin@127.0.0.1): serial.stout" \
        in gw.log()


def test_the_file_is_downloaded_and_an_upload_is_checked_before_it_replaces_it(console):
    gw, path, web, _ = console()
    admin(web)
    code, text, headers = web.get("/api/config/file")
    assert code == 200 and text == path.read_text()
    assert 'filename="mbgw.toml"' in headers["Content-Disposition"]
    bad = text.replace("stout = 100", "stout = 0").replace("[net]", "[net]\nbogus = 1")
    code, reply, _ = web.call("POST", "/api/config/file", raw=bad.encode())
    assert code == 400 and any("serial.stout" in p for p in reply["problems"]) \
        and any("bogus" in p for p in reply["problems"])
    assert path.read_text() == text
    good = text.replace("stout = 100", "stout = 650")
    assert web.call("POST", "/api/config/file", raw=good.encode())[0] == 200
    assert path.read_text() == good
    until(lambda: status(gw)["serial"]["stout_ms"] == 650, "reloaded", WAIT_S)


def test_the_answer_is_the_reloads_outcome_as_the_log_says_it(console):
    """A file written whose reload put only part of it in force: 409, the outcome the daemon
    logged (once), and the daemon does what it says: the new stout in force, no metrics
    endpoint (it takes effect at restart)."""
    gw, path, web, _ = console()
    admin(web)
    metrics = free_port()
    text = path.read_text().replace("stout = 100", "stout = 250") \
        + f'[general]\nmetrics = "127.0.0.1:{metrics}"\n'
    code, reply, _ = web.call("POST", "/api/config/file", raw=text.encode())
    assert code == 409 and reply["written"] is True and path.read_text() == text
    outcome = reply["reload"]
    assert outcome["status"] == "partly applied" and outcome["changed"] == ["serial.stout_ms"]
    assert outcome["not_applied"] == {"metrics": "takes effect at restart (systemctl restart "
                                                 "mbgw)"}
    assert reply["error"] == f"written, but {outcome['message']}"
    log = gw.log()
    assert log.count(outcome["message"]) == 1 and log.count("configuration reloaded") == 1
    assert status(gw)["serial"]["stout_ms"] == 250
    with pytest.raises(ConnectionRefusedError):
        socket.create_connection(("127.0.0.1", metrics), timeout=5).close()


def test_what_the_start_would_refuse_is_never_written_nor_reloaded(console):
    gw, path, web, _ = console()
    admin(web)
    before = path.read_text()
    console_port = web.base.rsplit(":", 1)[1]
    code, reply, _ = web.post("/api/config", {"group": "general", "key": "metrics",
                                              "value": f":{console_port}"})
    assert code == 400 and reply["field"] == "general.metrics"
    assert f"general.metrics: port {console_port} is web.listen's already" in reply["error"]
    code, reply, _ = web.post("/api/config", {"group": "net", "key": "bind",
                                              "value": "999.0.0.1"})
    assert code == 400 and "'999.0.0.1' is not an IP address" in reply["error"]
    no_admin = "\n".join(line for line in before.splitlines()
                         if not line.startswith("admin-password")) + "\n"
    code, reply, _ = web.call("POST", "/api/config/file", raw=no_admin.encode())
    assert code == 400 and any("web.listen: no admin password set" in p
                               for p in reply["problems"])
    assert path.read_text() == before
    assert "reload" not in gw.log()


# --- the user role, and what is refused ----------------------------------------------------

USER_CHANGES = [("/api/clients/1/close", {}), ("/api/scenarios/a/disable", {}),
                ("/api/scenarios/test", {"slave": 60}), ("/api/table",
                                                         {"address": 100, "values": [1]}),
                ("/api/stats/reset", {}),
                ("/api/config", {"group": "serial", "key": "stout", "value": 700})]


def test_the_user_role_reads_everything_and_every_change_is_refused(console):
    gw, path, web, _ = console([poll("a", 50, 3, 0, 1, 0)])
    assert web.login("user", USER_PASSWORD) == 200
    assert web.ok("GET", "/api/session")["role"] == "user"
    for read in ("/api/status", "/api/clients", "/api/devices", "/api/scenarios",
                 "/api/table?address=0", "/api/stats", "/api/config"):
        web.ok("GET", read)
    before = path.read_text()
    for change, data in USER_CHANGES:
        code, reply, _ = web.post(change, data)
        assert code == 403 and "admin" in reply["error"], change
    assert web.call("POST", "/api/config/file", raw=b"")[0] == 403
    assert web.get("/api/config/file")[0] == 403         # it holds the password hashes
    assert path.read_text() == before
    assert web.ok("GET", "/api/table?address=100")["values"] == [0]
    assert {s["name"]: s["state"] for s in web.ok("GET", "/api/scenarios")["scenarios"]}["a"] \
        != "disabled"
    assert web.ok("POST", "/api/logout", {}) == {"ok": True}


def test_a_change_without_the_csrf_token_is_refused(console):
    gw, _, web, _ = console()
    admin(web)
    code, reply, _ = web.post("/api/table", {"address": 5, "values": [9]}, csrf=False)
    assert code == 403 and "X-CSRF-Token" in reply["error"]
    token, web.csrf = web.csrf, "not-the-token"
    assert web.post("/api/table", {"address": 5, "values": [9]})[0] == 403
    web.csrf = token
    assert web.ok("GET", "/api/table?address=5")["values"] == [0]
    assert "missing or wrong CSRF token" in gw.log()


def test_a_wrong_password_is_refused_and_logins_are_rate_limited(console):
    gw, _, web, _ = console()
    assert web.login("admin", "wrong") == 401
    assert web.login("nobody", ADMIN_PASSWORD) == 401
    assert web.login("user", ADMIN_PASSWORD) == 401
    assert web.get("/api/session")[0] == 401
    for _ in range(2):
        assert web.login("admin", "wrong") == 401
    code, reply, headers = web.call("POST", "/api/login",
                                    {"user": "admin", "password": ADMIN_PASSWORD})
    assert code == 429 and 1 <= int(headers["Retry-After"]) <= 60, reply
    log = gw.log()
    assert log.count("web login failed") == 5 and "too many failed logins" in log


def test_an_idle_session_expires(console):
    gw, _, web, _ = console(env={"MBGW_WEB_IDLE_S": str(IDLE_S)})
    admin(web)
    assert web.get("/api/session")[0] == 200
    time.sleep(IDLE_S * 1.5)         # the idle time itself is what is tested
    assert web.get("/api/session")[0] == 401
    assert web.post("/api/stats/reset")[0] == 401


# --- start, modes ---------------------------------------------------------------------------

def test_the_console_refuses_to_start_without_an_admin_password(tmp_path, pty_pair):
    done = subprocess.run([sys.executable, "-m", "mbgw", "slave", "--device", pty_pair.gateway,
                           "--web", f"127.0.0.1:{free_port()}", "--control",
                           str(tmp_path / "c.sock")],
                          capture_output=True, text=True, timeout=30, cwd=CHECKOUT)
    assert done.returncode == 2
    assert "no admin password set" in done.stderr and "mbgw config password admin" in \
        done.stderr


def test_config_password_stores_a_salted_hash_that_config_show_never_shows(tmp_path):
    path = tmp_path / "mbgw.toml"
    set_passwords(path, ("admin", ADMIN_PASSWORD), ("user", ADMIN_PASSWORD))
    text = path.read_text()
    hashes = [line.split('"')[1] for line in text.splitlines() if "-password = " in line]
    assert len(hashes) == 2 and hashes[0] != hashes[1]            # salted
    assert all(h.startswith("scrypt$16384$8$1$") for h in hashes) and ADMIN_PASSWORD not in text
    assert path.stat().st_mode & 0o007 == 0                      # not for other local users
    shown = subprocess.run([sys.executable, "-m", "mbgw", "config", "show", "--config",
                            str(path)], capture_output=True, text=True, cwd=CHECKOUT)
    assert "scrypt" not in shown.stdout and "password" not in shown.stdout
    short = subprocess.run([sys.executable, "-m", "mbgw", "config", "password", "admin",
                            "--stdin", "--config", str(path)], input="nine-char\n",
                           capture_output=True, text=True, cwd=CHECKOUT)
    assert short.returncode == 1 and "at least 10 characters" in short.stderr
    assert path.read_text() == text


@pytest.mark.parametrize("mode", ["master", "transparent"])
def test_master_and_transparent_mode_serve_the_console(mode, tmp_path, pty_pair, start_gateway):
    path = tmp_path / "mbgw.toml"
    set_passwords(path, ("admin", ADMIN_PASSWORD))
    port = listen_on(path)
    options = ["--baudrate", "19200", "--config", str(path)]
    table_port = free_port()
    options += ["--table", "--table-port", str(table_port)] if mode == "master" else \
        ["--bind", "127.0.0.1", "--mdbport", str(table_port)]
    gw = start_gateway(pty_pair.gateway, *options, mode=mode, listen=False)
    web = admin(Web(f"http://127.0.0.1:{port}"))
    assert web.ok("GET", "/api/status")["mode"] == mode
    assert web.ok("POST", "/api/table", {"address": 4100, "values": [42]})
    assert web.ok("GET", "/api/table?address=4100")["values"] == [42]
    c = Client(table_port)          # the table server's clients are the Clients page's
    try:
        assert c.ask(1, read_holding(4100, 1)) == bytes.fromhex("03 02 002a")   # the 42
        close_the_only_client(web, c)
    finally:
        c.close()
    assert web.ok("GET", "/api/scenarios") == {"scenarios": []} or mode == "master"
    assert gw.stop() == 0


# --- HTTPS, reload ---------------------------------------------------------------------------

def self_signed(directory) -> tuple[str, str]:
    cert, key = directory / "web.pem", directory / "web.key"
    done = subprocess.run(["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes",
                           "-keyout", str(key), "-out", str(cert), "-days", "2", "-subj",
                           "/CN=localhost", "-addext", "subjectAltName=IP:127.0.0.1"],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    return str(cert), str(key)


def test_https_with_a_self_signed_certificate_and_a_secure_cookie(console, tmp_path):
    import ssl
    cert, key = self_signed(tmp_path)
    gw, path, web, _ = console()
    assert web.ok("POST", "/api/login", {"user": "admin", "password": ADMIN_PASSWORD})
    port = web.base.rsplit(":", 1)[1]
    text = path.read_text().replace("[web]\n", f'[web]\ncert = "{cert}"\nkey = "{key}"\n', 1)
    assert web.call("POST", "/api/config/file", raw=text.encode(),
                    csrf=False)[0] == 403                     # without the CSRF token
    web = admin(web)
    assert web.call("POST", "/api/config/file", raw=text.encode())[0] == 200
    secure = Web(f"https://127.0.0.1:{port}", ssl.create_default_context(cafile=cert))
    until(lambda: _serves(secure), "HTTPS after the reload", WAIT_S)
    code, reply, headers = secure.call("POST", "/api/login",
                                       {"user": "admin", "password": ADMIN_PASSWORD})
    assert code == 200 and "Secure" in headers["Set-Cookie"]
    secure.csrf = reply["csrf"]
    assert secure.ok("GET", "/api/status")["mode"] == "slave"
    with pytest.raises((urllib.error.URLError, ConnectionError)):      # plain HTTP is gone
        urllib.request.urlopen(web.base + "/api/session", timeout=5)
    assert "web console on https://127.0.0.1:" in gw.log()


def _serves(web: Web) -> bool:
    try:
        return web.get("/api/session")[0] == 401
    except (urllib.error.URLError, ConnectionError):
        return False


def test_a_reload_moves_the_console_and_new_passwords_end_the_sessions(console, tmp_path):
    gw, path, web, _ = console()
    admin(web)
    port = free_port()
    assert web.ok("POST", "/api/config", {"group": "web", "key": "listen",
                                          "value": f"127.0.0.1:{port}"})
    moved = Web(f"http://127.0.0.1:{port}")
    until(lambda: _serves(moved), "the console on its new port", WAIT_S)
    assert not _serves(web)
    admin(moved)
    set_passwords(path, ("admin", "another-secret"))
    gw.proc.send_signal(signal.SIGHUP)
    until(lambda: moved.get("/api/session")[0] == 401, "the session ended", WAIT_S)
    assert moved.login("admin", ADMIN_PASSWORD) == 401
    assert moved.login("admin", "another-secret") == 200
