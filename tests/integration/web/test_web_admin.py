"""The console's changes done through its pages, each seen from outside: several settings
applied by one reload; a password changed (the new one in, the old one not); the user role
refused every change (403, its buttons off); the Events page showing what the log got;
reload, restart and the factory reset (the shipped file back); a scenario created in the
browser polling the slave; a firewall rule refusing a write; the table in typed views; a
master-mode table client closed; firewall rules changed, moved and the default set; a
scenario changed in its form."""
import hashlib
import json
import os
import re
import subprocess
import sys
import urllib.error
import urllib.request
from functools import partial
from http.cookiejar import CookieJar
from types import SimpleNamespace

import pytest
from pymodbus.client import ModbusTcpClient
from pymodbus.exceptions import ModbusException
from selenium.webdriver.common.by import By
from selenium.webdriver.support import expected_conditions as EC
from selenium.webdriver.support.ui import Select

import mbgw
from tests.harness import Gateway, PtyPair, free_port
from tests.integration.web.test_web_ui import (
    GREEN,
    LOST,
    PASSWORDS,
    TABLE_UNIT,
    Console,
    found,
    go,
    log_in,
    scenarios,
    set_password,
    text_in,
    wait,
)
from tests.modbus import Client, read_holding
from tests.ops import wait_for, wait_for_log
from tests.wait import until

pytestmark = pytest.mark.integration

RELOADED = "configuration reloaded: "
NEW_PASSWORD = "a new user secret 3"
ADMIN_ACTIONS = ["#password-change", "#admin-reload", "#admin-restart",
                 "#admin-factory-reset", "#config-apply"]


class Api:
    """The JSON API as a script sees it: a session's cookie and CSRF token."""

    def __init__(self, url: str) -> None:
        self.url = url
        self.opener = urllib.request.build_opener(urllib.request.HTTPCookieProcessor(
            CookieJar()))
        self.csrf = ""

    def call(self, method: str, path: str, body: dict | None = None) -> tuple[int, dict]:
        request = urllib.request.Request(
            self.url + path.lstrip("/"), method=method,
            data=None if body is None else json.dumps(body).encode(),
            headers={"Content-Type": "application/json", "X-CSRF-Token": self.csrf})
        try:
            with self.opener.open(request, timeout=15) as response:
                return response.status, json.loads(response.read() or b"{}")
        except urllib.error.HTTPError as err:
            return err.code, json.loads(err.read() or b"{}")

    def log_in(self, role: str, password: str) -> int:
        code, data = self.call("POST", "/api/login", {"user": role, "password": password})
        self.csrf = data.get("csrf", "")
        return code


@pytest.fixture(scope="module")
def console(tmp_path_factory):
    running = Console(tmp_path_factory.mktemp("admin"))
    yield running
    running.stop()


def field(browser, name: str):
    return wait(browser, found(f'[data-field="{name}"]'))


def test_several_settings_are_applied_by_one_reload(browser, console):
    log_in(browser, console, "admin")
    go(browser, "config")
    reloads = console.gw.log().count(RELOADED)
    stout = field(browser, "serial.stout")
    stout.clear()
    stout.send_keys("250")
    retries = field(browser, "serial.retries")
    retries.clear()
    retries.send_keys("2")
    exception = Select(field(browser, "net.exception"))
    flipped = {"on": "off", "off": "on"}[exception.first_selected_option.text]
    exception.select_by_value(flipped)
    browser.find_element(By.ID, "config-apply").click()
    wait(browser, text_in("#config-apply-result", "applied by one reload"))
    text = console.path.read_text()
    assert "stout = 250" in text and "retries = 2" in text
    assert f"exception = {'true' if flipped == 'on' else 'false'}" in text
    s = wait_for(console.gw, lambda s: s["serial"]["stout_ms"] == 250, "the new stout")
    assert console.gw.log().count(RELOADED) == reloads + 1, console.gw.log()
    assert s["serial"]["stout_ms"] == 250


