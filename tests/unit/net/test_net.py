"""mbgw.net: listening sockets, addresses, authip and the logs kept to once an interval; and
the errors that name the option they are about (errors.ListenError, ConfigError.key)."""
import errno
import socket
import ssl

import click
import pytest

from mbgw.cli.options import convert
from mbgw.config.model import SerialConfig, SlaveConfig
from mbgw.config.scenario import parse_scenario
from mbgw.errors import ConfigError, ListenError, MbgwError
from mbgw.net.acl import AccessList
from mbgw.net.address import format_address, parse_host_port
from mbgw.net.listen import listen
from mbgw.net.ratelimit import RateLimitedLog
from mbgw.net.tls import handshake_step
from mbgw.table.memory import Table
from mbgw.table.server import TableServer


def _close(sockets):
    for sock in sockets:
        sock.close()


def test_listen_on_an_ephemeral_port_accepts_connections():
    sockets = listen("127.0.0.1", 0, option="table-port")
    try:
        assert len(sockets) == 1 and not sockets[0].getblocking()
        port = sockets[0].getsockname()[1]
        with socket.create_connection(("127.0.0.1", port), timeout=5):
            sockets[0].setblocking(True)
            peer, _ = sockets[0].accept()
            peer.close()
    finally:
        _close(sockets)


def test_a_port_taken_is_a_listen_error_naming_the_option_and_the_port():
    taken = listen("127.0.0.1", 0, option="table-port")
    port = taken[0].getsockname()[1]
    try:
        with pytest.raises(ListenError) as caught:
            listen("127.0.0.1", port, option="raw-port")
    finally:
        _close(taken)
    err = caught.value
    assert (err.option, err.port, err.errno) == ("raw-port", port, errno.EADDRINUSE)
    assert err.reason == "Address already in use"
    assert str(err) == f"raw-port {port}: cannot listen there: Address already in use"
    assert isinstance(err, OSError) and isinstance(err, MbgwError)


def test_a_bind_address_that_does_not_resolve_is_a_listen_error():
    with pytest.raises(ListenError, match=r"^mdbport 1502: cannot listen there: "):
        listen("nohost.invalid", 1502, option="mdbport")


def test_listen_stamps_each_socket_before_it_listens():
    stamped = []
    sockets = listen("127.0.0.1", 0, option="mdbport", stamp_arrivals=stamped.append)
    try:
        assert stamped == [s.fileno() for s in sockets]
    finally:
        _close(sockets)


def test_the_table_server_names_the_option_of_its_port():
    taken = listen("127.0.0.1", 0, option="x")
    port = taken[0].getsockname()[1]
    try:
        with pytest.raises(ListenError, match=f"^table-port {port}: cannot listen there"):
            TableServer(Table(), port, "127.0.0.1")
        with pytest.raises(ListenError, match=f"^mdbport {port}: cannot listen there"):
            TableServer(Table(), port, "127.0.0.1", port_option="mdbport")
    finally:
        _close(taken)


def test_a_listen_error_from_a_text_reason_has_no_errno():
    err = ListenError("bind", 502, "the table server does not answer")
    assert err.errno is None and str(err) == \
        "bind 502: cannot listen there: the table server does not answer"


@pytest.mark.parametrize("address, text", [
    (("192.0.2.7", 502), "192.0.2.7:502"),
    (("2001:db8::5", 802, 0, 0), "[2001:db8::5]:802"),
    (("::ffff:192.0.2.7", 502, 0, 0), "[::ffff:192.0.2.7]:502"),
    (("fe80::1%eth0", 502, 0, 2), "[fe80::1%eth0]:502"),
])
def test_format_address(address, text):
    assert format_address(address) == text


@pytest.mark.parametrize("text, expected", [
    ("127.0.0.1:8080", ("127.0.0.1", 8080)),
    ("[::1]:65535", ("::1", 65535)),
    (":1", (None, 1)),
    ("[::]:502", ("::", 502)),
    ("localhost:9502", ("localhost", 9502)),
])
def test_parse_host_port(text, expected):
    assert parse_host_port(text) == expected
    assert format_address((expected[0] or "", expected[1])).endswith(f":{expected[1]}")


