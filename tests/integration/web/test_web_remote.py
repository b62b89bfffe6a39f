"""The Lines page of a daemon without line serial: a remote line's page (its device across
the network: state, reconnects and stray replies in words) and a route from a serial face
added in the browser, each seen from outside.  Line inverter connects to a device emulator
that takes one Modbus TCP connection (tests/peers/single_client_device.py: its late replies
and its closing come from the test); line panel is in master mode, pymodbus's RTU master on
its pty.  No sideways scroll at a desktop's and a phone's width; screenshots kept in
artifacts/console/."""
import pytest
from pymodbus.client import ModbusSerialClient
from pymodbus.exceptions import ModbusIOException
from selenium.webdriver.common.by import By

from tests.harness import Gateway, PtyPair
from tests.integration.web.chrome import DESKTOP, PHONE, assert_fits, page_of_size
from tests.integration.web.test_web_admin import Api
from tests.integration.web.test_web_lines import apply, choose, editor_row, fill
from tests.integration.web.test_web_ui import (
    PASSWORDS,
    console_file,
    found,
    go,
    log_in,
    text_in,
    wait,
)
from tests.modbus import Client, read_holding
from tests.ops import wait_for
from tests.peers.single_client_device import LATE_REGISTER, SingleClientDevice

pytestmark = pytest.mark.integration

INVERTER = 40               # the TCP face's units 40-49 go to line inverter
PANEL_UNIT = 7              # what the serial master asks on line panel
STOUT_MS = 300
ROUTES = [{"units": "40-49", "line": "inverter"}]


def reply(start: int, count: int) -> bytes:
    """The emulator's: holding register n holds 100 + n."""
    return bytes((3, 2 * count)) + b"".join((100 + start + i).to_bytes(2, "big")
                                            for i in range(count))


class RemoteAndPanel:
    """`mbgw slave` without [serial]: line inverter at the device emulator's address, line
    panel in master mode on a pty pair (the test is the master on its other end)."""

    def __init__(self, directory) -> None:
        self.device = SingleClientDevice(delays=(0.001, 0.005), late_s=STOUT_MS / 1000 + 0.5)
        self.panel = PtyPair(directory)
        self.path = directory / "mbgw.toml"
        self.url = console_file(self.path, [
            "[net]", "exception = true",
            "[[line]]", 'name = "inverter"', f'connect = "{self.device.url}"',
            f"stout = {STOUT_MS}",
            "[[line]]", 'name = "panel"', f'device = "{self.panel.gateway}"',
            "baudrate = 19200", 'mode = "master"',
            "[[route]]", 'units = "40-49"', 'line = "inverter"'], PASSWORDS)
        self.gw = Gateway(directory, None, "--config", str(self.path))
        self.modbus = Client(self.gw.port)

    def stop(self) -> None:
        self.modbus.close()
        self.gw.stop()
        self.panel.stop()
        self.device.stop()


@pytest.fixture(scope="module")
def daemon(tmp_path_factory):
    running = RemoteAndPanel(tmp_path_factory.mktemp("remote"))
    yield running
    running.stop()


def inverter(s: dict) -> dict:
    return next(r for r in s["lines"] if r["name"] == "inverter")