def test_one_bad_setting_refuses_them_all_next_to_its_field(browser, console):
    log_in(browser, console, "admin")
    go(browser, "config")
    before = console.path.read_bytes()
    reloads = console.gw.log().count(RELOADED)
    stout = field(browser, "serial.stout")
    stout.clear()
    stout.send_keys("300")
    retries = field(browser, "serial.retries")
    retries.clear()
    retries.send_keys("many")
    browser.find_element(By.ID, "config-apply").click()
    wait(browser, text_in('[data-error-for="serial.retries"]', "retries"))
    assert "error" in browser.find_element(By.ID, "config-apply-result").get_attribute("class")
    assert console.path.read_bytes() == before
    assert console.gw.log().count(RELOADED) == reloads


def test_groups_of_other_modes_are_hidden_and_keys_have_help_units_and_choices(browser,
                                                                              console):
    log_in(browser, console, "admin")
    go(browser, "config")
    wait(browser, found('fieldset[data-group="serial"]'))
    groups = [f.get_attribute("data-group")
              for f in browser.find_elements(By.CSS_SELECTOR, "#config-groups fieldset")]
    assert "transparent" not in groups and "serial" in groups, groups
    assert browser.find_elements(By.CSS_SELECTOR, '[data-field="table.address"]') == []
    row = browser.find_element(By.CSS_SELECTOR, '.config-row[data-key="serial.stout"]')
    assert row.find_element(By.CSS_SELECTOR, ".unit").text == "ms"
    assert "end of its answer" in row.find_element(By.CSS_SELECTOR, ".help").text
    choices = [o.get_attribute("value") for o in
               Select(field(browser, "serial.format")).options]
    assert "8n1" in choices and "7e1" in choices
    assert Select(field(browser, "serial.protocol")).first_selected_option.text == "rtu"
    wait_for_log(console.gw, "web login")


# Every control of a page that changes something (the Lines page's: test_web_lines.py).
USER_OFF = {
    "clients": ["#clients-table button.close-client"],
    "scenarios": ["button.disable", "input.tick", "#scenario-save", "#scenario-test",
                  "#scenarios-delete", "#sc-name", "#sc-function", "#scenario-save-form",
                  "#scenario-try"],
    "table": ["#table-write-address", "#table-write-values", "#table-write"],
    "stats": ["#stats-reset"],
    "config": ["button.config-save", "#config-apply", "#config-upload-file", "#config-upload"],
    "firewall": ["#firewall-default", "#firewall-add", "#firewall-apply"],
    "admin": ["#password-role", "#password-current", "#password-change", "#admin-reload",
              "#admin-restart", "#admin-factory-reset"],
}


def test_the_user_role_can_change_nothing(browser, console):
    modbus = Client(console.gw.port)                # a row on Clients, with its Close
    try:
        modbus.ask(TABLE_UNIT, read_holding(0, 1))
        log_in(browser, console, "user")
        for page, controls in USER_OFF.items():
            go(browser, page)
            for control in controls:
                assert not wait(browser, found(control)).is_enabled(), (page, control)
            enabled = [e.get_attribute("outerHTML")[:80] for e in browser.find_elements(
                By.CSS_SELECTOR, "#page .admin-only") if e.is_enabled()]
            assert enabled == [], (page, enabled)
    finally:
        modbus.close()
    api = Api(console.url)
    assert api.log_in("user", PASSWORDS["user"]) == 200
    before = console.path.read_bytes()
    for path, body in (("/api/password", {"role": "user", "current": PASSWORDS["user"],
                                           "new": NEW_PASSWORD, "again": NEW_PASSWORD}),
                       ("/api/reload", {}), ("/api/restart", {}),
                       ("/api/factory-reset", {"confirm": True}),
                       ("/api/scenarios/config", {"remove": ["boiler"], "add": []}),
                       ("/api/scenarios/boiler/enable", {"save": True}),
                       ("/api/firewall", {"default": "deny", "rules": []}),
                       ("/api/config", {"changes": [{"group": "serial", "key": "stout",
                                                     "value": "400"}]})):
        code, data = api.call("POST", path, body)
        assert code == 403, (path, data)
    assert api.call("GET", "/api/events")[0] == 200 and api.call("GET", "/api/system")[0] == 200
    assert console.path.read_bytes() == before