@pytest.mark.parametrize("text, why", [
    ("8080", "'8080': not ADDR:PORT (e.g. 127.0.0.1:8080)"),
    ("::1:8080", "'::1:8080': write an IPv6 address in brackets, [ADDR]:PORT"),
    ("127.0.0.1:0", "'127.0.0.1:0': port '0' is not 1..65535"),
    ("127.0.0.1:65536", "'127.0.0.1:65536': port '65536' is not 1..65535"),
    ("127.0.0.1:http", "'127.0.0.1:http': port 'http' is not 1..65535"),
    ("127.0.0.1:", "'127.0.0.1:': port '' is not 1..65535"),
])
def test_parse_host_port_errors_say_why(text, why):
    with pytest.raises(ConfigError) as caught:
        parse_host_port(text, example="127.0.0.1:8080")
    assert str(caught.value) == why
    with pytest.raises(ConfigError, match="^metrics "):
        parse_host_port(text, "metrics")


def test_the_access_list_compares_a_peer_without_its_scope_id():
    acl = AccessList(SlaveConfig(SerialConfig("/dev/null"), authip=("fe80::1",)).authip)
    assert acl.allows("fe80::1%eth0") and acl.allows("fe80::1")
    assert not acl.allows("fe80::2%eth0")


class _Clock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


def test_a_rate_limited_log_lets_one_line_an_interval_through_and_counts_the_rest():
    clock = _Clock()
    limit = RateLimitedLog(60.0, clock=clock)
    assert limit.due(("10.0.0.1", "busy")) == 0
    assert [limit.due(("10.0.0.1", "busy")) for _ in range(3)] == [None] * 3
    assert limit.due(("10.0.0.2", "busy")) == 0           # each key its own
    clock.now += 59.9
    assert limit.due(("10.0.0.1", "busy")) is None
    clock.now += 0.1
    assert limit.due(("10.0.0.1", "busy")) == 4           # left out since its last line
    assert limit.due(("10.0.0.1", "busy")) is None
    clock.now += 60
    assert limit.due(("10.0.0.1", "busy")) == 1
    assert limit.due(("10.0.0.2", "busy")) == 0


def test_a_rate_limited_log_forgets_its_oldest_key_when_full():
    clock = _Clock()
    limit = RateLimitedLog(60.0, clock=clock, max_keys=2)
    assert limit.due("a") == 0 and limit.due("b") == 0
    assert limit.due("a") is None
    assert limit.due("c") == 0                  # "a" forgotten, its count with it
    assert limit.due("a") == 0
    assert limit.due("c") is None


def test_a_refusal_of_the_model_names_the_option_of_its_key():
    with pytest.raises(click.BadParameter) as caught:
        convert(None, lambda: SlaveConfig(SerialConfig("/dev/null"), mdbport=0))
    assert caught.value.format_message() == "Invalid value for '--mdbport': 0 turns plain " \
        "Modbus TCP off: it needs TLS (--tls-cert)"
    with pytest.raises(ConfigError) as model:
        SlaveConfig(SerialConfig("/dev/null"), mdbport=0)
    assert model.value.key == "mdbport" and str(model.value).startswith("mdbport 0 ")


def test_a_refusal_without_a_key_blames_no_option():
    scenario = parse_scenario({"name": "remote", "server": "10.0.0.5", "function": 3,
                               "address": 0, "quantity": 2, "table": 0, "cycle": 1000,
                               "tls": True}, "scenario 1")
    with pytest.raises(click.BadParameter) as caught:
        convert(None, lambda: SlaveConfig(SerialConfig("/dev/null"), scenarios=(scenario,)))
    message = caught.value.format_message()
    assert "--authip" not in message and "scenario remote: " in message


def _client_handshake():
    """A client TLS socket whose ClientHello is out, and the peer's plain end."""
    ours, peer = socket.socketpair()
    ours.setblocking(False)
    context = ssl.create_default_context()
    context.check_hostname = False
    context.verify_mode = ssl.CERT_NONE
    tls = context.wrap_socket(ours, do_handshake_on_connect=False)
    assert handshake_step(tls) == ("read", "")
    return tls, peer


@pytest.mark.parametrize("describe, why", [
    (None, "TLS handshake refused (WRONG_VERSION_NUMBER)"),
    (lambda err: f"TLS handshake failed: {type(err).__name__}", "TLS handshake failed: SSLError"),
])
def test_a_handshake_step_says_why_it_failed_in_its_callers_words(describe, why):
    tls, peer = _client_handshake()
    try:
        peer.sendall(b"HTTP/1.0 400 Bad Request\r\n\r\n")     # not a TLS server
        assert handshake_step(tls, describe) == ("failed", why)
    finally:
        tls.close()
        peer.close()
