"""The Lines page: a page per line (settings, state, load, devices with their next probe),
the route map, and the routes edited in the browser, each change seen by a Modbus TCP client:
two serial lines over socat ptys, a pymodbus RTU slave on each with other register values.
The user role gets 403 from the route API and no enabled control.  No sideways scroll at a
desktop's and a phone's width; screenshots kept in artifacts/console/."""
import pytest
from selenium.webdriver.common.by import By

from tests.harness import Gateway, Peer, PtyPair
from tests.integration.web.chrome import ARTIFACTS, DESKTOP, PHONE, assert_fits, page_of_size
from tests.integration.web.test_web_admin import RELOADED, Api
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

pytestmark = pytest.mark.integration

UNIT = 5                    # routed nowhere at first; slave A and slave B both answer it
SILENT = 3                  # routed to line serial, where nobody answers: down, then probed
VALUE_A, VALUE_B = 100, 500     # holding register 0 of the slave on line serial, on line beta
FIRST_ROUTE = {"units": "1-4", "line": "serial"}
NO_ROUTE = bytes((0x83, 0x0A))  # exception 0x0A: no route for the unit


class TwoLines:
    """`mbgw slave` with line serial and line beta, a pymodbus slave on each (A answers 1
    and 5, B answers 5), the console on, and unit 5 routed nowhere."""

    def __init__(self, directory) -> None:
        self.pairs = {}
        for name in ("serial", "beta"):
            (directory / name).mkdir()
            self.pairs[name] = PtyPair(directory / name)
        self.peers = [
            Peer("pymodbus_slave.py", self.pairs["serial"].device, "1", str(UNIT),
                 "--silent-unknown", "--holding", str(VALUE_A)),
            Peer("pymodbus_slave.py", self.pairs["beta"].device, str(UNIT), "--silent-unknown",
                 "--holding", str(VALUE_B))]
        self.path = directory / "mbgw.toml"
        self.url = console_file(self.path, [
            "[net]", "exception = true",
            "[serial]", f'device = "{self.pairs["serial"].gateway}"', "baudrate = 19200",
            "stout = 300",      # pymodbus on a busy machine: no timeout but the silent one
            "[[line]]", 'name = "beta"', f'device = "{self.pairs["beta"].gateway}"',
            "baudrate = 38400", "stout = 400", 'format = "8e1"',
            "[[route]]", 'units = "1-4"', 'line = "serial"'], PASSWORDS)
        self.gw = Gateway(directory, None, "--config", str(self.path))
        self.modbus = Client(self.gw.port)

    def read(self, unit: int) -> bytes:
        return self.modbus.ask(unit, read_holding(0, 1))

    def stop(self) -> None:
        self.modbus.close()
        self.gw.stop()
        for peer in self.peers:
            peer.stop()
        for pair in self.pairs.values():
            pair.stop()


def value(reply: bytes) -> int:
    assert reply[:2] == bytes((3, 2)), reply
    return int.from_bytes(reply[2:4], "big")


@pytest.fixture(scope="module")
def daemon(tmp_path_factory):
    running = TwoLines(tmp_path_factory.mktemp("lines"))
    yield running
    running.stop()


@pytest.fixture
def admin(daemon):
    """The API as the admin, with the file's routes back to the first one."""
    api = Api(daemon.url)
    assert api.log_in("admin", PASSWORDS["admin"]) == 200
    if api.call("GET", "/api/routes")[1]["routes"] != [FIRST_ROUTE]:
        code, data = api.call("POST", "/api/routes", {"routes": [FIRST_ROUTE]})
        assert code == 200, data
    return api


def editor_row(browser, index: int):
    return wait(browser, found(f"#routes-edit tbody tr:nth-child({index})"))


def fill(row, key: str, text: str) -> None:
    field = row.find_element(By.CSS_SELECTOR, f'[data-key="{key}"]')
    field.clear()
    field.send_keys(text)


def choose(row, key: str, value: str) -> None:
    row.find_element(By.CSS_SELECTOR, f'[data-key="{key}"] option[value="{value}"]').click()


def outcome(browser) -> str:
    """The editor's outcome once there is one: "ok ..." or "error ..." with its words."""
    result = browser.find_element(By.ID, "routes-result")
    kind = result.get_attribute("class").split()
    return next((f"{k} {result.text}" for k in ("ok", "error") if k in kind), "")


def apply(browser, daemon) -> None:
    """Apply the editor's routes: one reload applies them all."""
    reloads = daemon.gw.log().count(RELOADED)
    browser.find_element(By.ID, "routes-apply").click()
    done = wait(browser, outcome)
    assert done.startswith("ok configuration reloaded"), done
    assert daemon.gw.log().count(RELOADED) == reloads + 1


def lines_page(browser, daemon, role: str = "admin") -> None:
    log_in(browser, daemon, role)
    go(browser, "lines")
    wait(browser, found("#routes-edit tbody tr"))