def test_a_short_password_or_a_wrong_current_one_changes_nothing(browser, console):
    before = console.path.read_bytes()
    log_in(browser, console, "admin")
    go(browser, "admin")
    Select(wait(browser, found("#password-role"))).select_by_value("user")
    browser.find_element(By.ID, "password-current").send_keys(PASSWORDS["admin"])
    for field_id in ("password-new", "password-again"):
        browser.find_element(By.ID, field_id).send_keys("9 letters")
    browser.find_element(By.ID, "password-change").click()
    wait(browser, text_in("#password-result", "at least 10 characters"))
    api = Api(console.url)
    assert api.log_in("admin", PASSWORDS["admin"]) == 200
    short = {"role": "user", "current": PASSWORDS["admin"], "new": "9 letters",
             "again": "9 letters"}
    code, data = api.call("POST", "/api/password", short)        # the gateway checks too
    assert code == 400 and "10" in data["error"], data
    code, data = api.call("POST", "/api/password", {**short, "current": "not the password",
                                                    "new": NEW_PASSWORD, "again": NEW_PASSWORD})
    assert code == 403, data
    assert console.path.read_bytes() == before
    assert Api(console.url).log_in("user", PASSWORDS["user"]) == 200


def test_a_password_changed_lets_the_new_one_in_and_the_old_one_not(browser, console):
    log_in(browser, console, "admin")
    go(browser, "admin")
    Select(wait(browser, found("#password-role"))).select_by_value("user")
    browser.find_element(By.ID, "password-current").send_keys(PASSWORDS["admin"])
    browser.find_element(By.ID, "password-new").send_keys(NEW_PASSWORD)
    browser.find_element(By.ID, "password-again").send_keys(NEW_PASSWORD[:-1])
    browser.find_element(By.ID, "password-change").click()
    wait(browser, text_in("#password-result", "differ"))
    browser.find_element(By.ID, "password-again").send_keys(NEW_PASSWORD[-1])
    browser.find_element(By.ID, "password-change").click()
    # the change ends every session: the page's next refresh may show the login form before
    # the result is read, so either says it went through (the API checks below say it did)
    wait(browser, lambda d: any("log in again" in e.text for e in d.find_elements(
        By.ID, "password-result")) or d.find_element(By.ID, "login-form").is_displayed())
    api = Api(console.url)
    assert api.log_in("user", PASSWORDS["user"]) == 401
    assert api.log_in("user", NEW_PASSWORD) == 200
    assert "user-password" in console.path.read_text()
    wait(browser, EC.visibility_of_element_located((By.ID, "login-form")))  # sessions ended


def test_the_events_page_shows_what_the_log_got_newest_first(browser, console):
    wait_for_log(console.gw, f"scenario {LOST} (slave 9): ")
    # its own refused login and change: the test must not lean on others having run first
    assert Api(console.url).log_in("admin", "not the password") != 200
    admin = Api(console.url)
    assert admin.log_in("admin", PASSWORDS["admin"]) == 200
    assert admin.call("POST", "/api/config", {"changes": [
        {"group": "general", "key": "location", "value": "events page"}]})[0] == 200
    log_in(browser, console, "admin")
    go(browser, "events")
    wait(browser, text_in("#events-table", f"scenario {LOST} (slave 9): "))
    wait(browser, text_in("#events-table", "web login: admin"))
    events = Api(console.url)
    events.log_in("admin", PASSWORDS["admin"])
    shown = events.call("GET", "/api/events")[1]["events"]
    times = [e["time"] for e in shown]
    assert times == sorted(times, reverse=True)
    kinds = {e["event"] for e in shown}
    assert {"scenario-error", "login-ok", "login-failed", "config-changed"} <= kinds, kinds
    assert any(e["event"] == "device-down" and e.get("device") for e in shown), shown
    Select(browser.find_element(By.ID, "events-kind")).select_by_value("device-down")
    wait(browser, lambda d: {td.text for td in d.find_elements(
        By.CSS_SELECTOR, "#events-table td.event")} == {"device-down"})