def test_a_remote_line_s_page_shows_its_state_reconnects_and_stray_replies(browser, daemon):
    c = daemon.modbus
    assert c.ask(INVERTER, read_holding(0, 2)) == reply(0, 2)
    assert c.ask(INVERTER, read_holding(LATE_REGISTER, 1)) == b"\x83\x0b"     # too late
    # the late reply comes while the line is idle: stray
    wait_for(daemon.gw, lambda s: inverter(s)["counters"]["stray_replies"] == 1, "1 stray")
    daemon.device.close_connection()                    # the device ends it: opened again
    assert c.ask(INVERTER, read_holding(4, 1)) == reply(4, 1)
    s = wait_for(daemon.gw, lambda s: inverter(s)["counters"]["reconnects"] == 1,
                 "1 reconnect")
    assert daemon.device.connections == 2
    log_in(browser, daemon, "admin")
    browser.get(daemon.url + "#lines/inverter")
    page = '#line-page[data-line="inverter"]'
    wait(browser, text_in(f'{page} #line-settings tr[data-name="connect"] td', daemon.device.url))
    wait(browser, text_in(f'{page} #line-state tr[data-name="state"] td', "open"))
    assert inverter(s)["state"] == "up"
    reconnects = browser.find_element(
        By.CSS_SELECTOR, f'{page} #line-state tr[data-name="reconnects"] td').text
    assert reconnects == "1: the connection to the device was opened again once", reconnects
    stray = browser.find_element(
        By.CSS_SELECTOR, f'{page} #line-state tr[data-name="stray_replies"] td').text
    assert stray == "1 dropped: late, twice, or answering no request", stray
    wait(browser, text_in(f'{page} #line-settings tr[data-name="stout_ms"] td', "300 ms"))
    wait(browser, found(f'{page} #line-devices tr[data-address="{INVERTER}"]'))


def serial_master(daemon) -> ModbusSerialClient:
    master = ModbusSerialClient(daemon.panel.device, baudrate=19200, timeout=1, retries=0)
    assert master.connect()
    return master


def test_a_route_from_a_serial_face_added_in_the_browser(browser, daemon):
    admin = Api(daemon.url)
    assert admin.log_in("admin", PASSWORDS["admin"]) == 200
    assert admin.call("GET", "/api/routes")[1]["routes"] == ROUTES
    master = serial_master(daemon)
    try:
        with pytest.raises(ModbusIOException):          # no route: nobody answers unit 7
            master.read_holding_registers(5, count=2, device_id=PANEL_UNIT)
        asked = len(daemon.device.requests)
        log_in(browser, daemon, "admin")
        go(browser, "lines")
        wait(browser, found("#routes-edit tbody tr"))
        browser.find_element(By.ID, "routes-add").click()
        row = editor_row(browser, 2)
        choose(row, "from", "panel")
        fill(row, "units", str(PANEL_UNIT))
        choose(row, "target", "line:inverter")
        choose(row, "rewrite", "address")
        fill(row, "amount", str(INVERTER + 2))
        apply(browser, daemon)
        assert 'from = "panel"\nunits = "7"\nline = "inverter"\naddress = 42' in \
            daemon.path.read_text()
        answer = master.read_holding_registers(5, count=2, device_id=PANEL_UNIT)
        assert not answer.isError() and answer.registers == [105, 106], answer
        # on the wire: the device got the serial master's read, to address 42
        assert daemon.device.requests[asked:] == [(INVERTER + 2, read_holding(5, 2))]
        wait(browser, lambda d: any(
            [td.text for td in tr.find_elements(By.CSS_SELECTOR, "td")][:3] ==
            ["line panel", "7", "line inverter"]
            for tr in d.find_elements(By.CSS_SELECTOR, "#routes-table tbody tr")))
        browser.get(daemon.url + "#lines/panel")    # the face's page lists its route too
        wait(browser, text_in('#line-page[data-line="panel"]', "line inverter"))
    finally:
        master.close()
        code, data = admin.call("POST", "/api/routes", {"routes": ROUTES})
        assert code == 200, data


@pytest.mark.parametrize("size", [DESKTOP, PHONE], ids=["desktop", "phone"])
def test_a_remote_line_s_page_is_no_wider_than_the_window(browser, daemon, size):
    with page_of_size(browser, size):
        assert daemon.modbus.ask(INVERTER, read_holding(0, 1)) == reply(0, 1)
        log_in(browser, daemon, "admin")
        browser.get(daemon.url + "#lines/inverter")
        wait(browser, found('#line-page[data-line="inverter"] #line-devices'))
        wait(browser, found("#routes-edit tbody tr"))
        assert_fits(browser, "line-remote-%dx%d" % size)