def test_a_route_added_in_the_browser_sends_the_unit_to_the_other_line(browser, daemon,
                                                                         admin):
    assert daemon.read(UNIT) == NO_ROUTE
    assert value(daemon.read(1)) == VALUE_A
    lines_page(browser, daemon)
    browser.find_element(By.ID, "routes-add").click()
    row = editor_row(browser, 2)
    fill(row, "units", str(UNIT))
    choose(row, "target", "line:beta")
    apply(browser, daemon)
    assert 'units = "5"\nline = "beta"' in daemon.path.read_text()
    assert value(daemon.read(UNIT)) == VALUE_B
    # the route map shows it, from the Modbus TCP face to line beta, as the file's
    wait(browser, lambda d: any(
        [td.text for td in tr.find_elements(By.CSS_SELECTOR, "td")] ==
        ["Modbus TCP", "5", "line beta", "as is", "the file's"]
        for tr in d.find_elements(By.CSS_SELECTOR, "#routes-table tbody tr")))


def test_a_route_changed_then_deleted_in_the_browser(browser, daemon, admin):
    code, data = admin.call("POST", "/api/routes", {"routes": [
        FIRST_ROUTE, {"units": str(UNIT), "line": "beta"}]})
    assert code == 200, data
    assert value(daemon.read(UNIT)) == VALUE_B
    lines_page(browser, daemon)
    row = editor_row(browser, 2)
    choose(row, "target", "line:serial")
    apply(browser, daemon)
    assert value(daemon.read(UNIT)) == VALUE_A            # line serial's slave now
    row = editor_row(browser, 2)
    assert row.find_element(By.CSS_SELECTOR, '[data-key="target"]').get_attribute(
        "value") == "line:serial"
    row.find_element(By.CSS_SELECTOR, "button.delete").click()
    apply(browser, daemon)
    assert daemon.read(UNIT) == NO_ROUTE
    assert admin.call("GET", "/api/routes")[1]["routes"] == [FIRST_ROUTE]


def test_a_refused_route_names_its_key_and_nothing_is_written(browser, daemon, admin):
    before = daemon.path.read_bytes()
    reloads = daemon.gw.log().count(RELOADED)
    lines_page(browser, daemon)
    browser.find_element(By.ID, "routes-add").click()
    row = editor_row(browser, 2)
    fill(row, "units", "3-6")                   # 3 and 4 are route 1's already
    choose(row, "target", "line:beta")
    browser.find_element(By.ID, "routes-apply").click()
    refused = wait(browser, outcome)
    assert refused.startswith("error ") and "route 2.units" in refused, refused
    assert "invalid" in row.find_element(By.CSS_SELECTOR, '[data-key="units"]').get_attribute(
        "class")
    assert daemon.path.read_bytes() == before
    assert daemon.gw.log().count(RELOADED) == reloads


def test_the_user_role_gets_403_and_no_enabled_control(browser, daemon, admin):
    before = daemon.path.read_bytes()
    api = Api(daemon.url)
    assert api.log_in("user", PASSWORDS["user"]) == 200
    assert api.call("GET", "/api/routes")[0] == 200
    code, data = api.call("POST", "/api/routes", {"routes": []})
    assert code == 403, data
    assert daemon.path.read_bytes() == before
    lines_page(browser, daemon, "user")
    controls = browser.find_elements(By.CSS_SELECTOR, "#route-editor input, "
                                     "#route-editor select, #route-editor button")
    assert controls and not [c for c in controls if c.is_enabled()]


def test_a_line_s_page_shows_its_settings_load_and_a_device_s_next_probe(browser, daemon):
    for _ in range(3):                      # three timeouts in a row: address 3 is down
        assert daemon.read(SILENT) == bytes((0x83, 0x0B))
    wait_for(daemon.gw, lambda s: any(d["address"] == SILENT and d["health"] == "down"
                                      for d in s["devices"]), "address 3 down")
    log_in(browser, daemon, "admin")
    browser.get(daemon.url + "#lines/serial")
    row = f'#line-page[data-line="serial"] #line-devices tr[data-address="{SILENT}"]'
    wait(browser, text_in(f"{row} td.next-probe", "in "))
    wait(browser, text_in(f"{row} td.health-down", "down"))
    wait(browser, text_in('#line-state tr[data-name="requests_per_s"] td', "/s"))
    wait(browser, text_in('#line-state tr[data-name="state_since"] td', " ago)"))
    browser.get(daemon.url + "#lines/beta")     # the other line's page, its settings in words
    settings = '#line-page[data-line="beta"] #line-settings'
    wait(browser, text_in(f'{settings} tr[data-name="baudrate"] td', "38400 bit/s"))
    wait(browser, text_in(f'{settings} tr[data-name="format"] td',
                          "8 data bits, even parity, 1 stop bit"))
    wait(browser, text_in(f'{settings} tr[data-name="stout_ms"] td', "400 ms"))


@pytest.mark.parametrize("size", [DESKTOP, PHONE], ids=["desktop", "phone"])
def test_the_lines_page_is_no_wider_than_the_window(browser, daemon, size):
    with page_of_size(browser, size):
        assert value(daemon.read(UNIT - 4)) == VALUE_A         # a device with figures
        lines_page(browser, daemon)
        browser.get(daemon.url + "#lines/serial")
        wait(browser, found('#line-page[data-line="serial"] #line-devices'))
        wait(browser, text_in('#line-state tr[data-name="busy"] td', "%"))
        wait(browser, found("#routes-edit tbody tr"))
        assert_fits(browser, "line-serial-%dx%d" % size)
        browser.execute_script("document.getElementById('routes-table').scrollIntoView()")
        browser.save_screenshot(str(ARTIFACTS / ("routes-%dx%d.png" % size)))