def test_system_information_and_a_reload_from_the_page(browser, console):
    log_in(browser, console, "admin")
    go(browser, "admin")
    wait(browser, text_in('#system-table tr[data-name="file"] td', str(console.path)))
    digest = hashlib.sha256(console.path.read_bytes()).hexdigest()
    wait(browser, text_in('#system-table tr[data-name="sha256"] td', digest))
    assert browser.find_element(By.CSS_SELECTOR, '#system-table tr[data-name="host"] td').text \
        == os.uname().nodename
    system = Api(console.url)
    assert system.log_in("admin", PASSWORDS["admin"]) == 200
    ports = system.call("GET", "/api/system")[1]["serial_ports"]
    cell = partial(browser.find_element, By.CSS_SELECTOR)
    assert cell('#system-table tr[data-name="version"] td').text == mbgw.__version__
    assert " ago)" not in cell('#system-table tr[data-name="uptime"] td').text
    assert re.fullmatch(r"\d\d:\d\d:\d\d \(since \d{4}-\d\d-\d\d \d\d:\d\d:\d\d\)",
                        cell('#system-table tr[data-name="uptime"] td').text)
    shown = cell('#system-table tr[data-name="ports"] td').text
    assert shown == "none found" if not ports else all(
        p["device"] in shown and all(name in shown for name in p["by_id"]) for p in ports)
    reloads = console.gw.log().count(RELOADED)
    browser.find_element(By.ID, "admin-reload").click()
    wait(browser, text_in("#admin-reload-result", "configuration reloaded"))
    assert console.gw.log().count(RELOADED) == reloads + 1


def test_a_restart_runs_the_daemon_again_in_the_same_process(browser, console):
    log_in(browser, console, "admin")
    go(browser, "admin")
    started = console.gw.log().count("web console on ")
    pid = wait_for(console.gw, lambda s: True, "status")["pid"]
    wait(browser, found("#admin-restart")).click()
    wait(browser, EC.alert_is_present()).accept()
    wait(browser, text_in("#admin-restart-result", "restarting"))
    wait_for_log(console.gw, "web console on ", started + 1)
    assert wait_for(console.gw, lambda s: True, "status after the restart")["pid"] == pid
    log_in(browser, console, "admin")                        # the console is back


def test_a_scenario_created_in_the_browser_polls_the_slave_and_is_deleted(browser, console):
    log_in(browser, console, "admin")
    go(browser, "scenarios")
    wait(browser, found("#scenario-form"))
    for key, value in (("name", "pump"), ("slave", "1"), ("address", "4"), ("quantity", "2"),
                       ("table", "300"), ("cycle", "200")):
        element = browser.find_element(By.ID, f"sc-{key}")
        element.clear()
        element.send_keys(value)
    Select(browser.find_element(By.ID, "sc-function")).select_by_value("3")
    browser.find_element(By.ID, "scenario-try").click()          # a one-off poll: values
    wait(browser, text_in("#scenario-form-result", "answered in "))
    assert "{" not in browser.find_element(By.ID, "scenario-form-result").text
    browser.find_element(By.ID, "scenario-save-form").click()
    wait(browser, text_in("#scenario-form-result", "saved and applied"))
    assert 'name = "pump"' in console.path.read_text()
    wait_for(console.gw, lambda s: scenarios(s).get("pump", {}).get("successes", 0) > 0,
             "the new scenario polling the slave")
    row = 'tr[data-key="serial/pump"]'
    wait(browser, text_in(f"{row} td.place", "4 ×2 → table 300"))
    # the list: the device, the function and the trigger, as the status has them
    pump = scenarios(wait_for(console.gw, lambda s: True, "status"))["pump"]
    cells = [td.text for td in browser.find_elements(By.CSS_SELECTOR, f"{row} td")]
    assert [pump["target"], "3", pump["trigger"]] == [cells[3], cells[4], cells[6]], cells
    assert pump["target"] == "slave 1" and "200" in pump["trigger"], pump
    browser.find_element(By.CSS_SELECTOR, f"{row} button.duplicate").click()
    assert browser.find_element(By.ID, "sc-name").get_attribute("value") == "pump-copy"
    browser.find_element(By.ID, "scenario-save-form").click()
    wait(browser, text_in("#scenario-form-result", "pump-copy added"))
    wait(browser, found('tr[data-key="serial/pump-copy"]'))
    for name in ("pump", "pump-copy"):
        browser.find_element(By.CSS_SELECTOR, f'tr[data-key="serial/{name}"] input.tick').click()
    browser.find_element(By.ID, "scenarios-delete").click()
    wait(browser, EC.alert_is_present()).accept()
    wait(browser, text_in("#scenarios-message", "deleted"))
    assert "pump" not in console.path.read_text()
    wait_for(console.gw, lambda s: not {"pump", "pump-copy"} & set(scenarios(s)),
             "both scenarios gone")


