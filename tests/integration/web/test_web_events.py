"""The Events page names the refusals of the Modbus TCP faces in words, who and why: a client
from an address net.authip leaves out, and a TLS client whose certificate another CA signed.
One daemon for the module: `mbgw slave` allowing 127.0.0.1 only, Modbus/TCP Security on
(certificates from tests/pki.py), the console on; its line a pty nobody answers on."""
import socket
import ssl

import pytest
from selenium.webdriver.common.by import By
from selenium.webdriver.support.ui import Select

from tests.harness import Gateway, PtyPair, free_port
from tests.integration.tls.test_tls import client_context
from tests.integration.web.test_web_ui import WAIT_S, console_file, found, go, log_in, wait
from tests.ops import status, wait_for_log
from tests.pki import Authority

pytestmark = pytest.mark.integration

ELSEWHERE = "127.0.0.2"          # a loopback address, not in authip
UNTRUSTED = "unable to get local issuer certificate"
ONCE_A_MINUTE = " (logged at most once a minute per address and reason)"     # as the log


class Guarded:
    """`mbgw slave` with authip 127.0.0.1, a TLS port whose clients our CA must have signed,
    and the console; a CA of its own for certificates the gateway does not trust."""

    def __init__(self, directory) -> None:
        self.ca = Authority(directory)
        self.stranger = Authority(directory, "stranger")
        cert, key = self.ca.issue("server", server=True)
        self.pty = PtyPair(directory)
        self.tls_port = free_port()
        path = directory / "mbgw.toml"
        self.url = console_file(path, [
            "[serial]", "baudrate = 19200",
            "[net]", 'authip = ["127.0.0.1"]',
            "[tls]", f"port = {self.tls_port}", f'cert = "{cert}"', f'key = "{key}"',
            f'ca = "{self.ca.cert}"'])
        self.gw = Gateway(directory, self.pty.gateway, "--config", str(path))

    def stop(self) -> None:
        self.gw.stop()
        self.pty.stop()


@pytest.fixture(scope="module")
def daemon(tmp_path_factory):
    running = Guarded(tmp_path_factory.mktemp("events"))
    yield running
    running.stop()


def events_of_kind(browser, daemon, kind: str) -> list[tuple[str, str]]:
    """The Events page showing kind only, once it shows one: (event, message) of each row."""
    log_in(browser, daemon, "admin")
    go(browser, "events")
    Select(wait(browser, found("#events-kind"))).select_by_value(kind)
    rows = "#events-table tbody tr"
    return wait(browser, lambda d: [
        (row.find_element(By.CSS_SELECTOR, "td.event").text,
         row.find_element(By.CSS_SELECTOR, "td.message").text)
        for row in d.find_elements(By.CSS_SELECTOR, rows)])


def test_a_client_authip_leaves_out_is_a_refusal_on_the_events_page(browser, daemon):
    with socket.create_connection(("127.0.0.1", daemon.gw.port), timeout=WAIT_S,
                                  source_address=(ELSEWHERE, 0)) as client:
        assert client.recv(1) == b""            # closed by the gateway before a byte
    wait_for_log(daemon.gw, f"connection from {ELSEWHERE} refused: not in authip")
    assert status(daemon.gw)["counters"]["connections_refused_authip"] == 1
    shown = events_of_kind(browser, daemon, "connection-refused")
    assert shown == [("connection-refused",
                      f"connection from {ELSEWHERE} refused: not in authip{ONCE_A_MINUTE}")], shown


def test_a_tls_client_with_an_untrusted_certificate_is_a_refusal_on_the_events_page(
        browser, daemon):
    context = client_context(daemon.ca, daemon.stranger.issue("intruder", role="operator"))
    with socket.create_connection(("127.0.0.1", daemon.tls_port), timeout=WAIT_S) as raw:
        # TLS 1.3: the client's side of the handshake ends before the gateway checks the
        # certificate, so the refusal (an alert) comes with the first read
        with pytest.raises((ssl.SSLError, ConnectionResetError)):
            with context.wrap_socket(raw) as tls:
                tls.recv(1)
    wait_for_log(daemon.gw, f"TLS handshake refused (client certificate: {UNTRUSTED})")
    assert status(daemon.gw)["counters"]["connections_refused_tls"] == 1
    shown = events_of_kind(browser, daemon, "tls-refused")
    assert shown == [("tls-refused", "connection from 127.0.0.1 refused: TLS handshake "
                      f"refused (client certificate: {UNTRUSTED}){ONCE_A_MINUTE}")], shown