def test_the_exchange_table_in_typed_views_with_zones_and_owners(browser, console):
    with ModbusTcpClient("127.0.0.1", port=console.gw.port) as modbus:
        assert not modbus.write_registers(0x1000, [0x4049, 0x0FDB, 0xFFFF, 0xFFFE, 0x4142],
                                          device_id=TABLE_UNIT).isError()
    log_in(browser, console, "admin")
    go(browser, "table")
    address = wait(browser, found("#table-address"))
    address.clear()
    address.send_keys("0x1000")
    view = Select(browser.find_element(By.ID, "table-view"))
    view.select_by_value("float32")
    cell = '#table-grid td.value[data-address="{}"]'
    wait(browser, text_in(cell.format(0x1000), "3.141593"))
    wait(browser, text_in("#table-grid tr.zone", "free zone 0x1000-0x7FFF"))   # rows rebuilt
    view.select_by_value("int32")
    wait(browser, text_in(cell.format(0x1002), "-2"))
    browser.find_element(By.ID, "table-swap-words").click()
    wait(browser, text_in(cell.format(0x1002), "-65537"))        # 0xFFFEFFFF
    view.select_by_value("ascii")
    browser.find_element(By.ID, "table-swap-bytes").click()
    wait(browser, text_in(cell.format(0x1004), "BA"))
    for swap in ("table-swap-words", "table-swap-bytes"):      # as the registers are again
        browser.find_element(By.ID, swap).click()
    view.select_by_value("uint32")
    wait(browser, text_in(cell.format(0x1002), "4294967294"))     # 0xFFFFFFFE
    view.select_by_value("int16")
    wait(browser, text_in(cell.format(0x1003), "-2"))
    view.select_by_value("hex")
    Select(browser.find_element(By.ID, "table-radix")).select_by_value("hex")
    wait(browser, text_in('#table-grid tr[data-address="4096"] th', "0x1000"))
    wait(browser, text_in(cell.format(0x1004), "0x4142"))
    # a dense grid: 16 registers a row
    assert len(browser.find_elements(
        By.CSS_SELECTOR, '#table-grid tr[data-address="4112"] td.value')) == 16
    Select(browser.find_element(By.ID, "table-radix")).select_by_value("dec")
    address.clear()
    address.send_keys("0")
    address.submit()
    wait(browser, text_in("#table-owners", "scenario boiler: 0-1"))
    # the grid is redrawn at each refresh: a cell read between two may have gone stale
    wait(browser, lambda d: "scenario boiler" in d.find_element(
        By.CSS_SELECTOR, cell.format(0)).get_attribute("title"))


def test_a_firewall_rule_added_in_the_browser_refuses_a_write(browser, console):
    def write() -> bool:
        with ModbusTcpClient("127.0.0.1", port=console.gw.port) as modbus:
            return not modbus.write_register(0x300, 5, device_id=TABLE_UNIT).isError()

    assert write()
    log_in(browser, console, "admin")
    go(browser, "firewall")
    wait(browser, found("#firewall-rules"))
    browser.find_element(By.ID, "firewall-add").click()
    rule = browser.find_element(By.CSS_SELECTOR, "#firewall-rules tr.rule")
    rule.find_element(By.CSS_SELECTOR, '[data-key="client"]').send_keys("127.0.0.1")
    rule.find_element(By.CSS_SELECTOR, '[data-key="read-only"]').click()
    browser.find_element(By.ID, "firewall-apply").click()
    wait(browser, text_in("#firewall-result", "configuration reloaded"))
    assert "[[rule]]" in console.path.read_text()
    assert not write()                                          # 0x01, by rule 1
    wait(browser, found("#firewall-rules tr.rule"))
    browser.refresh()
    wait(browser, text_in("#firewall-rules tr.rule td.refused", "1"))
    browser.find_element(By.CSS_SELECTOR, "#firewall-rules tr.rule button.delete").click()
    browser.find_element(By.ID, "firewall-apply").click()
    wait(browser, text_in("#firewall-result", "configuration reloaded"))
    assert "[[rule]]" not in console.path.read_text()
    assert write()


def test_device_details_on_demand_and_a_reset_of_the_counters_asked_first(browser, console):
    log_in(browser, console, "admin")
    go(browser, "devices")
    wait(browser, found('#devices-table tr[data-address="9"] button.details')).click()
    wait(browser, text_in("#devices-table tr.device-details", "Latency buckets"))
    go(browser, "stats")
    wait(browser, text_in('#stats-table tr[data-name="counters.requests"] td.rate', "/s"))
    headings = [h.text for h in browser.find_elements(By.CSS_SELECTOR, "#page-body h2")]
    assert {"Line", "Clients", "Devices", "Scenarios", "Table"} <= set(headings), headings
    wait(browser, text_in('#stats-table tr[data-name="counters_since"] td', " ago)"))
    browser.find_element(By.ID, "stats-reset").click()
    wait(browser, EC.alert_is_present()).dismiss()
    assert browser.find_element(By.ID, "stats-message").text == ""
    browser.find_element(By.ID, "stats-reset").click()
    wait(browser, EC.alert_is_present()).accept()
    wait(browser, text_in("#stats-message", "counters reset"))
    wait_for_log(console.gw, "counters reset by the operator (web admin@")


def test_a_factory_reset_puts_back_the_shipped_file(browser, tmp_path):
    shipped = tmp_path / "shipped.toml"
    done = subprocess.run([sys.executable, "-m", "mbgw", "config", "default", "--config",
                           str(shipped)], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    (tmp_path / "gateway").mkdir()
    console = Console(tmp_path / "gateway")     # its own: the reset leaves no passwords
    try:
        log_in(browser, console, "admin")
        go(browser, "admin")
        wait(browser, found("#admin-factory-reset")).click()
        wait(browser, EC.alert_is_present()).dismiss()             # asked first: no
        assert console.path.read_text() != shipped.read_text()
        browser.find_element(By.ID, "admin-factory-reset").click()
        wait(browser, EC.alert_is_present()).accept()
        wait(browser, text_in("#admin-factory-reset-result", "the shipped file is back"))
        assert console.path.read_text() == shipped.read_text()
    finally:
        console.stop()


def test_the_table_servers_clients_are_listed_and_closed_in_master_mode(browser, tmp_path):
    path = tmp_path / "mbgw.toml"
    web_port, table_port = free_port(), free_port()
    path.write_text(f'[serial]\nmode = "master"\n[web]\nlisten = "127.0.0.1:{web_port}"\n')
    set_password(path, "admin")
    pty = PtyPair(tmp_path)
    gw = Gateway(tmp_path, pty.gateway, "--config", str(path), "--table", "--table-port",
                 str(table_port), mode="master", listen=False)
    modbus = Client(table_port)
    try:
        modbus.ask(1, read_holding(0, 1))
        here = "127.0.0.1:%d" % modbus.sock.getsockname()[1]
        log_in(browser, SimpleNamespace(url=f"http://127.0.0.1:{web_port}/"), "admin")
        go(browser, "clients")
        row = wait(browser, lambda d: [r for r in d.find_elements(
            By.CSS_SELECTOR, "#clients-table tbody tr") if here in r.text])[0]
        row.find_element(By.CSS_SELECTOR, "button.close-client").click()
        wait(browser, EC.alert_is_present()).accept()
        wait(browser, text_in("#clients-message", "closed"))
        modbus.sock.settimeout(15)
        assert modbus.sock.recv(1) == b""
    finally:
        modbus.close()
        gw.stop()
        pty.stop()


def table_write_ok(console) -> bool:
    """A Modbus TCP client's write to the table: True if the gateway took it."""
    with ModbusTcpClient("127.0.0.1", port=console.gw.port) as modbus:
        try:
            return not modbus.write_register(0x310, 5, device_id=TABLE_UNIT).isError()
        except ModbusException:
            return False


def apply_rules(browser, confirm: bool = False) -> None:
    """Apply the page's rules; wait for the reload and the rules read again."""
    old = browser.find_elements(By.CSS_SELECTOR, "#firewall-rules tr.rule")
    browser.find_element(By.ID, "firewall-apply").click()
    if confirm:
        wait(browser, EC.alert_is_present()).accept()       # deny: asked first
    wait(browser, text_in("#firewall-result", "configuration reloaded"))
    for row in old:
        wait(browser, EC.staleness_of(row))


def rule_row(browser, index: int):
    return wait(browser, found(f"#firewall-rules tr.rule:nth-child({index})"))


def test_firewall_rules_changed_moved_and_the_default_set_in_the_browser(browser, console):
    assert table_write_ok(console)
    log_in(browser, console, "admin")
    go(browser, "firewall")
    wait(browser, found("#firewall-rules"))
    for read_only in (True, False):           # rule 1 read only, rule 2 anything: 1 decides
        browser.find_element(By.ID, "firewall-add").click()
        rule = browser.find_elements(By.CSS_SELECTOR, "#firewall-rules tr.rule")[-1]
        rule.find_element(By.CSS_SELECTOR, '[data-key="client"]').send_keys("127.0.0.1")
        if read_only:
            rule.find_element(By.CSS_SELECTOR, '[data-key="read-only"]').click()
    apply_rules(browser)
    assert not table_write_ok(console)
    rule_row(browser, 2).find_element(By.CSS_SELECTOR, "button.up").click()   # moved up
    apply_rules(browser)
    assert table_write_ok(console)                     # the unrestricted rule decides now
    assert console.path.read_text().index("read-only = true") > \
        console.path.read_text().rindex('client = ["127.0.0.1"]')
    client = rule_row(browser, 1).find_element(By.CSS_SELECTOR, '[data-key="client"]')
    client.clear()
    client.send_keys("127.0.0.2")                     # changed: it no longer selects us
    apply_rules(browser)
    assert not table_write_ok(console)
    assert 'client = ["127.0.0.2"]' in console.path.read_text()
    for _ in range(2):
        rule_row(browser, 1).find_element(By.CSS_SELECTOR, "button.delete").click()
    Select(browser.find_element(By.ID, "firewall-default")).select_by_value("deny")
    apply_rules(browser, confirm=True)
    assert not table_write_ok(console)                 # no rule: the default denies
    Select(browser.find_element(By.ID, "firewall-default")).select_by_value("allow")
    apply_rules(browser)
    assert table_write_ok(console)
    assert "[[rule]]" not in console.path.read_text()
    go(browser, "events")                     # the refusals are events, as the journal's
    Select(wait(browser, found("#events-kind"))).select_by_value("firewall-refused")
    wait(browser, lambda d: {td.text for td in d.find_elements(
        By.CSS_SELECTOR, "#events-table td.event")} == {"firewall-refused"})


def test_a_scenario_changed_in_the_browser_polls_its_new_place(browser, console):
    with ModbusTcpClient("127.0.0.1", port=console.gw.port) as modbus:
        assert modbus.read_holding_registers(0, count=2, device_id=TABLE_UNIT).registers == \
            [100, 101]                                # boiler: the slave's 0-1 at table 0
    admin = Api(console.url)
    assert admin.log_in("admin", PASSWORDS["admin"]) == 200
    original = next(t for t in admin.call("GET", "/api/scenarios/config")[1]["scenarios"]
                    if t["name"] == "boiler")
    log_in(browser, console, "admin")
    go(browser, "scenarios")
    lost = f'#scenarios-table tr[data-key="serial/{LOST}"] td.error-since'
    wait(browser, text_in(lost, " ago)"))                     # in error since when
    wait(browser, found('tr[data-key="serial/boiler"] button.edit')).click()
    assert browser.find_element(By.ID, "sc-name").get_attribute("value") == "boiler"
    address = browser.find_element(By.ID, "sc-address")
    address.clear()
    address.send_keys("6")
    browser.find_element(By.ID, "scenario-save-form").click()
    wait(browser, text_in("#scenario-form-result", "saved and applied"))
    try:
        assert "address = 6" in console.path.read_text()
        assert console.path.read_text().count('name = "boiler"') == 1    # changed, not added
        with ModbusTcpClient("127.0.0.1", port=console.gw.port) as modbus:
            until(lambda: modbus.read_holding_registers(
                0, count=2, device_id=TABLE_UNIT).registers == [106, 107],
                "the slave's 6-7 in the table", 10)
        wait(browser, text_in('tr[data-key="serial/boiler"] td.place', "6 ×2 → table 0"))
    finally:
        code, data = admin.call("POST", "/api/scenarios/config",
                                {"remove": ["boiler"], "add": [original]})
        assert code == 200, data


BLUE = "rgba(30, 100, 200, 1)"        # VPGate's starting


def test_a_change_scenario_is_blue_until_the_table_changes_then_green(browser, console):
    """VPGate's starting blue: a scenario sent on a change has not run until the table's
    register changes; then it writes the pymodbus slave and is running, green."""
    admin = Api(console.url)
    assert admin.log_in("admin", PASSWORDS["admin"]) == 200
    valve = {"name": "valve", "slave": 1, "function": 6, "address": 30, "table": 0x320,
             "trigger": "change"}
    code, data = admin.call("POST", "/api/scenarios/config", {"remove": [], "add": [valve]})
    assert code == 200, data
    try:
        log_in(browser, console, "admin")
        go(browser, "scenarios")
        badge = '#scenarios-table tr[data-key="serial/valve"] span.state'
        wait(browser, text_in(badge, "starting"))
        assert browser.find_element(By.CSS_SELECTOR, badge).value_of_css_property(
            "background-color") == BLUE
        with ModbusTcpClient("127.0.0.1", port=console.gw.port) as modbus:
            assert not modbus.write_register(0x320, 77, device_id=TABLE_UNIT).isError()
            wait_for(console.gw, lambda s: scenarios(s)["valve"]["successes"] > 0,
                     "valve's write sent")
            assert modbus.read_holding_registers(30, count=1, device_id=1).registers == [77]
        wait(browser, text_in(badge, "running"))
        assert browser.find_element(By.CSS_SELECTOR, badge).value_of_css_property(
            "background-color") == GREEN
    finally:
        code, data = admin.call("POST", "/api/scenarios/config",
                                {"remove": ["valve"], "add": []})
        assert code == 200, data


def test_a_scenario_the_checks_refuse_is_named_and_nothing_is_written(browser, console):
    """The toolbox checks as `mbgw config scenario add` does: a quantity over the function's
    limit (125 registers, Modbus application protocol 6.3) is refused, nothing written."""
    before = console.path.read_bytes()
    reloads = console.gw.log().count(RELOADED)
    log_in(browser, console, "admin")
    go(browser, "scenarios")
    wait(browser, found("#scenario-form"))
    for key, value in (("name", "too-many"), ("slave", "1"), ("address", "0"),
                       ("quantity", "126"), ("table", "500"), ("cycle", "1000")):
        element = browser.find_element(By.ID, f"sc-{key}")
        element.clear()
        element.send_keys(value)
    Select(browser.find_element(By.ID, "sc-function")).select_by_value("3")
    browser.find_element(By.ID, "scenario-save-form").click()
    wait(browser, lambda d: "error" in d.find_element(
        By.ID, "scenario-form-result").get_attribute("class").split())
    said = browser.find_element(By.ID, "scenario-form-result").text
    assert "too-many" in said and "quantity" in said, said
    assert console.path.read_bytes() == before
    assert console.gw.log().count(RELOADED) == reloads
